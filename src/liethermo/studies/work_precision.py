"""Work–precision: measured cost per member against the error at ``t_end``, on any model.

Every method of the study (default: the model's own, the reference aside) runs
the same ensemble at a ladder of fixed steps h; its error against the model's
reference (:meth:`liethermo.models.Model.study_state`) is, per member, the
largest over the state variables that do not start at zero of
|x(t_end) − x_ref(t_end)| / |x(0)|, and the error of a level is its maximum
over members.  Costs are measured in a serial stage: at each h every method's
run (``timing_member_steps`` member-steps at least, on the kernel a large run
uses) is timed interleaved with the others', threads pinned
(:func:`liethermo.studies.timing.measure`), the minimum over repeats kept and
the spread stored beside it.  Where the model has a continuous right-hand side
(:meth:`~liethermo.models.Model.ode`), scipy's ``solve_ivp`` runs the first
``scipy_members`` members one at a time at a ladder of tolerances, timed the
same way.  One computation, the time to reach each ε (log–log interpolation
between levels), gives both the time-to-ε table and the cheapest method per ε;
a ranking is stated only beyond the measured spread.
"""

from __future__ import annotations

import math
import time

import numpy as np
import xarray as xr

from . import timing
from .common import StudyError
from .convergence import fit_order
from .framework import PALETTE, Figure, Option, Stage, Study, Table, Verdict, first_point, run_scene

SCIPY_SOLVERS = ("RK23", "RK45", "DOP853")


def _check(ctx) -> None:
    o = ctx.opt
    for h in o["h"]:
        n = o["t_end"] / h
        if abs(n - round(n)) > 1e-9 * n:
            raise StudyError(f"options.h: every h must divide t_end = {o['t_end']} (got {h})")
    if o["scipy_members"] > o["members"]:
        raise StudyError("options.scipy_members: must be ≤ options.members")
    for m in o["scipy_methods"]:
        if m not in SCIPY_SOLVERS:
            raise StudyError(f"options.scipy_methods: unknown scipy method {m!r}; known: {', '.join(SCIPY_SOLVERS)}")
    if ctx.sweep_keys:
        raise StudyError("sweep: a work_precision study compares methods on one scene (no sweep)")
    if "reference" in ctx.methods:
        raise StudyError("methods: 'reference' is the ground truth, not a compared method")
    ctx.methods = ctx.methods or [m for m in ctx.model.methods() if m != "reference"]  # default: the model's


def _axes(ctx) -> dict:
    scipy = ctx.opt["scipy_members"] > 0 and ctx.model.ode is not None
    return {"h": [float(h) for h in ctx.opt["h"]], "solver": list(ctx.opt["scipy_methods"]) if scipy else [],
            "rtol": [float(r) for r in ctx.opt["scipy_rtol"]] if scipy else []}


def timing_copies(members: int, steps: int, timing_member_steps: int) -> int:
    """Copies of the ensemble one timed run integrates: enough to cover ``timing_member_steps``
    member-steps, so that what a call costs besides its steps does not show."""
    return max(1, -(-int(timing_member_steps) // max(members * steps, 1)))


def _run(ctx, point, method: str, h: float, members: int):
    """Members 0:members at step h to t_end on the kernel a large run uses, on ``threads`` threads."""
    from ..models import model_of

    scene, steps = ctx.scene(point), round(ctx.opt["t_end"] / h)
    model = model_of(scene)
    sc = scene.with_overrides({**model.study_outputs, **model.method_overrides(method), "integrator.h": h,
                               "integrator.steps": steps, "output.every": steps, "ensemble.members": members})
    return model.run_chunk(sc, 0, members, kernel="fast", threads=ctx.opt["threads"])


def _scaled(model, ds, names=None) -> dict:
    """{name: (x(t_end) (member, n), |x(0)| (member,))} of the state variables that do not start at zero."""
    out = {}
    for name, (x, *_) in model.study_state(ds).items():
        x = np.asarray(x).reshape(*np.shape(x)[:2], -1)
        s0 = np.sqrt(np.sum(np.abs(x[:, 0]) ** 2, axis=-1))
        if np.all(s0 > 0) and (names is None or name in names):
            out[name] = (x[:, -1], s0)
    return out


def _error(got: dict, ref: dict, rows=slice(None)) -> np.ndarray:
    """(state, member) |x − x_ref| / |x_ref(0)| (inf where not finite)."""
    e = np.array([np.linalg.norm(np.reshape(got[n], ref[n][0][rows].shape) - ref[n][0][rows], axis=-1)
                  / ref[n][1][rows] for n in ref if n in got])
    return np.where(np.isfinite(e), e, np.inf)


def reference(ctx, coords) -> xr.Dataset:
    T = float(ctx.opt["t_end"])
    ds, _ = run_scene(ctx.scene(coords["point"]), "reference", h=T, steps=1, members=ctx.opt["members"])
    if int(np.max(ds["status"].values)) != 0:
        raise ArithmeticError(f"the reference failed at sweep point {coords['point'] or 'base scene'}")
    return ds


def errors(ctx, coords, reference) -> xr.Dataset:
    ds, _ = _run(ctx, coords["point"], coords["scheme"], float(coords["h"]), ctx.opt["members"])
    ref = _scaled(ctx.model, reference)
    got = {n: v[0] for n, v in _scaled(ctx.model, ds, ref).items()}
    err = np.where(ds["status"].values != 0, np.inf, _error(got, ref))
    return xr.Dataset({"state_error": (("state", "member"), err), "failed": ((), int(np.sum(ds["status"].values != 0)))},
                      coords={"state": list(ref)})


def costs(ctx, coords) -> xr.Dataset:
    """Every method at this h timed interleaved: cost per member, min over repeats, with its spread."""
    h, N = float(coords["h"]), ctx.opt["members"]
    n = N * timing_copies(N, round(ctx.opt["t_end"] / h), ctx.opt["timing_member_steps"])
    c = timing.measure({m: (lambda m=m: _run(ctx, coords["point"], m, h, n)[1].kernel_time) for m in ctx.methods},
                       repeats=ctx.opt["repeats"], min_time=ctx.opt["min_timing"], threads=ctx.opt["threads"])
    return _cost_ds({m: c[m].per(n) for m in ctx.methods}, "scheme", timed_members=((), n))


def _cost_ds(c: dict, dim: str, **more) -> xr.Dataset:
    return xr.Dataset({"cost": (dim, [c[m].best for m in c]), "cost_spread": (dim, [c[m].spread for m in c]),
                       "cost_repeats": (dim, [c[m].repeats for m in c]), **more}, coords={dim: list(c)})


def scipy_runs(ctx, coords, reference) -> xr.Dataset:
    """solve_ivp on the first scipy_members members, one at a time, each solver timed interleaved."""
    from scipy.integrate import solve_ivp

    M, T, r = ctx.opt["scipy_members"], float(ctx.opt["t_end"]), float(coords["rtol"])
    scene = ctx.scene(coords["point"]).with_overrides({"ensemble.members": ctx.opt["members"]})
    y0, fs, state = ctx.model.ode(scene, 0, M)
    sols = {}

    def solve(sm):
        took = 0.0
        for m in range(M):
            t0 = time.perf_counter()
            sols[sm, m] = solve_ivp(fs[m], (0.0, T), y0[m].copy(), method=sm, rtol=r, atol=ctx.opt["scipy_atol_factor"] * r)
            took += time.perf_counter() - t0
        return took

    solvers = ctx.axes["solver"]
    c = timing.measure({sm: (lambda sm=sm: solve(sm)) for sm in solvers}, repeats=ctx.opt["repeats"], warm=0,
                       threads=ctx.opt["threads"])
    ref = _scaled(ctx.model, reference)
    err = [[np.max(_error(state(sols[sm, m].y[:, -1]), ref, slice(m, m + 1))) if sols[sm, m].success else np.inf
            for m in range(M)] for sm in solvers]
    return _cost_ds({sm: c[sm].per(M) for sm in solvers}, "solver",
                    error=("solver", np.max(err, axis=1)), error_median=("solver", np.median(err, axis=1)),
                    evaluations=("solver", [np.mean([sols[sm, m].nfev for m in range(M)]) for sm in solvers]),
                    failed=("solver", [sum(not sols[sm, m].success for m in range(M)) for sm in solvers]))


def time_to_error(errors, times, eps: float):
    """(time, how, levels): the cost to reach ``eps``, log–log interpolated between consecutive
    levels (coarse → fine); how = "interpolated", "coarsest" (the coarsest level is already that
    accurate: an upper bound) or "not reached" (time NaN); levels: the indices it rests on."""
    e = np.where(np.isfinite(np.asarray(errors, float)), np.asarray(errors, float), np.inf)
    t = np.asarray(times, float)
    if e.size and e[0] <= eps:
        return float(t[0]), "coarsest", (0,)
    for i in range(e.size - 1):
        e1, e2 = e[i], e[i + 1]
        if e1 >= eps >= e2 and np.isfinite(e1) and e2 > 0 and e1 != e2:
            s = (math.log(eps) - math.log(e1)) / (math.log(e2) - math.log(e1))
            return float(math.exp(math.log(t[i]) + s * (math.log(t[i + 1]) - math.log(t[i])))), "interpolated", (i, i + 1)
        if e1 >= eps >= e2:
            return float(t[i + 1]), "interpolated", (i + 1,)
    return float("nan"), "not reached", ()


def _curves(ds) -> dict:
    """{candidate: (levels, errors, costs, spreads)}: the methods over h, scipy's solvers over rtol."""
    out = {m: (ds["h"].values, ds["error"].sel(scheme=m).values, ds["cost"].sel(scheme=m).values,
               ds["cost_spread"].sel(scheme=m).values) for m in ds["scheme"].values}
    for sm in ds["solver"].values if "solver" in ds.dims else []:
        out[f"scipy {sm}"] = (ds["rtol"].values, *(ds[f"scipy_{v}"].sel(solver=sm).values for v in ("error", "cost", "cost_spread")))
    return out


def reach(ds, ctx) -> dict:
    """{ε: {candidate: (Cost or None, how)}}: the one computation both closing tables read."""
    out = {}
    for eps in ctx.opt["epsilons"]:
        out[eps] = {}
        for name, (lev, e, t, sp) in _curves(ds).items():
            tt, how, used = time_to_error(e, t, eps)
            s = max((sp[i] for i in used), default=0.0)
            out[eps][name] = (timing.Cost(tt, tt * (1 + s), s, 0, ()) if used else None, how)
    return out


def derive(ds, ctx) -> xr.Dataset:
    ds = ds.reindex(scheme=ctx.methods)
    ds["error"] = ds["state_error"].max(["state", "member"])
    ds["error_median"] = ds["state_error"].max("state").median("member")
    ds["declared_order"] = ("scheme", [ctx.model.method_order(m) for m in ctx.methods])
    r = reach(ds, ctx)
    names = list(next(iter(r.values())))
    for v, f in (("time_to_error", lambda c: c.best), ("time_to_error_spread", lambda c: c.spread)):
        ds[v] = (("candidate", "epsilon"), [[f(r[e][n][0]) if r[e][n][0] else np.nan for e in r] for n in names])
    return ds.assign_coords(candidate=names, epsilon=list(r))


def tables(ds, ctx) -> list[Table]:
    r = reach(ds, ctx)
    ttr = [{"method": n, **{k: v for e in r for k, v in (
        (f"time/member to {e:.0e} (s)", r[e][n][0].best if r[e][n][0] else np.nan),
        (f"spread ({e:.0e})", r[e][n][0].spread if r[e][n][0] else np.nan), (f"({e:.0e})", r[e][n][1]))}}
           for n in ds["candidate"].values]
    cheap = []
    for e, got in r.items():
        c = {n: v[0] for n, v in got.items() if v[0] is not None}
        g = timing.rank(c)[0] if c else []
        cheap.append({"error ≤": e, "cheapest": " = ".join(g) or "not reached", "time/member (s)":
                      c[g[0]].best if g else np.nan, "ranking (beyond the spread)": timing.describe(c) if c else "—"})
    runs = [{"method": m, "h (s)": float(h), "rtol": np.nan, "error at t_end (max)": float(x["error"]),
             "error (median)": float(x["error_median"]), "cost/member (s)": float(x["cost"]),
             "spread": float(x["cost_spread"]), "repeats": int(x["cost_repeats"]), "evaluations/member": np.nan,
             "failed members": int(x["failed"])} for m in ctx.methods for h in ds["h"].values
            for x in [ds.sel(scheme=m, h=h)]]
    for sm in ds["solver"].values if "solver" in ds.dims else []:
        runs += [{"method": f"scipy {sm}", "h (s)": np.nan, "rtol": float(rt), **{k: float(ds[f"scipy_{v}"].sel(
            solver=sm, rtol=rt)) for k, v in (("error at t_end (max)", "error"), ("error (median)", "error_median"),
            ("cost/member (s)", "cost"), ("spread", "cost_spread"), ("repeats", "cost_repeats"),
            ("evaluations/member", "evaluations"), ("failed members", "failed"))}} for rt in ds["rtol"].values]
    slopes = [{"method": m, "declared order": int(ds["declared_order"].sel(scheme=m)), "observed slope":
               fit_order(ds["h"].values, ds["error"].sel(scheme=m).values, 1.0, ctx.opt["floor_rel"])[0]}
              for m in ctx.methods]
    return [Table("time_to_error", "Time per member to reach error ε (log–log interpolation between levels; "
                  "spread: of the levels it rests on)", ttr),
            Table("cheapest", "The cheapest method per error level (from the table above)", cheap),
            Table("slopes", "Observed slope of log error on log h (the fit ends at the round-off floor)", slopes),
            Table("work_precision", "All runs", runs)]


def verdicts(ds, ctx) -> list[Verdict]:
    out = []
    for row in tables(ds, ctx)[1].rows:
        g = row["cheapest"].split(" = ")
        out.append(Verdict(f"{g[0]} is the cheapest to error {row['error ≤']:.0e}" if len(g) == 1 else
                           f"to error {row['error ≤']:.0e}: {', '.join(g)} tie within noise",
                           row["ranking (beyond the spread)"], "its gap to the next > both spreads (≥ 2 %)",
                           None if g == ["not reached"] else len(g) == 1 or None))
    return out


def findings(ds, ctx) -> list[str]:
    out = []
    base = [n for n in ds["candidate"].values if n.startswith(("rk", "scipy"))]
    for row in tables(ds, ctx)[1].rows:
        g, e = row["cheapest"].split(" = "), row["error ≤"]
        won = [b for b in base if b in g]
        out.append(f"To {e:.0e}: {row['cheapest']}" + (f" (the baseline {', '.join(won)} wins or ties)." if won
                   else "; no baseline (RK, scipy) wins."))
    if not ds.sizes.get("solver"):
        out.append("scipy's solve_ivp was not run (the model has no continuous right-hand side, or scipy_members = 0).")
    return out


def _draw(ds, ctx, fig) -> None:
    ax = fig.subplots(1, 2)
    for j, (name, (lev, e, t, sp)) in enumerate(_curves(ds).items()):
        ok = np.isfinite(e) & (e > 0) & np.isfinite(t)
        col = ctx.color(name) if name in ctx.methods else PALETTE[(len(ctx.methods) + j) % len(PALETTE)]
        ax[0].errorbar(e[ok], t[ok], yerr=[0 * t[ok], t[ok] * sp[ok]], fmt="o-" if name in ctx.methods else "s--",
                       color=col, mfc="none", capsize=2, label=name)
        if name in ctx.methods:
            ax[1].loglog(lev[ok], e[ok], "o-", color=col, mfc="none")
    ax[0].set(xscale="log", yscale="log", xlabel="error at t_end (1)", ylabel="cost per member (s)")
    ax[0].invert_xaxis()
    ax[1].set(xlabel="h (s)", ylabel="error at t_end (1)", title="error against step")
    for a in ax:
        a.grid(True, which="both", alpha=0.3)
    fig.legend(fontsize=8, loc="outside right upper")


STUDY = Study(
    kind="work_precision", title="Work–precision", models=None, needs_methods=False,
    description="Cost per member against the error at t_end, every method and scipy's solve_ivp",
    options=(Option("t_end", 10.0, "number>0", "s", "end time (a multiple of every h)"),
             Option("members", 32, "int>=1", "1", "members whose errors are measured"),
             Option("h", [0.2, 0.1, 0.05, 0.025, 0.0125, 0.00625, 0.003125, 0.0015625, 0.00078125],
                    "list[number>0]", "s", "the ladder of fixed steps, coarse to fine"),
             Option("scipy_methods", ["RK45", "DOP853"], "list[str]", "", "solve_ivp methods (if the model has an ode)"),
             Option("scipy_rtol", [10.0**-k for k in range(3, 13)], "list[number>0]", "1", "solve_ivp rtol ladder"),
             Option("scipy_atol_factor", 1e-3, "number>0", "1", "atol = factor × rtol"),
             Option("scipy_members", 4, "int>=0", "1", "members scipy integrates (0: none)"),
             Option("epsilons", [1e-3, 1e-6, 1e-9], "list[number>0]", "1", "error levels of the closing tables"),
             Option("threads", 1, "int>=1", "1", "threads while timing (pinned)"),
             Option("min_timing", 0.2, "number>0", "s", "timed seconds per method and level, at least"),
             Option("repeats", 5, "int>=1", "1", "interleaved rounds per level, at least"),
             Option("timing_member_steps", 2**18, "int>=1", "1", "member-steps of one timed run, at least"),
             Option("floor_rel", 1e-12, "number>0", "1", "errors below this are round-off (slope fit)")),
    axes=_axes, check=_check,
    stages=(Stage("reference", reference, keep=()),
            Stage("errors", errors, over=("point", "scheme", "h"), needs=("reference",)),
            Stage("costs", costs, over=("point", "h"), serial=True),
            Stage("scipy", scipy_runs, over=("point", "rtol"), needs=("reference",), serial=True, prefix="scipy_")),
    quantities={"state_error": ("1", "|x - x_ref| / |x(0)| at t_end per state variable and member"),
                "state": ("1", "state variable of the model"),
                "error": ("1", "max over members of the error at t_end"), "error_median": ("1", "median over members of the error at t_end"),
                "failed": ("1", "members with a non-zero status"), "cost": ("s", "cost per member (min over repeats)"),
                "cost_spread": ("1", "timing spread: median / min - 1"), "cost_repeats": ("1", "timed repeats"),
                "timed_members": ("1", "members of one timed run"), "declared_order": ("1", "order the method declares"),
                "rtol": ("1", "solve_ivp relative tolerance"), "solver": ("1", "solve_ivp method"),
                **{f"scipy_{k}": v for k, v in (("error", ("1", "max over members of the error at t_end")),
                   ("error_median", ("1", "median over members of the error at t_end")),
                   ("cost", ("s", "cost per member, serial (min over repeats)")), ("cost_spread", ("1", "timing spread")),
                   ("cost_repeats", ("1", "timed repeats")), ("evaluations", ("1", "rhs evaluations per member")),
                   ("failed", ("1", "members scipy failed on")))},
                "candidate": ("1", "method or scipy solver"), "epsilon": ("1", "error level"),
                "time_to_error": ("s", "cost per member to reach the error level"),
                "time_to_error_spread": ("1", "timing spread of the levels the time to error rests on")},
    derive=derive, tables=tables, verdicts=verdicts, findings=findings,
    figures=(Figure("work_precision", kind="custom", draw=_draw, size=(12, 4.8),
                    claim="cost per member against error, bars up to the median repeat: the cheapest curve at an "
                          "error level is the method the tables name, ties where the bars overlap"),),
    report=("Scene `{scene}` ({model}), {opt[members]} members, t_end = {opt[t_end]} s. Error: per member the largest "
            "of |x(t_end) − x_ref(t_end)| / |x(0)| over {state}; the reference: {ref}. Costs: every method at an h "
            "timed interleaved with the others, on {opt[threads]} pinned thread(s), runs of at least "
            "{opt[timing_member_steps]} member-steps, ≥ {opt[repeats]} rounds and {opt[min_timing]} s; the minimum "
            "over repeats, with spread = median / min − 1. {scipy}"),
    facts=lambda ds, ctx: {
        "state": ", ".join(ds["state"].values),
        "ref": ctx.model.methods()["reference"].description,
        "scipy": (f"scipy's solve_ivp ({', '.join(ctx.axes['solver'])}; atol = {ctx.opt['scipy_atol_factor']:g}·rtol) "
                  f"integrates {ctx.opt['scipy_members']} member(s) one at a time, serially, through a Python wrapper."
                  if ctx.axes["solver"] else "scipy's solve_ivp is skipped: the model has no continuous right-hand side "
                  "(or scipy_members = 0).")},
)
