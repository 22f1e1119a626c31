"""Convergence: observed orders of every method against the model's reference.

The base scene (either model) is integrated to ``t_end`` with h = h0, h0/2, …,
h0/2^(levels−1) and compared at the common times t_j = j·h0 with the reference
method (fixed-step DOP853 for the top, DOP853 at rtol 1e-13 for the fluid) at
the finest h / 2.  The compared state is the model's own
(:meth:`liethermo.models.Model.study_state`): Ω, Γ, S and E for the top
(node values), W, q and S for the fluid.  The error of a variable is the max
over members and times of the norm of the difference; the observed order is
the least-squares slope of log(error) on log(h) over the levels before the
round-off floor, and the verdict compares it with the declared order.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from ..analysis import judge_order, order_tolerance
from .common import StudyError
from .framework import Figure, Option, Stage, Study, Table, Verdict, first_point, run_scene


def _levels(ctx) -> list[float]:
    return [ctx.opt["h0"] / 2**i for i in range(ctx.opt["levels"])]


def _h_ref(ctx) -> float:
    return _levels(ctx)[-1] / 2


def _check(ctx) -> None:
    n0 = ctx.opt["t_end"] / ctx.opt["h0"]
    if abs(n0 - round(n0)) > 1e-9:
        raise StudyError("options.t_end: must be a whole multiple of options.h0")


def reference(ctx, coords) -> xr.Dataset:
    h = _h_ref(ctx)
    ds, _ = run_scene(ctx.scene(coords["point"]), "reference", h=h, steps=round(ctx.opt["t_end"] / h),
                      every=round(ctx.opt["h0"] / h), members=ctx.opt["members"])
    if int(np.max(ds["status"].values)) != 0:
        raise ArithmeticError(f"the reference failed at sweep point {coords['point'] or 'base scene'}")
    return ds


def errors(ctx, coords, reference) -> xr.Dataset:
    h = float(coords["h"])
    scene = ctx.scene(coords["point"])
    model = ctx.model
    ds, stats = run_scene(scene, coords["scheme"], h=h, steps=round(ctx.opt["t_end"] / h),
                          every=round(ctx.opt["h0"] / h), members=ctx.opt["members"])
    got, ref = model.study_state(ds), model.study_state(reference)
    failed = int(np.max(ds["status"].values)) != 0
    out = {"status": ((), int(np.max(ds["status"].values))), "kernel_time": ((), float(stats.kernel_time))}
    for name, (x, units, long, scale) in got.items():
        r = ref[name][0]
        diff = np.abs(x[:, 1:] - r[:, 1:]).reshape(x.shape[0], x.shape[1] - 1, -1)
        err = np.inf if failed else float(np.max(np.sqrt(np.sum(diff * diff, axis=-1))))
        out[f"error_{name}"] = ((), err, {"units": units, "long_name": f"error in {long}"})
        out[f"scale_{name}"] = ((), ref[name][3] or float(np.max(np.abs(r))) or 1.0, {"units": units})
    return xr.Dataset(out)


def fit_order(hs, errs, scale: float, floor_rel: float):
    """(order, constant, levels fitted): least squares of log(error) on log(h)
    from the coarsest level while the error is above ``floor_rel`` × ``scale``
    and the local order log2(e_{i-1}/e_i) stays near the first one (a
    level on the way into the round-off plateau ends the fit: a local order
    more than max(1, first/4) below the first one)."""
    hs, errs = np.asarray(hs, float), np.asarray(errs, float)
    used, first = 0, None
    for i, e in enumerate(errs):
        if not np.isfinite(e) or e < floor_rel * scale:
            break
        if i > 0:
            local = np.log(errs[i - 1] / e) / np.log(hs[i - 1] / hs[i])
            first = local if first is None else first
            if local < max(0.26, first - max(1.0, 0.25 * first)):
                break
        used = i + 1
    if used < 3:
        return np.nan, np.nan, used
    slope, icept = np.polyfit(np.log(hs[:used]), np.log(errs[:used]), 1)
    return float(slope), float(np.exp(icept)), used


def _names(ds) -> list[str]:
    return [v[6:] for v in ds.data_vars if v.startswith("error_") and not v.startswith("error_constant_")]


def derive(ds: xr.Dataset, ctx) -> xr.Dataset:
    hs = ds["h"].values
    for name in _names(ds):
        e, sc = ds[f"error_{name}"], ds[f"scale_{name}"].max("h")
        fit = xr.apply_ufunc(lambda y, s: np.array(fit_order(hs, y, s, ctx.opt["floor_rel"])), e, sc,
                             input_core_dims=[["h"], []], output_core_dims=[["fit"]], vectorize=True)
        what = e.attrs["long_name"][len("error in "):]
        ds[f"observed_order_{name}"] = fit.isel(fit=0).assign_attrs(units="1", long_name=f"observed order of {what}")
        ds[f"error_constant_{name}"] = fit.isel(fit=1).assign_attrs(units=e.attrs["units"],
                                                                     long_name=f"C in error = C h^p ({what})")
        ds[f"levels_fitted_{name}"] = fit.isel(fit=2).astype(np.int64).assign_attrs(
            units="1", long_name=f"levels h in the order fit of {what}")
        e.attrs["long_name"] = f"max over t = j h0 and members of |{what} - reference|"
    ds["declared_order"] = ("scheme", [ctx.model.method_order(m) for m in ctx.methods])
    return ds.drop_vars([v for v in ds.data_vars if v.startswith("scale_")])


QUANTITIES = {"kernel_time": ("s", "wall time of the run, compilation excluded"),
              "declared_order": ("1", "order the method declares"),
              "status": ("1", "worst member status of the run (0 ok)")}


def tables(ds, ctx) -> list[Table]:
    d = first_point(ds, ctx)
    names = _names(d)
    rows = []
    for m in ctx.methods:
        x = d.sel(scheme=m)
        rows.append({"method": m, **ctx.model.method_details(m), "declared order": int(x["declared_order"]),
                     **{f"order {n}": float(x[f"observed_order_{n}"]) for n in names},
                     **{f"C {n} ({ds[f'error_{n}'].attrs.get('units', '')})": float(x[f"error_constant_{n}"])
                        for n in names},
                     "levels fitted": ", ".join(str(int(x[f"levels_fitted_{n}"])) for n in names)})
    errs = [{"method": m, "h (s)": float(h),
             **{f"error {n} ({ds[f'error_{n}'].attrs.get('units', '')})": float(d[f"error_{n}"].sel(scheme=m, h=h))
                for n in names}} for m in ctx.methods for h in d["h"].values]
    return [Table("orders", "Observed orders and error constants (first sweep point; error ≈ C h^p)", rows),
            Table("errors", "Errors per level (first sweep point)", errs)]


def verdicts(ds, ctx) -> list[Verdict]:
    d = first_point(ds, ctx)
    out = []
    for m in ctx.methods:
        p = int(d["declared_order"].sel(scheme=m))
        obs = {n: float(d[f"observed_order_{n}"].sel(scheme=m)) for n in _names(d)}
        judged = {n: judge_order(o, p) for n, o in obs.items()}
        fitted = {n: o for n, o in obs.items() if judged[n] != "not fitted"}
        measured = ", ".join(f"{n} {o:.2f}" for n, o in obs.items())
        out.append(Verdict(f"{m} converges at order {p}", measured, f"every fitted order ≥ {p} − "
                           f"{order_tolerance(p):g}", None if not fitted else
                           all(judged[n] != "below declared" for n in fitted)))
    return out


def findings(ds, ctx) -> list[str]:
    vs = verdicts(ds, ctx)
    bad = [v.claim.split(" ")[0] for v in vs if v.holds is False]
    unfit = [v.claim.split(" ")[0] for v in vs if v.holds is None]
    out = [f"{len(vs) - len(bad) - len(unfit)} of {len(vs)} methods reach their declared order on every fitted "
           "variable" + (f"; below it: {', '.join(bad)}" if bad else "") + "."]
    if unfit:
        out.append(f"No order could be fitted for {', '.join(unfit)} (fewer than 3 levels above round-off).")
    return out


def reference_slopes(ax, var, d, ctx) -> None:
    """Dashed grey lines C h^p, one per declared order p, through the median error at the coarsest h of the methods
    of that order: the slope a method of order p follows until the round-off floor."""
    h = np.asarray(d["h"].values, float)
    h0 = h.max()
    for p in sorted({int(ctx.model.method_order(m)) for m in ctx.methods}):
        ms = [m for m in ctx.methods if int(ctx.model.method_order(m)) == p and m in d["scheme"].values]
        e0 = [float(d[var].sel(scheme=m, h=h0)) for m in ms]
        e0 = [e for e in e0 if np.isfinite(e) and e > 0]
        if not e0:
            continue
        c = float(np.median(e0))
        vals = np.asarray(d[var].values, float)
        floor = np.min(vals[np.isfinite(vals) & (vals > 0)], initial=c)
        hh = h[(c * (h / h0) ** p) >= floor]  # down to the panel's least error, not below it
        if hh.size < 2:
            continue
        from matplotlib.lines import Line2D

        # a factor 3 above: beside the data; an artist, not a plotted line, so that the data alone set the view
        ax.add_artist(Line2D(hh, c * (hh / h0) ** p * 3.0, ls=":", color="0.35", lw=1.0))
        ax.annotate(f"h$^{p}$", (hh.min(), c * (hh.min() / h0) ** p * 3.0), fontsize=8, color="0.25",
                    xytext=(-2, 0), textcoords="offset points", ha="right", va="center", annotation_clip=True)


STUDY = Study(
    kind="convergence", title="Convergence", models=None,
    description="Observed orders per method and variable against the reference, h halving",
    options=(Option("h0", 0.1, "number>0", "s", "coarsest step"),
             Option("levels", 7, "int>=3", "1", "h0, h0/2, …, h0/2^(levels−1) (an order fit needs 3)"),
             Option("t_end", 5.0, "number>0", "s", "end time (a multiple of h0)"),
             Option("members", 1, "int>=1", "1", "members compared (the first ones of the scene)"),
             Option("floor_rel", 1e-12, "number>0", "1", "errors below this × the variable's scale are round-off")),
    axes=lambda ctx: {"h": _levels(ctx)}, check=_check,
    stages=(Stage("reference", reference, over=("point",), keep=()),
            Stage("errors", errors, over=("point", "scheme", "h"), needs=("reference",))),
    quantities=QUANTITIES, derive=derive, tables=tables, verdicts=verdicts, findings=findings,
    figures=(Figure("convergence", kind="lines", x="h", y=lambda ds: [f"error_{n}" for n in _names(ds)], logx=True, logy=True,
                    decorate=reference_slopes, title="Convergence: error against the step (dotted: h^p, the declared orders)",
                    claim="the errors fall as h^p with each method's declared order until the round-off floor"),),
    report=("Scene `{scene}` ({model}), {opt[members]} member(s), t_end = {opt[t_end]} s, h = {opt[h0]} s halved "
            "{levels_less} times, compared at t = j·{opt[h0]} s with the reference at h = {h_ref:.3g} s. The fit "
            "ends at the round-off floor (error < {opt[floor_rel]:g} × the variable's scale) or where the local "
            "order falls more than max(1, p/4) below its first value; `levels fitted` says how many levels "
            "entered it. Compared: {state}."),
    facts=lambda ds, ctx: {"levels_less": ctx.opt["levels"] - 1, "h_ref": _h_ref(ctx),
                           "state": "; ".join(f"{n}: {ds[f'error_{n}'].attrs['long_name']}" for n in _names(ds))},
)
