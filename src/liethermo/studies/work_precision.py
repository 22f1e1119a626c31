"""Work–precision study: wall time (and Newton iterations / right-hand-side
evaluations) against the error at ``t_end``.

Methods compared on the same ensemble of random initial conditions:

* liethermo's kernels — the variational integrators (``vi`` with the
  legendre start, ``vi4``, ``vi6``, or any method spec), RK2 and RK4 — at a
  ladder of fixed steps h, compared on NODE values (Ω(t_end), Γ(t_end)); every
  level runs on the vectorized block kernel ("fast", the one a large run uses),
  warm (compiled before timing), on ``threads`` numba threads (default one, so
  that their cost per member compares fairly with
* scipy's ``solve_ivp`` (RK45, DOP853) at a ladder of tolerances, which is
  what a user would otherwise reach for.  scipy integrates **one member at a
  time, serially**, calling the numba-jitted right-hand side through a small
  Python wrapper (so the cost is dominated by scipy's per-step Python
  overhead, not by the model)).

Error of a member: ``max(|Ω − Ω_ref| / |Ω(0)|, |Γ − Γ_ref|)`` (dimensionless),
the reference being the fixed-step DOP853 with automatic substeps (error
~1e-15; checked against twice as many substeps and reported).  The error of a
run is the maximum over its members.

Options (``[options]`` of the study file): ``t_end`` (s), ``members``,
``h`` (list, s), ``scipy_methods``, ``scipy_rtol`` (list), ``scipy_atol_factor``
(atol = factor·rtol), ``scipy_members`` (members integrated by scipy),
``epsilons`` (targets of the time-to-error table), ``threads`` (numba threads
for the liethermo kernels, default 1), ``min_timing`` (s of timed repeats per
level, at least; the cost is their minimum) and ``timing_member_steps`` (a
timed run integrates the members repeated until it covers at least this many
member-steps).
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np
import xarray as xr

from ..initial import initial_conditions
from ..methods import METHODS
from ..physics import physics_of_scene
from ..simulate import simulate
from .common import (closing_section, parse_method, study_options, StudyError, cached_point, point_key, progress_bar, study_name,
                     study_netcdf_path, study_scene, write_netcdf_atomic, write_report, write_table, start_study,
                     study_history)
from .tools import NODE_VALUES_NOTE, continuous_rhs, repeat_timing, run_spec

EXTRA_KEYS = ()

DEFAULT_OPTIONS = {
    "t_end": 10.0,
    "members": 32,
    "h": [0.2, 0.1, 0.05, 0.025, 0.0125, 0.00625, 0.003125, 0.0015625, 0.00078125],
    "scipy_methods": ["RK45", "DOP853"],
    "scipy_rtol": [1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12],
    "scipy_atol_factor": 1e-3,
    "scipy_members": 4,
    "epsilons": [1e-3, 1e-6, 1e-9],
    "threads": 1,
    "min_timing": 0.2,
    "timing_member_steps": 2**18,
}
#: the ensemble loop every level is timed on: the one a large run uses
#: (:func:`liethermo.simulate.kernel_for`), whatever the level's size
KERNEL = "fast"
SCIPY_METHODS = ("RK23", "RK45", "DOP853")


#: Printed (and added to the report) when the study is asked to use Dask.
DASK_NOTE = ("work_precision ignores --dask and runs in-process: its wall times per member-step are the "
             "measurement, and tasks on Dask workers (shared cores, other tasks, worker overhead) would "
             "distort them.")


def options(study: dict) -> dict:
    return study_options(study, DEFAULT_OPTIONS, "work_precision")


def validate(study: dict) -> None:
    opt = options(study)
    if not (isinstance(opt["t_end"], (int, float)) and opt["t_end"] > 0):
        raise StudyError("options.t_end: must be a number > 0 (s)")
    for k in ("members", "scipy_members", "threads", "timing_member_steps"):
        if not (isinstance(opt[k], int) and opt[k] >= 1):
            raise StudyError(f"options.{k}: must be an integer ≥ 1")
    if not (isinstance(opt["min_timing"], (int, float)) and opt["min_timing"] > 0):
        raise StudyError("options.min_timing: must be a number > 0 (s)")
    if opt["scipy_members"] > opt["members"]:
        raise StudyError("options.scipy_members: must be ≤ options.members")
    for k in ("h", "scipy_rtol", "epsilons"):
        v = opt[k]
        if not isinstance(v, list) or not all(isinstance(x, (int, float)) and x > 0 for x in v):
            raise StudyError(f"options.{k}: must be a list of numbers > 0")
    for h in opt["h"]:
        n = opt["t_end"] / h
        if abs(n - round(n)) > 1e-9 * n:
            raise StudyError(f"options.h: every h must divide t_end = {opt['t_end']} (got {h})")
    for m in opt["scipy_methods"]:
        if m not in SCIPY_METHODS:
            raise StudyError(f"options.scipy_methods: unknown scipy method {m!r}; known: {', '.join(SCIPY_METHODS)}")
    for m in study.get("methods", ["vi", "rk2", "rk4"]):
        if parse_method(m)["method"] == "reference":
            raise StudyError("methods: 'reference' is the ground truth, not a compared method")


# ----------------------------------------------------------------------------- numerics

def ensemble(scene, members: int):
    """(physics, Ω(0) (N, 3), R(0) (N, 3, 3), |Ω(0)| (N,)) of ``members`` random initial conditions."""
    sc = scene.with_overrides({"ensemble.members": int(members)})
    om, R = initial_conditions(sc)
    return physics_of_scene(sc, members), om, R, np.linalg.norm(om, axis=1)


def reference_at(phys, om, R, T: float, *, check: bool = False):
    """Reference (Ω, Γ) at time T, each (N, 3) (fixed-step DOP853, auto
    substeps); with ``check``: also the max difference to twice as many substeps."""
    tr = simulate(phys, om, R, float(T), 1, "reference")
    ref = (tr.omega[:, 1], tr.gamma[:, 1])
    if not check:
        return ref, float("nan")
    tr2 = simulate(phys, om, R, float(T), 1, "reference", ref_substeps=2 * tr.reference_substeps)
    return ref, float(max(np.max(np.abs(tr2.omega[:, 1] - ref[0])), np.max(np.abs(tr2.gamma[:, 1] - ref[1]))))


def member_errors(omega, gamma, ref_omega, ref_gamma, omega0_norm):
    """max(|ΔΩ|/|Ω(0)|, |ΔΓ|) per member (inf where not finite)."""
    e = np.maximum(np.linalg.norm(omega - ref_omega, axis=-1) / omega0_norm,
                   np.linalg.norm(gamma - ref_gamma, axis=-1))
    return np.where(np.isfinite(e), e, np.inf)


def run_kernel_point(method: str, h: float, t_end: float, phys, om, R, w0, threads: int,
                     min_time: float, ref, timing_member_steps: int) -> xr.Dataset:
    """One (method spec, h) level; the whole call runs on ``threads`` numba threads."""
    import numba

    old = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        return _kernel_point(method, h, t_end, phys, om, R, w0, threads, min_time, ref, timing_member_steps)
    finally:
        numba.set_num_threads(old)


def timing_copies(members: int, steps: int, timing_member_steps: int) -> int:
    """How many copies of the ensemble one timed run integrates: enough that it
    covers at least ``timing_member_steps`` member-steps, so that what a call
    costs besides its steps (setting up, the start, dispatch) does not show."""
    return max(1, -(-int(timing_member_steps) // max(members * steps, 1)))


def _kernel_point(method, h, t_end, phys, om, R, w0, threads, min_time, ref, timing_member_steps):
    steps = int(round(t_end / h))
    spec = parse_method(method)
    kw = dict(threads=threads, kernel=KERNEL)
    run_spec(phys, om, R, h, steps, spec, every=steps, compile_only=True, **kw)  # compile or load from cache
    tr = run_spec(phys, om, R, h, steps, spec, every=steps, **kw)  # the errors (and a warm-up)
    N = om.shape[0]
    copies = timing_copies(N, steps, timing_member_steps)
    idx = np.tile(np.arange(N), copies)
    tp, tom, tR = phys.take(idx), om[idx], R[idx]
    walls = repeat_timing(lambda: run_spec(tp, tom, tR, h, steps, spec, every=steps, **kw), min_time)
    ref_O, ref_G = ref
    err = member_errors(tr.omega[:, -1], tr.gamma[:, -1], ref_O, ref_G, w0)
    m = METHODS[spec["method"]]
    if m.implicit:
        evals = tr.newton_iterations.astype(float)
    else:
        evals = np.full(N, float(m.evaluations_per_step * steps))
    member_steps = float(copies * N * steps)
    return xr.Dataset({
        "error": ("member", err),
        "evals": ("member", evals),
        "status": ("member", tr.status.astype(np.int8)),
        "newton_max": ("member", tr.newton_max.astype(np.int64)),
        "max_h_omega": ("member", tr.max_h_omega),
        "wall_repeats": ("repeat", walls / member_steps),
    }, attrs={"wall": float(np.min(walls)) / (copies * N) * N, "steps": steps, "h": h, "members": N,
              "timed_members": copies * N, "repeats": walls.size, "kernel": KERNEL, "threads": threads})


def run_scipy_point(sp_method: str, rtol: float, atol: float, t_end: float, phys, om, R, w0) -> xr.Dataset:
    from scipy.integrate import solve_ivp

    M = om.shape[0]
    (ref_O, ref_G), _ = reference_at(phys, om, R, t_end)
    y0 = np.concatenate([om, R[:, 2, :], np.zeros((M, 1))], axis=1)
    f0 = continuous_rhs(phys, 0)
    solve_ivp(f0, (0.0, 0.1), y0[0].copy(), method=sp_method, rtol=rtol, atol=atol)  # warm scipy and numba
    walls = np.empty(M)
    nfev = np.empty(M)
    nsteps = np.empty(M)
    err = np.empty(M)
    ok = np.empty(M, dtype=np.int8)
    for m in range(M):
        f = continuous_rhs(phys, m)
        f(0.0, y0[m])
        t0 = time.perf_counter()
        sol = solve_ivp(f, (0.0, t_end), y0[m].copy(), method=sp_method, rtol=rtol, atol=atol)
        walls[m] = time.perf_counter() - t0
        nfev[m] = sol.nfev
        nsteps[m] = sol.t.size - 1
        ok[m] = 0 if sol.success else 2
        y = sol.y[:, -1]
        err[m] = member_errors(y[0:3], y[3:6], ref_O[m], ref_G[m], w0[m]) if sol.success else np.inf
    return xr.Dataset({
        "error": ("member", err), "evals": ("member", nfev), "status": ("member", ok),
        "wall_member": ("member", walls), "scipy_steps": ("member", nsteps),
    }, attrs={"rtol": rtol, "atol": atol, "members": M})


def level_spread(rows, methods) -> list[dict]:
    """Per liethermo method: the median, least and greatest cost per member-step
    over its levels, and the greatest over the median (1)."""
    out = []
    for m in methods:
        c = np.array([r["wall/member-step (s)"] for r in rows if r["method"] == m], float)
        med = float(np.median(c))
        out.append({"method": m, "median cost/member-step (s)": med, "least (s)": float(c.min()),
                    "greatest (s)": float(c.max()), "greatest / median": float(c.max() / med)})
    return out


def time_to_error(errors, times, eps: float):
    """Cost to reach error ``eps``, interpolating log(time) against log(error)
    between consecutive levels of the ladder (coarse → fine).

    Returns (time, how): how = "interpolated", "coarsest" (already the
    coarsest level is at least that accurate: the time is an upper bound),
    or "not reached" (time NaN)."""
    e = np.asarray(errors, float)
    t = np.asarray(times, float)
    e = np.where(np.isfinite(e), e, np.inf)
    if e.size and e[0] <= eps:
        return float(t[0]), "coarsest"
    for i in range(e.size - 1):
        e1, e2 = e[i], e[i + 1]
        if e1 >= eps >= e2 and np.isfinite(e1) and e2 > 0:
            if e1 == e2:
                return float(t[i + 1]), "interpolated"
            s = (math.log(eps) - math.log(e1)) / (math.log(e2) - math.log(e1))
            return float(math.exp(math.log(t[i]) + s * (math.log(t[i + 1]) - math.log(t[i])))), "interpolated"
        if e1 >= eps and not np.isfinite(e1) and e2 <= eps:
            return float(t[i + 1]), "interpolated"
    return float("nan"), "not reached"


def observed_slope(hs, errs, floor: float = 1e-12) -> float:
    """Least-squares slope of log(error) against log(h) over levels above ``floor``."""
    hs = np.asarray(hs, float)
    errs = np.asarray(errs, float)
    keep = np.isfinite(errs) & (errs > floor)
    if keep.sum() < 2:
        return float("nan")
    return float(np.polyfit(np.log(hs[keep]), np.log(errs[keep]), 1)[0])


# ----------------------------------------------------------------------------- study

def run(study: dict, outdir: Path, *, reduced: bool, progress: bool | None, dask: str | None = None,
        history: str | None = None) -> Path:
    s, outdir, opt = start_study(study, outdir, reduced, validate, options)
    if dask is not None:  # the wall times are the measurement: never on Dask workers
        print(DASK_NOTE, file=sys.stderr)
    methods = list(s.get("methods", ["vi", "rk2", "rk4"]))
    scene = study_scene(s)
    t_end = float(opt["t_end"])
    N = int(opt["members"])
    phys, om, R, w0 = ensemble(scene, N)
    M = int(opt["scipy_members"])
    hs = [float(h) for h in opt["h"]]
    rtols = [float(r) for r in opt["scipy_rtol"]]
    sp_methods = list(opt["scipy_methods"])
    tag = {"study": study_name(s), "scene": scene, "t_end": t_end, "members": N}
    t_wall = time.perf_counter()
    ref, ref_check = reference_at(phys, om, R, t_end, check=True)

    total = len(methods) * len(hs) + len(sp_methods) * len(rtols)
    bar = progress_bar(total, progress, f"{study_name(s)}")
    rows = []
    curves = {}
    try:
        for m in methods:
            errs, times = [], []
            implicit = METHODS[parse_method(m)["method"]].implicit
            for h in hs:
                key = point_key({**tag, "kind": "kernel", "method": m, "h": h, "threads": opt["threads"],
                                 "kernel": KERNEL, "timing": [opt["min_timing"], opt["timing_member_steps"]]})
                ds = cached_point(outdir, key, lambda m=m, h=h: run_kernel_point(
                    m, h, t_end, phys, om, R, w0, int(opt["threads"]), float(opt["min_timing"]), ref,
                    int(opt["timing_member_steps"])))
                steps = int(ds.attrs["steps"])
                wall_member = float(ds.attrs["wall"]) / N
                reps = ds["wall_repeats"].values
                e = float(np.max(ds["error"].values))
                failed = int(np.sum(ds["status"].values != 0))
                rows.append({
                    "method": m, "h (s)": h, "rtol": float("nan"), "steps": steps,
                    "wall/member (s)": wall_member, "wall/member-step (s)": wall_member / steps,
                    "median repeat /member-step (s)": float(np.median(reps)), "repeats": int(reps.size),
                    "timed members": int(ds.attrs["timed_members"]),
                    "evals/member": float(np.mean(ds["evals"].values)),
                    "eval kind": ("Newton iterations" if implicit else "Strang steps"
                                  if METHODS[parse_method(m)["method"]].family == "split" else "rhs evaluations"),
                    "error at t_end (max)": e, "error (median)": float(np.median(ds["error"].values)),
                    "failed members": failed,
                    "max Newton it./step": int(ds["newton_max"].max()) if implicit else float("nan"),
                })
                errs.append(e)
                times.append(wall_member)
                if bar:
                    bar.update(1)
            curves[m] = (hs, errs, times)
        for sm in sp_methods:
            errs, times = [], []
            for r in rtols:
                atol = float(opt["scipy_atol_factor"]) * r
                key = point_key({**tag, "kind": "scipy", "method": sm, "rtol": r, "atol": atol, "M": M})
                ds = cached_point(outdir, key, lambda sm=sm, r=r, atol=atol: run_scipy_point(
                    sm, r, atol, t_end, phys.take(slice(0, M)), om[:M], R[:M], w0[:M]))
                wall_member = float(np.mean(ds["wall_member"].values))
                nst = float(np.mean(ds["scipy_steps"].values))
                e = float(np.max(ds["error"].values))
                rows.append({
                    "method": f"scipy {sm}", "h (s)": float("nan"), "rtol": r, "steps": int(round(nst)),
                    "wall/member (s)": wall_member, "wall/member-step (s)": wall_member / max(nst, 1.0),
                    "median repeat /member-step (s)": float("nan"), "repeats": 1, "timed members": M,
                    "evals/member": float(np.mean(ds["evals"].values)), "eval kind": "rhs evaluations",
                    "error at t_end (max)": e, "error (median)": float(np.median(ds["error"].values)),
                    "failed members": int(np.sum(ds["status"].values != 0)),
                    "max Newton it./step": float("nan"),
                })
                errs.append(e)
                times.append(wall_member)
                if bar:
                    bar.update(1)
            curves[f"scipy {sm}"] = (rtols, errs, times)
    finally:
        if bar:
            bar.close()

    # --- time to reach error eps
    eps_list = [float(e) for e in opt["epsilons"]]
    ttr_rows = []
    for name, (lev, errs, times) in curves.items():
        row = {"method": name}
        for eps in eps_list:
            t, how = time_to_error(errs, times, eps)
            row[f"time/member to {eps:.0e} (s)"] = t
            row[f"({eps:.0e})"] = how
        ttr_rows.append(row)
    slope_rows = []
    for m in methods:
        lev, errs, _ = curves[m]
        spec = parse_method(m)
        slope_rows.append({"method": m, "start": spec["start"] or "—",
                           "expected order": METHODS[spec["method"]].order(spec["start"] or "legendre",
                                                                           spec["friction"] or "trapezoid"),
                           "observed slope": observed_slope(lev, errs)})

    # --- netCDF
    names = list(curves)
    L = max(len(hs), len(rtols))
    shape = (len(names), L)
    arr = {k: np.full(shape, np.nan) for k in ("h", "rtol", "error", "error_median", "wall_member",
                                                "wall_member_step", "evals", "steps", "failed")}
    i_row = 0
    for i, name in enumerate(names):
        n_lev = len(curves[name][0])
        for j in range(n_lev):
            r = rows[i_row]
            i_row += 1
            arr["h"][i, j] = r["h (s)"]
            arr["rtol"][i, j] = r["rtol"]
            arr["error"][i, j] = r["error at t_end (max)"]
            arr["error_median"][i, j] = r["error (median)"]
            arr["wall_member"][i, j] = r["wall/member (s)"]
            arr["wall_member_step"][i, j] = r["wall/member-step (s)"]
            arr["evals"][i, j] = r["evals/member"]
            arr["steps"][i, j] = r["steps"]
            arr["failed"][i, j] = r["failed members"]
    dims = ("method", "level")
    meta = {
        "h": ("s", "fixed step (liethermo kernels)"),
        "rtol": ("1", "relative tolerance (scipy solve_ivp)"),
        "error": ("1", "max over members of max(|dOmega|/|Omega(0)|, |dGamma|) at t_end"),
        "error_median": ("1", "median over members of the error at t_end"),
        "wall_member": ("s", "wall time per member"),
        "wall_member_step": ("s", "wall time per member-step"),
        "evals": ("1", "Newton iterations (vi) or right-hand-side evaluations per member"),
        "steps": ("1", "steps per member (scipy: accepted steps, mean)"),
        "failed": ("1", "members with a non-zero status"),
    }
    ds = xr.Dataset({k: (dims, arr[k], {"units": u, "long_name": ln}) for k, (u, ln) in meta.items()},
                    coords={"method": ("method", np.array(names, dtype=object), {"long_name": "method", "units": "1"}),
                            "level": ("level", np.arange(L), {"long_name": "step/tolerance level (coarse to fine)", "units": "1"})},
                    attrs={"title": "liethermo work-precision study: time per member-step against error",
                           "study": study_name(s), "t_end": t_end, "members": N, "scipy_members": M,
                           "kernel_threads": int(opt["threads"]), "kernel": KERNEL,
                           "timing": "warm kernels; minimum over repeats of at least min_timing s per level",
                           "min_timing": float(opt["min_timing"]), "values": "node values at t_end",
                           "reference_self_check": ref_check})
    nc = write_netcdf_atomic(ds, study_netcdf_path(s, outdir),
                             history=study_history("work_precision", study, outdir, reduced, history))

    fig = _figure(curves, methods, outdir, int(opt["threads"]))
    wall = time.perf_counter() - t_wall

    import pandas as pd

    df = pd.DataFrame(rows)
    sections = [
        write_table(pd.DataFrame(ttr_rows), outdir, "time_to_error",
                    "Wall time per member to reach error ε (log–log interpolation between ladder levels)"),
        f"Scene `{scene['scene']['name']}`, {N} members with random initial conditions "
        f"(seed {scene['ensemble']['seed']}), t_end = {t_end:g} s. Error = max over members of "
        f"max(|Ω − Ω_ref|/|Ω(0)|, |Γ − Γ_ref|) at t_end on **node values** (dimensionless; the VI's Ω(t_end) is "
        f"its node velocity 𝕀⁻¹μ_N). **Timing.** Every level of every liethermo method runs on the "
        f"`{KERNEL}` kernel (the vectorized block loop a large run uses) on {opt['threads']} numba thread(s), "
        f"compiled (or loaded from numba's cache) before anything is timed. A timed run is the whole "
        f"`simulate` call on the {N} members repeated until the run covers at least "
        f"{int(opt['timing_member_steps'])} member-steps (so a call's fixed cost does not show at coarse "
        f"levels), repeated until at least {float(opt['min_timing']):g} s per level were spent; the cost is the "
        f"**minimum** over the repeats (their median is in the table of all runs), per member-step and per "
        f"member. vi4 and vi6 take {METHODS['vi4'].evaluations_per_step} and {METHODS['vi6'].evaluations_per_step} "
        f"Newton solves per step, split4 and split6 {METHODS['split4'].evaluations_per_step} and "
        f"{METHODS['split6'].evaluations_per_step} Strang steps; "
        f"scipy `solve_ivp` integrates {M} member(s) **one at a time, serially**, calling the numba-jitted "
        f"right-hand side through a Python wrapper (atol = {opt['scipy_atol_factor']:g}·rtol). "
        f"Reference: fixed-step DOP853 with automatic substeps; |ref − ref(2× substeps)| = {ref_check:.1e}. "
        f"\"coarsest\" in the time-to-ε table means the coarsest level already reaches ε (the time is an "
        f"upper bound); \"not reached\" means no level did (round-off floor or too coarse a ladder).",
        NODE_VALUES_NOTE,
        write_table(pd.DataFrame(slope_rows), outdir, "slopes", "Observed slope of log error against log h"),
        write_table(pd.DataFrame(level_spread(rows, methods)), outdir, "level_costs",
                    f"Cost per member-step across the ladder (kernel `{KERNEL}`, {opt['threads']} thread(s))"),
        write_table(df, outdir, "work_precision", "All runs"),
        f"![work–precision]({fig.name})",
        f"netCDF: `{nc.name}`. Study wall time {wall:.1f} s (points loaded from the resume cache are not re-timed).",
    ]
    if dask is not None:
        sections.append(f"**Note.** {DASK_NOTE}")
    sections.append(closing_section(
        [{"method": r["method"], "error": r["error at t_end (max)"], "cost": r["wall/member (s)"],
          "setting": f"h = {r['h (s)']:g} s" if np.isfinite(r["h (s)"]) else f"rtol = {r['rtol']:g}"}
         for r in rows if r["failed members"] == 0],
        regime=f"scene `{scene['scene']['name']}`, t_end = {t_end:g} s", levels=eps_list,
        error="max over members of the node-value error at t_end (1)",
        cost=f"wall time per member (s): liethermo kernels `{KERNEL}` on {opt['threads']} thread(s), scipy serial",
        outdir=outdir))
    return write_report(outdir, "Work–precision: wall time and evaluations against error at t_end", sections)


def _figure(curves: dict, methods: list, outdir: Path, threads: int) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 5), layout="constrained")
    for name, (lev, errs, times) in curves.items():
        e = np.asarray(errs, float)
        t = np.asarray(times, float)
        ok = np.isfinite(e) & (e > 0)
        axes[0].loglog(e[ok], t[ok], "o-" if name in methods else "s--", label=name)
        if name in methods:
            axes[1].loglog(np.asarray(lev)[ok], e[ok], "o-", label=name)
    axes[0].set_xlabel("error at t_end, node values (1)")
    axes[0].set_ylabel("wall time per member (s)")
    axes[0].invert_xaxis()
    axes[0].set_title(f"work–precision (kernels: {KERNEL}, {threads} thread(s); scipy: serial)")
    axes[0].legend(fontsize=8)
    axes[0].grid(True, which="both", alpha=0.3)
    axes[1].set_xlabel("h (s)")
    axes[1].set_ylabel("error at t_end, node values (1)")
    axes[1].set_title("error against step")
    axes[1].legend(fontsize=8)
    axes[1].grid(True, which="both", alpha=0.3)
    path = Path(outdir) / "work_precision.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
