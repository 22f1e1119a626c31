"""Entropy production against the analytic rate, over a grid of scene keys.

On members whose every term keeps the spherical-decay law (a spherical top
whose torques are −cΩ with one c), the motion is known exactly:
Ω(t) = Ω₀e^{−ct/I₀} and S(t) − S₀ = c_v log(1 + I₀|Ω₀|²(1 − e^{−2ct/I₀})/(2c_vT₀)),
so the entropy production rate is Ṡ = P(Ω(t))/T(t) with the dissipated power P
of the model's terms.  Each method runs each point of the sweep (typically a
viscosity × spin grid); the study reports the largest error of the produced
entropy relative to the entropy produced by t_end, the largest error of the
rate P(Ω_k)/T_k of the computed states against the analytic rate, and whether
the entropy ever fell.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from ..findings import exact_spherical_top
from ..kernels.terms import LAW_SPHERICAL_DECAY
from ..physics import dissipated_power, physics_of_scene, torque
from ...analysis import ROUND_OFF
from ...studies.common import StudyError, dim_name
from ...studies.framework import Figure, Option, Stage, Study, Table, Verdict, run_scene


def _check(ctx) -> None:
    for pt in ctx.points or [{}]:
        phys = physics_of_scene(ctx.scene(pt))
        if not (np.ptp(phys.inertia, axis=1) == 0).all() or not phys.keeps(LAW_SPHERICAL_DECAY).all():
            raise StudyError(f"study.base_scene: the analytic rate needs a spherical top whose every term keeps the "
                             f"spherical-decay law; sweep point {pt or 'base scene'} does not")


def exact(phys, ds) -> dict:
    """The analytic Ω, σ = S − S₀ and rate Ṡ at the run's output times, and the entropy Q/T₀ that code
    ignoring the temperature's rise would produce from the same heat Q."""
    e1, e3 = np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0]])
    c = -torque(phys, e1, e3)[:, 0]  # the one friction coefficient of these members
    t = ds["t"].values
    om, _, sig = exact_spherical_top(phys.inertia[:, 0], c, phys.heat_capacity, phys.T0,
                                     ds["initial_omega"].values, ds["initial_attitude"].values[:, 2, :], t)
    temp = phys.T0[:, None] * np.exp(sig / phys.heat_capacity[:, None])
    rate = dissipated_power(phys, om.reshape(-1, 3)).reshape(sig.shape) / temp
    heat_over_T0 = phys.heat_capacity[:, None] * np.expm1(sig / phys.heat_capacity[:, None])  # Q / T0
    return {"omega": om, "sigma": sig, "rate": rate, "heat_over_T0": heat_over_T0}


def run(ctx, coords) -> xr.Dataset:
    scene = ctx.scene(coords["point"])
    ds, _ = run_scene(scene, coords["scheme"], h=ctx.opt["h"], steps=round(ctx.opt["t_end"] / ctx.opt["h"]),
                      every=ctx.opt["every"], members=1)
    phys = physics_of_scene(scene)
    ex = exact(phys, ds)
    sig = ds["entropy"].values - ds["entropy"].values[:, :1]
    om = ds["omega"].values
    rate = dissipated_power(phys, om.reshape(-1, 3)).reshape(sig.shape) / ds["temperature"].values
    produced = ex["sigma"][0, -1]
    return xr.Dataset({
        "entropy_produced": ("t", sig[0]), "entropy_produced_exact": ("t", ex["sigma"][0]),
        "entropy_rate": ("t", rate[0]), "entropy_rate_exact": ("t", ex["rate"][0]),
        "entropy_error_t": ("t", np.abs(sig[0] - ex["sigma"][0]) / produced),
        "rate_error_t": ("t", np.abs(rate[0] - ex["rate"][0]) / np.max(ex["rate"][0])),
        "entropy_min_increment": ((), float(np.min(np.diff(sig[0])))),
        "temperature_rise": ((), float(np.max(ds["temperature"].values[0]) - ds["temperature"].values[0, 0])),
        "entropy_error_ignoring_T": ((), float(np.max(np.abs(ex["heat_over_T0"][0] - ex["sigma"][0])) / produced)),
        "status": ((), int(ds["status"].values[0]))}, coords={"t": ds["t"].values})


QUANTITIES = {
    "entropy_produced": ("J K-1", "entropy produced S - S0"),
    "entropy_produced_exact": ("J K-1", "analytic entropy produced"),
    "entropy_rate": ("W K-1", "entropy production rate P/T of the computed state"),
    "entropy_rate_exact": ("W K-1", "analytic entropy production rate P/T"),
    "entropy_error_t": ("1", "|S - S_exact| / (S_exact - S0 at t_end)"),
    "rate_error_t": ("1", "|P/T - (P/T)_exact| / max_t (P/T)_exact"),
    "entropy_error": ("1", "max_t |S - S_exact| / (S_exact - S0 at t_end)"),
    "rate_error": ("1", "max_t |P/T - (P/T)_exact| / max_t (P/T)_exact"),
    "entropy_min_increment": ("J K-1", "least change of S between outputs (< 0: entropy fell)"),
    "temperature_rise": ("K", "max_t T - T(0) of the computed run"),
    "entropy_error_ignoring_T": ("1", "max_t |Q/T0 - S_exact + S0| / (S_exact - S0 at t_end): the entropy error of "
                                 "code that ignored the temperature's rise"),
}


def derive(ds, ctx):
    ds["entropy_error"] = ds["entropy_error_t"].max("t")
    ds["rate_error"] = ds["rate_error_t"].max("t")
    return ds


def _grid_rows(ds, ctx):
    flat = ds[["entropy_error", "rate_error", "entropy_min_increment", "temperature_rise"]].to_dataframe().reset_index()
    return flat[[c for c in flat.columns if c != "t"]].drop_duplicates().to_dict("records")


def tables(ds, ctx) -> list[Table]:
    rows = [{"method": m, "max entropy error (1)": float(ds["entropy_error"].sel(scheme=m).max()),
             "max rate error (1)": float(ds["rate_error"].sel(scheme=m).max()),
             "least entropy step (J K-1)": float(ds["entropy_min_increment"].sel(scheme=m).min())}
            for m in ctx.methods]
    return [Table("summary", "Worst case over the grid, per method", rows),
            Table("grid", "Every point of the grid", _grid_rows(ds, ctx))]


#: a grid point "tests the temperature" when T rises by at least this
HOT = 10.0


def _hot(ds):
    """Where T rises by at least HOT kelvin (the split's run: exact to round-off)."""
    return ds["temperature_rise"].sel(scheme=ds["scheme"].values[0]) >= HOT


def verdicts(ds, ctx) -> list[Verdict]:
    tol = ctx.opt["tolerance"]
    lin, rise = float(ds["entropy_error_ignoring_T"].max()), float(ds["temperature_rise"].max())
    out = [Verdict("the grid can tell the temperature's rise: an entropy Q/T₀ that ignored it fails the tolerance",
                   f"its error {lin:.2e} where T rises {rise:.3g} K", f"> {tol:g} at some grid point", bool(lin > tol))]
    for m in ctx.methods:
        e = float(ds["entropy_error"].sel(scheme=m).max())
        r = float(ds["rate_error"].sel(scheme=m).max())
        inc = float(ds["entropy_min_increment"].sel(scheme=m).min())
        floor = 1e-12 * float(ds["entropy_produced_exact"].max())  # round-off of S
        out.append(Verdict(f"{m} produces the analytic entropy", f"{e:.2e} (rate {r:.2e})",
                           f"both ≤ {tol:g} (the fixed tolerance, the same for every method) at every grid point",
                           bool(e <= tol and r <= tol)))
        out.append(Verdict(f"{m} never lowers the entropy", f"least step {inc:.2e} J K-1",
                           f"≥ −{floor:.1e} J K-1 (round-off: 1e-12 of the most produced)", bool(inc >= -floor)))
    return out


def findings(ds, ctx) -> list[str]:
    tol, worst = ctx.opt["tolerance"], {m: float(ds["entropy_error"].sel(scheme=m).max()) for m in ctx.methods}
    exact = [m for m in ctx.methods if worst[m] <= ROUND_OFF]
    rest = sorted((m for m in ctx.methods if m not in exact), key=worst.get)
    out = [("Closest to the analytic entropy over the whole grid: "
            + (f"{' and '.join(exact)}, tied at round-off ({', '.join(f'{worst[m]:.1e}' for m in exact)} ≤ "
               f"{ROUND_OFF:g}); " if len(exact) > 1 else f"{exact[0]} at round-off ({worst[exact[0]]:.1e}); " if exact
               else "") + ", ".join(f"{m} {worst[m]:.2e}" for m in rest) + ".")]
    if any(m.startswith("split") for m in exact):
        out.append("On a sphere the splitting's two flows (the free rotation and the friction's decay of Ω along "
                   "itself) commute, so the splitting is the exact flow: its error is round-off.")
    hot = _hot(ds)
    if bool(hot.any()):
        lin = float(ds["entropy_error_ignoring_T"].where(hot).max())
        e = {m: (float(ds["entropy_error"].sel(scheme=m).where(hot).max()),
                 float(ds["entropy_error"].sel(scheme=m).where(~hot).max())) for m in ctx.methods}
        out.append(f"Where T rises by {HOT:g} K or more (up to {float(ds['temperature_rise'].max()):.3g} K), an entropy "
                   f"that ignored the rise (Q/T₀) would be off by {lin:.1%}; each method's worst error there / "
                   f"elsewhere: " + ", ".join(f"{m} {a:.2e} / {b:.2e}" for m, (a, b) in e.items()) + ".")
        turn = [m for m, (a, b) in e.items() if a > tol >= b]
        if turn:
            out.append(f"{', '.join(turn)} {'passes' if len(turn) == 1 else 'pass'} the {tol:g} tolerance where T "
                       f"hardly moves but not where it rises, so {'its' if len(turn) == 1 else 'their'} verdict "
                       "fails: the tolerance is the same for every method and not moved to fit one.")
    else:
        out.append(f"No grid point raises T by {HOT:g} K: the check cannot tell code that ignored the rise.")
    for dim in [d for d in ds["entropy_error"].dims if d != "scheme"]:  # what drives each method's error
        span = ds["entropy_error"].max([d for d in ds["entropy_error"].dims if d not in ("scheme", dim)])
        grows = [m for m in ctx.methods if float(span.sel(scheme=m).max()) > 10 * float(span.sel(scheme=m).min())]
        if grows:
            out.append(f"Along {ds[dim].attrs.get('scene_key', dim)} the error changes more than tenfold for "
                       f"{', '.join(grows)}.")
    return out


def _worst_over_cv(ds, ctx):
    """The heatmap's two axes: the worst entropy error over every sweep key past the first two."""
    dims = [dim_name(k) for k in ctx.sweep_keys if dim_name(k) in ds["entropy_error"].dims]
    return ds[["entropy_error"]].max(dims[2:]) if len(dims) > 2 else ds


STUDY = Study(
    kind="entropy_rate", title="Entropy production against the analytic rate", models=("top",),
    description="Entropy produced and its rate P/T per method against the spherical top's exact solution",
    options=(Option("h", 0.05, "number>0", "s", "time step"),
             Option("t_end", 30.0, "number>0", "s", "end time"),
             Option("every", 10, "int>=1", "1", "keep every k-th step"),
             Option("tolerance", 1e-4, "number>0", "1", "largest relative error the verdicts accept")),
    check=_check, stages=(Stage("run", run, over=("point", "scheme")),),
    quantities=QUANTITIES, derive=derive, tables=tables, verdicts=verdicts, findings=findings,
    figures=(Figure("entropy_error", kind="heatmap", title="Entropy rate: relative entropy error over the grid", facet="scheme", y=("entropy_error",), select=_worst_over_cv,
                    claim=("the relative entropy error of each method over the grid (one panel per method; the worse "
                           "of the grid's heat capacities); hatched cells are runs that failed")),
             Figure("errors_in_time", kind="lines", x="t", y=("entropy_error_t", "rate_error_t"),
                    title=lambda ds, ctx: "Entropy rate: errors in time at the first grid point\n" + ", ".join(
                        f"{k} = {v}" for k, v in (ctx.points[0] if ctx.points else {}).items()),
                    claim="at the first grid point, how each method's entropy and rate errors grow in time (the "
                          "computed and exact curves themselves are in the netCDF)")),
    report=("Scene `{scene}`, h = {opt[h]} s to t = {opt[t_end]} s, one member per grid point; the exact solution "
            "holds because every term keeps the spherical-decay law (checked before the run). A method passes when "
            "its entropy and rate errors are ≤ {opt[tolerance]:g} at every grid point: one fixed tolerance for every "
            "method, set before the runs. The grid's heat capacities make T rise by a fraction of a millikelvin and "
            "by tens of kelvin: there S − S₀ = c_v log(T/T₀) is far from the Q/T₀ of code that ignored T. Errors "
            "≤ {floor:g} are round-off and tie."),
    facts=lambda ds, ctx: {"floor": ROUND_OFF},
)
