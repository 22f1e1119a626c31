"""Energy drift: the relative energy error over a random ensemble, per method and swept h.

Any model.  Every method runs the base scene's members (in chunks of
``member_chunk``) at every swept ``integrator.h`` to ``t_end``, storing every
step; the relative energy error is the model's
(:meth:`liethermo.models.Model.relative_energy_error`: node values, relative to
E_mech,0 for the top, to H(0) for the fluid).  For the methods in
``paper_convention`` the model's other readings of it
(:meth:`~liethermo.models.Model.energy_conventions`: the paper's step
velocity for the top) are reported beside.  Per member: max and final
|error|, the drift rate (least-squares slope in t) and whether it **blew up**:
its run failed (status ≠ 0) or its max |error| passed ``diverged_above``;
that one definition is counted in the table, the figure and the verdicts.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from .common import StudyError, dim_name
from .framework import Figure, Option, Stage, Study, Table, Verdict, first_point

QUANTILES = (0.05, 0.5, 0.95)
CLIP = 1e3  # the band figure draws larger errors (and blown-up members) at this value
H = dim_name("integrator.h")


def _check(ctx) -> None:
    hs = [p.get("integrator.h") for p in ctx.points]
    if not ctx.points or None in hs:
        raise StudyError('sweep."integrator.h": an energy-drift study sweeps the time step')
    for h in hs:
        for what in ("t_end", "band_dt"):
            r = ctx.opt[what] / h
            if abs(r - round(r)) > 1e-9 or round(r) < 1:
                raise StudyError(f"options.{what} = {ctx.opt[what]} must be a multiple of every swept h (h = {h})")
    for m in ctx.opt["paper_convention"] or []:
        if m not in ctx.methods or not ctx.model.energy_convention_names:
            raise StudyError(f"options.paper_convention: {m!r} must be a method of the study whose model "
                             f"({ctx.model.name}) records another energy convention")


def _conventions(ctx) -> list[str]:
    return [""] + [f"_{c}" for c in ctx.model.energy_convention_names]


def ensemble(ctx, coords) -> xr.Dataset:
    opt, m, model = ctx.opt, coords["scheme"], ctx.model
    h = float(coords["point"]["integrator.h"])
    steps, be = round(opt["t_end"] / h), round(opt["band_dt"] / h)
    sc = ctx.scene(coords["point"]).with_overrides({**model.method_overrides(m), "integrator.steps": steps,
                                                    "output.every": 1})
    N, t = int(sc["ensemble"]["members"]), np.arange(steps + 1) * h
    out = {c: {k: np.full((N, t[::be].size) if k == "band" else N, np.nan) for k in ("band", "max", "final", "drift")}
           for c in _conventions(ctx)}
    status, wall = np.empty(N, np.int8), 0.0
    for lo in range(0, N, int(opt["member_chunk"])):
        hi = min(N, lo + int(opt["member_chunk"]))
        ds, st = model.run_chunk(sc, lo, hi)
        wall += st.kernel_time
        ok = ds["status"].values == 0
        status[lo:hi] = ds["status"].values
        rels = {"": model.relative_energy_error(ds)}
        if m in (opt["paper_convention"] or []):
            rels.update({f"_{c}": r for c, r in model.energy_conventions(ds).items()})
        for c, rel in rels.items():
            with np.errstate(over="ignore", invalid="ignore"):
                arel = np.abs(rel)
                arel[~np.isfinite(arel)] = np.inf  # after a failure: counts as +inf
                tc = t - t.mean()
                slope = (rel - rel.mean(axis=1, keepdims=True)) @ tc / (tc @ tc)
            o = out[c]
            o["band"][lo:hi], o["final"][lo:hi] = arel[:, ::be], arel[:, -1]
            o["max"][lo:hi] = np.where(ok, arel.max(axis=1), np.inf)
            o["drift"][lo:hi] = np.where(ok, slope, np.nan)
    data = {"status": ("member", status), "kernel_time": ((), wall),
            "blown_up": ("member", ((status != 0) | ~(out[""]["max"] <= opt["diverged_above"])).astype(np.int8))}
    for c, o in out.items():
        data[f"relative_energy_error_quantiles{c}"] = (("quantile", "t"), np.quantile(
            o["band"], QUANTILES, axis=0, method="inverted_cdf") if not np.isnan(o["max"]).all()
            else np.full((len(QUANTILES), t[::be].size), np.nan))
        data.update({f"max_relative_energy_error{c}": ("member", o["max"]),
                     f"final_relative_energy_error{c}": ("member", o["final"]),
                     f"energy_drift_rate{c}": ("member", o["drift"])})
    return xr.Dataset(data, coords={"quantile": list(QUANTILES), "t": t[::be], "member": np.arange(N)})


def quantities(ctx) -> dict:
    q = {"kernel_time": ("s", "kernel wall time of the point's ensemble"), "quantile": ("1", "quantile over members"),
         "blown_up": ("1", "1 where the member blew up: it failed, or its max |relative energy error| passed "
                           f"{ctx.opt['diverged_above']:g}"), "blown_up_members": ("1", "members that blew up"),
         "median_max_relative_energy_error": ("1", "median max |rel. energy error|"), H: ("s", "time step h")}
    for c in _conventions(ctx):
        w = f" ({c[1:]} convention; NaN where not asked)" if c else ""
        q.update({f"relative_energy_error_quantiles{c}": ("1", f"quantiles over members of |relative energy error|{w}"),
                  f"max_relative_energy_error{c}": ("1", f"max over t of |relative energy error|{w}; failed: inf"),
                  f"final_relative_energy_error{c}": ("1", f"|relative energy error| at t_end{w}"),
                  f"energy_drift_rate{c}": ("s-1", f"least-squares slope of the relative energy error in t{w}")})
    return q


def derive(ds, ctx) -> xr.Dataset:
    ds["median_max_relative_energy_error"] = ds["max_relative_energy_error"].quantile(
        0.5, "member", method="inverted_cdf").drop_vars("quantile")
    ds["blown_up_members"] = ds["blown_up"].sum("member")
    return ds


def _q(x, q) -> float:
    return float(np.quantile(x, q, method="inverted_cdf"))


def tables(ds, ctx) -> list[Table]:
    d, rows = first_point(ds, ctx, keep=(H,)), []
    for h in d[H].values:
        for m in ctx.methods:
            for c in _conventions(ctx):
                x = d.sel({H: h, "scheme": m})
                mx, dr = x[f"max_relative_energy_error{c}"].values, x[f"energy_drift_rate{c}"].values
                if np.isnan(mx).all():
                    continue
                dr = dr[np.isfinite(dr)]
                rows.append({"method": m + (f" ({c[1:]} convention)" if c else ""), "h (s)": float(h),
                             "members": mx.size, "median max |rel. energy error|": _q(mx, 0.5),
                             "5% max |rel. energy error|": _q(mx, 0.05), "95% max |rel. energy error|": _q(mx, 0.95),
                             "median final |rel. energy error|": _q(x[f"final_relative_energy_error{c}"].values, 0.5),
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
        b = x["blown_up_members"].values
        out.append(Verdict(f"no member of {m} blows up", ", ".join(f"h = {h:g}: {n}" for h, n in zip(hs, b)),
                           "0 blown-up members at every h", bool((b == 0).all())))
        e = x["median_max_relative_energy_error"].values
        with np.errstate(divide="ignore", invalid="ignore"):
            obs = np.log(e[:-1] / e[1:]) / np.log(hs[:-1] / hs[1:])
        ok = np.isfinite(obs) & (b[:-1] == 0) & (b[1:] == 0) & (e[1:] > 1e-12)
        out.append(Verdict(f"{m}'s median max error falls at order ≥ {p - 1} as h shrinks",
                           ", ".join(f"{o:.2f}" for o in obs) or "one h", f"observed order ≥ {p} − 1 between "
                           "neighbouring h (blown up or below 1e-12: not decided)", bool((obs[ok] >= p - 1).all())
                           if ok.any() else None))
    return out


def findings(ds, ctx) -> list[str]:
    d, base, out = first_point(ds, ctx, keep=(H,)), ctx.methods[0], []
    for h in d[H].values:
        e = d["median_max_relative_energy_error"].sel({H: h}).to_series().sort_values()
        beats = [m for m in e.index if e[m] > e[base] or not np.isfinite(e[m])]
        out.append(f"At h = {h:g} s {e.index[0]} has the least median max error ({e.iloc[0]:.3g}); the baseline {base} "
                   f"({e[base]:.3g}) beats " + (", ".join(beats) if beats else "no other method") + ".")
    return out


def _draw_bands(d, ctx, fig):
    hs = d[H].values
    fig.set_size_inches(15.5, 1.0 + 4.4 * -(-len(hs) // 3))
    axes = fig.subplots(-(-len(hs) // 3), min(3, len(hs)), squeeze=False, sharey=True).ravel()
    t = d["t"].values
    later = t > 0  # E_k − E₀ is 0 at t = 0: not on a log axis
    for ax, h in zip(axes, hs):
        blown = []
        for m in ctx.methods:
            x = d.sel({H: h, "scheme": m})
            lo, med, hi = (np.minimum(np.nan_to_num(q, nan=CLIP), CLIP)[later] for q in
                           x["relative_energy_error_quantiles"].values)
            ax.fill_between(t[later], lo, hi, color=ctx.color(m), alpha=0.12, lw=0)
            ax.plot(t[later], med, color=ctx.color(m), lw=1.3, label=m)
            for c in _conventions(ctx)[1:]:
                qp = x[f"relative_energy_error_quantiles{c}"].sel(quantile=0.5).values
                if not np.isnan(qp).all():
                    ax.plot(t[later], np.minimum(qp, CLIP)[later], "--", color=ctx.color(m), lw=1,
                            label=f"{m}, {c[1:]} convention")
            if int(x["blown_up_members"]):
                blown.append(f"{m} {int(x['blown_up_members'])}/{d.sizes['member']}")
        ax.set(yscale="log", xlabel="t (s)", title=f"h = {h:g} s" + ("\nblown up: " + ", ".join(blown) if blown else ""))
        ax.grid(True, which="major", alpha=0.3)
    axes[0].set_ylabel(f"|relative energy error| (1), median and 5–95 %; ≥ {CLIP:g} drawn at {CLIP:g}")
    for ax in axes[len(hs):]:
        ax.set_visible(False)
    fig.legend(*axes[0].get_legend_handles_labels(), title="scheme", loc="outside right upper", fontsize=8)


STUDY = Study(
    kind="energy_drift", title="Energy drift over a random ensemble", models=None,
    description="Median and 5-95 % band of the relative energy error per method and h; drift rates; blow-ups",
    options=(Option("t_end", 30.0, "number>0", "s", "simulated time"),
             Option("band_dt", 0.2, "number>0", "s", "time grid of the stored quantile bands"),
             Option("member_chunk", 1024, "int>=1", "1", "members simulated at a time (bounds memory)"),
             Option("diverged_above", 1.0, "number>0", "1", "a member whose max |error| passes this blew up"),
             Option("paper_convention", None, "list[str]", "", "methods also read in the model's other energy "
                    "convention(s)", optional=True)),
    check=_check, stages=(Stage("runs", ensemble, over=("point", "scheme")),),
    quantities=quantities, derive=derive, tables=tables, verdicts=verdicts, findings=findings,
    figures=(Figure("energy_drift_bands", kind="custom", draw=_draw_bands, size=(15.5, 8.4),
                    select=lambda ds, ctx: first_point(ds, ctx, keep=(H,)),
                    claim="how each method's energy error grows over time at each h, and where it blows up"),
             Figure("energy_drift_error", x=H, y=("median_max_relative_energy_error",), logx=True, logy=True,
                    select=lambda ds, ctx: first_point(ds, ctx, keep=(H,)),
                    claim="the median max error against h: a method's slope is its order until it blows up")),
    report=("Scene `{scene}` ({model}), {members} members with random initial conditions, t_end = {opt[t_end]} s, "
            "every step stored. The relative energy error is the model's (node values for every method); a member "
            "**blew up** when its run failed or its max |error| passed {opt[diverged_above]:g}."),
    facts=lambda ds, ctx: {"members": ds.sizes["member"]},
)
