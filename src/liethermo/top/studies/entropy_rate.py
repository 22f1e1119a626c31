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
from ...studies.common import StudyError
from ...studies.framework import Figure, Option, Stage, Study, Table, Verdict, run_scene


def _check(ctx) -> None:
    for pt in ctx.points or [{}]:
        phys = physics_of_scene(ctx.scene(pt))
        if not (np.ptp(phys.inertia, axis=1) == 0).all() or not phys.keeps(LAW_SPHERICAL_DECAY).all():
            raise StudyError(f"study.base_scene: the analytic rate needs a spherical top whose every term keeps the "
                             f"spherical-decay law; sweep point {pt or 'base scene'} does not")


def exact(phys, ds) -> dict:
    """The analytic Ω, σ = S − S₀ and rate Ṡ at the run's output times."""
    e1, e3 = np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0]])
    c = -torque(phys, e1, e3)[:, 0]  # the one friction coefficient of these members
    t = ds["t"].values
    om, _, sig = exact_spherical_top(phys.inertia[:, 0], c, phys.heat_capacity, phys.T0,
                                     ds["initial_omega"].values, ds["initial_attitude"].values[:, 2, :], t)
    temp = phys.T0[:, None] * np.exp(sig / phys.heat_capacity[:, None])
    rate = dissipated_power(phys, om.reshape(-1, 3)).reshape(sig.shape) / temp
    return {"omega": om, "sigma": sig, "rate": rate}


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
}


def derive(ds, ctx):
    ds["entropy_error"] = ds["entropy_error_t"].max("t")
    ds["rate_error"] = ds["rate_error_t"].max("t")
    return ds


def _grid_rows(ds, ctx):
    flat = ds[["entropy_error", "rate_error", "entropy_min_increment"]].to_dataframe().reset_index()
    return flat[[c for c in flat.columns if c != "t"]].drop_duplicates().to_dict("records")


def tables(ds, ctx) -> list[Table]:
    rows = [{"method": m, "max entropy error (1)": float(ds["entropy_error"].sel(scheme=m).max()),
             "max rate error (1)": float(ds["rate_error"].sel(scheme=m).max()),
             "least entropy step (J K-1)": float(ds["entropy_min_increment"].sel(scheme=m).min())}
            for m in ctx.methods]
    return [Table("summary", "Worst case over the grid, per method", rows),
            Table("grid", "Every point of the grid", _grid_rows(ds, ctx))]


def verdicts(ds, ctx) -> list[Verdict]:
    tol = ctx.opt["tolerance"]
    out = []
    for m in ctx.methods:
        e = float(ds["entropy_error"].sel(scheme=m).max())
        r = float(ds["rate_error"].sel(scheme=m).max())
        inc = float(ds["entropy_min_increment"].sel(scheme=m).min())
        floor = 1e-12 * float(ds["entropy_produced_exact"].max())  # round-off of S
        out.append(Verdict(f"{m} produces the analytic entropy", f"{e:.2e} (rate {r:.2e})",
                           f"both ≤ {tol:g} over the grid", bool(e <= tol and r <= tol)))
        out.append(Verdict(f"{m} never lowers the entropy", f"least step {inc:.2e} J K-1",
                           f"≥ −{floor:.1e} J K-1 (round-off: 1e-12 of the most produced)", bool(inc >= -floor)))
    return out


def findings(ds, ctx) -> list[str]:
    worst = {m: float(ds["entropy_error"].sel(scheme=m).max()) for m in ctx.methods}
    best = min(worst, key=worst.get)
    out = [f"Closest to the analytic entropy over the whole grid: {best} ({worst[best]:.2e}); "
           + ", ".join(f"{m} {e:.2e}" for m, e in worst.items() if m != best) + "."]
    for dim in [d for d in ds["entropy_error"].dims if d != "scheme"]:  # what drives each method's error
        span = ds["entropy_error"].max([d for d in ds["entropy_error"].dims if d not in ("scheme", dim)])
        grows = [m for m in ctx.methods if float(span.sel(scheme=m).max()) > 10 * float(span.sel(scheme=m).min())]
        if grows:
            out.append(f"Along {ds[dim].attrs.get('scene_key', dim)} the error changes more than tenfold for "
                       f"{', '.join(grows)}.")
    return out


STUDY = Study(
    kind="entropy_rate", title="Entropy production against the analytic rate", models=("top",),
    description="Entropy produced and its rate P/T per method against the spherical top's exact solution",
    options=(Option("h", 0.05, "number>0", "s", "time step"),
             Option("t_end", 30.0, "number>0", "s", "end time"),
             Option("every", 10, "int>=1", "1", "keep every k-th step"),
             Option("tolerance", 1e-4, "number>0", "1", "largest relative error the verdicts accept")),
    check=_check, stages=(Stage("run", run, over=("point", "scheme")),),
    quantities=QUANTITIES, derive=derive, tables=tables, verdicts=verdicts, findings=findings,
    figures=(Figure("entropy_error", kind="heatmap", facet="scheme", y=("entropy_error",), claim=(
                 "the relative entropy error of each method over the grid (one panel per method); hatched cells "
                 "are runs that failed")),
             Figure("errors_in_time", kind="lines", x="t", y=("entropy_error_t", "rate_error_t"),
                    claim="at the first grid point, how each method's entropy and rate errors grow in time (the "
                          "computed and exact curves themselves are in the netCDF)")),
    report=("Scene `{scene}`, h = {opt[h]} s to t = {opt[t_end]} s, one member per grid point; the exact solution "
            "holds because every term keeps the spherical-decay law (checked before the run)."),
)
