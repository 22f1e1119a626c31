"""Viscous decay of the Zeitlin fluid, one run per viscosity: the heat against the energy lost (their
difference is the method's energy error), entropy, enstrophy, the spectrum over time, the angular momentum."""

import numpy as np
import xarray as xr

from ..plotting import spectrum_lines
from ...studies.common import StudyError, dim_name
from ...studies.framework import PALETTE, Figure, Option, Stage, Study, Table, Verdict, run_scene

SWEEP_KEY = "fluid.kinematic_viscosity"
NU = dim_name(SWEEP_KEY)


def _check(ctx):
    if list(ctx.study.get("sweep") or {}) != [SWEEP_KEY]:
        raise StudyError(f"sweep: a zeitlin_decay study sweeps exactly one key, {SWEEP_KEY!r}")


def decay(ctx, coords) -> xr.Dataset:
    sc = ctx.scene(coords["point"])
    return run_scene(sc, ctx.opt["method"], h=sc["integrator"]["h"], steps=sc["integrator"]["steps"],
                     every=sc["output"]["every"], output__vorticity=False)[0]


def derive(ds, ctx):
    H, q, S, Z, L = (ds[v] for v in ("energy", "heat", "entropy", "enstrophy", "angular_momentum"))
    mta = ("member", "t", "axis")
    return ds.assign(heat_fraction=(q.isel(t=-1) / H.isel(t=0)).mean("member"),
                     max_energy_error=abs(ds["energy_error"]).max(mta[:2]),
                     entropy_produced=S.isel(t=-1).mean("member"), min_entropy_change=S.diff("t").min(mta[:2]),
                     enstrophy_ratio=(Z.isel(t=-1) / Z.isel(t=0)).mean("member"),
                     angular_momentum_drift=abs(L - L.isel(t=0)).max(mta) / abs(L).max(mta),
                     members_failed=(ds["status"] != 0).sum("member"))


#: name: (units, long name, the table's column)
SUMMARY = {
    "heat_fraction": ("1", "member mean of q(t_end) / H(0)", "heat / H(0) at the end"),
    "max_energy_error": ("1", "max over members and t of |H + q - H(0)| / H(0)", "max |H + q − H(0)| / H(0)"),
    "entropy_produced": ("J K-1", "member mean of the entropy produced by t_end", "entropy produced (J K-1)"),
    "min_entropy_change": ("J K-1", "smallest entropy change per output", "smallest entropy change per output (J K-1)"),
    "enstrophy_ratio": ("1", "member mean of Z(t_end) / Z(0)", "enstrophy Z(t_end) / Z(0)"),
    "angular_momentum_drift": ("1", "max |L - L(0)| / max |L|", "angular momentum drift (relative)"),
    "members_failed": ("1", "members that failed", "members failed"),
}


def tables(ds, ctx):
    rows = ds[list(SUMMARY)].to_dataframe().rename(columns={k: v[2] for k, v in SUMMARY.items()})
    return [Table("decay", "Energy into heat, entropy, enstrophy and angular momentum per viscosity",
                  rows.rename_axis("viscosity (s-1)").reset_index().to_dict("records"))]


def verdicts(ds, ctx):
    nu, heat = ds[NU].values, ds["heat_fraction"].values
    dS, dL, bad = ds["min_entropy_change"].values, ds["angular_momentum_drift"].values, int(ds["members_failed"].sum())
    return [Verdict("more viscosity turns more energy into heat", ", ".join(f"{v:.3g}" for v in heat),
                    "heat / H(0) grows with ν", bool(np.all(np.diff(heat[np.argsort(nu)]) > 0))),
            Verdict("the entropy never decreases", f"smallest change {dS.min():.3g} J K-1",
                    "≥ 0 in every output of every member", bool(dS.min() >= 0)),
            Verdict("viscosity keeps the angular momentum", f"{dL.max():.2g}", "drift < 1e-10", dL.max() < 1e-10),
            Verdict("every member completes", f"{bad} failed", "0 failed", bad == 0)]


def findings(ds, ctx):
    return ["Member means: " + "; ".join(
        f"at ν = {nu:g} s⁻¹ the heat takes {100 * d['heat_fraction'].item():.1f} % of H(0), |H + q − H(0)|/H(0) ≤ "
        f"{d['max_energy_error'].item():.2g}" for nu, d in ds.groupby(NU)) + " (at ν = 0 the method's energy error)."]


def draw_decay(ds, ctx, fig):
    axes = fig.subplots(1, 3)
    H0, Z = ds["energy"].isel(t=0), ds["enstrophy"]
    xy = (((H0 - ds["energy"]) / H0, ds["heat"] / H0), (ds["t"], ds["entropy"]), (ds["t"], Z / Z.isel(t=0)))
    mean = lambda v, nu: (v.sel({NU: nu}).mean("member") if "member" in v.dims else v).values  # noqa: E731
    for i, nu in enumerate(ds[NU].values):
        for a, (x, y) in zip(axes, xy):
            a.plot(mean(x, nu), mean(y, nu), color=PALETTE[i % len(PALETTE)], label=f"ν = {nu:g} s⁻¹")
    axes[0].plot(axes[0].get_xlim(), axes[0].get_xlim(), "k:", lw=0.8, label="q = H(0) − H")
    for a, x, y in zip(axes, ("energy lost (H(0) − H)/H(0) (1)", "time t (s)", "time t (s)"),
                       ("heat q / H(0) (1)", "entropy produced (J K⁻¹)", "enstrophy Z / Z(0) (1)")):
        a.set(xlabel=x, ylabel=y, yscale="log" if a is axes[2] else "linear")
        a.grid(True, alpha=0.3)
    axes[1].ticklabel_format(axis="y", style="sci", scilimits=(-2, 3))
    fig.legend(*axes[0].get_legend_handles_labels(), fontsize=8, loc="outside right center")
    return axes


def draw_spectrum(ds, ctx, fig):
    nus = ds[NU].values
    axes = fig.subplots(-(-len(nus) // 3), min(3, len(nus)), sharey=True, squeeze=False).ravel()
    for a, nu in zip(axes, nus):
        spectrum_lines(a, ds["l"].values, ds["t"].values, ds["energy_spectrum"].sel({NU: nu}).values, 5)
        a.set(title=f"ν = {nu:g} s⁻¹", xlabel="degree l", ylabel="E_l (J)")
        a.yaxis.set_tick_params(labelleft=True)  # shared, but numbered on every panel
    for a in axes[len(nus):]:
        a.set_visible(False)
    fig.legend(*axes[0].get_legend_handles_labels(), fontsize=7, loc="outside right center")
    return axes


STUDY = Study(
    kind="zeitlin_decay", title="Zeitlin fluid: viscous decay", models=("zeitlin",), needs_methods=False,
    description="Energy into heat and entropy per viscosity, over an ensemble",
    options=(Option("method", "split", "one of split|split4|split6|rk4|reference", "", "the method run"),),
    check=_check, stages=(Stage("decay", decay, over=("point",)),),
    quantities={NU: ("s-1", "kinematic viscosity nu (sweep)"), **{k: v[:2] for k, v in SUMMARY.items()}},
    derive=derive, tables=tables, verdicts=verdicts, findings=findings,
    facts=lambda ds, ctx: {"sc": ctx.scene(ctx.points[0] if ctx.points else None)},
    figures=(Figure("decay", kind="custom", draw=draw_decay, select=lambda ds, ctx: ds, size=(15, 4.4),
                    claim="the heat follows the energy lost (the dotted diagonal), the entropy rises, and the "
                          "enstrophy decays faster at larger ν (member means)"),
             Figure("spectrum", kind="custom", draw=draw_spectrum, select=lambda ds, ctx: ds, size=(12, 4),
                    claim="at ν = 0 the energy spreads to high degrees; viscosity drains them, the highest most")),
    report=("Scene `{scene}`: N = {sc[zeitlin][N]}, {sc[ensemble][members]} members, method {opt[method]}, "
            "{sc[integrator][steps]} steps of h = {sc[integrator][h]:g} s. The heat equals the energy lost up to "
            "the method's energy error H + q − H(0); the verdicts check the other laws."),
)
