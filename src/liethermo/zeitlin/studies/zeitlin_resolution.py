"""Resolution of the Zeitlin fluid: one flow (the same coefficients of degrees l ≤ initial.lmax at every N)
at N = 16 … 256.  Per N: the spectrum at the end against the next and the finest N's, over the degrees every
N resolves; energy, heat, cost; the finest N at h/2 gives the time error the differences must stay above."""

import numpy as np
import xarray as xr

from ...studies.common import StudyError, dim_name
from ...studies.framework import PALETTE, Figure, Option, Stage, Study, Table, Verdict, run_scene

SWEEP_KEY = "zeitlin.N"
DIM = dim_name(SWEEP_KEY)
KEEP = ["energy", "heat", "total_energy", "energy_error", "enstrophy", "angular_momentum", "energy_spectrum", "status"]


def _Ns(ctx):  # noqa: N802
    return [int(p[SWEEP_KEY]) for p in ctx.points]


def _check(ctx):
    Ns = (ctx.study.get("sweep") or {}).get(SWEEP_KEY)
    if list(ctx.study.get("sweep") or {}) != [SWEEP_KEY]:
        raise StudyError(f"sweep: a zeitlin_resolution study sweeps exactly one key, {SWEEP_KEY!r}")
    if not isinstance(Ns, list) or len(Ns) < 3 or Ns != sorted(set(Ns)):
        raise StudyError(f"sweep.{SWEEP_KEY}: at least three different N in increasing order, got {Ns!r}")
    if (lmax := ctx.scene(ctx.points[0])["initial"]["lmax"]) > Ns[0] - 1:
        raise StudyError(f"sweep.{SWEEP_KEY}: the smallest N must resolve initial.lmax = {lmax} (N > lmax)")


def _run(ctx, sc, h_factor: int = 1, **kw):
    itg = sc["integrator"]
    return run_scene(sc, ctx.opt["method"], h=itg["h"] / h_factor, steps=itg["steps"] * h_factor,
                     every=sc["output"]["every"] * h_factor, output__vorticity=False, **kw)


def resolve(ctx, coords) -> xr.Dataset:
    """The run at one N (degrees padded to the finest N's), its warm cost, and at the finest N its end at h/2."""
    sc = ctx.scene(coords["point"])
    _run(ctx, sc.with_overrides({"integrator.steps": sc["output"]["every"]}), members=1)  # compile, basis
    ds, stats = _run(ctx, sc)
    half = xr.full_like(ds["energy_spectrum"].isel(t=-1, drop=True), np.nan)
    if ctx.opt["time_check"] and coords["point"] == ctx.points[-1]:
        half = _run(ctx, sc, 2)[0]["energy_spectrum"].isel(t=-1, drop=True)
    cost = stats.kernel_time / (sc["integrator"]["steps"] * sc["ensemble"]["members"])
    ds = ds[KEEP].assign(cost_per_member_step=cost, half_step_spectrum=half)
    return ds.reindex(l=np.arange(1, _Ns(ctx)[-1]))


def derive(ds, ctx):
    Ns, half, ds = _Ns(ctx), ds["half_step_spectrum"].isel({DIM: -1}), ds.drop_vars("half_step_spectrum")
    spec, L, fin = ds["energy_spectrum"], Ns[0] - 1, ds.sel({DIM: Ns[-1]})
    H0 = fin["energy"].isel(t=0)
    diff = lambda a, b: abs(a - b).sel(l=slice(1, L)).sum("l", skipna=False) / H0  # noqa: E731
    ds["spectrum_difference_finest"] = diff(spec, fin["energy_spectrum"]).where(ds[DIM] != Ns[-1])
    ds["spectrum_difference_next"] = diff(spec, spec.shift({DIM: -1}))
    ds["energy_difference_finest"] = (abs(ds["energy"] - fin["energy"]).isel(t=-1) / H0).where(ds[DIM] != Ns[-1])
    ds["heat_fraction"] = (ds["heat"].isel(t=-1) / ds["energy"].isel(t=0)).mean("member")
    if ctx.opt["time_check"]:
        ds["time_error"] = diff(fin["energy_spectrum"].isel(t=-1), half).max("member")
    return ds


QUANTITIES = {
    DIM: ("1", "matrix size N (sweep)"),
    "cost_per_member_step": ("s", "kernel wall time per member and step, compiled"),
    "spectrum_difference_finest": ("1", "Σ_l |E_l − E_l(finest N)| / H(0) over the degrees every N resolves"),
    "spectrum_difference_next": ("1", "Σ_l |E_l − E_l(next N)| / H(0) over the degrees every N resolves"),
    "energy_difference_finest": ("1", "|H − H(finest N)| / H(0) at t_end"),
    "heat_fraction": ("1", "member mean of q(t_end) / H(0)"),
    "time_error": ("1", "max over members of Σ_l |E_l(h) − E_l(h/2)| / H(0) at the finest N, t_end"),
}


def _next(ds):
    return ds["spectrum_difference_next"].isel(t=-1).max("member").values


def tables(ds, ctx):
    nxt, end = _next(ds), ds.isel(t=-1, drop=True).max("member")
    df = end[["spectrum_difference_next", "spectrum_difference_finest", "energy_difference_finest", "heat_fraction",
              "cost_per_member_step"]].to_dataframe().reset_index()
    df.columns = ["N", "Σ|ΔE_l| to the next N / H(0), t end", "Σ|ΔE_l| to the finest N / H(0), t end",
                  "|H − H(finest)| / H(0), t end", "heat / H(0), t end", "cost per member-step (ms)"]
    df["cost per member-step (ms)"] *= 1e3
    df["ratio to the previous N's difference"] = np.concatenate([[np.nan], nxt[1:] / nxt[:-1]])
    return [Table("resolution", "Energy spectrum at t_end per N (the largest over the members)", df.to_dict("records"))]


def verdicts(ds, ctx):
    nxt, bad = _next(ds)[:-1], int((ds["status"] != 0).sum())
    out = [Verdict("every member completes at every N", f"{bad} failed", "0 failed (else: a smaller h)", bad == 0),
           Verdict("the spectra converge in N", ", ".join(f"{v:.2g}" for v in nxt),
                   "the difference to the next N shrinks at every N", bool(np.all(np.diff(nxt) < 0)))]
    if "time_error" in ds:
        te = float(ds["time_error"])
        out.append(Verdict("the time error is below the resolution differences", f"{te:.2g} (h/2 at the finest N)",
                           "below every difference to the next N", te < nxt.min()))
    return out


def findings(ds, ctx):
    nxt = _next(ds)[:-1]
    return [f"From N = {int(ds[DIM][0])} to {int(ds[DIM][-1])} the spectrum's difference to the next N falls from "
            f"{nxt[0]:.2g} to {nxt[-1]:.2g} (ratios {', '.join(f'{r:.2f}' for r in nxt[1:] / nxt[:-1])}); the heat "
            f"fraction at the end is {', '.join(f'{v:.4g}' for v in ds['heat_fraction'].values)}."]


def draw(ds, ctx, fig):
    axes, Ns, t_end = fig.subplots(1, 2), _Ns(ctx), float(ds["t"][-1])
    for i, N in enumerate(Ns):
        spec = ds["energy_spectrum"].sel({DIM: N}).isel(t=-1).mean("member")
        axes[0].loglog(spec["l"], spec.where(spec > 0), color=PALETTE[i % len(PALETTE)], label=f"N = {N}")
    axes[0].axvline(Ns[0] - 1, color="0.5", lw=0.8, ls=":", label=f"l ≤ {Ns[0] - 1}: the degrees compared")
    for var, label, style in (("next", "to the next N", "o-"), ("finest", "to the finest N", "s--")):
        y = ds[f"spectrum_difference_{var}"].isel(t=-1).max("member")
        axes[1].loglog(np.array(Ns, float), y.where(y > 0), style, label=label)
    if float(ds.get("time_error", 0)) > 0:
        axes[1].axhline(float(ds["time_error"]), color="0.3", lw=0.9, ls=":", label="time error at the finest N (h/2)")
    axes[0].set(xlabel="degree l", ylabel=f"E_l at t = {t_end:g} s (J), member mean", title="energy spectrum at each N")
    axes[1].set(xlabel="matrix size N", ylabel=f"Σ_l |ΔE_l| / H(0) at t = {t_end:g} s (1)",
                title="spectrum differences (largest over the members)", xticks=Ns, xticklabels=[str(n) for n in Ns])
    axes[1].minorticks_off()
    return [a.legend(fontsize=8).axes for a in axes]


STUDY = Study(
    kind="zeitlin_resolution", title="Zeitlin fluid: resolution", models=("zeitlin",), needs_methods=False,
    description="One flow at N = 16 ... 256: the spectra converge",
    options=(Option("method", "rk4", "one of split|split4|split6|rk4", "", "the method run"),
             Option("time_check", True, "bool", "", "repeat the finest N at h/2 (the time error)")),
    check=_check, stages=(Stage("run", resolve, over=("point",)),),
    quantities=QUANTITIES, derive=derive, tables=tables, verdicts=verdicts, findings=findings,
    facts=lambda ds, ctx: {"sc": ctx.scene(ctx.points[0]), "L": _Ns(ctx)[0] - 1},
    figures=(Figure("resolution", kind="custom", draw=draw, select=lambda ds, ctx: ds, size=(11.5, 4.4),
                    claim="the spectra at the end lie on one another as N grows; their differences fall with N "
                          "and stay above the time error"),),
    report=("Scene `{scene}`: {sc[ensemble][members]} members, ν = {sc[fluid][kinematic_viscosity]:g} s⁻¹, degrees "
            "l ≤ {sc[initial][lmax]} (the same coefficients at every N), {opt[method]}, {sc[integrator][steps]} steps "
            "of h = {sc[integrator][h]:g} s. Differences: Σ_l |ΔE_l| over l ≤ {L} (every N), over the finest H(0)."),
)
