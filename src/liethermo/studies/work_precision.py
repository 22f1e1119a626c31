"""Work–precision: measured cost per member against the error at ``t_end``, on any model. The methods (default: the
model's own) run one ensemble at steps h; a member's error is the largest |x − x_ref| / |x(0)| at ``t_end`` over the
model's state variables that do not start at zero. A serial stage times all methods at one h interleaved
(:func:`.timing.measure`), scipy's ``solve_ivp`` likewise; one time-to-ε computation follows. Costs are the process's
CPU time on pinned threads (one by default): the machine's other load does not enter them, as it enters wall time."""

from __future__ import annotations

import math
import time

import numpy as np
import xarray as xr

from .. import timing
from .common import StudyError
from .framework import PALETTE, Figure, Option, Stage, Study, Table, Verdict, run_scene

SCIPY = ("RK23", "RK45", "DOP853")  # solve_ivp methods
REMEASURE = 3  # measurements of one h at most, while a spread says the machine is loaded
SCIPY_NOTE = ("scipy's solve_ivp ({s}; atol = {o[scipy_atol_factor]:g}·rtol) integrates {o[scipy_members]} member(s) one "
              "at a time, serially, through a Python wrapper.")


def _check(ctx) -> None:
    o, n = ctx.opt, [ctx.opt["t_end"] / h for h in ctx.opt["h"]]
    rules = {"options.h": (any(abs(k - round(k)) > 1e-9 * k for k in n), f"every h must divide t_end = {o['t_end']}"),
             "options.scipy_members": (o["scipy_members"] > o["members"], "must be ≤ options.members"),
             "options.scipy_methods": (not set(o["scipy_methods"]) <= set(SCIPY), f"each one of {', '.join(SCIPY)}"),
             "sweep": (bool(ctx.sweep_keys), "a work_precision study compares methods on one scene"),
             "methods": ("reference" in ctx.methods, "'reference' is the ground truth, not a compared method")}
    for where, (bad, why) in rules.items():
        if bad:
            raise StudyError(f"{where}: {why}")
    ctx.methods = ctx.methods or [m for m in ctx.model.methods() if m != "reference"]  # default: the model's


def _axes(ctx) -> dict:
    on = ctx.opt["scipy_members"] > 0 and ctx.model.ode is not None  # else no scipy tasks
    return {"h": [float(h) for h in ctx.opt["h"]], "solver": ctx.opt["scipy_methods"] * on,
            "rtol": [float(r) for r in ctx.opt["scipy_rtol"]] * on}


def _run(ctx, point, method: str, h: float, members: int):
    """Members 0:members at step h to t_end on the kernel a large run uses, on ``threads`` threads."""
    steps = round(ctx.opt["t_end"] / h)
    return run_scene(ctx.scene(point), method, h=h, steps=steps, every=steps, members=members, kernel="fast",
                     threads=ctx.opt["threads"])


def _cpu(ctx, point, method: str, h: float, members: int) -> float:
    """The CPU time of the process over the kernels of one :func:`_run`, s: the model's ``kernel_cpu_time`` where
    its stats give one (setup and output excluded, like the kernel's wall time), else over the whole run."""
    t = time.process_time()
    st = _run(ctx, point, method, h, members)[1]
    whole = time.process_time() - t
    k = getattr(st, "kernel_cpu_time", 0.0)
    return float(k) if k > 0 else whole


def _state(model, ds) -> dict:
    """{name: x (member, t, n)} of the model's state variables that do not start at zero."""
    st = {n: np.asarray(x).reshape(*np.shape(x)[:2], -1) for n, (x, *_) in model.study_state(ds).items()}
    return {n: x for n, x in st.items() if np.all(np.linalg.norm(x[:, 0], axis=-1) > 0)}


def _error(got: dict, ref: dict) -> np.ndarray:
    """(state, member) |x − x_ref| / |x_ref(0)| at the last time (inf where not finite)."""
    e = np.array([np.linalg.norm(got[n][:, -1] - x[:, -1], axis=-1) / np.linalg.norm(x[:, 0], axis=-1)
                  for n, x in ref.items()])
    return np.where(np.isfinite(e), e, np.inf)


def reference(ctx, coords) -> xr.Dataset:
    ds, _ = run_scene(ctx.scene(), "reference", h=float(ctx.opt["t_end"]), steps=1, members=ctx.opt["members"])
    if np.any(ds["status"].values):
        raise ArithmeticError("the reference failed")
    return ds


def errors(ctx, coords, reference) -> xr.Dataset:
    ds, _ = _run(ctx, coords["point"], coords["scheme"], float(coords["h"]), ctx.opt["members"])
    ref, bad = _state(ctx.model, reference), ds["status"].values != 0
    return xr.Dataset({"state_error": (("state", "member"), np.where(bad, np.inf, _error(_state(ctx.model, ds), ref))),
                       "failed": ((), int(bad.sum()))}, coords={"state": list(ref)})


def _max_error(ctx, coords, reference, h: float) -> float:
    """The largest error over the members and state variables of the method at step h (inf: a failed member)."""
    return float(np.max(errors(ctx, {**coords, "h": h}, reference)["state_error"].values))


def costs(ctx, coords) -> xr.Dataset:
    """Every method at this h timed interleaved, each run of the members repeated to cover timing_member_steps."""
    h, N = float(coords["h"]), ctx.opt["members"]
    n = N * -(-ctx.opt["timing_member_steps"] // (N * round(ctx.opt["t_end"] / h)))  # members of a timed run
    for _ in range(REMEASURE):  # a spread over 100 % says the machine was loaded: time again, up to REMEASURE times
        c = timing.measure({m: (lambda m=m: _cpu(ctx, coords["point"], m, h, n)) for m in ctx.methods},
                           repeats=ctx.opt["repeats"], min_time=ctx.opt["min_timing"], threads=ctx.opt["threads"])
        if not timing.loaded(c):
            break
    return _cost_ds({m: c[m].per(n) for m in ctx.methods}, "scheme", timed_members=((), n))


def extend_ladder(levels, errors, epsilons, cap: int, error_at, fits=lambda h: True) -> list[tuple[float, float]]:
    """Levels to add to a ladder of steps (coarse → fine) so that a time to each ε in ``epsilons`` the ladder only
    bounds becomes bracketed: ``[(h, error)]``, found by calling ``error_at(h)``.

    Where the finest level is still above an ε (a lower bound), h is halved below the finest level; where the
    coarsest is already below one (an upper bound), h is doubled above the coarsest (while ``fits(h)``, e.g. h
    divides t_end).  At most ``cap`` levels at each end, and only while the log–log line of the two levels at
    that end (the method's observed h^p) says the ε it bounds is reached within what is left of the cap;
    otherwise that time keeps its bound label.  A level that stops gaining (the round-off floor) or fails ends
    that side."""
    hs, es, added = [float(h) for h in levels], [float(e) for e in errors], []
    left = {"fine": int(cap), "coarse": int(cap)}

    def side() -> tuple[str, float] | None:
        t = 1.0 / np.asarray(hs)  # cost ∝ 1/h: only what the ladder brackets matters here
        hows = {eps: time_to_error(es, t, eps)[1] for eps in epsilons}
        lower = [x for x, how in hows.items() if how == "lower bound"]
        upper = [x for x, how in hows.items() if how == "upper bound"]
        if lower and left["fine"]:  # the nearest ε first: the largest one still above the finest level
            return "fine", max(lower)
        if upper and left["coarse"]:  # the smallest one already below the coarsest level
            return "coarse", min(upper)
        return None

    while (s := side()) is not None:
        where, eps = s
        i, j = (-2, -1) if where == "fine" else (1, 0)
        e_end = np.nan_to_num(es[j], nan=np.inf)
        if len(hs) < 2 or not (np.isfinite(es[i]) and np.isfinite(e_end) and es[i] > 0 and e_end > 0):
            left[where] = 0
            continue
        p = math.log(es[i] / e_end) / math.log(hs[i] / hs[j])  # the observed order at that end
        need = math.log(e_end / eps) / (p * math.log(2.0)) if p > 0 else math.inf  # halvings (doublings) to ε
        h = hs[j] / 2.0 if where == "fine" else hs[j] * 2.0
        if not (0 < abs(need) <= left[where]) or (where == "coarse" and not fits(h)):
            left[where] = 0
            continue
        e = float(error_at(h))
        left[where] -= 1
        added.append((h, e))
        if where == "fine":
            hs.append(h), es.append(e)
            if not np.isfinite(e) or e * FLOOR_GAIN > e_end:  # failed, or stopped gaining: the floor
                left["fine"] = 0
        else:
            hs.insert(0, h), es.insert(0, e)
            if not np.isfinite(e):
                left["coarse"] = 0
    return sorted(added, reverse=True)


def extend(ctx, coords, reference, errors) -> xr.Dataset:
    """The levels this method's ladder adds to bracket its times to ε (:func:`extend_ladder`, at most
    ``extend_levels`` at each end), each run on the members and timed alone like the ladder's levels."""
    m, cap, T = coords["scheme"], int(ctx.opt["extend_levels"]), float(ctx.opt["t_end"])
    lev = sorted(((float(c["h"]), float(np.max(d["state_error"].values))) for c, d in errors), reverse=True)
    got = extend_ladder([h for h, _ in lev], [e for _, e in lev], ctx.opt["epsilons"], cap,
                        lambda h: _max_error(ctx, coords, reference, h),
                        fits=lambda h: h <= T and abs(T / h - round(T / h)) <= 1e-9 * T / h)
    rows = {k: np.full(2 * cap, np.nan) for k in ("h", "error", "cost", "cost_spread", "cost_repeats", "failed")}
    N = ctx.opt["members"]
    for k, (h, e) in enumerate(got):
        n = N * -(-ctx.opt["timing_member_steps"] // (N * round(T / h)))
        c = timing.measure({m: lambda: _cpu(ctx, coords["point"], m, h, n)},
                           repeats=ctx.opt["repeats"], min_time=ctx.opt["min_timing"], threads=ctx.opt["threads"])[m]
        c = c.per(n)
        for key, v in (("h", h), ("error", e), ("cost", c.best), ("cost_spread", c.spread),
                       ("cost_repeats", c.repeats), ("failed", float(not np.isfinite(e)))):
            rows[key][k] = v
    return xr.Dataset({k: ("added", v) for k, v in rows.items()})


def _cost_ds(c: dict, dim: str, **more) -> xr.Dataset:
    return xr.Dataset({"cost": (dim, [c[m].best for m in c]), "cost_spread": (dim, [c[m].spread for m in c]),
                       "cost_repeats": (dim, [c[m].repeats for m in c]), **more}, coords={dim: list(c)})


def scipy_runs(ctx, coords, reference) -> xr.Dataset:
    """solve_ivp on the first scipy_members members, one at a time, the solvers timed interleaved."""
    from scipy.integrate import solve_ivp

    M, T, r, sols, solvers = ctx.opt["scipy_members"], float(ctx.opt["t_end"]), float(coords["rtol"]), {}, ctx.axes["solver"]
    y0, fs, state = ctx.model.ode(ctx.scene(coords["point"]).with_overrides({"ensemble.members": ctx.opt["members"]}), 0, M)

    def solve(sm):
        sols[sm] = [solve_ivp(fs[m], (0.0, T), y0[m].copy(), method=sm, rtol=r, atol=ctx.opt["scipy_atol_factor"] * r)
                    for m in range(M)]

    c = timing.measure({sm: (lambda sm=sm: solve(sm)) for sm in solvers}, repeats=ctx.opt["repeats"], warm=0,
                       threads=ctx.opt["threads"], clock=time.process_time)
    ref, err = {n: x[:M] for n, x in _state(ctx.model, reference).items()}, []
    for sm in solvers:
        got = {n: np.array([state(s.y[:, -1])[n] for s in sols[sm]])[:, None] for n in ref}  # (member, t_end, n)
        err.append(np.where([s.success for s in sols[sm]], _error(got, ref).max(axis=0), np.inf))
    return _cost_ds({sm: c[sm].per(M) for sm in solvers}, "solver", error=("solver", np.max(err, axis=1)),
                    failed=("solver", np.isinf(err).sum(axis=1)))


#: a ladder whose finest level lowers the error by less than this factor has reached its round-off floor
FLOOR_GAIN = 2.0
#: what a time to ε is, by where ε falls on the ladder
HOW = {"bracketed": "bracketed (log–log between two levels)",
       "upper bound": "upper bound (≤: the coarsest level is already below ε)",
       "lower bound": "lower bound (≥: the finest level is still above ε)",
       "below the round-off floor": "below the round-off floor (the finest levels stopped gaining)",
       "not reached": "not reached (no finite error)"}


def _line(e, t, i: int, j: int, eps: float) -> float:
    """The cost at ε on the log–log line through levels i and j (NaN where it is not a falling line)."""
    if not (np.isfinite(e[i]) and np.isfinite(e[j]) and e[i] > 0 and e[j] > 0 and e[i] != e[j] and t[i] > 0 and t[j] > 0):
        return float("nan")
    return float(t[i] * (t[j] / t[i]) ** (math.log(eps / e[i]) / math.log(e[j] / e[i])))


def time_to_error(errors, times, eps: float):
    """(time, how, levels used, estimate): the cost to reach ``eps`` on a ladder of levels (coarse → fine).

    how: "bracketed" (two neighbouring levels lie on either side of ε: log–log interpolation between them, or a
    level exactly at ε), "upper bound" (the coarsest level is already below ε: the time is its cost, and the true
    one is at most that), "lower bound" (the finest level is still above ε and the ladder was still gaining: the
    true time is at least the finest level's cost), "below the round-off floor" (still above ε, but the finest
    level lowered the error by less than :data:`FLOOR_GAIN`: no time) or "not reached" (no finite error).  The
    estimate of a bound is the log–log line of the two levels at that end of the ladder carried to ε (the
    method's h^p line); NaN for the others."""
    e, t = np.nan_to_num(np.asarray(errors, float), nan=np.inf, posinf=np.inf), np.asarray(times, float)
    nan = float("nan")
    ok = np.flatnonzero(np.isfinite(e) & (e > 0))
    for i in np.flatnonzero((e[:-1] >= eps) & (e[1:] <= eps))[:1].tolist():
        if not (np.isfinite(e[i]) and e[i + 1] > 0 and e[i] != e[i + 1]):
            return float(t[i + 1]), "bracketed", (i + 1,), nan
        return _line(e, t, i, i + 1, eps), "bracketed", (i, i + 1), nan
    if e.size and e[0] <= eps:
        return float(t[0]), "upper bound", (0,), (min(_line(e, t, 0, 1, eps), float(t[0])) if e.size > 1 else nan)
    if not ok.size:
        return nan, "not reached", (), nan
    last = int(ok[-1])
    if ok.size > 1 and e[last] * FLOOR_GAIN > e[int(ok[-2])]:
        return nan, "below the round-off floor", (), nan
    est = max(_line(e, t, int(ok[-2]), last, eps), float(t[last])) if ok.size > 1 else nan
    return float(t[last]), "lower bound", (last,), est


def _curves(ds) -> dict:
    """{candidate: (levels, errors, costs, spreads, repeats, failed)}: the methods over h (the ladder and the levels
    it added, coarse to fine), scipy's over rtol."""
    v = ("error", "cost", "cost_spread", "cost_repeats", "failed")
    out = {}
    for m in ds["scheme"].values:
        cols = [np.asarray(ds["h"].values, float), *(np.asarray(ds[k].sel(scheme=m).values, float) for k in v)]
        if "added_h" in ds and ds.sizes.get("added", 0):
            more = [np.asarray(ds[f"added_{k}"].sel(scheme=m).values, float) for k in ("h", *v)]
            keep = np.isfinite(more[0])
            cols = [np.concatenate([a, b[keep]]) for a, b in zip(cols, more)]
            order = np.argsort(-cols[0], kind="stable")
            cols = [c[order] for c in cols]
        out[m] = tuple(cols)
    for sm in ds["solver"].values if "solver" in ds.dims else []:
        out[f"scipy {sm}"] = (ds["rtol"].values, *(ds[f"scipy_{k}"].sel(solver=sm).values for k in v))
    return out


def _bound_text(name: str, r: dict, eps: float) -> str:
    """``"split6 (≤ 1.38 µs, its h^p line: 0.46 µs)"``."""
    sign = "≤" if r["how"] == "upper bound" else "≥"
    est = f", its h^p line: {timing.format_seconds(r['estimate'])}" if np.isfinite(r["estimate"]) else ""
    return f"{name} ({sign} {timing.format_seconds(r['time'])}{est})"


def reach(ds, ctx) -> tuple[list[dict], list[dict]]:
    """(the time to each ε per candidate, the cheapest per ε): one computation for both closing tables.

    The cheapest is ranked on bracketed times only (:func:`timing.rank`: pairwise ties within the spreads).  It is
    decided only when no candidate with a bound could be cheaper (an upper bound, or a lower bound below the
    leader's time plus its spread) and no time it rests on was measured on a loaded machine
    (:data:`timing.LOADED_SPREAD`)."""
    curves, rows = _curves(ds), []
    ttr = {n: {"method": n} for n in curves}
    for eps in ctx.opt["epsilons"]:
        c, got = {}, {}
        for name, (lev, e, t, sp, *_) in curves.items():
            tt, how, used, est = time_to_error(e, t, eps)
            s = max((sp[i] for i in used), default=np.nan)  # the spread of the levels it rests on
            got[name] = {"time": tt, "how": how, "estimate": est, "spread": s}
            ttr[name].update({f"time/member to {eps:.0e} (s)": tt, f"spread ({eps:.0e})": s, f"({eps:.0e})": HOW[how],
                              f"h^p line to {eps:.0e} (s)": est})
            c.update({name: timing.Cost(tt, tt * (1 + s), s, 0, ())} if how == "bracketed" else {})
        g = timing.rank(c)[0] if c else []
        lead = c[g[0]] if g else None
        could = [n for n, r in got.items() if r["how"] == "upper bound" or (
            r["how"] == "lower bound" and (lead is None or r["time"] <= lead.best * (1 + max(lead.spread, timing.NOISE_FLOOR))))]
        busy = timing.loaded({n: c[n] for n in g})
        rows.append({"error ≤": eps, "cheapest": " = ".join(g) or "not reached", "reached by": len(c), "time/member (s)":
                     lead.best if g else np.nan, "ranking (beyond the spread)": timing.describe(c) if c else "—",
                     "possibly cheaper, not bracketed": "; ".join(_bound_text(n, got[n], eps) for n in could) or "none",
                     "loaded": ", ".join(f"{n} (spread {c[n].spread:.0%})" for n in busy) or "no"})
    return list(ttr.values()), rows


def _added_text(ds) -> str:
    """``": added vi at h = 2.44e-05, 1.22e-05 s"`` (or ``"; none added"``)."""
    if "added_h" not in ds or not ds.sizes.get("added", 0):
        return "; none added"
    parts = [f"{m} at h = " + ", ".join(f"{h:.3g}" for h in ds["added_h"].sel(scheme=m).values if np.isfinite(h)) + " s"
             for m in ds["scheme"].values if np.isfinite(ds["added_h"].sel(scheme=m).values).any()]
    return ": added " + "; ".join(parts) if parts else "; none added"


def derive(ds, ctx) -> xr.Dataset:
    return ds.reindex(scheme=ctx.methods).assign(error=lambda d: d["state_error"].max(["state", "member"]))


def tables(ds, ctx) -> list[Table]:
    ttr, cheapest = reach(ds, ctx)
    cols = ("error at t_end (max)", "CPU time/member (s)", "spread", "repeats", "failed members")
    runs = [{"method": n, "h (s)" if n in ctx.methods else "rtol": lev[i], **{k: c[i] for k, c in zip(cols, cs)}}
            for n, (lev, *cs) in _curves(ds).items() for i in range(len(lev))]
    return [Table("time_to_error", "CPU time per member to reach error ε (log–log between levels; spread: that of the "
                  "levels it rests on)", ttr),
            Table("cheapest", "The cheapest per error level (from the table above)", cheapest),
            Table("work_precision", "All runs", runs)]


def verdicts(ds, ctx) -> list[Verdict]:
    """Per ε: the cheapest on bracketed times; not decided (—) where a method with only a bound could be cheaper,
    where the machine was loaded, or where no method brackets ε."""
    out = []
    for r in reach(ds, ctx)[1]:
        e, g = f"{r['error ≤']:.0e}", r["cheapest"].split(" = ")
        claim = (f"no method's time to error {e} is bracketed" if not r["reached by"] else
                 f"to error {e}: {', '.join(g)} tie within noise" if len(g) > 1 else f"{g[0]} is the cheapest to "
                 f"error {e}" + (" (the only bracketed time)" if r["reached by"] == 1 else ""))
        why = ([f"not bracketed, possibly cheaper: {r['possibly cheaper, not bracketed']}"] * (r["possibly cheaper, "
               "not bracketed"] != "none") + [f"loaded machine, re-measure: {r['loaded']}"] * (r["loaded"] != "no"))
        decided = bool(r["reached by"]) and len(g) == 1 and not why
        out.append(Verdict(claim, "; ".join([r["ranking (beyond the spread)"], *why]),
                           "bracketed times only; its gap to the next > both spreads (≥ 2 %); no method with only a "
                           "bound possibly cheaper; no spread > 100 %", True if decided else None))
    return out


def findings(ds, ctx) -> list[str]:
    out = []
    for r in reach(ds, ctx)[1]:
        w = [n for n in r["cheapest"].split(" = ") if n.startswith(("rk", "scipy"))]
        s = (f"To {r['error ≤']:.0e}: {r['cheapest']} (bracketed); " + (f"the baseline {', '.join(w)} wins or ties"
             if w else "no baseline (RK, scipy) wins among the bracketed"))
        if r["possibly cheaper, not bracketed"] != "none":
            s += f", but not decided: the ladder does not bracket {r['possibly cheaper, not bracketed']}"
        if r["loaded"] != "no":
            s += f"; the machine was loaded ({r['loaded']}): not ranked, re-measure"
        out.append(s + ".")
    return out


#: the figure's marker of a time to ε, by what it is
MARK = {"bracketed": ("o", "full"), "upper bound": ("v", "none"), "lower bound": ("^", "none")}


def _draw(ds, ctx, fig) -> None:
    """Error against cost per member (bars: to the median repeat), and each time to ε of the closing tables:
    a filled circle where the ladder brackets ε, an open ▼ at an upper bound and ▲ at a lower bound, each bound
    with a dotted line to its h^p-line estimate (×)."""
    from matplotlib.lines import Line2D

    ax, curves, ttr = fig.subplots(), _curves(ds), reach(ds, ctx)[0]
    for j, (name, (lev, e, t, sp, *_)) in enumerate(curves.items()):
        ok, col = np.isfinite(e) & (e > 0) & np.isfinite(t), PALETTE[j % len(PALETTE)]
        ax.errorbar(e[ok], t[ok], yerr=[0 * t[ok], t[ok] * sp[ok]], fmt="o-" if name in ctx.methods else "s--",
                    color=col, mfc="none", capsize=2, label=name, alpha=0.8)
        for eps in ctx.opt["epsilons"]:
            r = ttr[j]
            tt, how, est = r[f"time/member to {eps:.0e} (s)"], r[f"({eps:.0e})"].split(" (")[0], r[f"h^p line to {eps:.0e} (s)"]
            if how in MARK and np.isfinite(tt):
                ax.plot([eps], [tt], MARK[how][0], fillstyle=MARK[how][1], color=col, ms=9, mew=1.6)
                if np.isfinite(est):
                    ax.plot([eps, eps], [tt, est], ":", color=col, lw=1.2)
                    ax.plot([eps], [est], "x", color=col, ms=7)
    for eps in ctx.opt["epsilons"]:
        ax.axvline(eps, color="0.6", lw=0.8, ls="--")
    ax.set(xscale="log", yscale="log", xlabel="error at t_end (1)", ylabel="CPU time per member (s)")
    ax.invert_xaxis()
    ax.grid(True, which="both", alpha=0.3)
    keys = [Line2D([], [], marker="o", color="0.3", ls="", label="time to ε: bracketed"),
            Line2D([], [], marker="v", fillstyle="none", color="0.3", ls="", label="upper bound (≤)"),
            Line2D([], [], marker="^", fillstyle="none", color="0.3", ls="", label="lower bound (≥)"),
            Line2D([], [], marker="x", color="0.3", ls=":", label="h^p-line estimate")]
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles + keys, labels + [k.get_label() for k in keys], fontsize=8, loc="outside right center")


_Q = {"error": ("1", "max over members of the error at t_end"), "failed": ("1", "members that failed"), "cost_repeats":
      ("1", "repeats"), "cost": ("s", "CPU time per member (min over repeats)"), "cost_spread": ("1", "median / min - 1")}
QUANTITIES = {**_Q, **{f"scipy_{k}": v for k, v in _Q.items()}, "timed_members": ("1", "members of one timed run"),
              "state_error": ("1", "|x - x_ref| / |x(0)| at t_end"), "state": ("1", "state variable of the model"),
              "rtol": ("1", "solve_ivp relative tolerance"), "solver": ("1", "solve_ivp method"),
              **{f"added_{k}": (u, f"level added to the ladder: {n}") for k, (u, n) in
                 {**_Q, "h": ("s", "time step")}.items()}, "added": ("1", "level added to the ladder (NaN: none)")}

STUDY = Study(
    kind="work_precision", title="Work–precision", models=None, needs_methods=False,
    description="CPU time per member against the error at t_end, every method and scipy's solve_ivp",
    options=(Option("t_end", 10.0, "number>0", "s", "end time"), Option("members", 32, "int>=1", "1", "members measured"),
             Option("h", [0.2 / 2**k for k in range(9)], "list[number>0]", "s", "the ladder of steps, coarse to fine"),
             Option("scipy_methods", ["RK45", "DOP853"], "list[str]", "", "solve_ivp methods (where the model has an ode)"),
             Option("scipy_rtol", [10.0**-k for k in range(3, 13)], "list[number>0]", "1", "solve_ivp rtol ladder"),
             Option("scipy_atol_factor", 1e-3, "number>0", "1", "atol / rtol"),
             Option("scipy_members", 4, "int>=0", "1", "members scipy integrates, one at a time (0: none)"),
             Option("epsilons", [1e-3, 1e-6, 1e-9], "list[number>0]", "1", "error levels of the closing tables"),
             Option("threads", 1, "int>=1", "1", "threads when timing"), Option("repeats", 5, "int>=1", "1", "rounds"),
             Option("min_timing", 0.05, "number>0", "s", "timed seconds per method and h, at least"),
             Option("extend_levels", 2, "int>=0", "1", "levels the ladder may add at each end (h halved below the "
                    "finest, doubled above the coarsest) to bracket a time to ε it only bounds"),
             Option("timing_member_steps", 2**18, "int>=1", "1", "member-steps of a timed run, at least")),
    axes=_axes, check=_check, quantities=QUANTITIES, derive=derive, tables=tables, verdicts=verdicts, findings=findings,
    stages=(Stage("reference", reference, keep=()),
            Stage("errors", errors, over=("point", "scheme", "h"), needs=("reference",)),
            Stage("costs", costs, over=("point", "h"), serial=True),
            Stage("extend", extend, over=("point", "scheme"), needs=("reference", "errors"), serial=True,
                  prefix="added_"),
            Stage("scipy", scipy_runs, over=("point", "rtol"), needs=("reference",), serial=True, prefix="scipy_")),
    figures=(Figure("work_precision", kind="custom", draw=_draw, size=(9.5, 5.5), claim=(
        "the lowest curve at an error level (dashed lines) is the tables' cheapest; bars reach the median repeat; "
        "filled circles are bracketed times to ε, open triangles bounds (▼ at most, ▲ at least) with their h^p-line "
        "estimates (×)")),),
    report=("Scene `{scene}` ({model}), {opt[members]} members, t_end = {opt[t_end]} s. Error: per member the largest "
            "|x(t_end) − x_ref(t_end)| / |x(0)| over {state}; the reference: {ref}. Costs: the process's CPU time over "
            "the kernels (not wall time: the machine's other load does not enter it), all methods at an h timed "
            "interleaved on {opt[threads]} pinned thread(s), runs of ≥ {opt[timing_member_steps]} member-steps, ≥ "
            "{opt[repeats]} rounds and {opt[min_timing]} s; the minimum over repeats, spread = median / min − 1 (a spread "
            "over 100 % means a loaded machine: that h is timed again, up to 3 times, and a ranking that rests on "
            "it is not stated). A time to ε is **bracketed** when two neighbouring levels lie on either side of ε; "
            "where the coarsest level is already below ε it is an **upper bound**, where the finest is still above "
            "it a **lower bound** (each with its h^p-line estimate, not used by any verdict), and where the finest "
            "levels stopped gaining (less than 2× per level) ε is **below the round-off floor**. Where a time is only "
            "bounded, the ladder adds up to {opt[extend_levels]} level(s) at that end (h halved below the finest, doubled "
            "above the coarsest while it divides t_end), each timed alone, when the log–log line of its two end levels "
            "says ε is reached within them{added}. A verdict rests on "
            "bracketed times only and is left undecided (—) where a method with only a bound could be cheaper. "
            "{scipy}"),
    facts=lambda ds, ctx: {"added": _added_text(ds),
                           "state": ", ".join(ds["state"].values), "ref": ctx.model.methods()["reference"].description,
                           "scipy": SCIPY_NOTE.format(s=", ".join(ctx.axes["solver"]), o=ctx.opt) if ctx.axes["solver"]
                           else "scipy's solve_ivp is skipped (no continuous right-hand side, or scipy_members = 0)."},
)
