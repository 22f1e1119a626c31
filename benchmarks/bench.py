"""Kernel benchmark: ns per member-step of the ensemble kernels.

``python benchmarks/bench.py`` times the variational integrators (vi, vi4,
vi6), the explicit splitting (split, split4, split6) and the explicit RK2 /
RK4 on a random ensemble of the paper scene —
attitudes uniform on SO(3) (so Γ = Rᵀe₃ uniform on S²), spins uniform in
direction with |Ω₀| uniform in [0.5, 1.5]·√2 rad s⁻¹ — at h = 0.1 s, for
``--steps`` steps keeping every ``--every``-th state, with

* ``simple``: the straightforward kernel, one member at a time (the baseline);
* ``fast``: the structure-of-arrays block kernel (same results, bitwise).

The ``vi`` method runs with the paper's choices (first step velocity Ω(0),
trapezoid friction, explicit entropy update) so that its figures compare
with earlier kernels; vi4 and vi6 use their own (node momentum start,
symmetric entropy update).

Reported per (variant, kernel, method, members): kernel wall time of one run
(best of ``--repeat``, compilation excluded: the first call of every kernel
compiles it or loads it from numba's cache), ns per member-step =
wall / (members · steps) with all threads, the speed-up over ``simple``,
whether the results agree bitwise with ``simple`` (else the largest relative
difference), the members that completed, and Newton iterations per step.

``--variants`` runs other models than the paper's top, to see what a term
costs: ``no_gravity`` (g = 0), ``no_friction`` (μ = 0: no friction, no
entropy), ``coupled`` (the coupled top of the ``coupled_egg`` scene, with
entropy-dependent inertia) and ``coupled_alpha0`` (the same scene with
α = 0: the decoupled kernel on the same motion).

``--scenes`` times what users run: a built-in scene's own ensemble
(``ensemble.members`` drawn from its seed, default 65 536 members × 2 000
steps) through the same driver as ``liethermo run`` (``runner.run_scene``,
in memory: member chunks, labelling and summary included), for each method
of ``--scene-methods``, over ``--rounds`` rounds that alternate the methods:
the whole run's wall time and its kernel time alone, each as min / median /
max in ns per member-step.  Shared machines move these figures by ±20 % from
one run to the next; the spread over rounds says how much.

Start-up (``liethermo run paper`` from a cold and a warm numba cache, in a
fresh process) is timed unless ``--no-startup``; ``--asm`` counts the
instructions of the hot loop of each of the fast kernel's sweeps (packed
``v*pd`` arithmetic, FMAs, memory operands, spills) to confirm that LLVM
vectorized them.  The table goes to stdout, the numbers to a JSON file
(``--out PATH``, default ``benchmarks/out/results.json``, which git ignores; the
tracked ``benchmarks/results.json`` is the recorded reference of
benchmarks/README.md and is rewritten only with ``--out benchmarks/results.json``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("NUMBA_OPT", "2")  # as the liethermo console script (numba reads it on import)

import numpy as np  # noqa: E402

METHODS = ("vi", "vi4", "vi6", "split", "split4", "split6", "rk2", "rk4")
VARIANTS = ("paper", "no_gravity", "no_friction", "coupled", "coupled_alpha0")
HERE = os.path.dirname(os.path.abspath(__file__))


def variant_physics(variant: str, N: int):
    """The physics of a benchmark variant, N members."""
    from liethermo.top.physics import physics_of_scene
    from liethermo.scene import load_scene

    if variant == "paper":
        scene = load_scene("paper")
    elif variant == "no_gravity":
        scene = load_scene("paper", {"gravity.g": 0.0})
    elif variant == "no_friction":
        scene = load_scene("paper", {"fluid.viscosity": 0.0})
    elif variant in ("coupled", "coupled_alpha0"):
        scene = load_scene("coupled_egg")
    else:
        raise ValueError(f"unknown variant {variant!r}: expected one of {VARIANTS}")
    phys = physics_of_scene(scene, N)
    if variant == "coupled_alpha0":
        phys = dataclasses.replace(phys, thermal_expansion=np.zeros(N))
    return phys


def random_ensemble(N: int, seed: int = 0):
    """(Ω₀, R₀) of N random members (see module docstring)."""
    from liethermo.top.initial import quat_to_matrix

    rng = np.random.default_rng(seed)
    q = rng.standard_normal((N, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    R = quat_to_matrix(q)
    d = rng.standard_normal((N, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * (rng.uniform(0.5, 1.5, N) * math.sqrt(2.0))[:, None], R


def run(kernel, method, phys, om0, R0, h, steps, every, attitude, threads):
    from liethermo.top.methods import MethodChoice
    from liethermo.top.simulate import simulate

    kw = {"start": "node", "entropy": "explicit"} if method == "vi" else {}
    if phys.n and np.any(phys.thermal_expansion) and method == "vi":
        kw = {}  # the coupled top starts from its node momentum
    # the heat bound a run passes (its scene's): here the largest of this ensemble
    from liethermo.top.physics import mechanical_energy_scale

    heat = float(np.max(mechanical_energy_scale(phys, om0, R0[:, 2, :]), initial=0.0)) if phys.n else None
    return simulate(phys, om0, R0, h, steps, MethodChoice.of(method, **kw), every=every, attitude=attitude,
                    threads=threads, kernel=kernel, heat_bound=heat)


def scene_report(scenes, methods, members: int, steps: int, rounds: int) -> list[dict]:
    """Wall and kernel time of each (scene, method) run through runner.run_scene
    (in memory), over ``rounds`` rounds alternating the methods; the first run
    of each, which compiles or loads its kernels, is not counted."""
    from liethermo.runner import run_scene
    from liethermo.scene import load_scene

    out = []
    for name in scenes:
        cases = [load_scene(name, {"ensemble.members": members, "integrator.steps": steps,
                                   "integrator.method": m, "output.compare": [], "output.every": steps // 10,
                                   "output.figures": False}) for m in methods]
        for sc in cases:  # compile (or load) first
            run_scene(sc.with_overrides({"ensemble.members": 64, "integrator.steps": steps // 100 or 1,
                                          "output.every": 1}), None, progress=False)
        times = {m: ([], []) for m in methods}
        newton = {}
        for _ in range(max(1, rounds)):
            for m, sc in zip(methods, cases):
                t0 = time.perf_counter()
                ds, summ = run_scene(sc, None, progress=False)
                wall = time.perf_counter() - t0
                del ds
                times[m][0].append(wall / (members * steps) * 1e9)
                times[m][1].append(summ.kernel_time / (members * steps) * 1e9)
                newton[m] = summ.newton_mean
        for m in methods:
            w, k = np.array(times[m][0]), np.array(times[m][1])
            out.append(dict(scene=name, method=m, members=members, steps=steps, rounds=len(w),
                            run_ns=[float(w.min()), float(np.median(w)), float(w.max())],
                            kernel_ns=[float(k.min()), float(np.median(k)), float(k.max())],
                            newton_per_solve=float(newton[m])))
    return out


def _bits_equal(a: np.ndarray, b: np.ndarray) -> bool:
    if a.dtype.kind != "f":
        return np.array_equal(a, b)
    return a.shape == b.shape and np.array_equal(np.ascontiguousarray(a).view(np.uint64),
                                                 np.ascontiguousarray(b).view(np.uint64))


def _max_rel_diff(a: np.ndarray, b: np.ndarray) -> float:
    fa, fb = np.isfinite(a), np.isfinite(b)
    if not np.array_equal(fa, fb):
        return math.inf
    if not fa.any():
        return 0.0
    scale = np.maximum(np.abs(a[fa]), np.abs(b[fb]))
    diff = np.abs(a[fa] - b[fb])
    with np.errstate(invalid="ignore", divide="ignore"):
        return float(np.where(diff == 0.0, 0.0, diff / scale).max())


def _outputs(tr):
    return (tr.states, tr.status, tr.fail_step, tr.newton_iterations, tr.newton_max,
            tr.steps_done, tr.max_h_omega)


def cpu_name() -> str:
    """Model name, family/model and widest SIMD of the CPU: VMs often hide the
    model name, and the SIMD width decides how many lanes one packed
    instruction advances (4 doubles with AVX2, 8 with AVX-512)."""
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


def startup_report(warm_runs: int = 3) -> dict:
    """Wall time of ``liethermo run paper`` (VI + RK2 + 4 figures) in a fresh
    process: once with an empty numba cache (cold: every kernel compiles),
    then ``warm_runs`` times with that cache (warm: kernels load)."""
    import resource

    exe = shutil.which("liethermo")
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=os.path.join(tmp, "cache"))
        env.pop("NUMBA_OPT", None)  # the console script sets its own
        base = [exe] if exe else [sys.executable, "-m", "liethermo.cli"]
        cmd = base + ["run", "paper", "-o", os.path.join(tmp, "paper.nc"), "--no-progress"]

        def once() -> float:
            t0 = time.perf_counter()
            subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL)
            return time.perf_counter() - t0

        cold = once()
        warm = [once() for _ in range(warm_runs)]
    rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    return dict(command="liethermo run paper", cold_s=cold,
                warm_s=min(warm), warm_runs_s=warm, warm_peak_rss_mb=rss)


def hot_loop_counts(asm: str) -> dict:
    """Instruction counts of the hottest loop of an x86-64 listing: the
    backward jump whose body holds the most packed (ymm/zmm) instructions.

    ``width``: register width (``zmm`` = 8 doubles, ``ymm`` = 4); ``packed``:
    packed double arithmetic (add/sub/mul/div/sqrt/FMA) of which ``fma``,
    ``mul``, ``addsub``, ``div``; ``mem``: packed instructions that read or
    write memory, of which ``stack`` address the stack (spilled registers)
    and ``stores`` write; ``masked``: masked loads and stores (``vmaskmovpd``
    is slow microcode on AMD Zen 2/3); ``instructions``: all of the body."""
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
    """Hot-loop counts of the fast kernel's sweeps for the paper model, from
    fresh (uncached) compilations (shared parameters: the model lives in
    registers).  The RK sweep is compiled as the kernel calls it, through a
    jitted caller: its buffer direction a literal, its lane count a runtime
    value (a literal lane count equal to the vector width lets LLVM replace
    the loop by one straight-line vector, which has no loop to count)."""
    import numba

    from liethermo.top.kernels import fast as F
    from liethermo.top.kernels import rk
    from liethermo.top.kernels.terms.thermo import EXPLICIT
    from liethermo.top.kernels.vi import vi_coefficients
    from liethermo.top.physics import build_model

    def fresh(f):
        return numba.njit(fastmath=False, error_model="numpy")(f.py_func)

    model = build_model(variant_physics("paper", 1)).model
    S = np.ones(F.buffer_size(0))
    vv = vi_coefficients(model, 0.1, 0.5, 0.5)
    out = {}
    from liethermo.top.methods import METHODS as M

    for name, tab in (("rk2 sweep", rk.MIDPOINT), ("rk4 sweep", rk.RK4)):
        g = fresh(F._rk_sweep)
        caller = numba.njit(lambda tab, model, S, nb: g(tab, model, model, S, nb, 0.1, 0))
        caller(tab, model, S, 8)
        sig = next(s for s in g.signatures if isinstance(s[-1], numba.types.IntegerLiteral))
        out[name] = hot_loop_counts(g.inspect_asm(sig))
    # the splitting's block step is five passes over the lanes (a Strang stage each),
    # inlined into one function; each is compiled alone here to count its loop
    first, stage, last = F._split_first, F._split_stage_pass, F._split_last
    passes = (("split stage 0", lambda model, S, nb: first(model, model, S, nb, 0.1, 0)),
              ("split stage 1-3", lambda model, S, nb: stage(model, model, S, nb, 2, 0.1, 0)),
              ("split stage 4", lambda model, S, nb: last(model, model, S, nb, 0.1, 0)))
    for name, body in passes:
        g = numba.njit(fastmath=False, error_model="numpy")(body)
        g(model, S, 8)
        out[name] = hot_loop_counts(g.inspect_asm(g.signatures[0]))
    out["split step (0 + 3×(1-3) + 4)"] = {
        k: (out["split stage 0"][k] + 3 * out["split stage 1-3"][k] + out["split stage 4"][k]
            if isinstance(out["split stage 0"][k], int) and k != "lanes" else out["split stage 0"][k])
        for k in out["split stage 0"]}
    cases = (("vi prepare", F._vi_prepare,
              (model, model, S, 8, vv, vv, 0.1, 0.1, 1.0, 0.5, 0.5, EXPLICIT, 1e-14, True)),
             ("vi newton", F._newton_sweep, (model, model, S, 8, vv, 0.1, 0.5, 0.5, 1e-14, 2)),
             ("vi check", F._vi_check, (model, model, S, 8)))
    for name, f, args in cases:
        g = fresh(f)
        g(*args)
        out[name] = hot_loop_counts(g.inspect_asm(g.signatures[0]))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="benchmarks/bench.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--members", type=int, nargs="+", default=[4096, 65536])
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--every", type=int, default=100)
    ap.add_argument("--h", type=float, default=0.1)
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--variants", nargs="+", default=["paper"], choices=VARIANTS)
    ap.add_argument("--kernels", nargs="+", default=["simple", "fast"], choices=["simple", "fast"])
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per case (best is kept)")
    ap.add_argument("--attitude", action="store_true", help="integrate R as well")
    ap.add_argument("--threads", type=int, default=None, help="threads (default: all cores)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", "--json", dest="json", default=os.path.join(HERE, "out", "results.json"),
                    metavar="PATH", help="output JSON path ('' = none; default benchmarks/out/results.json, "
                    "ignored by git; --out benchmarks/results.json updates the recorded reference)")
    ap.add_argument("--no-startup", action="store_true",
                    help="skip timing `liethermo run paper` from a cold and a warm numba cache")
    ap.add_argument("--asm", action="store_true",
                    help="count packed SIMD instructions in the fast kernel's lane loops")
    ap.add_argument("--scenes", nargs="*", default=None, metavar="SCENE",
                    help="also time these built-in scenes' own ensembles through the run driver "
                    "(no name: paper)")
    ap.add_argument("--scene-methods", nargs="+", default=["vi", "rk4"], choices=METHODS)
    ap.add_argument("--scene-members", type=int, default=65536)
    ap.add_argument("--scene-steps", type=int, default=2000)
    ap.add_argument("--rounds", type=int, default=5, help="rounds of the --scenes timing")
    args = ap.parse_args(argv)
    if args.steps % args.every:
        ap.error("--steps must be a multiple of --every")

    import numba

    from liethermo import __version__
    from liethermo.top.kernels.parallel import default_threads

    threads = args.threads or default_threads()
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import liethermo.top.simulate"], check=True)
    import_s = time.perf_counter() - t0
    rows = []
    hdr = (f"{'variant':<15}{'kernel':<7}{'method':<7}{'members':>8}{'wall s':>9}{'ns/mstep':>10}"
           f"{'speedup':>9}{'agree':>10}{'ok':>7}{'newton':>8}{'compile s':>10}")
    print(f"bench: random ensemble, h={args.h}, {args.steps} steps, every {args.every}, "
          f"{threads} threads, attitude {args.attitude}, numba -O{int(numba.config.OPT)}")
    print(f"cpu: {cpu_name()}")
    print(hdr)
    print("-" * len(hdr))
    if os.getloadavg()[0] > 0.5:
        print(f"note: 1-min load average {os.getloadavg()[0]:.1f} before the run: other processes "
              "may compete for the cores and inflate wall times")
    for variant in args.variants:
        for N in args.members:
            phys = variant_physics(variant, N)
            om0, R0 = random_ensemble(N, seed=args.seed)
            for method in args.methods:
                ref = None
                for kernel in args.kernels:
                    best, tr, comp = math.inf, None, 0.0
                    for rep in range(max(1, args.repeat)):
                        tr = None  # free the previous run's arrays first
                        tr = run(kernel, method, phys, om0, R0, args.h, args.steps, args.every,
                                 args.attitude, threads)
                        comp = max(comp, tr.compile_time)
                        best = min(best, tr.wall_time)
                    out = _outputs(tr)
                    row = dict(variant=variant, kernel=kernel, method=method, members=N,
                               steps=args.steps, every=args.every, h=args.h, threads=threads,
                               wall_s=best, ns_per_member_step=best / (N * args.steps) * 1e9,
                               compile_s=comp, n_ok=int((tr.status == 0).sum()),
                               newton_per_step=float(tr.newton_iterations.sum()
                                                     / max(1, tr.steps_done.sum())))
                    if ref is None:
                        ref = (row, out)
                        row.update(speedup=1.0, bitwise=True, max_rel_diff=0.0)
                    else:
                        r0, out0 = ref
                        row["speedup"] = r0["wall_s"] / best
                        row["bitwise"] = all(_bits_equal(a, b) for a, b in zip(out, out0))
                        row["max_rel_diff"] = max(
                            (_max_rel_diff(a, b) if a.dtype.kind == "f"
                             else (0.0 if np.array_equal(a, b) else math.inf))
                            for a, b in zip(out, out0))
                    rows.append(row)
                    agree = "bitwise" if row["bitwise"] else f"{row['max_rel_diff']:.1e}"
                    print(f"{variant:<15}{kernel:<7}{method:<7}{N:>8}{best:>9.3f}"
                          f"{row['ns_per_member_step']:>10.2f}{row['speedup']:>9.2f}{agree:>10}"
                          f"{row['n_ok']:>7}{row['newton_per_step']:>8.2f}{comp:>10.2f}")
    print(f"import liethermo.top.simulate: {import_s:.2f} s (fresh interpreter, compiles nothing)")
    startup = None if args.no_startup else startup_report()
    if startup:
        print(f"{startup['command']}: cold start {startup['cold_s']:.1f} s (empty numba cache), "
              f"warm start {startup['warm_s']:.2f} s (best of {len(startup['warm_runs_s'])})")
    scenes = None
    if args.scenes is not None:
        scenes = scene_report(args.scenes or ["paper"], args.scene_methods, args.scene_members,
                              args.scene_steps, args.rounds)
        print(f"scene runs through the run driver ({args.scene_members} members x {args.scene_steps} steps, "
              f"{args.rounds} rounds alternating the methods), ns per member-step min / median / max:")
        for r in scenes:
            print(f"  {r['scene']:<14}{r['method']:<5} whole run {r['run_ns'][0]:6.2f} / {r['run_ns'][1]:6.2f} / "
                  f"{r['run_ns'][2]:6.2f}   kernels {r['kernel_ns'][0]:6.2f} / {r['kernel_ns'][1]:6.2f} / "
                  f"{r['kernel_ns'][2]:6.2f}   Newton per solve {r['newton_per_solve']:.2f}")
    asm = asm_report() if args.asm else None
    if asm:
        print("hot loop of each sweep (paper model, shared parameters), per iteration:")
        for name, c in asm.items():
            if not c:
                print(f"  {name:<29} no vectorized loop found")
                continue
            print(f"  {name:<29} {c['width']} ({c['lanes']} lanes): {c['instructions']:>4} "
                  f"instructions, packed arithmetic {c['packed']:>3} (fma {c['fma']:>3}, mul "
                  f"{c['mul']:>3}, add/sub {c['addsub']:>3}, div {c['div']}), memory operands "
                  f"{c['mem']:>3} (stack {c['stack']:>3}, stores {c['stores']:>3}), masked {c['masked']}")
    if args.json:
        doc = dict(
            machine=dict(platform=platform.platform(), cpu=cpu_name(), cores=os.cpu_count(),
                         threads=threads, numba=numba.__version__, numpy=np.__version__,
                         python=sys.version.split()[0]),
            liethermo=__version__, created=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            import_s=import_s, asm=asm, startup=startup, results=rows, scenes=scenes)
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        tmp = args.json + ".tmp"
        with open(tmp, "w") as f:
            json.dump(doc, f, indent=1)
        os.replace(tmp, args.json)
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
