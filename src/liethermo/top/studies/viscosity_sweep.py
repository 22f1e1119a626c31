"""Viscosity sweep: settling times and entropy production of one ensemble over the strength (:data:`SWEEP_KEY`)
of the friction linear in Ω; entropy rates are the model's dissipated power over T."""

from __future__ import annotations

import numpy as np
import xarray as xr

from ..dataset import node_energies
from ..initial import initial_conditions
from ..kernels.terms import ROLE_LINEAR_FRICTION, key_of
from ..physics import physics_of_scene, temperature
from ...studies.common import StudyError, dim_name
from ...studies.framework import Figure, Option, Stage, Study, Table, Verdict
from .tools import method_choice, run_members, status_units

SWEEP_KEY = key_of(ROLE_LINEAR_FRICTION)  #: the key swept: the strength of the friction linear in Ω
DIM = dim_name(SWEEP_KEY)


def _check(ctx) -> None:
    sweep = ctx.study.get("sweep") or {}
    if list(sweep) != [SWEEP_KEY] or any(not isinstance(v, (int, float)) or v <= 0 for v in sweep[SWEEP_KEY]):
        raise StudyError(f"sweep: a viscosity_sweep study sweeps {SWEEP_KEY!r} alone, viscosities > 0, got {sweep}")
    if ctx.opt["outputs"] < 10:
        raise StudyError(f"options.outputs: must be an integer ≥ 10, got {ctx.opt['outputs']!r}")
    try:
        method_choice(ctx.opt["method"])
    except StudyError as e:
        raise StudyError(f"options.method: {str(e).removeprefix('methods: ')}") from None


def settling_times(t: np.ndarray, E: np.ndarray, threshold: float) -> np.ndarray:
    """Per member, the time after which E stays below threshold·E[:, 0] (linear interpolation; NaN: censored)."""
    thr, out = threshold * E[:, 0], np.full(E.shape[0], np.nan)
    for m, above in enumerate(~(E < thr[:, None])):  # NaN counts as above
        if not above.any():
            out[m] = t[0]
        elif (j := np.flatnonzero(above)[-1]) < t.size - 1:
            s = (E[m, j] - thr[m]) / (E[m, j] - E[m, j + 1]) if E[m, j] > E[m, j + 1] else 1.0
            out[m] = t[j] + np.clip(s, 0.0, 1.0) * (t[j + 1] - t[j])
    return out


def sweep(ctx, coords) -> xr.Dataset:
    scene, opt = ctx.scene(coords["point"]), ctx.opt
    n, (om, R), h = int(scene["ensemble"]["members"]), initial_conditions(scene), float(opt["h"])
    phys, times = physics_of_scene(scene, n), [float(x) for x in opt["entropy_times"]]
    c, g = float(phys.linear_resistance()[0].max()), 0.5 * float(phys.potential_span()[0])
    tau = max(float(phys.inertia[0].max()) / c, c / g if g > 0 else 0.0)  # the slowest relaxation (either damping)
    lo = max(float(opt["t_end_min"]), max(times))
    t_end = float(np.clip(opt["t_end_factor"] * tau, lo, max(lo, float(opt["t_end_max"]))))
    # about `outputs` nodes, the first entropy time resolved
    every = min(max(1, int(round(t_end / h / int(opt["outputs"])))), max(1, int(np.floor(min(times) / h + 1e-9))))
    tr = run_members(scene, opt["method"], om, R, h=h, steps=int(np.ceil(t_end / (h * every))) * every, every=every)
    t, sig, E = tr.times, tr.sigma, phys.mechanical_energy((e := node_energies(tr))["K"], e["V"])
    by = [np.full(n, np.nan) if ti > t[-1] else np.array([np.interp(ti, t, y) for y in sig]) for ti in times]
    mb = "member"
    return xr.Dataset({
        "settling_time": (mb, settling_times(t, E, float(opt["threshold"]))), "entropy_produced": (mb, sig[:, -1]),
        "entropy_by_time": ((mb, "entropy_time"), np.stack(by, axis=1)), "mech_energy_initial": (mb, E[:, 0]),
        "mech_energy_final": (mb, E[:, -1]), "heat_ratio": (mb, e["dU"][:, -1] / (E[:, 0] - E[:, -1])),
        "entropy_rate_initial": (mb, phys.dissipated_power(om) / temperature(phys, om, np.zeros(n))),
        "status": (mb, tr.status.astype(np.int8)), "t_end": ((), float(t[-1]))},
        coords={mb: np.arange(n), "entropy_time": times})


QUANTITIES = {
    "settling_time": ("s", "time after which K + V above rest stays below threshold x its initial value (NaN: "
                           "censored)"), "settling_time_quartiles": ("s", "settling time quartiles"),
    "entropy_produced": ("J K-1", "entropy produced by t_end"), "entropy_time": ("s", "time of the entropy count"),
    "entropy_by_time": ("J K-1", "entropy produced by entropy_time"), "quantile": ("1", "quantile over members"),
    "entropy_by_time_mean": ("J K-1", "mean entropy produced"), DIM: ("kg m-1 s-1", "fluid viscosity mu (sweep)"),
    "mech_energy_initial": ("J", "initial mechanical energy above rest"), "mech_energy_final": ("J", "same at t_end"),
    "heat_ratio": ("1", "heat U - U0 produced by t_end over the mechanical energy lost (1 = exact balance)"),
    "entropy_rate_initial": ("W K-1", "initial entropy production rate P(Omega0) / T(0), P the dissipated power"),
    "status": status_units(), "t_end": ("s", "simulated time (adapted to the viscosity)"),
    "mu_crit": ("kg m-1 s-1", "viscosity above which the pendulum mode is over-damped, c = 2 sqrt(I_min m g l)")}


def derive(ds, ctx):
    st, ds = ds["settling_time"].values, ds.assign_coords(quantile=[0.25, 0.5, 0.75])
    ds["settling_time_quartiles"] = ((DIM, "quantile"), np.array([np.quantile(r[np.isfinite(r)], ds["quantile"].values)
                                      if np.isfinite(r).any() else np.full(3, np.nan) for r in st]))
    ds["entropy_by_time_mean"] = ds["entropy_by_time"].mean("member", skipna=False)
    phys = physics_of_scene(scene := ctx.scene(ctx.points[0]))  # c is linear in μ: μ_crit = μ c_crit / c
    section, key = SWEEP_KEY.split(".")
    g, per_mu = 0.5 * float(phys.potential_span()[0]), scene[section][key] / phys.linear_resistance().max()
    ds["mu_crit"] = 2 * np.sqrt(float(phys.inertia[0].min()) * g) * per_mu if g > 0 else np.inf
    return ds


def tables(ds, ctx) -> list[Table]:
    rows = []
    for mu in ds[DIM].values:
        d, (q25, med, q75) = ds.sel({DIM: mu}), ds["settling_time_quartiles"].sel({DIM: mu}).values.tolist()
        rows.append({"μ (kg m⁻¹ s⁻¹)": float(mu), "t_end (s)": float(d["t_end"]), "settling time median (s)": med,
                     "q25 (s)": q25, "q75 (s)": q75, "μ × median (kg m⁻¹)": float(mu) * med,
                     "censored": int(np.isnan(d["settling_time"]).sum()), "failed": int((d["status"] != 0).sum()),
                     **{f"mean ΔS by {t:g} s (J/K)": float(v)
                        for t, v in zip(d["entropy_time"].values, d["entropy_by_time_mean"].values)},
                     "mean ΔS total (J/K)": float(d["entropy_produced"].mean()),
                     "(U − U₀)/ΔE_mech (mean)": float(d["heat_ratio"].mean())})
    return [Table("viscosity_sweep", "Settling time and entropy production against viscosity", rows)]


def verdicts(ds, ctx) -> list[Verdict]:
    mu, med = ds[DIM].values, ds["settling_time_quartiles"].sel(quantile=0.5).values
    S, heat = ds["entropy_produced"].mean("member").values, ds["heat_ratio"].mean("member").values
    bad = int(np.isnan(ds["settling_time"].values).sum() + (ds["status"].values != 0).sum())
    prod = (mu * med)[mu <= float(ds["mu_crit"]) / 2]
    spread = prod.max() / prod.min() if prod.size > 1 else np.nan
    return [Verdict("every member settles by t_end", f"{bad} censored or failed", "0", bad == 0),
            Verdict("the heat is the mechanical energy lost", f"mean (U − U₀)/ΔE_mech in [{heat.min():.4f}, "
                    f"{heat.max():.4f}]", "within 1 ± 0.01 at every μ", bool(np.all(np.abs(heat - 1) <= 0.01))),
            Verdict("the entropy produced by settling does not depend on μ", f"mean ΔS total: max/min − 1 = "
                    f"{S.max() / S.min() - 1:.2e}", "≤ 0.02", bool(S.max() / S.min() - 1 <= 0.02)),
            Verdict("under-damped (μ ≤ μ_crit/2): settling time ∝ 1/μ", f"μ × median: max/min = {spread:.3f} over "
                    f"{prod.size} μ", "≤ 1.2 (two μ or more)", bool(spread <= 1.2) if prod.size > 1 else None)]


def findings(ds, ctx) -> list[str]:
    e0, rate = float(ds["mech_energy_initial"].isel({DIM: 0}).mean()), ds["entropy_rate_initial"].mean("member").values
    e0 /= float(ctx.scene(ctx.points[0])["thermo"]["T0"])
    return [f"The entropy produced by settling is set by the initial data (mean E_mech(0)/T₀ = {e0:.4e} J/K, measured "
            f"{float(ds['entropy_produced'].mean()):.4e} J/K); viscosity sets how fast (mean initial rate P/T₀ from "
            f"{rate.min():.3g} to {rate.max():.3g} W/K), not how much.", f"The pendulum mode is over-damped above "
            f"μ_crit ≈ {float(ds['mu_crit']):.3g} kg m⁻¹ s⁻¹ (settling ∝ 1/μ below, slower above). No error, no cost."]


STUDY = Study(
    kind="viscosity_sweep", title="Viscosity sweep: entropy production and settling times", models=("top",),
    description="Settling times and entropy production of one ensemble over the viscosity",
    options=(Option("method", "vi", "str", "", "the method"), Option("h", 0.02, "number>0", "s", "time step"),
             Option("threshold", 0.01, "fraction", "1", "settled: E_mech below this × its initial value"),
             Option("entropy_times", [1.0, 10.0], "list[number>0]", "s", "times of the entropy counts"),
             Option("t_end_factor", 10.0, "number>0", "1", "t_end over the slowest relaxation time"),
             Option("t_end_min", 5.0, "number>0", "s", "shortest run"), Option("t_end_max", 5000.0, "number>0", "s"),
             Option("outputs", 4000, "int>=1", "1", "stored steps per run, about (≥ 10)")),
    needs_methods=False, check=_check, stages=(Stage("sweep", sweep, over=("point",)),),
    quantities=QUANTITIES, derive=derive, tables=tables, verdicts=verdicts, findings=findings,
    figures=(Figure("settling_time", x=DIM, y=("settling_time_quartiles",), band="quantile", logy=True,
                    title="Viscosity sweep: settling time (median, quartile band)",
                    select=lambda ds, ctx: ds, claim="settled members' quartiles: ∝ 1/μ below μ_crit, longer above"),
             Figure("entropy_by_time", x=DIM, title="Viscosity sweep: mean entropy produced by each time", y=("entropy_by_time_mean",), hue="entropy_time",
                    select=lambda ds, ctx: ds, claim="the mean entropy produced by each entropy_time against μ: by the last it is the same at "
                          "every μ (the initial mechanical energy over T₀), while at an early time it depends on "
                          "how fast each μ has settled, not monotonically")),
    report=("Scene `{scene}`, method `{opt[method]}`, h = {opt[h]} s, the same members at every μ. Settled: E_mech "
            "above rest stays below {opt[threshold]} × its start; *censored*: not settled by t_end = "
            "{opt[t_end_factor]} × max(I_max/c, c/mgℓ) in [max({opt[t_end_min]}, entropy times), {opt[t_end_max]}] s."))
