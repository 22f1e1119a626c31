"""Flat spin: a free asymmetric body under a friction that keeps |μ| (f = λ μ×(μ×Ω)), λ swept: K falls at fixed |μ|
to |μ|²/(2 I_max), every member ends on the major axis, the heat gained is the kinetic energy lost.  Per member (node
values): settling of X = K − |μ_k|²/(2 I_max), axis angle, Casimir drift, energy balance; Casimir drift against h."""

from __future__ import annotations

import numpy as np
import xarray as xr

from ..dataset import node_energies
from ..kernels.terms import LAW_MOMENTUM_NORM, ROLE_MOMENTUM_FRICTION, key_of
from ..methods import judge_order, order_tolerance
from ..physics import kinetic_energy, physics_of_scene
from ...studies.common import StudyError, dim_name
from ...studies.framework import Figure, Option, Stage, Study, Table, Verdict
from ...analysis import direction_angle, observed_orders, settling_time
from .tools import column, ensemble, method_choice, pad_members, quantile_columns, reference_label, run_members, same_members, status_units

SWEEP_KEY = key_of(ROLE_MOMENTUM_FRICTION)
DIM, ROUNDOFF = dim_name(SWEEP_KEY), 1e-12  # ROUNDOFF: a Casimir drift below it is round-off, no order is fitted


def _check(ctx) -> None:
    if list(ctx.study.get("sweep") or {}) != [SWEEP_KEY] or not min(ctx.study["sweep"][SWEEP_KEY]) > 0:
        raise StudyError(f"sweep: a flat_spin study sweeps {SWEEP_KEY!r} over values > 0 (s kg-1 m-2)")
    phys = physics_of_scene(ctx.scene(ctx.points[0]))
    if phys.breaking(LAW_MOMENTUM_NORM) or not np.all(phys.has_constant_inertia()):
        raise StudyError("scene: a flat_spin study needs a free body of constant inertia on which |μ| is a Casimir; "
                         f"{', '.join(phys.breaking(LAW_MOMENTUM_NORM)) or 'the inertia that depends on S'} break it")


def _spin(ctx, point: dict, method: str, h: float | None, limit: int | None):
    """At the point's λ: (run, physics, Ω₀, μ_k, Casimir drift (n, T), t_end, N)."""
    scene, spec, phys, om, R, N = ensemble(ctx, point, method, limit)
    h = float(scene["integrator"]["h"]) if h is None else h
    every = max(1, int(round(ctx.opt["lambda_t_end"] / float(point[SWEEP_KEY]) / (h * ctx.opt["nodes"]))))
    tr = run_members(scene, spec, om, R, h=h, steps=every * ctx.opt["nodes"], every=every)
    mu = tr.momentum if tr.choice.method.node_form else phys.inertia[:, None, :] * tr.omega
    mu0 = np.linalg.norm(phys.inertia * om, axis=-1)[:, None]
    return tr, phys, om, mu, np.abs(np.linalg.norm(mu, axis=-1) - mu0) / mu0, every * ctx.opt["nodes"] * h, N


def run(ctx, coords) -> xr.Dataset:
    """One (λ, method): per-member settling, axis, Casimir and energy balance, and quantiles."""
    tr, phys, om, mu, cas, t_end, N = _spin(ctx, coords["point"], coords["scheme"], None, ctx.opt["reference_members"]
                                            if method_choice(coords["scheme"]).name == "reference" else None)
    ok, q = tr.status == 0, [0.05, 0.5, 0.95]
    with np.errstate(invalid="ignore", over="ignore"):
        e, K0 = node_energies(tr), kinetic_energy(phys, om, None)
        ratio = (x := e["K"] - np.linalg.norm(mu, axis=-1) ** 2 / (2.0 * phys.inertia.max(axis=1)[:, None])) / x[:, :1]
        ang = np.minimum(a := direction_angle(mu[:, -1], np.eye(3)[np.argmax(phys.inertia, axis=1)]), np.pi - a)
        per = {"settling_time": settling_time(tr.times, ratio, ctx.opt["settle_fraction"]), "final_axis_angle": ang,
               "casimir_drift": np.where(ok, np.nanmax(cas, axis=1), np.inf), "energy_balance_error": np.where(
                   ok, np.nanmax(np.abs(e["dU"] - (K0[:, None] - e["K"])) / K0[:, None], axis=1), np.inf)}
    data = {k: ("member", pad_members(v, N)) for k, v in per.items()}
    data.update({k: ("member", pad_members(v.astype(np.int8), N, np.int8(-1)).astype(np.int8)) for k, v in (
        ("status", tr.status), ("on_major_axis", ok & (ang < ctx.opt["axis_tolerance"])))},
                casimir_drift_quantiles=(("quantile", "node"), np.nanquantile(cas, q, axis=0)),
                excess_ratio_quantiles=(("quantile", "node"), np.nanquantile(ratio, q, axis=0)),
                node_time=("node", tr.times), t_end=((), t_end))
    return xr.Dataset(data, coords={"member": np.arange(N), "quantile": q})


def casimir(ctx, coords) -> xr.Dataset:
    """One (h, method) at λ = casimir_lambda: max Casimir drift per member."""
    tr, *_, cas, _, _ = _spin(ctx, {SWEEP_KEY: ctx.opt["casimir_lambda"]}, coords["scheme"],
                              float(coords["casimir_step"]), ctx.opt["casimir_members"])
    return xr.Dataset({"casimir_drift_h": ("casimir_member", np.where(tr.status == 0, np.nanmax(cas, 1), np.inf))})


Q = {DIM: ("s kg-1 m-2", "friction strength lambda (keeps |mu|)"), "t_end": ("s", "horizon lambda_t_end / lambda"),
     "settling_time": ("s", "settling time (excess energy)"), "casimir_step": ("s", "time step h of the Casimir runs"),
     "final_axis_angle": ("rad", "angle of mu at t_end from the major axis (either sense)"),
     "on_major_axis": ("1", "1: final_axis_angle < axis_tolerance and run to the end; 0: not; -1: not run"),
     "casimir_drift": ("1", "Casimir drift max_k ||mu_k| - |mu_0|| / |mu_0| (failed: inf)"),
     "energy_balance_error": ("1", "max_k |(U(S_k) - U(S_0)) - (K_0 - K_k)| / K_0 (failed: inf)"),
     "excess_ratio_quantiles": ("1", "X/X_0, X = K - |mu|^2/(2 I_max)"), "node_time": ("s", "time of the node"),
     "casimir_drift_quantiles": ("1", "||mu_k| - |mu_0|| / |mu_0|"), "casimir_drift_h": ("1", "Casimir drift, h sweep"),
     "settling_time_minus_reference": ("s", "settling time minus the reference's (same member and lambda)"),
     "status": status_units(True), **{k: ("1", k.replace("_", " ")) for k in ("quantile", "node", "casimir_member")}}


def _orders(ds, m):
    v = ds["casimir_drift_h"].sel(scheme=m).median("casimir_member").values
    return observed_orders(ds["casimir_step"].values, np.where(v > ROUNDOFF, v, np.nan))


def tables(ds, ctx) -> list[Table]:
    same, ref, ens, vs = same_members(ds, ctx.methods), reference_label(ctx.methods), [], []
    for d in (ds.sel({DIM: lam, "scheme": m}) for lam in ds[DIM].values for m in ctx.methods):  # λ outer
        m, r = d["scheme"].item(), d["status"].values >= 0
        row = {column(ds, DIM): float(d[DIM]), "method": m, column(ds, "t_end"): float(d["t_end"])}
        worst = lambda w: {column(ds, v, "max"): float(np.max(d[v].values[w]))  # noqa: E731
                           for v in ("casimir_drift", "energy_balance_error")}
        ens += [{**row, "members": int(r.sum()), "not settled": int(np.isnan(d["settling_time"][r]).sum()),
                 "on major axis": int((d["on_major_axis"].values[r] == 1).sum()), **worst(r),
                 **quantile_columns(ds, d, ("settling_time",), r),
                 **quantile_columns(ds, d, ("casimir_drift",), r, ("median",))}] if m != ref else []
        vs.append({**row, "members": int(same.sum()), **worst(same), **quantile_columns(ds, d, ("settling_time",), same,
                   ("median",)), **{column(ds, v, "max |…|"): float(np.max(np.abs(d[v].values[same])))
                                    for v in ["settling_time_minus_reference"] if ref}})
    cas = [{"method": m, column(ds, "casimir_step"): float(h), "members": ds.sizes["casimir_member"],
            **{column(ds, "casimir_drift_h", s): float(f(ds["casimir_drift_h"].sel(scheme=m, casimir_step=h)))
               for s, f in (("median", np.median), ("max", np.max))},
            "observed order (median)": float(_orders(ds, m)[i - 1]) if i else float("nan")}
           for m in ctx.methods for i, h in enumerate(ds["casimir_step"].values)]
    return [Table("flat_spin", "Every method but the reference over all its members (node values)", ens),
            Table("flat_spin_reference", f"Every method on the {int(same.sum())} members the reference ran", vs),
            Table("flat_spin_casimir", f"Casimir drift against h (lambda = {ctx.opt['casimir_lambda']:g} s kg-1 m-2), "
                  f"no order fitted below {ROUNDOFF:g} (round-off)", cas)]


def verdicts(ds, ctx) -> list[Verdict]:
    same, ref, lam = same_members(ds, ctx.methods), reference_label(ctx.methods), ds[DIM].values
    on, n, med = int((ds["on_major_axis"] == 1).sum()), int((ds["status"] >= 0).sum()), \
        ds["settling_time"].isel(member=same).median("member")
    t = float(med.sel(scheme=ref).min()) if ref else np.nan  # the reference's least median settling time
    out = [Verdict("every member of every method ends on the major axis", f"{on} of {n} runs",
                   f"final_axis_angle < {ctx.opt['axis_tolerance']:g} rad for all", on == n)]
    for m in [m for m in ctx.methods if m != ref]:
        c, p, q = float(ds["casimir_drift"].sel(scheme=m).max()), _orders(ds, m)[-1], ctx.model.method_order(m)
        out.append(Verdict(f"{m} keeps the Casimir |μ|", f"max casimir_drift {c:.1e}", "≤ 1e-11 (round-off)",
                           c <= 1e-11) if method_choice(m).method.solves_newton else Verdict(
            f"{m}'s Casimir drift falls at its order {q}", f"{p:.2f} (finest pair of casimir_h)",
            f"≥ {q} − {order_tolerance(q):g} (the declared order less the fitting tolerance)",
            None if not np.isfinite(p) else judge_order(p, q) != "below declared"))
        e = float(np.abs(ds["settling_time_minus_reference"].sel(scheme=m).values[..., same]).max()) if ref else 0
        out += [Verdict(f"{m} meets the reference member by member", f"max |settling_time_minus_reference| {e:.2g} s",
                        f"≤ 1 % of the reference's least median ({t:.3g} s)", e <= 0.01 * t)] if ref else []
    k = {m: float(np.polyfit(np.log(lam), np.log(med.sel(scheme=m).values), 1)[0]) for m in ctx.methods}
    out += [Verdict("the settling time scales as 1/λ (median over the same members)", ", ".join(
        f"{m} {v:.3f}" for m, v in k.items()), "|slope of log t on log λ + 1| ≤ 0.05",
        max(abs(v + 1) for v in k.values()) <= 0.05)] if len(lam) > 1 else []
    b = float(ds["energy_balance_error"].sel(scheme=ref).max()) if ref else np.nan
    return out + ([Verdict("the reference turns the kinetic energy lost into heat", f"max energy_balance_error {b:.1e}",
                           "≤ 1e-10", b <= 1e-10)] if ref else [])


def findings(ds, ctx) -> list[str]:
    ref, same = reference_label(ctx.methods), same_members(ds, ctx.methods)
    c, b = ({m: float(np.nanmax(ds[v].sel(scheme=m).values[..., w])) for m in ctx.methods} for v, w in (
        ("casimir_drift", slice(None)), ("energy_balance_error", same)))
    return [f"Casimir drift, max over members and λ: {', '.join(f'{m} {v:.1e}' for m, v in c.items())}; energy "
            f"balance, max over the same {int(same.sum())} members: {', '.join(f'{m} {v:.1e}' for m, v in b.items())}."
            + (f" What the reference wins: the energy balance to {b[ref]:.1e} (others: O(h^p) errors)." if ref else "")]


STUDY = Study(
    kind="flat_spin", title="The flat spin of a free asymmetric body under a friction that keeps |μ|", models=("top",),
    description="Free ellipsoid under a friction that keeps |mu|: settling against lambda, major axis, Casimir drift",
    options=(Option("lambda_t_end", 4000.0, "number>0", "s2 kg-1 m-2"), Option("nodes", 2000, "int>=1", "1"),
             Option("settle_fraction", 1e-6, "fraction", "1"), Option("axis_tolerance", 1e-3, "number>0", "rad"),
             Option("reference_members", 16, "int>=1", "1"), Option("casimir_lambda", 20.0, "number>0", "s kg-1 m-2"),
             Option("casimir_members", 16, "int>=1"), Option("casimir_h", [.02, .01, .005], "list[number>0]", "s")),
    check=_check, axes=lambda ctx: {"casimir_step": ctx.opt["casimir_h"]}, quantities=Q, tables=tables,
    stages=(Stage("run", run, over=("point", "scheme")), Stage("casimir", casimir, over=("casimir_step", "scheme"))),
    verdicts=verdicts, findings=findings, derive=lambda ds, ctx: ds if not (ref := reference_label(ctx.methods)) else
        ds.assign(settling_time_minus_reference=ds.settling_time - ds.settling_time.sel(scheme=ref, drop=True)),
    figures=(Figure("flat_spin_excess", x="node_time", y=("excess_ratio_quantiles",), hue=DIM, logx=False, logy=True,
                    band="quantile", select=lambda ds, ctx: ds.sel(scheme=ctx.methods[0]),
                    title="Flat spin: kinetic energy above its floor (first method; median, 5-95 % band)",
                    claim="the kinetic energy falls onto the floor |μ|²/(2 I_max) of its orbit, sooner for a larger "
                          "λ (first method, median)"),
             Figure("flat_spin_casimir", x="node_time", y=("casimir_drift_quantiles",), logx=False, band="quantile",
                    select=lambda ds, ctx: ds.sel({DIM: ctx.opt["casimir_lambda"]}, method="nearest"),
                    title="Flat spin: Casimir drift |μ| (median, 5-95 % band over members)",
                    claim="the variational integrators keep |μ| to round-off; the others drift (median over members)"),
             Figure("flat_spin_casimir_h", x="casimir_step", title="Flat spin: Casimir drift against the step", y=("casimir_drift_h",), logx=True, logy=True,
                    select=lambda ds, ctx: ds[["casimir_drift_h"]].max("casimir_member", keep_attrs=True),
                    claim="the explicit methods' Casimir drift (max over members) falls with h at their order"),
             Figure("flat_spin_settling", x=DIM, title="Flat spin: median settling time against λ", y=("settling_time",), logx=True, logy=True, select=lambda ds, ctx: ds
                    .isel(member=same_members(ds, ctx.methods)).median("member", keep_attrs=True), claim="the median "
                    "settling time over the members the reference ran falls as 1/λ, alike for every method")),
    report=("Scene `{scene}`, node values over t_end = {opt[lambda_t_end]} s² kg⁻¹ m⁻² / λ ({opt[nodes]} nodes). The "
            "reference (DOP853 with substeps) runs the first {opt[reference_members]} members. No cost is reported."),
)
