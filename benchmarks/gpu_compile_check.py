"""Compile the heavy top's CUDA kernels for a real GPU, without one: every method × every scene.

    python benchmarks/gpu_compile_check.py [--cc 9.0] [--methods vi,rk4] [--scenes paper]

numba-cuda compiles the device kernel of ``simulate(..., device="gpu")``
(:mod:`liethermo.top.kernels.cuda`) through NVVM to PTX for the compute capability
given (default 9.0, the H100) — the step a first launch on the device does,
so a kernel that prints OK here compiles there.  NVVM comes with
``pip install 'numba-cuda[cu13]'``; no driver or GPU is needed.  (numba-cuda
compiles the device functions a kernel calls for the *current* device's
compute capability; without a device the script answers that question with
``--cc``.)  Where nvJitLink is there too, the PTX is also assembled for the
device and the registers, spills and local memory per thread are printed.
Each line also counts the FMAs in the PTX (the kernels' explicit ones) and
the double-precision operations the assembler could still fuse (0 expected:
:func:`liethermo.top.kernels.cuda.exact_arithmetic`).

Scenes: the paper's top, the triaxial ellipsoid (diagonal Stokes friction),
the coupled top (entropy-dependent inertia), the flat spin (double-bracket
friction alone) and "allforces": the paper's top with quadratic drag and
double-bracket friction added and its own parameters per member (every
term at once, parameters read from the device array).  The splittings need
an exact flow of every term: "n/a" where a scene has a term without one.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

METHODS = ("vi", "vi4", "vi6", "split", "split4", "split6", "rk2", "rk4")
SCENES = {
    "paper": ("paper", {}),
    "ellipsoid": ("ellipsoid", {}),
    "coupled_egg": ("coupled_egg", {}),
    "flat_spin": ("flat_spin", {}),
    "allforces": ("paper", {"fluid.quadratic_drag": 2e-6, "body.internal_friction": 5.0}),
}
N = 4


def _pretend_device(cc: tuple[int, int]) -> bool:
    """Without a device, tell numba-cuda's device-function compiler the
    compute capability it would read from one.  True if patched."""
    from liethermo.gpu import gpu_available

    if gpu_available()[0]:
        return False
    import numba.cuda.dispatcher as disp

    class _Device:
        compute_capability = cc

    disp.get_current_device = lambda: _Device()
    return True


def stepper_and_model(scene: str, overrides: dict, method: str):
    """The stepper, kernel model and state size ``simulate`` would build, or
    None when the method cannot run the scene (a splitting without an exact flow)."""
    from liethermo.top.kernels import vi as _vi
    from liethermo.top.kernels.split import can_split
    from liethermo.top.kernels.steppers import Explicit, Split, Variational
    from liethermo.top.kernels.terms.thermo import EXPLICIT, SYMMETRIC
    from liethermo.top.methods import MethodChoice
    from liethermo.top.physics import build_model
    from liethermo.top.resolve import resolve
    from liethermo.scene import load_scene

    sc = load_scene(scene, {"ensemble.members": N, **overrides})
    run = resolve(sc)
    phys = run.physics_for(N)
    if overrides:  # its own parameters per member
        phys = replace(phys, gravity_torque=phys.gravity_torque * np.linspace(0.5, 1.5, N)[:, None])
    opts = run.simulate_options("simple")
    km = build_model(phys, opts["attitude"], heat=opts["heat_bound"])
    integ = sc["integrator"]
    c = MethodChoice.of(method, start=integ["start"], friction=integ["friction"], entropy=integ["entropy"],
                        composition=integ["composition"])
    m = c.method
    if m.family == "split" and can_split(km.model) is not None:
        return None
    composition = c.composition or "small_error"
    if m.layout in ("rk", "split"):
        tab = m.kernel_tableau(composition)
        stepper = Split(tab, 1, type(tab).factors) if m.layout == "split" else Explicit(tab, 1)
    else:
        factors = tuple(float(f) for f in m.substeps(composition))
        wl, wr = _vi.FRICTION_WEIGHTS[c.friction]
        mode = EXPLICIT if c.entropy == "explicit" else SYMMETRIC
        stepper = Variational(factors, float(wl), float(wr), mode, float(opts["newton_tol"]),
                              int(opts["newton_maxiter"]))
    return stepper, km, km.layout(m.layout).size


def kernel_signature():
    """The argument types of a launch by :func:`liethermo.top.kernels.cuda.advance_on_device`."""
    from numba import types

    f1 = types.Array(types.float64, 1, "C")
    i = types.int64
    return (f1, f1, i, i, i, i, types.float64, i, i, f1, types.Array(types.int64, 2, "F"),
            types.Array(types.float64, 2, "F"))


def contractible(ptx: str) -> int:
    """Double-precision adds, subtracts and multiplies without a rounding
    mode: PTX lets the assembler fuse those into FMAs (NVVM's default output);
    0 when the kernel rounds every operation as the CPU kernels do."""
    import re

    return len(re.findall(r"\b(?:add|sub|mul)\.f64\b", ptx))


def ptxas_info(ptx: str, cc: tuple[int, int]) -> str:
    """Registers, spills and local memory per thread from assembling the PTX
    (nvJitLink), or '' where it is not installed."""
    try:
        from cuda.core import Linker, LinkerOptions, ObjectCode
    except ImportError:
        try:
            from cuda.core.experimental import Linker, LinkerOptions, ObjectCode
        except ImportError:
            return ""
    try:
        obj = ObjectCode.from_ptx(ptx.encode() if isinstance(ptx, str) else ptx)
        linker = Linker(obj, options=LinkerOptions(arch=f"sm_{cc[0]}{cc[1]}", verbose=True))
        linker.link("cubin")
        log = linker.get_info_log() or ""
    except Exception as exc:  # noqa: BLE001 - informative only
        return f"(no ptxas info: {type(exc).__name__})"
    import re

    regs = re.findall(r"Used (\d+) registers", log)
    spill = re.findall(r"(\d+) bytes spill stores, (\d+) bytes spill loads", log)
    stack = re.findall(r"(\d+) bytes stack frame", log)
    out = []
    if regs:
        out.append(f"{regs[-1]} registers")
    if stack:
        out.append(f"{stack[-1]} B stack")
    if spill:
        out.append(f"spill {spill[-1][0]}/{spill[-1][1]} B st/ld")
    return ", ".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cc", default="9.0", help="compute capability to compile for (default 9.0)")
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--scenes", default=",".join(SCENES))
    args = ap.parse_args(argv)
    cc = tuple(int(x) for x in args.cc.split("."))
    patched = _pretend_device(cc)
    from numba import cuda

    from liethermo.top.kernels.cuda import exact_arithmetic, kernel_for

    print(f"compiling for compute capability {cc[0]}.{cc[1]}"
          + (" (no device here: numba-cuda told that capability)" if patched else ""))
    sig = kernel_signature()
    failures = 0
    for scene in args.scenes.split(","):
        name, over = SCENES[scene]
        for method in args.methods.split(","):
            got = stepper_and_model(name, over, method)
            if got is None:
                print(f"{scene:12s} {method:7s} n/a  (a term without an exact flow)", flush=True)
                continue
            stepper, km, n = got
            t0 = time.perf_counter()
            try:
                kern = kernel_for(stepper, km.model)
                with exact_arithmetic():  # as advance_on_device compiles it
                    ptx, _ = cuda.compile_ptx(kern.py_func, sig, cc=cc)
                fused = ptx.count("fma.rn.f64")
                loose = contractible(ptx)
            except Exception as exc:  # noqa: BLE001 - report and go on
                failures += 1
                msg = " ".join(str(exc).split())[:300]
                print(f"{scene:12s} {method:7s} FAIL {type(exc).__name__}: {msg}", flush=True)
                continue
            dt = time.perf_counter() - t0
            local = sum(1 for line in ptx.splitlines() if ".local" in line)
            info = ptxas_info(ptx, cc)
            print(f"{scene:12s} {method:7s} OK   {dt:5.1f} s, PTX {len(ptx) // 1024} KiB, "
                  f"{local} .local lines, {fused} FMAs, {loose} contractible"
                  f"{', ' + info if info else ''}", flush=True)
    print("all OK" if failures == 0 else f"{failures} FAILED")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
