"""Kernel benchmark: ns per member-step of the ensemble kernels.

``python benchmarks/bench.py`` (or ``liethermo bench``) times the VI, RK2 and
RK4 ensemble kernels on the paper scene (SPEC §2) with a random ensemble —
attitudes uniform on SO(3) (so Γ = Rᵀe₃ uniform on S²), spins uniform in
direction with |Ω₀| uniform in [0.5, 1.5]·√2 rad s⁻¹ — at h = 0.1 s, for
``steps`` steps keeping every ``every``-th state, with

* ``simple``: :func:`liethermo.kernels.ensemble.advance_ensemble`, the
  straightforward one-member-per-iteration ``prange`` kernel (the baseline);
* ``fast``: :func:`liethermo.kernels.fast.advance_ensemble_fast`, the
  structure-of-arrays block kernel (same contract, same results).

Reported per (kernel, method, members): wall time of one kernel call (best of
``--repeat``, after a warm-up call that compiles or loads the numba cache),
ns per member-step = wall / (members · steps) with all cores, ``cpu%`` = CPU
time of the process / (wall · threads) for that call (well below 100 % means
other processes took the cores or the threads were idle; OpenMP workers spin
briefly after a call, so very short calls can show more than 100 %), the speed-up
over ``simple``, whether the results agree bitwise with ``simple`` (and the
largest relative difference otherwise), and memory: the bytes of the arrays
the call works on, the process's peak resident set size during the case
(reset before each case where Linux allows it, else the process's peak) and
its increase over the resident size at the start of the case (``+MB``: what
the case itself allocated, the kernel's scratch included).

Start-up is reported too: ``import liethermo.simulate`` in a fresh
interpreter (nothing is compiled at import), and the first call of each
kernel (loading it from numba's on-disk cache, or compiling it on a cold
cache).  ``--asm`` compiles fresh copies of the fast kernel's lane loops and
counts the instructions of each one's hot loop (packed ``v*pd`` arithmetic on
ymm/zmm registers, FMAs, memory operands, stack spills)
to confirm that LLVM vectorized them.

The table goes to stdout, the numbers to a JSON file (``--json``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import resource
import sys
import time

import numpy as np

__all__ = ["paper_params", "random_ensemble", "run_kernel", "main"]

METHODS = ("vi", "rk2", "rk4")


def paper_params() -> np.ndarray:
    """Parameter row (model.py layout) of the paper scene, from SPEC §2 numbers."""
    from .kernels.model import NPARAM, P_C, P_CV, P_GX, P_GY, P_GZ, P_I1, P_I2, P_I3, P_T0

    a, mu, rho, M = 0.05, 0.1, 2700.0, 26.981539e-3
    g, R_gas, T0 = 9.81, 8.314462618, 300.0
    m = 4.0 / 3.0 * math.pi * a**3 * rho
    m1 = 0.6 * m
    m2 = m - m1
    Gz = 3.0 * m1 * a / (8.0 * m) - m2 * a / (2.0 * m)
    p = np.zeros(NPARAM)
    p[P_I1] = p[P_I2] = 83.0 * a * a * m1 / 320.0 + a * a * m2 / 12.0
    p[P_I3] = 2.0 * a * a * m1 / 5.0 + a * a * m2 / 3.0
    p[P_C] = 8.0 * math.pi * mu * a**3
    p[P_GX], p[P_GY], p[P_GZ] = 0.0, 0.0, m * g * Gz  # m g ℓ χ, χ = G/|G|
    p[P_CV] = 3.0 * (m / M) * R_gas
    p[P_T0] = T0
    return p


def random_ensemble(N: int, seed: int = 0, attitude: bool = False):
    """(Y, P): N random initial states on the paper scene (see module docstring)."""
    from .initial import quat_to_matrix
    from .kernels.model import NSTATE_ATTITUDE, NSTATE_BASE

    rng = np.random.default_rng(seed)
    q = rng.standard_normal((N, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    R = quat_to_matrix(q)
    d = rng.standard_normal((N, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    mag = rng.uniform(0.5, 1.5, N) * math.sqrt(2.0)
    n = NSTATE_ATTITUDE if attitude else NSTATE_BASE
    Y = np.zeros((N, n))
    Y[:, 0:3] = d * mag[:, None]
    Y[:, 3:6] = R[:, 2, :]  # Γ = Rᵀe₃ = third row of R
    if attitude:
        Y[:, 7:16] = R.reshape(N, 9)
    P = np.ascontiguousarray(np.broadcast_to(paper_params(), (N, paper_params().size)))
    return Y, P


def _kernel_fn(kernel: str):
    if kernel == "simple":
        from .kernels.ensemble import advance_ensemble

        return advance_ensemble
    if kernel == "fast":
        from .kernels.fast import advance_ensemble_fast

        return advance_ensemble_fast
    raise ValueError(f"unknown kernel {kernel!r}: expected 'simple' or 'fast'")


def run_kernel(kernel: str, method: str, Y0: np.ndarray, P: np.ndarray, h: float, steps: int,
               every: int, tol: float = 1e-14, maxiter: int = 30, friction=(0.5, 0.5)):
    """One call of an ensemble kernel on copies of Y0; returns (seconds, Y, OUT, IS, FS)."""
    from .kernels import ensemble as E
    from .kernels.rk import DOP853_A, DOP853_B

    mid = {"vi": E.METHOD_VI, "rk2": E.METHOD_RK2, "rk4": E.METHOD_RK4}[method]
    fn = _kernel_fn(kernel)
    N, n = Y0.shape
    Y = Y0.copy()
    n_out = steps // every
    OUT = np.full((N, n_out, n), np.nan)
    IS = np.zeros((N, E.NISTAT), np.int64)
    FS = np.zeros((N, E.NFSTAT))
    t0 = time.perf_counter()
    fn(mid, Y, P, float(h), int(every), int(n_out), friction[0], friction[1], float(tol),
       int(maxiter), 1, DOP853_A, DOP853_B, OUT, IS, FS)
    return time.perf_counter() - t0, Y, OUT, IS, FS


def _bits_equal(a: np.ndarray, b: np.ndarray) -> bool:
    """Bit-for-bit equality of two float64 arrays (signed zeros and NaNs included)."""
    return a.shape == b.shape and np.array_equal(np.ascontiguousarray(a).view(np.uint64),
                                                 np.ascontiguousarray(b).view(np.uint64))


def _max_rel_diff(a: np.ndarray, b: np.ndarray) -> float:
    fa, fb = np.isfinite(a), np.isfinite(b)
    if not np.array_equal(fa, fb) or not np.array_equal(a[~fa], b[~fb], equal_nan=True):
        return math.inf
    if not fa.any():
        return 0.0
    scale = np.maximum(np.abs(a[fa]), np.abs(b[fb]))
    diff = np.abs(a[fa] - b[fb])
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(diff == 0.0, 0.0, diff / scale)
    return float(rel.max())


def _reset_peak_rss() -> bool:
    """Reset the process's peak RSS (Linux: VmHWM via /proc/self/clear_refs)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _rss_mb(field: str = "VmRSS") -> float:
    """Current (VmRSS) or peak (VmHWM) resident set size in MiB; NaN if unknown."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return math.nan


def _peak_rss_mb() -> float:
    """Peak resident set size in MiB (since the last reset where supported)."""
    peak = _rss_mb("VmHWM")
    if peak == peak:
        return peak
    kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return kb / 1024.0 if sys.platform != "darwin" else kb / 2**20


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="liethermo bench", description=__doc__.split("\n\n")[0])
    ap.add_argument("--members", type=int, nargs="+", default=[4096, 65536])
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--every", type=int, default=100)
    ap.add_argument("--h", type=float, default=0.1)
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--kernels", nargs="+", default=["simple", "fast"], choices=["simple", "fast"])
    ap.add_argument("--repeat", type=int, default=3, help="timed calls per case (best is kept)")
    ap.add_argument("--attitude", action="store_true", help="carry R (16-wide state)")
    ap.add_argument("--threads", type=int, default=None, help="numba threads (default: all)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default="bench_results.json", help="output JSON path ('' = none)")
    ap.add_argument("--no-startup", action="store_true",
                    help="skip timing `liethermo run paper` from a cold and a warm numba cache")
    ap.add_argument("--asm", action="store_true",
                    help="count packed SIMD instructions in the fast kernel's lane loops")
    args = ap.parse_args(argv)
    if args.steps % args.every:
        ap.error("--steps must be a multiple of --every")

    import numba

    if args.threads:
        numba.set_num_threads(args.threads)
    threads = numba.get_num_threads()

    import subprocess

    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import liethermo.simulate"], check=True)
    import_s = time.perf_counter() - t0
    # warm-up: compile or load every kernel once on a tiny ensemble
    compile_s = {}
    Yw, Pw = random_ensemble(64, seed=1, attitude=args.attitude)
    for kernel in args.kernels:
        t0 = time.perf_counter()
        for method in args.methods:
            run_kernel(kernel, method, Yw, Pw, args.h, args.every, args.every)
        compile_s[kernel] = time.perf_counter() - t0

    rows = []
    hdr = (f"{'kernel':<7}{'method':<7}{'members':>8}{'wall s':>9}{'ns/mstep':>10}"
           f"{'speedup':>9}{'agree':>10}{'arrays MB':>10}{'peakRSS MB':>11}{'(+MB)':>7}{'cpu%':>6}")
    print(f"liethermo bench: paper scene, random ensemble, h={args.h}, {args.steps} steps, "
          f"every {args.every}, {threads} threads, state width {7 + 9 * args.attitude}, "
          f"numba -O{int(numba.config.OPT)}")
    print(f"cpu: {_cpu_name()}")
    print(hdr)
    print("-" * len(hdr))
    if os.getloadavg()[0] > 0.5:
        print(f"note: 1-min load average {os.getloadavg()[0]:.1f} before the run: other processes "
              "may compete for the cores and inflate wall times")
    for N in args.members:
        Y0, P = random_ensemble(N, seed=args.seed, attitude=args.attitude)
        for method in args.methods:
            ref = None
            for kernel in args.kernels:
                best = math.inf
                _reset_peak_rss()
                rss0 = _rss_mb()
                for _ in range(max(1, args.repeat)):
                    Y = OUT = IS = FS = None  # free the previous call's arrays first
                    c0 = time.process_time()
                    dt, Y, OUT, IS, FS = run_kernel(kernel, method, Y0, P, args.h, args.steps,
                                                    args.every)
                    if dt < best:
                        best = dt
                        util = (time.process_time() - c0) / (dt * threads)
                nbytes = Y.nbytes + P.nbytes + OUT.nbytes + IS.nbytes + FS.nbytes
                row = dict(kernel=kernel, method=method, members=N, steps=args.steps,
                           every=args.every, h=args.h, threads=threads, wall_s=best,
                           ns_per_member_step=best / (N * args.steps) * 1e9,
                           arrays_mb=nbytes / 2**20, peak_rss_mb=_peak_rss_mb(),
                           peak_rss_increase_mb=_peak_rss_mb() - rss0,
                           cpu_util=util,
                           n_ok=int((IS[:, 0] == 0).sum()),
                           newton_mean=float(IS[:, 2].sum() / max(1, IS[:, 4].sum())))
                if ref is None:
                    ref = (row, Y, OUT, IS, FS)
                    row["speedup"] = 1.0
                    row["bitwise"] = True
                    row["max_rel_diff"] = 0.0
                else:
                    r0, Yr, OUTr, ISr, FSr = ref
                    row["speedup"] = r0["wall_s"] / best
                    row["bitwise"] = bool(_bits_equal(OUT, OUTr) and _bits_equal(Y, Yr)
                                          and np.array_equal(IS, ISr) and _bits_equal(FS, FSr))
                    row["max_rel_diff"] = max(_max_rel_diff(OUT, OUTr), _max_rel_diff(Y, Yr),
                                              _max_rel_diff(FS, FSr),
                                              0.0 if np.array_equal(IS, ISr) else math.inf)
                rows.append(row)
                agree = ("bitwise" if row["bitwise"] else f"{row['max_rel_diff']:.1e}")
                print(f"{kernel:<7}{method:<7}{N:>8}{best:>9.3f}{row['ns_per_member_step']:>10.2f}"
                      f"{row['speedup']:>9.2f}{agree:>10}{row['arrays_mb']:>10.1f}"
                      f"{row['peak_rss_mb']:>11.0f}{row['peak_rss_increase_mb']:>7.0f}{100 * util:>6.0f}")
    print(f"start-up: import liethermo.simulate {import_s:.2f} s (fresh interpreter); first call "
          "of each kernel (cache load or compile), all methods: "
          + ", ".join(f"{k} {v:.2f} s" for k, v in compile_s.items()))
    startup = None if args.no_startup else startup_report()
    if startup:
        print(f"liethermo run paper: cold start {startup['cold_s']:.1f} s (empty numba cache), "
              f"warm start {startup['warm_s']:.2f} s (best of {len(startup['warm_runs_s'])}), "
              f"peak RSS {startup['warm_peak_rss_mb']:.0f} MB")
    asm = asm_report() if args.asm else None
    if asm:
        print("hot loop of each lane sweep (fresh compile), per iteration = one vector of lanes:")
        for name, c in asm.items():
            if not c:
                print(f"  {name:<19} no vectorized loop found")
                continue
            print(f"  {name:<19} {c['width']} ({c['lanes']} lanes): {c['instructions']:>4} instructions,"
                  f" packed arithmetic {c['packed']:>3} (fma {c['fma']:>3}, mul {c['mul']:>3},"
                  f" add/sub {c['addsub']:>3}, div {c['div']}), memory operands {c['mem']:>3}"
                  f" (stack {c['stack']:>3}, stores {c['stores']:>3}), masked {c['masked']}")
    if args.json:
        import numba as _nb

        from . import __version__

        doc = dict(
            machine=dict(platform=platform.platform(), processor=platform.processor(),
                         cpu=_cpu_name(), cores=os.cpu_count(), threads=threads,
                         numba=_nb.__version__, numpy=np.__version__, python=sys.version.split()[0]),
            liethermo=__version__, created=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            scene="paper (SPEC §2), random ensemble", import_s=import_s, warmup_s=compile_s,
            asm=asm, startup=startup, results=rows,
        )
        tmp = args.json + ".tmp"
        with open(tmp, "w") as f:
            json.dump(doc, f, indent=1)
        os.replace(tmp, args.json)
        print(f"wrote {args.json}")
    return 0


def startup_report(warm_runs: int = 3) -> dict:
    """Wall time of the whole command ``liethermo run paper`` (VI + RK2 + 4 figures) in a
    fresh interpreter: once with an empty numba cache (cold: every kernel compiles), then
    ``warm_runs`` times with that cache (warm: kernels load)."""
    import resource
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=os.path.join(tmp, "cache"))
        cmd = [sys.executable, "-m", "liethermo.cli", "run", "paper", "-o",
               os.path.join(tmp, "paper.nc"), "--no-progress"]

        def once() -> float:
            t0 = time.perf_counter()
            subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL)
            return time.perf_counter() - t0

        cold = once()
        warm = [once() for _ in range(warm_runs)]
    rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    return dict(cold_s=cold, warm_s=min(warm), warm_runs_s=warm, warm_peak_rss_mb=rss)


def hot_loop_counts(asm: str) -> dict:
    """Instruction counts of the hottest loop of an x86-64 listing: the backward
    jump whose body holds the most packed (ymm/zmm) instructions.

    ``width``: register width of the packed code (``zmm`` = 8 doubles, ``ymm`` = 4);
    ``packed``: packed double arithmetic (add/sub/mul/div/sqrt/FMA) of which
    ``fma``, ``mul``, ``addsub``, ``div``; ``mem``: packed instructions that read or
    write memory, of which ``stack`` address the stack (spilled registers)
    and ``stores`` write; ``masked``: masked loads and stores (``vmaskmovpd``:
    a masked store is slow microcode on AMD Zen 2/3); ``instructions``: all
    instructions of the body."""
    import re

    lines = asm.splitlines()
    labels = {}
    for k, line in enumerate(lines):
        m = re.match(r"^\s*(\.?L\w+):", line)
        if m:
            labels[m.group(1)] = k
    best = None
    for k, line in enumerate(lines):
        m = re.match(r"\s*j\w+\s+(\.?L\w+)\s*$", line)
        if m and labels.get(m.group(1), k) < k:
            body = lines[labels[m.group(1)]:k + 1]
            npk = sum(("%ymm" in b or "%zmm" in b) for b in body)
            if best is None or npk > best[0]:
                best = (npk, body)
    if best is None:
        return {}
    body = [b for b in best[1] if b.strip() and not b.strip().startswith((".", "#"))
            and not b.strip().endswith(":")]
    width = "zmm" if any("%zmm" in b for b in body) else "ymm"
    packed = [b for b in body if f"%{width}" in b]

    def count(pattern, rows=packed):
        return sum(1 for b in rows if re.match(r"\s*" + pattern + r"\b", b))

    arith = r"v(?:mul|div|add|sub|sqrt|fn?m(?:add|sub)\d*)pd"
    return dict(width=width, lanes=8 if width == "zmm" else 4, instructions=len(body),
                packed=count(arith), fma=count(r"vfn?m(?:add|sub)\d*pd"), mul=count("vmulpd"),
                addsub=count(r"v(?:add|sub)pd"), div=count("vdivpd"),
                mem=sum(1 for b in packed if "(" in b),
                stack=sum(1 for b in packed if "(%rsp)" in b),
                stores=sum(1 for b in packed if re.match(r"\s*vmov\w*\s+%[yz]mm\d+,\s*[^%\s]", b)),
                masked=count(r"vp?maskmov\w*"))


def asm_report() -> dict:
    """Instruction counts (:func:`hot_loop_counts`) of the lane loops of fresh
    (uncached) compilations of the fast kernel's sweeps, to confirm that LLVM
    vectorized them and to see what bounds their speed."""
    from .kernels import fast as F
    from .kernels.model import coefficients
    from .kernels.vi import vi_coefficients

    S = np.ones(F.NROWS * F.ROW)
    pp = F._load_params(S, 0)
    qq = coefficients(pp)
    vv = vi_coefficients(pp, 0.1, 0.5, 0.5)
    # an ensemble that shares its parameters (coefficient tuples) and a mixed
    # one (None: per-lane rows); the RK sweeps' last argument (which state
    # buffer is the source) is a literal in the kernel: see fresh_sweep_asm
    cases = {
        "_rk2_sweep": (F._rk2_sweep, (S, 8, 0.1, qq, 0)),
        "_rk2_sweep[rows]": (F._rk2_sweep, (S, 8, 0.1, None, 1)),
        "_rk4_sweep": (F._rk4_sweep, (S, 8, 0.1, qq, 0)),
        "_rk4_sweep[rows]": (F._rk4_sweep, (S, 8, 0.1, None, 1)),
        "_vi_prepare": (F._vi_prepare, (S, 8, 0.1, 1e-14, True, qq, vv)),
        "_vi_prepare[rows]": (F._vi_prepare, (S, 8, 0.1, 1e-14, True, None, None)),
        "_newton_sweep": (F._newton_sweep, (S, 8, 1e-14, 1, vv)),
        "_newton_sweep[rows]": (F._newton_sweep, (S, 8, 1e-14, 1, None)),
        "_vi_check": (F._vi_check, (S, 8)),
    }
    return {name: hot_loop_counts(fresh_sweep_asm(f, a)) for name, (f, a) in cases.items()}


def fresh_sweep_asm(f, args) -> str:
    """x86 listing of a fresh (uncached) compilation of the kernel function f
    for args.  The RK sweeps (whose last argument picks the source state
    buffer) are compiled as the kernel calls them, with that argument a
    literal, through a jitted caller."""
    import numba

    g = numba.njit(fastmath=False, error_model="numpy")(f.py_func)
    if f.__name__ in ("_rk2_sweep", "_rk4_sweep"):
        flip = args[-1]
        head = args[:-1]
        if flip == 0:
            caller = numba.njit(lambda S, nb, h, qq: g(S, nb, h, qq, 0))
        else:
            caller = numba.njit(lambda S, nb, h, qq: g(S, nb, h, qq, 1))
        caller(*head)
        sig = next(s for s in g.signatures if isinstance(s[-1], numba.types.IntegerLiteral))
        return g.inspect_asm(sig)
    g(*args)
    return g.inspect_asm(g.signatures[0])


def _cpu_name() -> str:
    """Model name, family/model and widest SIMD of the CPU ("AMD EPYC (family 25
    model 1, avx2)"): VMs often hide the model name, and the SIMD width decides
    how many lanes one packed instruction advances (4 with AVX2, 8 with AVX-512)."""
    info = {}
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                key, _, value = line.partition(":")
                info.setdefault(key.strip(), value.strip())
    except OSError:
        return platform.processor()
    flags = info.get("flags", "").split()
    simd = "avx512" if "avx512f" in flags else "avx2" if "avx2" in flags else "sse"
    return (f"{info.get('model name', platform.processor())} (family {info.get('cpu family', '?')}"
            f" model {info.get('model', '?')}, {simd})")


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
