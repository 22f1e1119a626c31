"""Energy drift: the model's relative energy error over a random ensemble, per method and swept h (any model).
Per member: max and final |error|, the drift rate (least-squares slope in t), and whether it **blew up** (failed,
or max |error| > ``diverged_above``: one definition for the table, the figure and the verdicts).
``paper_convention`` methods are also read in the model's other conventions (the top's step velocity)."""

from __future__ import annotations

import numpy as np
import xarray as xr

from ..analysis import MIN_MEMBERS, ROUND_OFF, least_over_members, paired_ratio
from .common import StudyError, dim_name
from .framework import Figure, Option, Stage, Study, Table, Verdict, first_point

QUANTILES = (0.05, 0.5, 0.95)
CLIP = 1e3  # the band figure draws larger errors at this value
H = dim_name("integrator.h")


def _check(ctx) -> None:
    for h, what in ((p.get("integrator.h"), w) for p in ctx.points or [{}] for w in ("t_end", "band_dt")):
        if h is None:
            raise StudyError('sweep."integrator.h": an energy-drift study sweeps the time step')
        if abs(ctx.opt[what] / h - round(ctx.opt[what] / h)) > 1e-9 or round(ctx.opt[what] / h) < 1:
            raise StudyError(f"options.{what} = {ctx.opt[what]} must be a multiple of every swept h (h = {h})")
    for m in ctx.opt["paper_convention"] or []:
        if m not in ctx.methods or not ctx.model.energy_convention_names:
            raise StudyError(f"options.paper_convention: {m!r} must be a method of the study, on a model with "
                             f"another energy convention (not {ctx.model.name})")


def _sfx(ctx) -> list[str]:
    return [""] + [f"_{c}" for c in ctx.model.energy_convention_names]


def ensemble(ctx, coords) -> xr.Dataset:
    from ..runner import run_chunk

    opt, m, model, h = ctx.opt, coords["scheme"], ctx.model, float(coords["point"]["integrator.h"])
    steps, be = round(opt["t_end"] / h), round(opt["band_dt"] / h)
    sc = ctx.scene(coords["point"]).with_overrides({**model.study_outputs, **model.method_overrides(m), "integrator.steps": steps,
                                                    "output.every": 1})
    N, t = int(sc["ensemble"]["members"]), np.arange(steps + 1) * h
    rel, status, wall = {c: np.full((N, t.size), np.nan) for c in _sfx(ctx)}, np.empty(N, np.int8), 0.0
    for lo in range(0, N, int(opt["member_chunk"])):
        hi = min(N, lo + int(opt["member_chunk"]))
        ds, st = run_chunk(sc, lo, hi)  # with the pools a run of sc uses
        status[lo:hi], wall = ds["status"].values, wall + st.kernel_time
        for c, r in {"": model.relative_energy_error(ds), **model.energy_conventions(ds)}.items():
            rel[f"_{c}" if c else ""][lo:hi] = r
    data, ok, tc = {"status": ("member", status), "kernel_time": ((), wall)}, status == 0, t - t.mean()
    for c, r in rel.items():
        with np.errstate(over="ignore", invalid="ignore"):
            arel = np.where(np.isfinite(r), np.abs(r), np.inf)  # after a failure: +inf
            slope = (r - r.mean(axis=1, keepdims=True)) @ tc / (tc @ tc)
        asked = np.nan if c and m not in (opt["paper_convention"] or []) else 1.0  # NaN: a convention not asked
        data.update({f"relative_energy_error_quantiles{c}": (("quantile", "t"), asked * np.quantile(
            arel[:, ::be], QUANTILES, axis=0, method="inverted_cdf")), f"max_relative_energy_error{c}": (
            "member", asked * np.where(ok, arel.max(axis=1), np.inf)), f"final_relative_energy_error{c}": (
            "member", asked * arel[:, -1]), f"energy_drift_rate{c}": ("member", asked * np.where(ok, slope, np.nan))})
    data["blown_up"] = ("member", (~ok | ~(data["max_relative_energy_error"][1] <= opt["diverged_above"])).astype(np.int8))
    return xr.Dataset(data, coords={"quantile": list(QUANTILES), "t": t[::be], "member": np.arange(N)})


def quantities(ctx) -> dict:
    return {"kernel_time": ("s", "kernel wall time of the point's ensemble"), "quantile": ("1", "quantile over members"),
            "blown_up": ("1", f"1: the member failed or its max |relative energy error| > {ctx.opt['diverged_above']:g}"),
            "blown_up_members": ("1", "members that blew up"), H: ("s", "time step h"),
            "median_max_relative_energy_error": ("1", "median max |rel. energy error|"),
            **{f"{v}{c}": (u, w + (f" ({c[1:]} convention; NaN where not asked)" if c else "")) for c in _sfx(ctx)
               for v, u, w in (("relative_energy_error_quantiles", "1", "quantiles over members of |relative energy "
                                "error|"), ("max_relative_energy_error", "1", "max over t of |relative energy error| "
                                "(failed: inf)"), ("final_relative_energy_error", "1", "|relative energy error| at t_end"),
                               ("energy_drift_rate", "s-1", "least-squares slope of the relative energy error in t"))}}


def derive(ds, ctx) -> xr.Dataset:
    return ds.assign(median_max_relative_energy_error=ds["max_relative_energy_error"].quantile(
        0.5, "member", method="inverted_cdf").drop_vars("quantile"), blown_up_members=ds["blown_up"].sum("member"))


def tables(ds, ctx) -> list[Table]:
    d, rows, q = first_point(ds, ctx, keep=(H,)), [], lambda x, p: float(np.quantile(x, p, method="inverted_cdf"))
    for h, m, c in ((h, m, c) for h in d[H].values for m in ctx.methods for c in _sfx(ctx)):
        x = d.sel({H: h, "scheme": m})
        mx, dr = x[f"max_relative_energy_error{c}"].values, x[f"energy_drift_rate{c}"].values
        dr = dr[np.isfinite(dr)]
        if not np.isnan(mx).all():
            rows.append({"method": m + (f" ({c[1:]} convention)" if c else ""), "h (s)": float(h), "members": mx.size,
                         "median max |rel. energy error|": q(mx, 0.5), "5% max |rel. energy error|": q(mx, 0.05),
                         "95% max |rel. energy error|": q(mx, 0.95),
                         "median final |rel. energy error|": q(x[f"final_relative_energy_error{c}"].values, 0.5),
                         "median drift rate (1/s)": float(np.median(dr)) if dr.size else np.nan,
                         "median |drift rate| (1/s)": float(np.median(np.abs(dr))) if dr.size else np.nan,
                         "blown-up members": int(x["blown_up_members"])})
    return [Table("energy_drift", f"Relative energy error over {ds.sizes['member']} members, t_end = "
                  f"{ctx.opt['t_end']:g} s (blown up: failed, or max |error| > {ctx.opt['diverged_above']:g})", rows)]


def verdicts(ds, ctx) -> list[Verdict]:
    d, out = first_point(ds, ctx, keep=(H,)), []
    hs = d[H].values
    for m in ctx.methods:
        x, p = d.sel(scheme=m), ctx.model.method_order(m)
        b, e = x["blown_up_members"].values, x["median_max_relative_energy_error"].values
        out.append(Verdict(f"no member of {m} blows up", ", ".join(f"h = {h:g}: {n}" for h, n in zip(hs, b)),
                           "0 blown-up members at every h", bool((b == 0).all())))
        with np.errstate(divide="ignore", invalid="ignore"):
            obs = np.log(e[:-1] / e[1:]) / np.log(hs[:-1] / hs[1:])
        ok = np.isfinite(obs) & (b[:-1] == 0) & (b[1:] == 0) & (e[1:] > 1e-12)
        out.append(Verdict(f"{m}'s median max error falls at order ≥ {p - 1} as h shrinks", ", ".join(
            f"{o:.2f}" for o in obs) or "one h", f"observed order ≥ {p} − 1 between neighbouring h (blown up or "
            "below 1e-12: not decided)", bool((obs[ok] >= p - 1).all()) if ok.any() else None))
    return out


def findings(ds, ctx) -> list[str]:
    """Per h: the methods with the least median max error, by a seeded paired bootstrap over members (a method
    ties with the least when the 95 % interval of the ratio of medians contains 1; values ≤ ROUND_OFF are equal;
    a blown-up member counts as the worst), and where the first of the study's methods stands against each other method."""
    d, base, out = first_point(ds, ctx, keep=(H,)), ctx.methods[0], []
    n = d.sizes["member"]
    for h in d[H].values:
        v = {m: d["max_relative_energy_error"].sel({H: h, "scheme": m}).values for m in ctx.methods}
        e = d["median_max_relative_energy_error"].sel({H: h}).to_series()
        least, cmp = least_over_members(v, floor=ROUND_OFF)
        if n < MIN_MEMBERS:
            out.append(f"At h = {h:g} s the least median max error is {e.idxmin()}'s ({e.min():.3g}); {n} members are "
                       f"too few for paired intervals (≥ {MIN_MEMBERS}): no ranking.")
            continue
        rel = {m: paired_ratio(v[base], v[m], floor=ROUND_OFF) for m in ctx.methods if m != base}
        says = {w: [m for m, p in rel.items() if p.verdict == k] for w, k in
                (("lower than", "a smaller"), ("tied with", "tie"), ("higher than", "b smaller"))}
        tie = f" (tied: {' = '.join(least)})" if len(least) > 1 else ""
        nxt = [m for m in e.sort_values().index if m not in least][:1]
        out.append(f"At h = {h:g} s the least median max error is {least[0]}'s ({e[least[0]]:.3g}){tie}"
                   + (f"; next {cmp[nxt[0]].text(nxt[0], least[0])}" if nxt else "") + f"; {base}, the first of "
                   f"the study's methods, ({e[base]:.3g}) is " + "; ".join(f"{w} {', '.join(ms)}" for w, ms in says.items() if ms) + ".")
    return out


def draw_bands(d, ctx, fig):
    hs, t, rows = d[H].values, d["t"].values, -(-d.sizes[H] // 3)
    fig.set_size_inches(15.5, 1.0 + 4.4 * rows)
    axes = fig.subplots(rows, min(3, len(hs)), squeeze=False, sharey=True).ravel()
    for ax, h in zip(axes, hs):
        x = d.sel({H: h})
        for m in ctx.methods:
            for c in _sfx(ctx):
                q = np.minimum(x[f"relative_energy_error_quantiles{c}"].sel(scheme=m).values, CLIP)[:, t > 0]
                if not np.isnan(q).all():
                    ax.plot(t[t > 0], q[1], "--" if c else "-", color=ctx.color(m), lw=1.2, label=m + (
                        f", {c[1:]} convention" if c else ""))
                    ax.fill_between(t[t > 0], q[0], q[2], color=ctx.color(m), alpha=0 if c else 0.12, lw=0)
        blown = ", ".join(f"{m} {n}/{d.sizes['member']}" for m, n in x["blown_up_members"].to_series().items() if n)
        ax.set(yscale="log", xlabel="t (s)", title=f"h = {h:g} s" + (f"\nblown up: {blown}" if blown else ""))
        ax.grid(True, which="major", alpha=0.3)
        ax.yaxis.set_tick_params(labelleft=True)  # shared, but numbered on every panel
    axes[0].set_ylabel(f"|relative energy error| (1), median and 5–95 %; ≥ {CLIP:g} drawn at {CLIP:g}")
    for ax in axes[len(hs):]:
        ax.set_visible(False)
    fig.legend(*axes[0].get_legend_handles_labels(), title="scheme", loc="outside right center", fontsize=8)


STUDY = Study(
    kind="energy_drift", title="Energy drift over a random ensemble", models=None,
    description="Median and 5-95 % band of the relative energy error per method and h; drift rates; blow-ups",
    options=(Option("t_end", 30.0, "number>0", "s", "simulated time"),
             Option("band_dt", 0.2, "number>0", "s", "time grid of the stored bands"),
             Option("member_chunk", 1024, "int>=1", "1", "members simulated at a time (bounds memory)"),
             Option("diverged_above", 1.0, "number>0", "1", "a member whose max |error| passes this blew up"),
             Option("paper_convention", None, "list?[str]", "", "methods also read in the model's other energy "
                    "convention(s)", optional=True)),
    check=_check, stages=(Stage("runs", ensemble, over=("point", "scheme")),),
    quantities=quantities, derive=derive, tables=tables, verdicts=verdicts, findings=findings,
    figures=(Figure("energy_drift_bands", kind="custom", draw=draw_bands, select=lambda ds, ctx: first_point(
        ds, ctx, keep=(H,)), claim="how each method's energy error grows over time at each h, and where it blows up"),
             Figure("energy_drift_error", x=H, y=("median_max_relative_energy_error",), logx=True, logy=True,
                    select=lambda ds, ctx: first_point(ds, ctx, keep=(H,)),
                    claim="the median max error against h: a method's slope is its order until it blows up")),
    report=("Scene `{scene}` ({model}), {members} members with random initial conditions, t_end = {opt[t_end]} s, "
            "every step stored. The relative energy error is the model's (node values for every method); a member "
            "**blew up** when its run failed or its max |error| passed {opt[diverged_above]:g}. The findings compare "
            "methods' median max errors on the same members by a seeded paired bootstrap (95 % interval of the ratio "
            "of medians; a tie where it contains 1; errors ≤ 1e-13 are equal; fewer than 10 members: no ranking)."),
    facts=lambda ds, ctx: {"members": ds.sizes["member"]},
)
