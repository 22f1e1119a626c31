"""The torus's steps on an array namespace (``ensemble.device = "gpu"`` runs
them on CuPy), run here with numpy standing in for CuPy: a module that is not
numpy itself but holds numpy's functions, so that the namespace path (the
basis built on it, the refusals, the host transfers) runs while the
operations are those of the CPU.  The kernels are written once over the array
module, so the stand-in gives the CPU's arrays bit for bit."""

from __future__ import annotations

import sys
import types

import numpy as np
import pytest

from liethermo.scene import load_scene
from liethermo.torus import kernels as tk
from liethermo.torus import run as tr
from liethermo.torus import step as ts

#: numpy under another name: the steps take the array-namespace path with numpy's operations
XP = types.ModuleType("numpy_standing_in_for_cupy")
XP.__dict__.update({k: getattr(np, k) for k in dir(np) if not k.startswith("__")})

SMALL = {"torus.N": 9, "ensemble.members": 3, "integrator.steps": 20, "output.every": 5,
         "output.vorticity": True, "output.entropy_field": True, "output.compare": [], "output.figures": False}


def _runs(name, **over):
    sc = load_scene(name, {**SMALL, **over})
    W0, S0 = tr.initial_fields(sc, np.arange(int(sc["ensemble"]["members"])))
    return sc, W0, S0, tr.integrate(sc, W0, S0, progress=False), tr.integrate_xp(XP, sc, W0, S0, progress=False)


def _same(a: tr.Trajectory, b: tr.Trajectory) -> list[str]:
    """The names of the arrays in which two runs differ (the kept W and S, every diagnostic, the flags)."""
    names = ("W", "S", "kinetic", "internal", "potential", "entropy", "enstrophy", "theta_min", "theta_max",
             "temperature_min", "temperature_max", "cas")
    bad = [n for n in names if not np.array_equal(getattr(a.out, n), getattr(b.out, n), equal_nan=True)]
    bad += [n for n in ("iterations", "status", "failed_step") if not np.array_equal(getattr(a, n), getattr(b, n))]
    return bad


@pytest.mark.parametrize("name, over", [
    ("torus_euler", {"integrator.method": "cmp"}),                       # ideal: the Cayley midpoint alone
    ("torus_convection", {"integrator.h": 0.05, "ensemble.members": 2}),  # ν = κ = 1e-3, α = 0.2: V, C and buoyancy
])
def test_the_xp_path_gives_the_cpu_arrays_bit_for_bit(name, over):
    sc, W0, S0, cpu, xp = _runs(name, **over)
    assert XP is not np and tk.basis(9, XP) is not tk.basis(9)  # the namespace path ran on its own basis
    assert (cpu.status == 0).all() and (cpu.iterations[:, 1:] > 0).all()
    assert _same(cpu, xp) == []
    # the same conduction sub-steps, the same halvings
    assert (cpu.conduction.substeps, cpu.conduction.rejected) == (xp.conduction.substeps, xp.conduction.rejected)
    if name == "torus_convection":  # the run did move heat: conduction sub-steps, S and W changed
        assert cpu.conduction.substeps > 0
        assert np.abs(cpu.out.S[:, -1] - cpu.out.S[:, 0]).max() > 1e-5
        assert np.abs(cpu.out.W[:, -1]).max() > 1e-5  # buoyancy set the rest state moving


def test_the_comparison_sees_a_difference_of_one_rounding():
    """Negative control: one member's W0 moved by one unit in the last place gives other bits."""
    sc = load_scene("torus_euler", SMALL)
    W0, S0 = tr.initial_fields(sc, np.arange(3))
    a = tr.integrate(sc, W0, S0, progress=False)
    W1 = W0.copy()
    W1[1, 1, 2] = np.nextafter(W1[1, 1, 2].real, np.inf) + 1j * W1[1, 1, 2].imag
    W1[1, 2, 1] = np.conj(W1[1, 1, 2])
    b = tr.integrate_xp(XP, sc, W1, S0, progress=False)
    assert "W" in _same(a, b)


def test_the_xp_path_keeps_the_members_flags():
    """A member whose fixed point runs out of iterations leaves the batch at the same step with
    the same status on both paths."""
    sc, _, _, cpu, xp = _runs("torus_euler", **{"integrator.max_iter": 2})
    assert (cpu.status == tk.STATUS_NOT_CONVERGED).all() and (cpu.failed_step == 1).all()
    assert _same(cpu, xp) == []


def test_backends_refuse_what_they_cannot_run(monkeypatch):
    from liethermo import gpu
    from liethermo.models import get_model
    from liethermo.preflight import PreflightError

    sc = load_scene("torus_euler", {**SMALL, "integrator.method": "reference"})
    W0, S0 = tr.initial_fields(sc, np.arange(1))
    with pytest.raises(ValueError, match="'reference' does not run on the array-namespace"):
        tr.integrate_xp(XP, sc, W0, S0, progress=False)
    with pytest.raises(ValueError, match="'reference' does not run on the array-namespace"):
        ts.drive(W0, S0, lambda *a: None, th=tr.thermo_of(sc), b=tk.basis(9, XP), method="reference", h=0.01,
                 steps=1, every=1)
    assert tr.integrate(sc, W0, S0, progress=False).status.tolist() == [0]  # the CPU runs it
    model = get_model("torus")
    gpu_scene = load_scene("torus_euler", {**SMALL, "ensemble.device": "gpu"})
    monkeypatch.setitem(sys.modules, "cupy", None)  # as where CuPy is not installed
    with pytest.raises(PreflightError, match="^scene key 'ensemble.device': \"gpu\" cannot run here: backend "
                       "'gpu' needs CuPy") as err:
        model.check_parameters(gpu_scene)
    assert "\n" not in str(err.value)
    monkeypatch.setattr(gpu, "namespace", lambda backend: np)  # as where CuPy and a device are present
    model.check_parameters(gpu_scene)
    with pytest.raises(PreflightError, match=r"^scene key 'ensemble.device': the reference method runs on the CPU "
                       r"only \(\"gpu\" runs cmp, magmp, isomp, cmp4, magmp4, isomp4 and rk4\)$"):
        model.check_parameters(gpu_scene.with_overrides({"integrator.method": "reference"}))
    with pytest.raises(PreflightError, match="^scene key 'output.compare': the reference method runs on the CPU"):
        model.check_parameters(gpu_scene.with_overrides({"output.compare": ["magmp", "reference"]}))
    cpu_scene = load_scene("torus_euler", {**SMALL, "integrator.method": "reference"})
    model.check_parameters(cpu_scene)  # the CPU runs the reference


@pytest.mark.parametrize("name, method", [("torus_euler", "cmp"), ("torus_euler", "cmp4"), ("torus_euler", "rk4"),
                                          ("torus_convection", "magmp"), ("torus_convection", "rk4")])
def test_the_memory_estimate_bounds_what_numpy_allocates(name, method):
    """The device memory :func:`step.memory_bytes` names for a member chunk bounds the
    peak of numpy's allocations over the same steps (the basis built anew), within 1.6×."""
    import tracemalloc

    N, M = 15, 8
    sc = load_scene(name, {**SMALL, "torus.N": N, "ensemble.members": M, "integrator.method": method,
                           "integrator.h": 0.05, "integrator.steps": 4, "output.every": 4})
    W0, S0 = tr.initial_fields(sc, np.arange(M))
    th = tr.thermo_of(sc)
    ns = types.ModuleType("numpy_for_the_memory")  # a basis of its own, allocated under the trace
    ns.__dict__.update(XP.__dict__)
    tracemalloc.start()
    try:
        ts.drive(W0, S0, lambda *a: None, th=th, b=tk.basis(N, ns), method=method, h=0.05, steps=4, every=4)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    est = ts.memory_bytes(N, M, method, sc["integrator"]["composition"])
    assert peak <= est <= 1.6 * peak, (peak, est)


def test_a_gpu_scene_names_its_device_memory():
    from liethermo.models import get_model

    model = get_model("torus")
    cpu = model.estimate(load_scene("torus_convection", SMALL))
    gpu = model.estimate(load_scene("torus_convection", {**SMALL, "ensemble.device": "gpu"}))
    assert cpu.device_memory == 0
    assert gpu.device_memory == ts.memory_bytes(9, gpu.chunk_members, "cmp")
    with pytest.raises(ValueError, match="'reference' does not run"):
        ts.memory_bytes(9, 4, "reference")
