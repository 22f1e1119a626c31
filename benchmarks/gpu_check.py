"""The device check: the GPU backend against the CPU kernels, and its speed.

``python benchmarks/gpu_check.py`` on a machine with a CUDA GPU prints

1. the device and the versions of numba, numba-cuda, CuPy and JAX;
2. CPU/GPU agreement for every method of the top on the paper scene's
   physics (a random ensemble as in ``bench.py``, ``--agree-members`` 4096,
   h = 0.01 s, 1000 steps): the largest relative difference of Ω and of Γ at
   the end (max over members of |x_gpu − x_cpu| / max|x_cpu|) and whether the
   status flags, failing steps, steps done and Newton iterations are identical;
3. ns per member-step of every method at ``--members`` 2²² × 1000 steps on
   the GPU, the kernel time alone and the whole ``simulate`` call (copies,
   allocation, labelling of the trajectory);
4. the fluid's ms per member-step on the GPU (CuPy) at N = 128, 256, 512 with
   64 members, and a run at N = 1024;
5. the peer: the same RK4 of the top written in JAX with ``vmap``
   (``jax_peer.py``), at the same members and steps, and its agreement with
   ours;
6. ``liethermo run`` with ``--device gpu`` against the CPU for the paper
   scene and the fluid (whole files compared variable by variable), and the
   ``--check`` line of a 2²²-member run;
7. whole runs of the paper scene (rk4, split; ``--members`` × ``--steps``, the
   end state only, writing included) with the summary's times, and the fluid at
   N = 1024 run twice from an empty basis cache: how soon the second starts.

Each method compiles in its own process (the device machine has many cores
and a CUDA compile is single-threaded); the timings are then taken one
method at a time.  Every section catches its own failure and prints it, so one
broken piece does not hide the others.  The GPU machine's image lacks some of
liethermo's dependencies: ``benchmarks/gpu_check.sh`` installs them from
wheels carried in ``.whl/`` and runs this script.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import platform
import sys
import threading
import time
import traceback

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

METHODS = ("vi", "vi4", "vi6", "split", "split4", "split6", "rk2", "rk4")
BASIS_SECONDS: dict = {}  # N -> seconds to build the fluid basis (or the traceback)


def say(*a):
    print(*a, flush=True)


def environment():
    import numba
    import numpy as np

    say(f"host: {platform.node()} {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} CPUs, Python {platform.python_version()}, numpy {np.__version__}, "
        f"numba {numba.__version__}")
    for mod in ("numba_cuda", "cupy", "jax", "xarray", "netCDF4"):
        try:
            m = __import__(mod)
            say(f"  {mod} {getattr(m, '__version__', '?')}")
        except Exception as exc:  # noqa: BLE001
            say(f"  {mod}: not importable ({exc})")
    try:
        from numba import cuda

        dev = cuda.get_current_device()
        free, total = cuda.current_context().get_memory_info()
        say(f"GPU: {dev.name.decode() if isinstance(dev.name, bytes) else dev.name}, "
            f"compute capability {dev.compute_capability}, {dev.MULTIPROCESSOR_COUNT} SMs, "
            f"{total / 2**30:.1f} GiB ({free / 2**30:.1f} free)")
    except Exception as exc:  # noqa: BLE001
        say(f"GPU: not usable through numba-cuda ({exc})")


def _ensemble(n, seed=0):
    from bench import random_ensemble, variant_physics

    phys = variant_physics("paper", n)
    om0, R0 = random_ensemble(n, seed)
    return phys, om0, R0


def _simulate(method, phys, om0, R0, h, steps, device, kernel="auto"):
    from bench import run

    if device == "cpu":
        return run(kernel, method, phys, om0, R0, h, steps, steps, False, None)
    from liethermo.top.physics import mechanical_energy_scale
    from liethermo.top.simulate import simulate

    kw = {"start": "node", "entropy": "explicit"} if method == "vi" else {}
    heat = float(mechanical_energy_scale(phys, om0, R0[:, 2, :]).max())
    from liethermo.top.methods import MethodChoice

    return simulate(phys, om0, R0, h, steps, MethodChoice.of(method, **kw), every=steps, heat_bound=heat,
                    device="gpu")


def _rel(a, b):
    import numpy as np

    scale = float(np.nanmax(np.abs(b))) or 1.0
    return float(np.nanmax(np.abs(a - b))) / scale


def _same_flags(a, b):
    import numpy as np

    names = ("status", "fail_step", "steps_done", "newton_iterations", "newton_max")
    bad = [n for n in names if not np.array_equal(getattr(a, n), getattr(b, n))]
    return "identical" if not bad else "DIFFER in " + ", ".join(bad)


def method_worker(method, args, barrier, lock, queue):
    """Compile, check agreement (in parallel with the other methods), then
    time under the lock (one method at a time)."""
    out = {"method": method}
    try:
        import numpy as np

        phys, om0, R0 = _ensemble(args.agree_members)
        t0 = time.perf_counter()
        cpu = _simulate(method, phys, om0, R0, args.h, args.steps, "cpu", kernel="simple")
        out["cpu_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        gpu = _simulate(method, phys, om0, R0, args.h, args.steps, "gpu")
        out["gpu_first_s"] = time.perf_counter() - t0
        out["d_omega"] = _rel(gpu.omega[:, -1], cpu.omega[:, -1])
        out["d_gamma"] = _rel(gpu.gamma[:, -1], cpu.gamma[:, -1])
        out["flags"] = _same_flags(gpu, cpu)
        out["ok"] = int(np.sum(cpu.status == 0))
    except Exception:  # noqa: BLE001
        out["agree_error"] = traceback.format_exc()
    try:
        barrier.wait(timeout=args.compile_timeout)
    except Exception:  # noqa: BLE001
        pass
    if "agree_error" not in out:
        try:
            with lock:
                phys, om0, R0 = _ensemble(args.members, seed=1)
                best_k, best_w = float("inf"), float("inf")
                for _ in range(args.repeat):
                    t0 = time.perf_counter()
                    tr = _simulate(method, phys, om0, R0, args.h, args.steps, "gpu")
                    best_w = min(best_w, time.perf_counter() - t0)
                    best_k = min(best_k, getattr(tr, "kernel_seconds", None) or tr.wall_time)
                ms = args.members * args.steps
                out["ns_kernel"] = best_k / ms * 1e9
                out["ns_whole"] = best_w / ms * 1e9
                out["ok_big"] = int(np.sum(tr.status == 0))
                if method == "rk4":
                    np.savez(os.path.join(args.scratch, "rk4_big.npz"), omega=tr.omega[:, -1],
                             gamma=tr.gamma[:, -1])
        except Exception:  # noqa: BLE001
            out["time_error"] = traceback.format_exc()
    queue.put(out)


def top_sections(args):
    ctx = mp.get_context("spawn")
    barrier = ctx.Barrier(len(args.methods))
    lock = ctx.Lock()
    queue = ctx.Queue()
    procs = [ctx.Process(target=method_worker, args=(m, args, barrier, lock, queue)) for m in args.methods]
    for p in procs:
        p.start()
    results = {}
    for _ in procs:
        r = queue.get()
        results[r["method"]] = r
    for p in procs:
        p.join()
    say(f"\n## Agreement with the CPU (paper scene, {args.agree_members} members, h = {args.h} s, "
        f"{args.steps} steps)")
    say("| method | max rel. diff Ω | max rel. diff Γ | status, steps, Newton | completed | "
        "first GPU call s (compile) |")
    say("|---|---:|---:|---|---:|---:|")
    for m in args.methods:
        r = results[m]
        if "agree_error" in r:
            say(f"| {m} | FAILED | | | | |")
            say(r["agree_error"])
            continue
        say(f"| {m} | {r['d_omega']:.2e} | {r['d_gamma']:.2e} | {r['flags']} | {r['ok']} | "
            f"{r['gpu_first_s']:.1f} |")
    say(f"\n## Speed ({args.members} members × {args.steps} steps, h = {args.h} s, best of "
        f"{args.repeat})")
    say("| method | kernel ns/member-step | whole run ns/member-step | completed |")
    say("|---|---:|---:|---:|")
    for m in args.methods:
        r = results[m]
        if "ns_kernel" in r:
            say(f"| {m} | {r['ns_kernel']:.4f} | {r['ns_whole']:.4f} | {r['ok_big']} |")
        else:
            say(f"| {m} | FAILED | | |")
            say(r.get("time_error", r.get("agree_error", "")))
    return results


def jax_section(args, results):
    import numpy as np

    from jax_peer import rk4_peer

    phys, om0, R0 = _ensemble(args.members, seed=1)
    (w, G, s), t = rk4_peer(phys, om0, R0[:, 2, :], args.h, args.steps, repeat=args.repeat)
    ns = t / (args.members * args.steps) * 1e9
    say(f"\n## Peer: RK4 in JAX (vmap, fori_loop, float64), {args.members} × {args.steps}")
    say(f"JAX rk4: {ns:.4f} ns/member-step (best of {args.repeat}, compile excluded)")
    ours = results.get("rk4", {}).get("ns_kernel")
    if ours:
        say(f"liethermo rk4 kernel: {ours:.4f} ns/member-step: {ns / ours:.2f}× faster than JAX")
    path = os.path.join(args.scratch, "rk4_big.npz")
    if os.path.exists(path):
        ref = np.load(path)
        say(f"JAX against liethermo rk4 at the end: max rel. diff Ω {_rel(w, ref['omega']):.2e}, "
            f"Γ {_rel(G, ref['gamma']):.2e}")


def fluid_section(args):
    import importlib

    cupy = importlib.import_module(args.fluid_xp)

    from fluid_xp import check
    from liethermo.zeitlin.xpstep import time_fluid_xp

    say("\n## Fluid on the GPU (CuPy): agreement with the numba kernels, N = 16, 50 steps")
    try:
        check(cupy)
    except Exception:  # noqa: BLE001
        say(traceback.format_exc())
    say("bases built while the top ran (s): " + ", ".join(
        f"N = {N}: {v:.1f}" if isinstance(v, float) else f"N = {N}: FAILED {v}" for N, v in BASIS_SECONDS.items()))
    say(f"\n## Fluid on the GPU (CuPy), {args.fluid_members} members, h = 0.01 s, nu = 1e-3 s-1")
    say("| N | method | ms/member-step | steps timed |")
    say("|---:|---|---:|---:|")
    for N in args.fluid_n:
        steps = max(2, int(args.fluid_steps * (128 / N) ** 2))
        for method in ("split", "rk4"):
            try:
                sec = time_fluid_xp(cupy, N, args.fluid_members, steps, method)
                say(f"| {N} | {method} | {sec * 1e3:.3f} | {steps} |")
            except Exception:  # noqa: BLE001
                say(f"| {N} | {method} | FAILED | |")
                say(traceback.format_exc())
        _free(cupy)
    try:
        t0 = time.perf_counter()
        # h = 0.01 s is beyond the fixed point's reach at N = 1024 (it does not converge)
        sec = time_fluid_xp(cupy, 1024, args.big_fluid_members, 2, "split", h=0.0025)
        say(f"N = 1024, {args.big_fluid_members} members, split, h = 0.0025 s, 2 steps: "
            f"{sec * 1e3:.1f} ms/member-step ({time.perf_counter() - t0:.1f} s with set-up)")
    except Exception:  # noqa: BLE001
        say("N = 1024: FAILED")
        say(traceback.format_exc())
    _free(cupy)


def _prebuild_bases(args):
    import importlib

    from liethermo.zeitlin.xpstep import xp_basis

    xp = importlib.import_module(args.fluid_xp)
    for N in [*args.fluid_n, 1024]:
        try:
            t0 = time.perf_counter()
            xp_basis(xp, N)
            BASIS_SECONDS[N] = time.perf_counter() - t0
        except Exception:  # noqa: BLE001
            BASIS_SECONDS[N] = traceback.format_exc()


def _free(xp):
    if hasattr(xp, "get_default_memory_pool"):
        xp.get_default_memory_pool().free_all_blocks()


def _cli(*args, env=None):
    import subprocess

    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "liethermo.cli", *args], capture_output=True, text=True, env=env)
    return p, time.perf_counter() - t0


def run_layer_section(args):
    """``liethermo run`` with ``--device gpu`` against the CPU, whole files."""
    import numpy as np
    import xarray as xr

    say("\n## The run layer: `liethermo run SCENE --device gpu` against the CPU")
    cases = (("paper", ["--set", f"ensemble.members={args.run_members}", "--set", "output.compare=[]"]),
             ("zeitlin_decay", ["--set", "zeitlin.N=64", "--set", "ensemble.members=64",
                                "--set", "integrator.steps=200"]))
    for scene, sets in cases:
        files = {}
        for device in ("gpu", "cpu"):
            out = os.path.join(args.scratch, f"{scene}_{device}.nc")
            p, sec = _cli("run", scene, "-o", out, "--force", "--no-progress", "--device", device, *sets)
            if p.returncode:
                say(f"{scene} on the {device}: FAILED\n{p.stderr[-3000:]}")
                break
            files[device] = out
            say(f"{scene} on the {device}: {sec:.1f} s (the command, start-up and compilation included)")
        if len(files) < 2:
            continue
        with xr.open_dataset(files["gpu"]) as g, xr.open_dataset(files["cpu"]) as c:
            same, worst = [], {}
            for v in c.data_vars:
                a, b = c[v].values, g[v].values
                if np.array_equal(a, b, equal_nan=a.dtype.kind == "f"):
                    same.append(v)
                elif a.dtype.kind == "f":
                    ok = np.isfinite(a) & np.isfinite(b)
                    worst[v] = float(np.abs(a[ok] - b[ok]).max() / max(np.abs(a[ok]).max(), 1e-300))
                else:
                    worst[v] = float("nan")
            others = ", ".join(f"{v} {d:.1e}" for v, d in worst.items())
            say(f"  {len(same)} of {len(c.data_vars)} variables bit for bit"
                + (f"; the others, largest difference over their largest value: {others}" if worst else "")
                + f"; status identical: {np.array_equal(g['status'].values, c['status'].values)}")
    p, _ = _cli("run", "paper", "-o", os.path.join(args.scratch, "check.nc"), "--device", "gpu", "--check",
                "--set", f"ensemble.members={2**22}", "--set", "output.every=100", "--set", "output.attitude=false",
                "--set", "output.compare=[]")
    say("`liethermo run paper --device gpu --check` (4 194 304 members): "
        + " ".join((p.stdout + p.stderr).split())[-600:])


def _summary_lines(text: str, *starts: str) -> str:
    """The summary's lines that begin (after spaces) with one of ``starts``, joined."""
    return "; ".join(ln.strip() for ln in text.splitlines() if ln.strip().startswith(starts))


def whole_runs_section(args):
    """Whole runs as a user starts them: ``liethermo run paper --device gpu`` of ``--members``
    × ``--steps`` (h = ``--h``) for rk4 and split, the end state only (``output.every`` =
    steps, the default variables, writing included), each with the summary's wall and kernel
    times, to set against a CPU's whole run of the same command; then the fluid at N = 1024
    twice on the GPU with an empty basis cache: the second run's start (the command's time
    less its stepping) is what the cache saves.  ``--whole-device cpu`` runs the same commands
    on the CPU: the other side of the comparison, measured the same way."""
    import shutil
    import tempfile

    dev = args.whole_device
    say(f"\n## Whole runs on the {dev.upper()} ({args.members} members × {args.steps} steps, h = {args.h} s, "
        "end state only, default variables, writing included)")
    for method in ("rk4", "split"):
        out = os.path.join(args.scratch, f"whole_{method}.nc")
        p, sec = _cli("run", "paper", "-o", out, "--force", "--no-progress", "--device", dev,
                      "--set", f"ensemble.members={args.members}", "--set", f"integrator.steps={args.steps}",
                      "--set", f"integrator.h={args.h}", "--set", f"output.every={args.steps}",
                      "--set", f'integrator.method="{method}"', "--set", "output.compare=[]",
                      "--set", "output.figures=false")
        if p.returncode:
            say(f"{method}: FAILED\n{p.stderr[-3000:]}")
            continue
        size = os.path.getsize(out) / 1e6
        os.remove(out)
        say(f"{method}: {_summary_lines(p.stdout, 'wall time', 'kernels')} (the command {sec:.1f} s; "
            f"file {size:.0f} MB)")
    cache = tempfile.mkdtemp(prefix="basis-cache-", dir=args.scratch)
    env = dict(os.environ, LIETHERMO_CACHE_DIR=cache)
    say(f"\n## The fluid at N = 1024 on the {dev.upper()}, twice, the basis cache empty at first")
    for tag in ("first", "second"):
        p, sec = _cli("run", "zeitlin_decay", "-o", os.path.join(args.scratch, "z1024.nc"), "--force", "--no-progress",
                      "--device", dev, "--set", "zeitlin.N=1024", "--set", "ensemble.members=1",
                      "--set", "integrator.steps=1", "--set", "output.every=1", "--set", 'integrator.method="rk4"',
                      "--set", "output.compare=[]", "--set", "output.figures=false", env=env)
        if p.returncode:
            say(f"{tag} run: FAILED\n{p.stderr[-3000:]}")
            break
        step = float(_summary_lines(p.stdout, "stepping").split()[1])
        say(f"{tag} run: the command {sec:.1f} s, stepping {step:.1f} s, so it started in {sec - step:.1f} s")
    shutil.rmtree(cache, ignore_errors=True)  # the basis of su(1024): 2.9 GB


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--members", type=int, default=2**22)
    ap.add_argument("--agree-members", type=int, default=4096)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--h", type=float, default=0.01)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--fluid-n", type=int, nargs="+", default=[128, 256, 512])
    ap.add_argument("--fluid-members", type=int, default=64)
    ap.add_argument("--fluid-steps", type=int, default=20, help="steps timed at N = 128 (fewer at larger N)")
    ap.add_argument("--big-fluid-members", type=int, default=8)
    ap.add_argument("--fluid-xp", default="cupy", help="array module of the fluid (numpy: a dry run here)")
    ap.add_argument("--compile-timeout", type=float, default=300.0)
    ap.add_argument("--run-members", type=int, default=65536, help="members of the run-layer check")
    ap.add_argument("--skip", nargs="*", default=[], choices=["top", "fluid", "jax", "run", "whole"])
    ap.add_argument("--whole-device", default="gpu", choices=["gpu", "cpu"],
                    help="where the whole runs of the last section run (cpu: the comparison's other side)")
    ap.add_argument("--scratch", default=os.environ.get("TMPDIR", "/tmp"))
    args = ap.parse_args()
    t0 = time.perf_counter()
    environment()
    prebuild = None
    if "fluid" not in args.skip:
        prebuild = threading.Thread(target=_prebuild_bases, args=(args,), daemon=True)
        prebuild.start()  # the fluid's bases (CPU work, most of it outside the GIL) while the top compiles
    results = {}
    if "top" not in args.skip:
        try:
            results = top_sections(args)
        except Exception:  # noqa: BLE001
            say(traceback.format_exc())
    say(f"[{time.perf_counter() - t0:.0f} s]")
    if "fluid" not in args.skip:
        try:
            prebuild.join()
            fluid_section(args)
        except Exception:  # noqa: BLE001
            say(traceback.format_exc())
    say(f"[{time.perf_counter() - t0:.0f} s]")
    if "jax" not in args.skip:
        try:
            jax_section(args, results)
        except Exception:  # noqa: BLE001
            say(traceback.format_exc())
    say(f"[{time.perf_counter() - t0:.0f} s]")
    if "run" not in args.skip:
        try:
            run_layer_section(args)
        except Exception:  # noqa: BLE001
            say(traceback.format_exc())
    if "whole" not in args.skip:
        try:
            whole_runs_section(args)
        except Exception:  # noqa: BLE001
            say(traceback.format_exc())
    say(f"\ntotal {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
