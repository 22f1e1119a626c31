"""Viscosity sweep: entropy production and settling-time statistics over an ensemble.

For each viscosity μ of the ``[sweep]`` (the scene key of the friction linear
in Ω, :data:`SWEEP_KEY`) the same
ensemble of random initial conditions (``ensemble.members``, ``ensemble.seed``
of the scene) is integrated until it has settled.  Per member:

* settling time — the time after which the mechanical energy above the resting
  state, E_mech = K + V + mgℓ, stays below ``threshold`` × its initial value
  (linear interpolation between stored steps; members that have not settled
  by t_end are counted as censored, never dropped silently);
* entropy produced by fixed times ``entropy_times`` and by t_end, and the
  check T₀ΔS / ΔE_mech (≈ 1: the heat is the mechanical energy lost, with
  T ≈ T₀ because c_v is large);
* the initial entropy production rate P(Ω₀)/T₀, P the model's dissipated power.

The run length adapts to μ: t_end = ``t_end_factor`` × max(I_max/c, c/mgℓ) —
the slowest relaxation time of an under-damped (I/c) and of an over-damped
(c/mgℓ) top — clipped to [``t_end_min``, ``t_end_max``].

Options: ``method`` (a method spec, default "vi": legendre start, trapezoid
friction, symmetric entropy update — its heat balance U(S_{k+1}) − U(S_k) =
friction work holds step by step), ``h``, ``threshold``,
``entropy_times``, ``t_end_factor``, ``t_end_min``, ``t_end_max``,
``outputs`` (stored steps per run, about).
"""

from __future__ import annotations

import math
import time
from functools import partial
from pathlib import Path

import numpy as np
import xarray as xr

from ..dataset import node_energies
from ..initial import initial_conditions
from ..kernels.terms import ROLE_LINEAR_FRICTION, key_of
from ..physics import Physics, physics_of_scene, temperature
from .common import (status_units, parse_method, study_options, StudyError, cached_point, expand_sweep, point_key, progress_bar,
                     dim_name, stack_points, study_name, study_netcdf_path, study_scene, write_netcdf_atomic,
                     write_report, write_table, start_study, study_history, closing_fact, kept_laws, scene_value)
from .tools import NODE_VALUES_NOTE, run_spec

EXTRA_KEYS = ()
#: the key swept: the strength of the friction linear in Ω
SWEEP_KEY = key_of(ROLE_LINEAR_FRICTION)
DEFAULT_OPTIONS = {
    "method": "vi",
    "h": 0.02,
    "threshold": 0.01,
    "entropy_times": [1.0, 10.0],
    "t_end_factor": 10.0,
    "t_end_min": 5.0,
    "t_end_max": 5000.0,
    "outputs": 4000,
}


def options(study: dict) -> dict:
    return study_options(study, DEFAULT_OPTIONS, "viscosity_sweep")


def validate(study: dict) -> None:
    opt = options(study)
    sweep = study.get("sweep", {}) or {}
    if list(sweep) != [SWEEP_KEY]:
        raise StudyError(f"sweep: a viscosity_sweep study sweeps exactly one key, {SWEEP_KEY!r}")
    if any(not isinstance(v, (int, float)) or v <= 0 for v in sweep[SWEEP_KEY]):
        raise StudyError(f"sweep.{SWEEP_KEY}: viscosities must be > 0 (a settling time needs friction)")
    for k in ("h", "threshold", "t_end_factor", "t_end_min", "t_end_max"):
        if not (isinstance(opt[k], (int, float)) and opt[k] > 0):
            raise StudyError(f"options.{k}: must be a number > 0")
    if not 0 < opt["threshold"] < 1:
        raise StudyError("options.threshold: must lie in (0, 1)")
    parse_method(opt["method"])
    if not (isinstance(opt["outputs"], int) and opt["outputs"] >= 10):
        raise StudyError("options.outputs: must be an integer ≥ 10")


# ----------------------------------------------------------------------------- numerics

def run_length(phys: Physics, opt: dict) -> float:
    """t_end = factor × max(I_max/c, c/mgℓ) of member 0, clipped (c: the largest
    linear friction coefficient, mgℓ half the span of the potential)."""
    c = float(phys.linear_resistance()[0].max())
    Imax = float(phys.inertia[0].max())
    g = 0.5 * float(phys.potential_span()[0])
    tau = Imax / c
    if g > 0:
        tau = max(tau, c / g)
    lo = max(float(opt["t_end_min"]), max(opt["entropy_times"], default=0.0))
    return float(np.clip(opt["t_end_factor"] * tau, lo, max(lo, float(opt["t_end_max"]))))


def mech_energy(phys: Physics, K: np.ndarray, V: np.ndarray) -> np.ndarray:
    """Mechanical energy above the resting state K + V − min V (J), K and V (N, T)."""
    return phys.mechanical_energy(K, V)


def settling_times(t: np.ndarray, E: np.ndarray, E0: np.ndarray, threshold: float) -> np.ndarray:
    """First time after which E stays below threshold·E0 (per member; NaN: not settled
    by the last stored time, or a failed member)."""
    thr = threshold * E0[:, None]
    above = ~(E < thr)  # NaN counts as above
    out = np.full(E.shape[0], np.nan)
    for m in range(E.shape[0]):
        idx = np.flatnonzero(above[m])
        if idx.size == 0:
            out[m] = t[0]
            continue
        j = idx[-1]
        if j == t.size - 1:
            continue
        e1, e2 = E[m, j], E[m, j + 1]
        s = (e1 - thr[m, 0]) / (e1 - e2) if e1 > e2 else 1.0
        out[m] = t[j] + np.clip(s, 0.0, 1.0) * (t[j + 1] - t[j])
    return out


def sweep_point(scene, opt: dict) -> xr.Dataset:
    N = int(scene["ensemble"]["members"])
    phys = physics_of_scene(scene, N)
    om, R = initial_conditions(scene)
    h = float(opt["h"])
    t_end = run_length(phys, opt)
    every = max(1, int(round(t_end / h / int(opt["outputs"]))))
    every = min(every, max(1, int(math.floor(min(opt["entropy_times"]) / h + 1e-9))))  # resolve t*
    steps = int(math.ceil(t_end / (h * every))) * every
    spec = parse_method(opt["method"])
    t0 = time.perf_counter()
    tr = run_spec(phys, om, R, h, steps, spec, every=every)
    wall = time.perf_counter() - t0
    t = tr.times
    e = node_energies(tr)
    E = mech_energy(phys, e["K"], e["V"])
    E0 = E[:, 0]
    ts = settling_times(t, E, E0, float(opt["threshold"]))
    sig = tr.sigma
    data = {
        "settling_time": ("member", ts),
        "entropy_produced": ("member", sig[:, -1]),
        "mech_energy_initial": ("member", E0),
        "mech_energy_final": ("member", E[:, -1]),
        # heat check: U(S) - U(S0) against the mechanical energy lost
        "heat_ratio": ("member", e["dU"][:, -1] / (E0 - E[:, -1])),
        "entropy_rate_initial": ("member", phys.dissipated_power(om) / temperature(phys, om, np.zeros(N))),
        "status": ("member", tr.status.astype(np.int8)),
    }
    for ti in opt["entropy_times"]:
        data[f"entropy_at_{_tname(ti)}"] = ("member", _interp_rows(t, sig, float(ti)))
    ds = xr.Dataset(data, coords={"member": np.arange(N)})
    ds.attrs.update(t_end=float(t[-1]), steps=steps, every=every, wall=wall, h=h,
                    newton_max=int(tr.newton_max.max(initial=0)))
    ds["t_end"] = ((), float(t[-1]))
    ds["wall_time"] = ((), wall)
    return ds


def _tname(t: float) -> str:
    return f"{t:g}s".replace(".", "p")


def _interp_rows(t, Y, ti):
    if ti > t[-1]:
        return np.full(Y.shape[0], np.nan)
    return np.array([np.interp(ti, t, y) for y in Y])


# ----------------------------------------------------------------------------- study

UNITS = {
    "settling_time": ("s", "time after which K + V + mgl stays below threshold x its initial value (NaN: censored)"),
    "entropy_produced": ("J K-1", "entropy produced by t_end"),
    "mech_energy_initial": ("J", "initial mechanical energy above the resting state K0 + V0 + mgl"),
    "mech_energy_final": ("J", "mechanical energy above the resting state at t_end"),
    "heat_ratio": ("1", "heat U - U0 produced by t_end over the mechanical energy lost (1 = exact balance)"),
    "entropy_rate_initial": ("W K-1", "initial entropy production rate P(Omega0) / T(0), P the dissipated power"),
    "status": status_units(),
    "t_end": ("s", "simulated time (adapted to the viscosity)"),
    "wall_time": ("s", "wall time of the simulation"),
}


def run(study: dict, outdir: Path, *, reduced: bool, progress: bool | None, dask: str | None = None,
        history: str | None = None) -> Path:
    import pandas as pd

    s, outdir, opt = start_study(study, outdir, reduced, validate, options)
    points = sorted(expand_sweep(s["sweep"]), key=lambda d: d[SWEEP_KEY])
    t_wall = time.perf_counter()
    tasks = []  # (key, func, args): module-level func, picklable args (Dask tasks)
    for pt in points:
        sc = study_scene(s, pt)
        tasks.append((point_key({"study": study_name(s), "scene": sc, "options": opt}), sweep_point, (sc, opt)))
    if dask is not None:  # compute the missing points as Dask tasks into the same cache
        from ..distributed import map_cached_points

        map_cached_points(outdir, tasks, dask, progress=progress)
    bar = progress_bar(len(points), progress, study_name(s))
    dss = []
    try:
        for key, func, args in tasks:
            dss.append(cached_point(outdir, key, partial(func, *args)))
            if bar:
                bar.update(1)
    finally:
        if bar:
            bar.close()
    dim = dim_name(SWEEP_KEY)
    ds = stack_points(dss, [{SWEEP_KEY: float(pt[SWEEP_KEY])} for pt in points])
    ds[dim].attrs = {"units": "kg m-1 s-1", "long_name": "fluid viscosity mu (sweep)", "scene_key": SWEEP_KEY}
    for k in ds.data_vars:
        if k in UNITS:
            ds[k].attrs.update(units=UNITS[k][0], long_name=UNITS[k][1])
        elif k.startswith("entropy_at_"):
            ds[k].attrs.update(units="J K-1", long_name=f"entropy produced by t = {k[len('entropy_at_'):].replace('p', '.')}")
    scene0 = study_scene(s, points[0])
    ds["member"].attrs.update(units="1", long_name="ensemble member")
    ds.attrs.update(title="liethermo viscosity sweep: entropy production and settling times",
                    study=study_name(s), method=opt["method"], h=float(opt["h"]),
                    threshold=float(opt["threshold"]), members=int(scene0["ensemble"]["members"]),
                    seed=int(scene0["ensemble"]["seed"]))
    nc = write_netcdf_atomic(ds, study_netcdf_path(s, outdir),
                             history=study_history("viscosity_sweep", study, outdir, reduced, history))

    rows = []
    mus = ds[dim].values
    tkeys = [f"entropy_at_{_tname(t)}" for t in opt["entropy_times"]]
    for i, mu in enumerate(mus):
        d = ds.isel({dim: i})
        ts = d["settling_time"].values
        ok = np.isfinite(ts)
        row = {"μ (kg m⁻¹ s⁻¹)": float(mu), "t_end (s)": float(d["t_end"]),
               "settling time median (s)": float(np.median(ts[ok])) if ok.any() else float("nan"),
               "q25 (s)": float(np.quantile(ts[ok], 0.25)) if ok.any() else float("nan"),
               "q75 (s)": float(np.quantile(ts[ok], 0.75)) if ok.any() else float("nan"),
               "μ × median (kg m⁻¹)": float(mu * np.median(ts[ok])) if ok.any() else float("nan"),
               "censored": int((~ok).sum()), "failed": int(np.sum(d["status"].values != 0))}
        for tk, tv in zip(tkeys, opt["entropy_times"]):
            v = d[tk].values
            row[f"mean ΔS by {tv:g} s (J/K)"] = float(np.mean(v[np.isfinite(v)])) if np.isfinite(v).any() else float("nan")
        row["mean ΔS total (J/K)"] = float(np.mean(d["entropy_produced"].values))
        row["(U − U₀)/ΔE_mech (mean)"] = float(np.mean(d["heat_ratio"].values))
        row["wall (s)"] = float(d["wall_time"])
        rows.append(row)
    df = pd.DataFrame(rows)
    fig = _figure(ds, dim, opt, tkeys, outdir)
    wall = time.perf_counter() - t_wall
    E0 = ds["mech_energy_initial"].isel({dim: 0}).values
    T0 = float(scene0["thermo"]["T0"])
    phys0 = physics_of_scene(scene0)
    g = 0.5 * float(phys0.potential_span()[0])
    Imin = float(phys0.inertia[0].min())
    # the friction is linear in μ: μ_crit = μ c_crit / c(μ), c_crit = 2√(I_min mgℓ)
    per_mu = scene_value(scene0, SWEEP_KEY) / float(phys0.linear_resistance()[0].max())
    mu_crit = 2 * math.sqrt(Imin * g) * per_mu if g > 0 else float("inf")
    sections = [
        write_table(df, outdir, "viscosity_sweep", "Settling time and entropy production against viscosity"),
        f"Scene `{scene0['scene']['name']}`, method `{opt['method']}` (start "
        f"{parse_method(opt['method'])['start'] or '—'}), h = {opt['h']:g} s; "
        f"{int(scene0['ensemble']['members'])} members with random initial conditions (seed "
        f"{int(scene0['ensemble']['seed'])}), the **same** for every μ. Settling time: after it, the mechanical "
        f"energy above rest stays below {opt['threshold']:g} × its initial value; *censored* members had not "
        f"settled by t_end = {opt['t_end_factor']:g} × max(I_max/c, c/mgℓ) (clipped to "
        f"[max({opt['t_end_min']:g}, the entropy times), {opt['t_end_max']:g}] s). Heat balance: "
        f"(U(S) − U(S₀))/ΔE_mech at t_end on node values; with the symmetric entropy update the VI puts the "
        f"friction work of each step into U exactly, so the ratio departs from 1 only by the difference of "
        f"the node energies from the step's energy balance, which vanishes as the top settles.",
        f"**Physics.** (i) The total entropy produced by settling is fixed by the initial data, not by μ: "
        f"ΔS ≈ ΔE_mech/T₀ (T ≈ T₀ since c_v is large), here ensemble mean E_mech(0)/T₀ = "
        f"{np.mean(E0) / T0:.4e} J/K — viscosity changes how *fast* the entropy is produced (the initial rate "
        f"c|Ω₀|²/T₀ ∝ μ, and ΔS by a fixed early time grows with μ), not how much. (ii) In the under-damped "
        f"regime the energy decays like e^(−ct/I), so the settling time scales like I/c ∝ 1/μ (μ × t_settle ≈ "
        f"const); the gravity (pendulum) mode becomes over-damped above μ_crit = 2√(I_min mgℓ)/(8πa³) ≈ "
        f"{mu_crit:.3g} kg m⁻¹ s⁻¹, beyond which the top creeps down at rate mgℓ/c and the settling time grows "
        f"∝ μ again.",
        f"![viscosity sweep]({fig.name})",
        NODE_VALUES_NOTE,
        f"netCDF: `{nc.name}` (dims `{dim}` × `member`). Study wall time {wall:.1f} s.",
        _closing(ds, dim, opt),
    ]
    return write_report(outdir, "Viscosity sweep: entropy production and settling times", sections)


def _closing(ds, dim, opt) -> str:
    """The closing section: one method and no reference, so no cost against error;
    the analogous fact measured here is what the one method cost per member-step."""
    h = float(opt["h"])
    n = int(ds.sizes["member"])
    cost = [float(ds["wall_time"].isel({dim: i})) / (n * max(1, int(round(float(ds["t_end"].isel({dim: i})) / h))))
            for i in range(ds.sizes[dim])]
    m = str(opt["method"])
    rows = [{"method": m, "h (s)": h, "wall per member-step (s), least": min(cost),
             "wall per member-step (s), median": float(np.median(cost)), "keeps": kept_laws(m)}]
    return closing_fact("viscosity sweep", "This study runs one method and no reference, so it measures no error "
                        "and cannot name the method that reaches an error level at least cost (that needs several "
                        "methods against a reference: the work_precision, energy_drift and long_drift studies); "
                        "what it measures is the cost of its one method:", rows,
                        "The method of this sweep and its cost (wall time of each viscosity's whole run, over "
                        "members × steps; a run that compiled the kernels costs more)",
                        f"**Cost here:** {m} at h = {h:g} s cost {min(cost):.3g} s per member-step at least "
                        f"(median {float(np.median(cost)):.3g} s over the {len(cost)} viscosities) and keeps "
                        f"{kept_laws(m)}.")


def _figure(ds, dim, opt, tkeys, outdir: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mus = ds[dim].values.astype(float)
    ts = ds["settling_time"].values
    med = np.array([np.nanmedian(r) if np.isfinite(r).any() else np.nan for r in ts])
    q25 = np.array([np.nanquantile(r, 0.25) if np.isfinite(r).any() else np.nan for r in ts])
    q75 = np.array([np.nanquantile(r, 0.75) if np.isfinite(r).any() else np.nan for r in ts])
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), layout="constrained")
    ax = axes[0]
    ax.fill_between(mus, q25, q75, alpha=0.3, label="interquartile range")
    ax.loglog(mus, med, "o-", label="median settling time")
    i = np.nanargmin(np.abs(np.log(mus) - np.log(0.1))) if mus.size else 0
    if np.isfinite(med[i]):
        ax.loglog(mus, med[i] * mus[i] / mus, "k--", lw=0.8, label="∝ 1/μ")
    ax.set_xlabel("viscosity μ (kg m⁻¹ s⁻¹)")
    ax.set_ylabel("settling time (s)")
    ax.set_title(f"time until E_mech < {opt['threshold']:g} E_mech(0)")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    ax = axes[1]
    for tk in tkeys:
        v = ds[tk].values
        mean = np.array([np.mean(r[np.isfinite(r)]) if np.isfinite(r).any() else np.nan for r in v])
        ax.loglog(mus, mean, "o-", label=f"mean ΔS by t = {tk[11:].replace('p', '.')}")
    ax.loglog(mus, np.mean(ds["entropy_produced"].values, axis=1), "s-", label="mean ΔS by t_end (settled)")
    ax.set_xlabel("viscosity μ (kg m⁻¹ s⁻¹)")
    ax.set_ylabel("entropy produced (J K⁻¹)")
    ax.set_title("entropy production")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    path = Path(outdir) / "viscosity_sweep.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
