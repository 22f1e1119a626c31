"""The CUDA kernels (numba-cuda) agree with the CPU's straightforward kernel.

The device kernels run here in numba-cuda's simulator
(``NUMBA_ENABLE_CUDASIM=1``, which must be set before numba-cuda is imported:
one subprocess runs every case, CPU and simulated GPU side by side, and this
module compares what it saved).  The subprocess runs with ``NUMBA_DISABLE_JIT=1``:
both sides are the same lane functions in plain Python, so what is compared is
the device path's own part (thread indexing, strided loads and stores, kernel
calls of a few outputs, statuses); compiled CPU kernels are checked against
plain Python in tests/test_plain_python.py, and the device compile itself by
benchmarks/gpu_compile_check.py on a GPU.  Each case: 6 members, 50 steps kept every 5,
kernel calls of 4 outputs (so the last call is a partial one).  The cases
take every method and every term at least once: the paper's top (shared
parameters; members whose explicit RK2 blows up), every force at once with
per-member parameters (members whose Newton iteration fails), the triaxial
ellipsoid, the coupled top, double-bracket friction alone;
``LIETHERMO_GPU_SIM_FULL=1`` adds every method on every scene.  States agree
to 1e-12 relative (NaN where the CPU has NaN); status, failing step, Newton
iterations and steps done are identical, max |h|·|Ω| agrees to 1e-12.

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
#: scene name → (scene file, overrides, per-member parameters)
SCENES = {
    "paper": ("paper", PAPER, False),
    # every force at once, each member its own parameters (read from rows)
    "allforces": ("paper", {**PAPER, "fluid.quadratic_drag": 2e-6, "body.internal_friction": 5.0}, True),
    "ellipsoid": ("ellipsoid", {"ensemble.members": N}, True),
    "coupled": ("coupled_egg", {"ensemble.members": N}, False),
    "flatspin": ("flat_spin", {"ensemble.members": N}, False),
}
METHODS = ("vi", "vi4", "vi6", "split", "split4", "split6", "rk2", "rk4")
SPLITTABLE = {"paper", "ellipsoid"}  # the others have a term without an exact flow

#: (case name, scene, method, extra simulate keywords, the status codes the CPU
#: run must show for the case to test what it says, or None).  Every method
#: and every term at least once; LIETHERMO_GPU_SIM_FULL=1 runs every method on
#: every scene instead (minutes: each case compiles its kernels twice).
CASES = [
    ("paper-vi", "paper", "vi", {}, {0}),
    ("paper-split", "paper", "split", {}, {0}),
    ("paper-split6", "paper", "split6", {}, {0}),
    ("paper-rk2-blowup", "paper", "rk2", {}, {0, 2}),
    ("allforces-vi4-newton", "allforces", "vi4", {"newton_maxiter": 3}, {0, 1}),
    ("allforces-rk4", "allforces", "rk4", {}, {0}),
    ("ellipsoid-split4", "ellipsoid", "split4", {}, {0}),
    ("ellipsoid-vi6", "ellipsoid", "vi6", {}, {0}),
    ("coupled-vi", "coupled", "vi", {}, {0}),
    ("flatspin-rk2", "flatspin", "rk2", {}, None),
]
if os.environ.get("LIETHERMO_GPU_SIM_FULL") == "1":
    CASES = CASES + [(f"{sc}-{m}-full", sc, m, {}, None) for sc in SCENES for m in METHODS
                     if not (m.startswith("split") and sc not in SPLITTABLE)]
FIELDS = ("states", "status", "fail_step", "newton_iterations", "newton_max", "steps_done",
          "max_h_omega")


def _run_cases(out: Path) -> None:
    """In the simulator process: every case on the CPU (straightforward
    kernel) and on the simulated device, saved to ``out`` (npz)."""
    from dataclasses import replace

    from liethermo.top.initial import initial_conditions
    from liethermo.top.resolve import resolve
    from liethermo.scene import load_scene
    from liethermo.top.simulate import simulate

    saved, devices = {}, {}
    for name, scene, method, kw, _ in CASES:
        file, over, per_member = SCENES[scene]
        sc = load_scene(file, over)
        run = resolve(sc)
        phys = run.physics_for(N)
        if per_member:  # every member its own parameters: the kernels read them from rows
            phys = replace(phys, gravity_torque=phys.gravity_torque * np.linspace(0.5, 1.5, N)[:, None],
                           stokes_resistance=phys.stokes_resistance * np.linspace(0.8, 1.2, N)[:, None])
        om, R = initial_conditions(sc, 0, N)
        opts = {**run.simulate_options("simple"), **kw}
        opts.pop("device")  # the scene's (cpu): each call below names its own
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
    # plain Python on both sides (NUMBA_DISABLE_JIT): the simulator runs a thread's lane functions in
    # Python either way, and compiling the CPU kernels of every case from an empty cache took longer
    # (about 100 s) than interpreting them (about 40 s)
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1", "NUMBA_DISABLE_JIT": "1",  # LIETHERMO_GPU_SIM_FULL passes
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
    if expected_status is not None:  # the case tests what it says
        assert set(np.unique(cpu["status"]).tolist()) == expected_status
    for f in ("status", "fail_step", "newton_iterations", "newton_max", "steps_done"):
        np.testing.assert_array_equal(gpu[f], cpu[f], err_msg=f)
    a, b = cpu["states"], gpu["states"]
    np.testing.assert_array_equal(np.isnan(b), np.isnan(a))
    ok = ~np.isnan(a)
    assert ok[:, -1].any() or expected_status != {0}
    assert ok.sum() > N  # something to compare beyond the initial states
    scale = np.maximum(np.abs(a[ok]), 1e-300)
    assert np.max(np.abs(b[ok] - a[ok]) / scale, initial=0.0) <= 1e-12
    fa, fb = cpu["max_h_omega"], gpu["max_h_omega"]
    np.testing.assert_allclose(fb, fa, rtol=1e-12, atol=0.0)


def test_gpu_refused_without_device(paper):
    """No device here (the simulator is off in this process): refused before any work."""
    from liethermo.gpu import gpu_available
    from liethermo.top.simulate import simulate

    ok, why = gpu_available()
    if ok:
        pytest.skip(f"this machine has a device: {why}")
    assert why and "\n" not in why
    phys, om, R = paper
    with pytest.raises(RuntimeError) as exc:
        simulate(phys, om, R, 0.1, 10, "rk4", device="gpu")
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith("device='gpu' cannot run here: ") and why in msg


def test_gpu_refused_without_numba_cuda(paper, monkeypatch):
    import importlib.util

    import liethermo.gpu as gpu
    from liethermo.top.simulate import simulate

    real = importlib.util.find_spec
    monkeypatch.setattr(gpu.importlib.util, "find_spec",
                        lambda name, *a: None if name == "numba_cuda" else real(name, *a))
    assert gpu.gpu_available() == (False, "numba-cuda is not installed (pip install 'liethermo[gpu]')")
    phys, om, R = paper
    with pytest.raises(RuntimeError, match=r"^device='gpu' cannot run here: numba-cuda is not installed"):
        simulate(phys, om, R, 0.1, 10, "vi", device="gpu")


def test_gpu_rejects_reference_and_unknown_device(paper):
    from liethermo.top.simulate import simulate

    phys, om, R = paper
    with pytest.raises(ValueError, match="'reference' runs on the CPU only"):
        simulate(phys, om, R, 0.1, 10, "reference", device="gpu")
    with pytest.raises(ValueError, match="unknown device 'tpu'"):
        simulate(phys, om, R, 0.1, 10, "rk4", device="tpu")


if __name__ == "__main__":
    _run_cases(Path(sys.argv[1]))
