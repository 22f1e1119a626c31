"""The CUDA kernels (numba-cuda) agree with the CPU's straightforward kernel.

The device kernels run here in numba-cuda's simulator
(``NUMBA_ENABLE_CUDASIM=1``, which must be set before numba-cuda is imported:
one subprocess runs every case, CPU and simulated GPU side by side, and this
module compares what it saved).  Each case: 6 members, 50 steps kept every 5,
kernel calls of 4 outputs (so the last call is a partial one), every method on
the paper's top (members whose explicit RK2 blows up, members whose Newton
iteration fails), and the other terms and layouts: per-member parameters with
every force at once, the triaxial ellipsoid, the coupled top, double-bracket
friction alone.  States agree to 1e-12 relative (NaN where the CPU has NaN);
status, failing step, Newton iterations, steps done are identical.

A process without a device (this one: numba-cuda's simulator is off) refuses
``device="gpu"`` before any work, with the reason in one line.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
N, STEPS, EVERY, CHUNK = 6, 50, 5, 20
PAPER = {"ensemble.members": N, "ensemble.spin_range": [0.1, 12.0]}
ALL_FORCES = {**PAPER, "fluid.quadratic_drag": 2e-6, "body.internal_friction": 5.0}

#: (case name, scene, overrides, method, extra simulate keywords, per-member
#: parameters, the status codes the CPU run must show for the case to test them)
CASES = [
    ("paper-vi", "paper", PAPER, "vi", {}, False, {0}),
    ("paper-vi4-newton", "paper", PAPER, "vi4", {"newton_maxiter": 3}, False, {0, 1}),
    ("paper-vi6", "paper", PAPER, "vi6", {}, False, {0}),
    ("paper-split", "paper", PAPER, "split", {}, False, {0}),
    ("paper-split4", "paper", PAPER, "split4", {}, False, {0}),
    ("paper-split6", "paper", PAPER, "split6", {}, False, {0}),
    ("paper-rk2-blowup", "paper", PAPER, "rk2", {}, False, {0, 2}),
    ("paper-rk4", "paper", PAPER, "rk4", {}, False, {0}),
    ("allforces-vi", "paper", ALL_FORCES, "vi", {"start": "legendre", "entropy": "symmetric"}, True, {0}),
    ("allforces-rk4", "paper", ALL_FORCES, "rk4", {}, True, {0}),
    ("ellipsoid-split4", "ellipsoid", {"ensemble.members": N}, "split4", {}, False, {0}),
    ("ellipsoid-vi6", "ellipsoid", {"ensemble.members": N}, "vi6", {}, True, {0}),
    ("coupled-vi", "coupled_egg", {"ensemble.members": N}, "vi", {}, False, {0}),
    ("coupled-rk2", "coupled_egg", {"ensemble.members": N}, "rk2", {}, False, {0}),
    ("flatspin-vi4", "flat_spin", {"ensemble.members": N}, "vi4", {}, False, {0}),
    ("flatspin-rk4", "flat_spin", {"ensemble.members": N}, "rk4", {}, False, {0}),
]
FIELDS = ("states", "status", "fail_step", "newton_iterations", "newton_max", "steps_done",
          "max_h_omega")


def _run_cases(out: Path) -> None:
    """In the simulator process: every case on the CPU (straightforward
    kernel) and on the simulated device, saved to ``out`` (npz)."""
    from dataclasses import replace

    from liethermo.initial import initial_conditions
    from liethermo.resolve import resolve
    from liethermo.scene import load_scene
    from liethermo.simulate import simulate

    saved, devices = {}, {}
    for name, scene, over, method, kw, per_member, _ in CASES:
        sc = load_scene(scene, over)
        run = resolve(sc)
        phys = run.physics_for(N)
        if per_member:  # every member its own parameters: the kernels read them from rows
            phys = replace(phys, gravity_torque=phys.gravity_torque * np.linspace(0.5, 1.5, N)[:, None],
                           friction=phys.friction * np.linspace(0.8, 1.2, N)[:, None])
        om, R = initial_conditions(sc, 0, N)
        opts = {**run.simulate_options("simple"), **kw}
        h = float(sc["integrator"]["h"])
        cpu = simulate(phys, om, R, h, STEPS, method, every=EVERY, **opts)
        gpu = simulate(phys, om, R, h, STEPS, method, every=EVERY, device="gpu", chunk_steps=CHUNK, **opts)
        for tag, tr in (("cpu", cpu), ("gpu", gpu)):
            for f in FIELDS:
                saved[f"{name}/{tag}/{f}"] = np.asarray(getattr(tr, f))
        devices[name] = [gpu.device, float(gpu.kernel_seconds), gpu.terms]
    np.savez(out, **saved)
    out.with_suffix(".json").write_text(json.dumps(devices))


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    import importlib.util

    if importlib.util.find_spec("numba_cuda") is None:
        pytest.skip("numba-cuda is not installed (it is in the test extra: pip install -e '.[test]')")
    out = tmp_path_factory.mktemp("gpu_sim") / "cases.npz"
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1",
           "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(HERE), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, str(Path(__file__).resolve()), str(out)], env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    data = np.load(out)
    return {k: data[k] for k in data.files}, json.loads(out.with_suffix(".json").read_text())


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_simulated_gpu_agrees_with_cpu(results, case):
    data, devices = results
    name, expected_status = case[0], case[-1]
    cpu = {f: data[f"{name}/cpu/{f}"] for f in FIELDS}
    gpu = {f: data[f"{name}/gpu/{f}"] for f in FIELDS}
    assert devices[name][0] == "gpu"
    assert set(np.unique(cpu["status"]).tolist()) == expected_status  # the case tests what it says
    for f in ("status", "fail_step", "newton_iterations", "newton_max", "steps_done"):
        np.testing.assert_array_equal(gpu[f], cpu[f], err_msg=f)
    a, b = cpu["states"], gpu["states"]
    np.testing.assert_array_equal(np.isnan(b), np.isnan(a))
    ok = ~np.isnan(a)
    assert ok[:, -1].any() or expected_status != {0}
    scale = np.maximum(np.abs(a[ok]), 1e-300)
    assert np.max(np.abs(b[ok] - a[ok]) / scale, initial=0.0) <= 1e-12
    fa, fb = cpu["max_h_omega"], gpu["max_h_omega"]
    np.testing.assert_allclose(fb, fa, rtol=1e-12, atol=0.0)


def test_gpu_refused_without_device(paper):
    """No device here (the simulator is off in this process): refused before any work."""
    from liethermo.gpu import gpu_available
    from liethermo.simulate import simulate

    ok, why = gpu_available()
    if ok:
        pytest.skip(f"this machine has a device: {why}")
    assert why and "\n" not in why
    phys, om, R = paper
    with pytest.raises(RuntimeError) as exc:
        simulate(phys, om, R, 0.1, 10, "rk4", device="gpu")
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith("device='gpu' cannot run here: ") and why in msg


def test_gpu_rejects_reference_and_unknown_device(paper):
    from liethermo.simulate import simulate

    phys, om, R = paper
    with pytest.raises(ValueError, match="'reference' runs on the CPU only"):
        simulate(phys, om, R, 0.1, 10, "reference", device="gpu")
    with pytest.raises(ValueError, match="unknown device 'tpu'"):
        simulate(phys, om, R, 0.1, 10, "rk4", device="tpu")


if __name__ == "__main__":
    _run_cases(Path(sys.argv[1]))
