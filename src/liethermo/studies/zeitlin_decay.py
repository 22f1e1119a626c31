"""Viscous decay of the Zeitlin fluid: a viscosity sweep over an ensemble.

Per viscosity (one run of the model per sweep point): the heat against the
energy lost (their difference is the method's total-energy error), the
entropy produced (never decreasing), the enstrophy's decay, the energy
spectrum over time and the angular momentum kept."""

from __future__ import annotations

import numpy as np
import xarray as xr

from .common import StudyError, dim_name
from .framework import PALETTE, Figure, Option, Stage, Study, Table, Verdict, run_scene

SWEEP_KEY = "fluid.kinematic_viscosity"
NU = dim_name(SWEEP_KEY)


def _check(ctx) -> None:
    if list(ctx.study.get("sweep") or {}) != [SWEEP_KEY]:
        raise StudyError(f"sweep: a zeitlin_decay study sweeps exactly one key, {SWEEP_KEY!r}")


def decay(ctx, coords) -> xr.Dataset:
    sc = ctx.scene(coords["point"])
    ds, _ = run_scene(sc, ctx.opt["method"], h=sc["integrator"]["h"], steps=sc["integrator"]["steps"],
                      every=sc["output"]["every"], output__vorticity=False)
    return ds


def derive(ds, ctx):
    H, q, S, Z, L = (ds[v] for v in ("energy", "heat", "entropy", "enstrophy", "angular_momentum"))
    H0 = H.isel(t=0)
    ds["heat_fraction"] = (q.isel(t=-1) / H0).mean("member")
    ds["max_energy_error"] = abs(ds["energy_error"]).max(("member", "t"))
    ds["entropy_produced"] = S.isel(t=-1).mean("member")
    ds["min_entropy_change"] = S.diff("t").min(("member", "t"))
    ds["enstrophy_ratio"] = (Z.isel(t=-1) / Z.isel(t=0)).mean("member")
    ds["angular_momentum_drift"] = (abs(L - L.isel(t=0)).max(("member", "t", "axis"))
                                    / abs(L).max(("member", "t", "axis")))
    ds["members_failed"] = (ds["status"] != 0).sum("member")
    return ds


QUANTITIES = {
    NU: ("s-1", "kinematic viscosity nu (sweep)"),
    "heat_fraction": ("1", "member mean of q(t_end) / H(0)"),
    "max_energy_error": ("1", "max over members and t of |H + q - H(0)| / H(0)"),
    "entropy_produced": ("J K-1", "member mean of the entropy produced by t_end"),
    "min_entropy_change": ("J K-1", "smallest entropy change between outputs (any member)"),
    "enstrophy_ratio": ("1", "member mean of Z(t_end) / Z(0)"),
    "angular_momentum_drift": ("1", "max |L - L(0)| / max |L|"),
    "members_failed": ("1", "members that failed"),
}
COLUMNS = {"heat_fraction": "heat / H(0) at the end", "max_energy_error": "max |H + q − H(0)| / H(0)",
           "entropy_produced": "entropy produced (J K-1)",
           "min_entropy_change": "smallest entropy change per output (J K-1)",
           "enstrophy_ratio": "enstrophy Z(t_end) / Z(0)", "angular_momentum_drift": "angular momentum drift (relative)",
           "members_failed": "members failed"}


def tables(ds, ctx):
    rows = [{"viscosity (s-1)": float(nu), **{c: ds[v].sel({NU: nu}).item() for v, c in COLUMNS.items()}}
            for nu in ds[NU].values]
    return [Table("decay", "Energy into heat, entropy, enstrophy and angular momentum per viscosity", rows)]


def verdicts(ds, ctx):
    nu, heat = ds[NU].values, ds["heat_fraction"].values
    dS, dL = ds["min_entropy_change"].values, ds["angular_momentum_drift"].values
    zero = nu == 0
    out = [Verdict("no heat without viscosity", ", ".join(f"{v:.3g}" for v in heat[zero]) or "no ν = 0",
                   "q(t_end) = 0 at ν = 0", bool(np.all(heat[zero] == 0)) if zero.any() else None),
           Verdict("more viscosity turns more energy into heat", ", ".join(f"{v:.3g}" for v in heat),
                   "heat / H(0) grows with ν", bool(np.all(np.diff(heat[np.argsort(nu)]) > 0))),
           Verdict("the entropy never decreases", f"smallest change {dS.min():.3g} J K-1",
                   "≥ 0 in every output of every member", bool(dS.min() >= 0)),
           Verdict("viscosity does not damp the angular momentum", f"{dL.max():.2g}", "relative drift < 1e-10",
                   bool(dL.max() < 1e-10)),
           Verdict("every member completes", f"{int(ds['members_failed'].sum())} failed", "0 failed",
                   bool(ds["members_failed"].sum() == 0))]
    return out


def findings(ds, ctx):
    parts = [f"at ν = {nu:g} s⁻¹ the heat takes {100 * float(ds['heat_fraction'].sel({NU: nu})):.1f} % of H(0) "
             f"(|H + q − H(0)|/H(0) ≤ {float(ds['max_energy_error'].sel({NU: nu})):.2g})" for nu in ds[NU].values]
    return ["Over the ensemble, " + "; ".join(parts) + ". At ν = 0 the energy error is the method's alone."]


def _all(ds, ctx):
    return ds


def _color(i: int) -> str:
    return PALETTE[i % len(PALETTE)]


def draw_decay(ds, ctx, fig):
    axes = fig.subplots(1, 3)
    t = ds["t"].values
    for i, nu in enumerate(ds[NU].values):
        d = ds.sel({NU: nu})
        H0 = d["energy"].values[:, :1]
        kw = {"color": _color(i), "label": f"ν = {nu:g} s⁻¹"}
        axes[0].plot(np.nanmean((H0 - d["energy"].values) / H0, axis=0), np.nanmean(d["heat"].values / H0, axis=0), **kw)
        axes[1].plot(t, np.nanmean(d["entropy"].values, axis=0), **kw)
        Z = d["enstrophy"].values
        axes[2].semilogy(t, np.nanmean(Z / Z[:, :1], axis=0), **kw)
    lim = axes[0].get_xlim()
    axes[0].plot(lim, lim, "k:", lw=0.8, label="q = H(0) − H")
    for a, (x, y) in zip(axes, (("energy lost (H(0) − H)/H(0) (1)", "heat q / H(0) (1)"),
                                ("time t (s)", "entropy produced (J K⁻¹)"), ("time t (s)", "enstrophy Z / Z(0) (1)"))):
        a.set_xlabel(x)
        a.set_ylabel(y)
        a.grid(True, alpha=0.3)
    axes[1].ticklabel_format(axis="y", style="sci", scilimits=(-2, 3))
    h, lab = axes[0].get_legend_handles_labels()
    fig.legend(h, lab, fontsize=8, loc="outside right upper")
    return axes


def draw_spectrum(ds, ctx, fig):
    from ..zeitlin.plotting import spectrum_lines

    nus = ds[NU].values
    cols = min(3, len(nus))
    axes = np.atleast_1d(fig.subplots(-(-len(nus) // cols), cols, sharey=True, squeeze=False).ravel())
    for a, nu in zip(axes, nus):
        spectrum_lines(a, ds["l"].values, ds["t"].values, ds["energy_spectrum"].sel({NU: nu}).values, 5)
        a.set_title(f"ν = {nu:g} s⁻¹", fontsize=9)
        a.set_xlabel("degree l")
        a.set_ylabel("E_l (J)")
    for a in axes[len(nus):]:
        a.set_visible(False)
    h, lab = axes[0].get_legend_handles_labels()
    fig.legend(h, lab, fontsize=7, loc="outside right upper")
    return axes


def _facts(ds, ctx):
    sc = ctx.scene(ctx.points[0] if ctx.points else None)
    itg = sc["integrator"]
    return {"N": sc["zeitlin"]["N"], "members": sc["ensemble"]["members"], "h": itg["h"],
            "t_end": itg["h"] * itg["steps"]}


STUDY = Study(
    kind="zeitlin_decay", title="Zeitlin fluid: viscous decay", models=("zeitlin",), needs_methods=False,
    description="Energy into heat and entropy per viscosity, over an ensemble",
    options=(Option("method", "split", "one of split|split4|split6|rk4|reference", "", "the method run"),),
    check=_check, stages=(Stage("decay", decay, over=("point",)),),
    quantities=QUANTITIES, derive=derive, tables=tables, verdicts=verdicts, findings=findings, facts=_facts,
    figures=(Figure("decay", kind="custom", draw=draw_decay, select=_all, size=(15, 4.4),
                    claim="the heat follows the energy lost (the dotted diagonal), the entropy rises, and the "
                          "enstrophy decays faster at larger ν (member means)"),
             Figure("spectrum", kind="custom", draw=draw_spectrum, select=_all, size=(12, 4),
                    claim="at ν = 0 the energy spreads to high degrees; viscosity drains them, most at the largest l")),
    report=("Scene `{scene}`: N = {N}, {members} members, method {opt[method]}, h = {h:g} s, t = {t_end:g} s. "
            "The heat equals the energy lost up to the method's total-energy error (H + q − H(0)); the entropy "
            "change per output is never negative; the angular momentum (the l = 1 modes) is not damped."),
)
