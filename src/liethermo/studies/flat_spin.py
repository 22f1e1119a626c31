"""Flat-spin study: double-bracket internal friction on a free asymmetric body.

The scene (built-in ``flat_spin``: a uniform triaxial ellipsoid turning about
its centre, g = 0, no Stokes friction) has only the internal friction

    f = λ μ×(μ×Ω),   μ = 𝕀Ω,   λ = ``body.internal_friction`` (s kg⁻¹ m⁻²),

whose power −⟨f, Ω⟩ = λ|μ×Ω|² turns kinetic energy into heat.  f ⟂ μ, so
|μ| is a Casimir: the kinetic energy K = ½ μ·𝕀⁻¹μ falls at fixed |μ| to its
floor |μ|²/(2 I_max), and the body ends spinning about its major axis.  The
heat gained U(S) − U(S₀) equals the kinetic energy lost K₀ − K (the total
energy is conserved).

An ensemble of random spins (:func:`liethermo.initial.initial_conditions`:
directions uniform on the sphere, |Ω₀| uniform in ``ensemble.spin_range`` ×
|initial.omega|) is integrated for every swept λ and method, over a horizon
t_end = ``options.lambda_t_end`` / λ (the flow's time scale is ∝ 1/λ), with
``options.nodes`` stored nodes.  The reference (DOP853 with substeps) runs on
the first ``options.reference_members`` members.  Per member, on node values
(the variational integrators' node momentum μ_k, Ω(t_k) = 𝕀⁻¹μ_k; RK:
μ = 𝕀Ω(t_k)):

* **excess kinetic energy** X_k = K_k − |μ_k|²/(2 I_max) ≥ 0, the energy
  above the floor of the member's current orbit (using |μ_k|, not |μ₀|, so
  a method that drifts off the orbit is not charged twice);
* **settling time**: the first t with X(t)/X₀ ≤ ``options.settle_fraction``
  (log-linear interpolation between stored nodes; NaN if never);
* **on the major axis**: the angle between μ at t_end and the body's major
  axis (either sense) is below ``options.axis_tolerance`` (rad);
* **Casimir drift**: max_k ||μ_k| − |μ₀|| / |μ₀| over the stored nodes;
* **energy balance**: max_k |(U(S_k) − U(S₀)) − (K₀ − K_k)| / K₀, with
  U(S) − U(S₀) = c_v T₀ expm1((S − S₀)/c_v) (no cancellation).

A second sweep, at λ = ``options.casimir_lambda``, runs every method at the
steps ``options.casimir_h`` on ``options.casimir_members`` members to show
how the Casimir drift of the explicit methods falls with h.
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
from ..kernels.terms import LAW_MOMENTUM_NORM, ROLE_MOMENTUM_FRICTION, key_of
from ..physics import kinetic_energy, physics_of_scene
from .common import (status_units, StudyError, cached_point, closing_section, dim_name, expand_sweep, method_overrides,
                     parse_method, point_key, progress_bar, stack_points, start_study, step_text, study_history,
                     study_name, study_netcdf_path, study_options, study_scene, write_netcdf_atomic, write_report, write_table,
                     scene_value)
from .tools import (band_text, direction_angle, display_table, observed_orders, quantile_band, run_spec,
                    settling_time)

EXTRA_KEYS = ()
#: the key swept: the strength of the friction that keeps |μ|
SWEEP_KEY = key_of(ROLE_MOMENTUM_FRICTION)
DEFAULT_OPTIONS = {
    "lambda_t_end": 4000.0,    # s² kg⁻¹ m⁻²: horizon t_end = lambda_t_end / λ
    "nodes": 2000,             # stored nodes per run (every = t_end / (h nodes), an integer)
    "settle_fraction": 1e-6,   # settled: excess kinetic energy ≤ this × its initial value
    "axis_tolerance": 1e-3,    # rad: on the major axis if μ is this close to it at t_end
    "reference_members": 16,   # members the reference (DOP853) runs
    "trace_members": 4,        # members whose K(t) is kept for the figure
    "casimir_lambda": 20.0,    # s kg⁻¹ m⁻², λ of the Casimir-against-h runs
    "casimir_h": [0.02, 0.01, 0.005],  # s
    "casimir_members": 16,
}
QUANTILES = np.array([0.05, 0.5, 0.95])
#: a Casimir drift below this is round-off: no order is fitted to it
ROUNDOFF = 1e-12


def options(study: dict) -> dict:
    return study_options(study, DEFAULT_OPTIONS, "flat_spin")


def validate(study: dict) -> None:
    opt = options(study)
    sweep = study.get("sweep", {}) or {}
    if list(sweep) != [SWEEP_KEY]:
        raise StudyError(f"sweep: a flat_spin study sweeps exactly one key, {SWEEP_KEY!r}")
    if any(not isinstance(v, (int, float)) or not v > 0 for v in sweep[SWEEP_KEY]):
        raise StudyError(f"sweep.{SWEEP_KEY}: internal friction λ must be > 0 (s kg-1 m-2)")
    methods = study.get("methods") or []
    if not methods:
        raise StudyError("methods: a flat_spin study needs at least one method")
    for m in methods:
        parse_method(m)
    for k in ("lambda_t_end", "settle_fraction", "axis_tolerance", "casimir_lambda"):
        if not (isinstance(opt[k], (int, float)) and opt[k] > 0):
            raise StudyError(f"options.{k}: must be a number > 0")
    if not opt["settle_fraction"] < 1:
        raise StudyError("options.settle_fraction: must be < 1")
    for k in ("nodes", "reference_members", "trace_members", "casimir_members"):
        if not (isinstance(opt[k], int) and opt[k] >= 1):
            raise StudyError(f"options.{k}: must be an integer ≥ 1")
    hs = opt["casimir_h"]
    if not (isinstance(hs, list) and hs and all(isinstance(h, (int, float)) and h > 0 for h in hs)):
        raise StudyError("options.casimir_h: must be a non-empty list of steps > 0 (s)")
    scene = study_scene(study, {SWEEP_KEY: sweep[SWEEP_KEY][0]})
    phys = physics_of_scene(scene)
    broken = phys.breaking(LAW_MOMENTUM_NORM)
    if broken:
        raise StudyError(f"scene: a flat_spin study needs a free body on which |μ| is a Casimir; "
                         f"{', '.join(broken)} break it: switch them off")
    if not np.all(phys.has_constant_inertia()):
        raise StudyError("scene: a flat_spin study needs a constant inertia (its energy floor is "
                         "|μ|²/(2 I_max)): switch off the inertia's dependence on the entropy")
    n = int(scene["ensemble"]["members"])
    if opt["trace_members"] > min(n, opt["reference_members"]):
        raise StudyError("options.trace_members: at most min(ensemble.members, options.reference_members)")


def horizon(lam: float, h: float, opt: dict) -> tuple[int, int]:
    """(steps, every) of a run at λ: t_end ≈ lambda_t_end/λ with ``nodes`` stored nodes."""
    every = max(1, int(round(float(opt["lambda_t_end"]) / lam / (h * int(opt["nodes"])))))
    return every * int(opt["nodes"]), every


def _members(scene, spec: dict, limit: int) -> int:
    n = int(scene["ensemble"]["members"])
    return min(n, int(limit)) if spec["method"] == "reference" else n


def _pad(a: np.ndarray, n: int, fill=np.nan) -> np.ndarray:
    out = np.full((n,) + a.shape[1:], fill, dtype=np.result_type(a.dtype, type(fill)))
    out[:a.shape[0]] = a
    return out


def _spin_run(scene, spec: dict, h: float, steps: int, every: int, n: int):
    """Run n members; return (trajectory, physics, Ω₀, μ_k (n, T, 3), |μ₀| (n,))."""
    N = int(scene["ensemble"]["members"])
    phys = physics_of_scene(scene, N).take(slice(0, n))
    om, R = initial_conditions(scene, 0, n)
    tr = run_spec(phys, om, R, h, steps, spec, every=every)
    mu = tr.momentum if tr.family == "vi" else phys.inertia[:, None, :] * tr.omega
    mu0 = np.linalg.norm(phys.inertia * om, axis=-1)
    return tr, phys, om, mu, mu0


def _casimir(mu: np.ndarray, mu0: np.ndarray) -> np.ndarray:
    """||μ_k| − |μ₀|| / |μ₀| (n, T)."""
    return np.abs(np.linalg.norm(mu, axis=-1) - mu0[:, None]) / mu0[:, None]


def point(scene, spec: dict, opt: dict) -> xr.Dataset:
    """One (λ, method) point: per-member settling, axis, Casimir and energy balance."""
    lam = float(scene_value(scene, SWEEP_KEY))
    h = float(scene["integrator"]["h"])
    steps, every = horizon(lam, h, opt)
    N = int(scene["ensemble"]["members"])
    n = _members(scene, spec, opt["reference_members"])
    tr, phys, om, mu, mu0 = _spin_run(scene, spec, h, steps, every, n)
    I = phys.inertia
    Imax = I.max(axis=1)
    major = np.eye(3)[np.argmax(I, axis=1)]
    with np.errstate(invalid="ignore", over="ignore"):
        e = node_energies(tr)
        K = e["K"]
        floor = np.linalg.norm(mu, axis=-1) ** 2 / (2.0 * Imax[:, None])
        excess = K - floor
        ratio = excess / excess[:, :1]
        cas = _casimir(mu, mu0)
        K0 = kinetic_energy(phys, om, None)
        dU = e["dU"]
        balance = np.abs(dU - (K0[:, None] - K)) / K0[:, None]
        ang = direction_angle(mu[:, -1], major)
        ang = np.minimum(ang, math.pi - ang)
    ok = tr.status == 0
    settle = settling_time(tr.times, ratio, float(opt["settle_fraction"]))
    on_axis = (ok & (ang < float(opt["axis_tolerance"]))).astype(np.int8)
    nt = int(opt["trace_members"])
    q = QUANTILES
    data = {
        "settling_time": ("member", _pad(settle, N)),
        "final_axis_angle": ("member", _pad(ang, N)),
        "on_major_axis": ("member", _pad(on_axis, N, np.int8(-1)).astype(np.int8)),
        "casimir_drift": ("member", _pad(np.where(ok, np.nanmax(cas, axis=1), np.inf), N)),
        "energy_balance_error": ("member", _pad(np.where(ok, np.nanmax(balance, axis=1), np.inf), N)),
        "heat_gained": ("member", _pad(dU[:, -1], N)),
        "kinetic_energy_lost": ("member", _pad(K0 - K[:, -1], N)),
        "initial_kinetic_energy": ("member", _pad(K0, N)),
        "kinetic_energy_floor": ("member", _pad(mu0 ** 2 / (2.0 * Imax), N)),
        "final_excess_ratio": ("member", _pad(ratio[:, -1], N)),
        "status": ("member", _pad(tr.status.astype(np.int8), N, np.int8(-1)).astype(np.int8)),
        "casimir_drift_quantiles": (("quantile", "node"), np.nanquantile(cas, q, axis=0)),
        "excess_ratio_quantiles": (("quantile", "node"), np.nanquantile(ratio, q, axis=0)),
        "kinetic_energy_trace": (("trace", "node"), K[:nt]),
        "kinetic_floor_trace": (("trace", "node"), floor[:nt]),
        "node_time": ("node", tr.times),
        "kernel_time": ((), tr.wall_time),
        "step": ((), h),
        "t_end": ((), steps * h),
    }
    return xr.Dataset(data, coords={"member": np.arange(N), "quantile": q, "trace": np.arange(nt),
                                    "node": np.arange(tr.times.size)})


def casimir_point(scene, spec: dict, h: float, opt: dict) -> xr.Dataset:
    """One (h, method) point of the Casimir-against-h sweep: max Casimir drift per member."""
    lam = float(scene_value(scene, SWEEP_KEY))
    steps, every = horizon(lam, h, opt)
    n = min(int(scene["ensemble"]["members"]), int(opt["casimir_members"]))
    tr, _, _, mu, mu0 = _spin_run(scene, spec, h, steps, every, n)
    with np.errstate(invalid="ignore", over="ignore"):
        cas = np.where(tr.status == 0, np.nanmax(_casimir(mu, mu0), axis=1), np.inf)
    return xr.Dataset({"casimir_drift_h": ("casimir_member", cas),
                       "casimir_t_end": ((), steps * h)},
                      coords={"casimir_member": np.arange(n)})


UNITS = {
    "settling_time": ("s", "first t with (K - |mu_k|^2/(2 I_max)) / (K_0 - |mu_0|^2/(2 I_max)) <= settle_fraction "
                           "(NaN: not settled within t_end or member not run)"),
    "final_axis_angle": ("rad", "angle between mu at t_end and the body's major axis (either sense)"),
    "on_major_axis": ("1", "1 if final_axis_angle < axis_tolerance and the member ran to the end; 0 if not; "
                           "-1 if the method did not run the member"),
    "casimir_drift": ("1", "max_k ||mu_k| - |mu_0|| / |mu_0| over the stored nodes (failed: inf)"),
    "energy_balance_error": ("1", "max_k |(U(S_k) - U(S_0)) - (K_0 - K_k)| / K_0, node values (failed: inf)"),
    "heat_gained": ("J", "U(S) - U(S_0) at t_end"),
    "kinetic_energy_lost": ("J", "K_0 - K at t_end, node values"),
    "initial_kinetic_energy": ("J", "K_0 = 1/2 Omega_0 . I Omega_0"),
    "kinetic_energy_floor": ("J", "|mu_0|^2 / (2 I_max): the kinetic energy of the flat spin"),
    "final_excess_ratio": ("1", "(K - |mu|^2/(2 I_max)) / (K_0 - |mu_0|^2/(2 I_max)) at t_end"),
    "status": status_units(not_run=True),
    "casimir_drift_quantiles": ("1", "quantiles over members of ||mu_k| - |mu_0|| / |mu_0|"),
    "excess_ratio_quantiles": ("1", "quantiles over members of the excess kinetic energy ratio "
                                    "(K - |mu|^2/(2 I_max)) / (K_0 - |mu_0|^2/(2 I_max))"),
    "kinetic_energy_trace": ("J", "kinetic energy K_k of the first members, node values"),
    "kinetic_floor_trace": ("J", "|mu_k|^2 / (2 I_max) of the first members"),
    "node_time": ("s", "time t_k of the stored node (depends on the internal friction: t_end ~ 1/lambda)"),
    "kernel_time": ("s", "kernel wall time of the point"),
    "step": ("s", "time step h"),
    "t_end": ("s", "horizon of the run"),
    "casimir_drift_h": ("1", "max_k ||mu_k| - |mu_0|| / |mu_0| at lambda = casimir_lambda (failed: inf)"),
    "casimir_t_end": ("s", "horizon of the Casimir-against-h run"),
}
COORDS = {
    "member": ("1", "ensemble member"),
    "quantile": ("1", "quantile over members"),
    "trace": ("1", "traced ensemble member"),
    "node": ("1", "index of the stored node"),
    "casimir_member": ("1", "ensemble member of the Casimir-against-h runs"),
    "casimir_step": ("s", "time step h of the Casimir-against-h runs"),
}


def run(study: dict, outdir: Path, *, reduced: bool, progress: bool | None, dask: str | None = None,
        history: str | None = None) -> Path:
    import pandas as pd

    s, outdir, opt = start_study(study, outdir, reduced, validate, options)
    specs = [parse_method(m) for m in s["methods"]]
    points = expand_sweep(s["sweep"])
    t_wall = time.perf_counter()
    tasks = []
    for pt in points:
        for spec in specs:
            sc = study_scene(s, dict(pt, **method_overrides(spec)))
            key = point_key({"study": "flat_spin", "scene": sc, "spec": spec, "opt": opt})
            tasks.append((key, point, (sc, spec, opt)))
    lam_c = float(opt["casimir_lambda"])
    ctasks = []
    for h in opt["casimir_h"]:
        for spec in specs:
            sc = study_scene(s, dict({SWEEP_KEY: lam_c}, **method_overrides(spec)))
            key = point_key({"study": "flat_spin/casimir", "scene": sc, "spec": spec, "h": float(h), "opt": opt})
            ctasks.append((key, casimir_point, (sc, spec, float(h), opt)))
    if dask is not None:
        from ..distributed import map_cached_points

        map_cached_points(outdir, tasks + ctasks, dask, progress=progress)
    bar = progress_bar(len(tasks) + len(ctasks), progress, study_name(s))
    dss, cdss = [], []
    try:
        for key, fn, args in tasks:
            dss.append(cached_point(outdir, key, partial(fn, *args)))
            bar.update(1)
        for key, fn, args in ctasks:
            cdss.append(cached_point(outdir, key, partial(fn, *args)))
            bar.update(1)
    finally:
        bar.close()
    labels = [sp["label"] for sp in specs]
    allpts = [dict(pt, scheme=sp["label"]) for pt in points for sp in specs]
    ds = stack_points(dss, allpts, [SWEEP_KEY, "scheme"])
    cds = stack_points(cdss, [{"casimir_step": float(h), "scheme": sp["label"]}
                              for h in opt["casimir_h"] for sp in specs], ["casimir_step", "scheme"])
    ds = xr.merge([ds, cds], compat="override", join="outer")
    for k, (u, ln) in {**UNITS, **COORDS}.items():
        if k in ds.variables:
            ds[k].attrs.update(units=u, long_name=ln)
    dim = dim_name(SWEEP_KEY)
    ds[dim].attrs.update(units="s kg-1 m-2", long_name="double-bracket internal friction lambda (sweep)")
    ds["casimir_step"].attrs.update(units="s", long_name="time step h of the Casimir-against-h runs")
    scene0 = study_scene(s, points[0])
    members = int(scene0["ensemble"]["members"])
    phys0 = physics_of_scene(scene0)
    ds.attrs.update(title="liethermo study: double-bracket friction and the flat spin of a free asymmetric body", study=study_name(s), kind="flat_spin", reduced=int(reduced), members=members,
                    seed=int(scene0["ensemble"]["seed"]), values="node values",
                    lambda_t_end=float(opt["lambda_t_end"]), settle_fraction=float(opt["settle_fraction"]),
                    axis_tolerance=float(opt["axis_tolerance"]), casimir_lambda=lam_c)
    nc = write_netcdf_atomic(ds, study_netcdf_path(s, outdir),
                             history=study_history("flat_spin", s, outdir, reduced, history))

    # ---------------------------------------------------------------- tables
    refs = {float(pt[SWEEP_KEY]): d for pt, d in zip(allpts, dss) if parse_method(pt["scheme"])["method"] == "reference"}
    rows, disp = [], []
    for (pt, d) in zip(allpts, dss):
        lam, lab = float(pt[SWEEP_KEY]), pt["scheme"]
        ran = d["status"].values >= 0
        st = d["settling_time"].values[ran]
        q5, q50, q95 = quantile_band(st)
        onax = d["on_major_axis"].values[ran]
        cas = d["casimir_drift"].values[ran]
        bal = d["energy_balance_error"].values[ran]
        heat, lost = d["heat_gained"].values[ran], d["kinetic_energy_lost"].values[ran]
        row = {
            "λ (s kg⁻¹ m⁻²)": lam, "method": lab, "h (s)": float(d["step"]), "t_end (s)": float(d["t_end"]),
            "members": int(ran.sum()), "median settling time (s)": q50, "5% settling time (s)": q5,
            "95% settling time (s)": q95, "not settled": int(np.isnan(st).sum()),
            "on major axis (fraction)": float(np.mean(onax == 1)),
            "max final axis angle (rad)": float(np.nanmax(d["final_axis_angle"].values[ran])),
            "median Casimir drift (1)": float(np.median(cas)), "max Casimir drift (1)": float(np.max(cas)),
            "median heat gained (J)": float(np.median(heat)), "median K0 − K (J)": float(np.median(lost)),
            "max |ΔU − (K0 − K)|/K0 (1)": float(np.max(bal)),
            "failed": int((d["status"].values[ran] > 0).sum()),
            "max |settling − reference| (s)": _vs_reference(d, refs.get(lam)),
        }
        rows.append(row)
        disp.append({
            "λ (s kg⁻¹ m⁻²)": lam, "method": lab, "members": row["members"],
            "settling time (s), median [5 %, 95 %]": band_text(q50, q5, q95),
            "on major axis": f"{int((onax == 1).sum())}/{onax.size}",
            "max |Δt| vs reference (s)": row["max |settling − reference| (s)"],
            "max Casimir drift (1)": row["max Casimir drift (1)"],
            "max |ΔU − (K₀ − K)|/K₀ (1)": row["max |ΔU − (K0 − K)|/K0 (1)"],
        })
    df = pd.DataFrame(rows)
    write_table(df, outdir, "flat_spin", "Flat spin")
    crow = []
    for h, group in zip(opt["casimir_h"], [cdss[i:i + len(specs)] for i in range(0, len(cdss), len(specs))]):
        for sp, d in zip(specs, group):
            v = d["casimir_drift_h"].values
            crow.append({"method": sp["label"], "h (s)": float(h), "members": v.size,
                         "median Casimir drift (1)": float(np.median(v)), "max Casimir drift (1)": float(np.max(v))})
    cdf = pd.DataFrame(crow)
    cdf["observed order (median)"] = np.nan
    for lab in labels:
        sel = cdf["method"] == lab
        g = cdf[sel].sort_values("h (s)", ascending=False)
        v = g["median Casimir drift (1)"].values
        p = observed_orders(g["h (s)"].values, np.where(v > ROUNDOFF, v, np.nan))
        cdf.loc[g.index[1:], "observed order (median)"] = p
    ctable = write_table(cdf, outdir, "flat_spin_casimir",
                         f"Casimir drift against the step (λ = {lam_c:g} s kg⁻¹ m⁻², "
                         f"{int(opt['casimir_members'])} members, t_end = {float(cdss[0]['casimir_t_end']):g} s)")
    _energy_figure(dss, allpts, labels, opt, outdir)
    _casimir_figure(dss, allpts, labels, cdf, opt, outdir)
    _settling_figure(df, labels, outdir)
    wall = time.perf_counter() - t_wall
    I = phys0.inertia[0]
    sections = [
        display_table(pd.DataFrame(disp), f"Flat spin under double-bracket friction ({members} members; the "
                      f"reference on {min(members, int(opt['reference_members']))}; node values)", "flat_spin"),
        _finding(df, cdf, opt, labels),
        f"Scene `{scene0['scene']['name']}`: a uniform ellipsoid with semi-axes "
        f"{', '.join(f'{a:g}' for a in scene0['body']['semi_axes'])} m turning freely about its centre "
        f"(principal moments {I[0]:.4g}, {I[1]:.4g}, {I[2]:.4g} kg m²; the major axis is axis "
        f"{int(np.argmax(I)) + 1}), no gravity, no fluid, heat capacity c_v = "
        f"{float(phys0.heat_capacity[0]):.4g} J/K. Internal friction f = λ μ×(μ×Ω). {members} members with "
        f"random spin directions and |Ω₀| in {scene0['ensemble']['spin_range']} × "
        f"{np.linalg.norm(scene0['initial']['omega']):.4g} rad/s (seed {int(scene0['ensemble']['seed'])}). "
        f"Horizon t_end = {float(opt['lambda_t_end']):g} s² kg⁻¹ m⁻² / λ, {int(opt['nodes'])} stored nodes "
        f"(maxima are over the stored nodes).",
        "**Definitions.** Excess kinetic energy X = K − |μ|²/(2 I_max) ≥ 0 (the energy above the floor of the "
        "member's current orbit, |μ| of the same node). *Settling time*: first t with X(t)/X(0) ≤ "
        f"{float(opt['settle_fraction']):g} (log-linear between nodes). *On the major axis*: μ at t_end within "
        f"{float(opt['axis_tolerance']):g} rad of the major axis. *Casimir drift*: max_k ||μ_k| − |μ₀||/|μ₀|. "
        "*Energy balance*: max_k |(U(S_k) − U(S₀)) − (K₀ − K_k)|/K₀; the continuous law makes heat gained "
        "equal energy lost.",
        "**Which energy.** Node values: K_k = ½ μ_k·𝕀⁻¹μ_k from the variational integrators' node momentum "
        "μ_k (node velocity Ω(t_k) = 𝕀⁻¹μ_k), and from Ω(t_k) for RK and the reference "
        "(`liethermo.dataset.node_energies`); U(S) − U(S₀) = c_v T₀ expm1((S − S₀)/c_v).",
        ctable + f"\nObserved order: log of the ratio of the median drifts of consecutive steps over the log of the "
        f"step ratio; none is fitted where the drift is round-off (below {ROUNDOFF:g}).",
        "![kinetic energy against time](flat_spin_energy.png)\n\n![Casimir drift](flat_spin_casimir.png)\n\n"
        "![settling time against lambda](flat_spin_settling.png)",
        f"netCDF: `{nc.name}`; numbers of the first table: `flat_spin.csv`. Study wall time {wall:.1f} s "
        f"(kernels {sum(float(d['kernel_time']) for d in dss):.1f} s).",
        closing_section(
            [{"method": lab, "error": float(g["max |settling − reference| (s)"].max()),
              "cost": float(sum(float(d["kernel_time"]) / max(int(r["members"]), 1)
                                for (pt, d), (_, r) in zip(zip(allpts, dss), df.iterrows()) if pt["scheme"] == lab)),
              "setting": step_text(g["h (s)"])}
             for lab, g in df.groupby("method", sort=False)
             if parse_method(lab)["method"] != "reference" and not g["failed"].any()],
            regime=f"free body, double-bracket friction, λ ∈ {{{', '.join(f'{x:g}' for x in df['λ (s kg⁻¹ m⁻²)'].unique())}}}",
            error="max over λ and the reference's members of |settling time − the reference's| (s)", unit="s",
            cost="kernel wall time per member, summed over the λ sweep (s)", outdir=outdir),
    ]
    return write_report(outdir, "Flat spin: double-bracket friction on a free asymmetric body"
                        + (" (reduced)" if reduced else ""), sections)


def _vs_reference(d: xr.Dataset, ref: xr.Dataset | None) -> float:
    """max over the members the reference ran of |settling time − the reference's| (s); NaN
    for the reference itself or without one."""
    if ref is None or d is ref:
        return float("nan")
    r = ref["settling_time"].values
    m = ref["status"].values >= 0
    diff = np.abs(d["settling_time"].values[m] - r[m])
    return float(np.max(diff)) if diff.size and np.all(np.isfinite(diff)) else float("nan")


def _finding(df, cdf, opt, labels) -> str:
    vi = df[df["method"].map(lambda m: parse_method(m)["family"] == "vi")]
    lines = ["**Findings (node values).**", ""]
    allon = df["on major axis (fraction)"] == 1.0
    if allon.all():
        lines.append(f"- Every member of every method ends on the major axis (within "
                     f"{float(opt['axis_tolerance']):g} rad) at every λ.")
    else:
        bad = df[~allon]
        lines.append("- Not every member ends on the major axis: " + "; ".join(
            f"{r['method']} at λ = {r['λ (s kg⁻¹ m⁻²)']:g}: {r['on major axis (fraction)']:.3f} of "
            f"{r['members']} (not settled: {r['not settled']})" for _, r in bad.iterrows()) + ".")
    if len(vi):
        lines.append(f"- Casimir |μ|: the variational integrators keep it to {vi['max Casimir drift (1)'].max():.1e} "
                     f"(max over members, λ and methods: round-off).")
    for lab in labels:
        if parse_method(lab)["family"] == "vi":
            continue
        g = df[df["method"] == lab]
        what = (" (DOP853 with substeps: it does not keep |μ| by construction, but its error is at round-off "
                "at this step)" if parse_method(lab)["method"] == "reference" else "")
        lines.append(f"- {lab}: Casimir drift up to {g['max Casimir drift (1)'].max():.1e} "
                     f"(median {g['median Casimir drift (1)'].median():.1e}) at h = {g['h (s)'].iloc[0]:g} s"
                     + what + ".")
    for lab in labels:
        g = cdf[cdf["method"] == lab].sort_values("h (s)")
        if parse_method(lab)["family"] == "rk" and lab != "reference" and len(g) > 1:
            p = g["observed order (median)"].dropna()
            lines.append(f"  Against h: {lab}'s median drift goes from {g['median Casimir drift (1)'].iloc[-1]:.1e} "
                         f"(h = {g['h (s)'].iloc[-1]:g} s) to {g['median Casimir drift (1)'].iloc[0]:.1e} "
                         f"(h = {g['h (s)'].iloc[0]:g} s)" + (f", observed order {p.mean():.2f}" if len(p) else "")
                         + ".")
    lines.append("- Energy lost against heat gained, max |ΔU − (K₀ − K)|/K₀ over members and λ: " + "; ".join(
        f"{lab} {df[df['method'] == lab]['max |ΔU − (K0 − K)|/K0 (1)'].max():.1e}" for lab in labels) + ".")
    lams = sorted(df["λ (s kg⁻¹ m⁻²)"].unique())
    if len(lams) > 1:
        for lab in labels[:1]:
            g = df[df["method"] == lab].set_index("λ (s kg⁻¹ m⁻²)")
            a, b = g.loc[lams[0], "median settling time (s)"], g.loc[lams[-1], "median settling time (s)"]
            slope = math.log(b / a) / math.log(lams[-1] / lams[0])
            lines.append(f"- Settling time ({lab}, median) falls from {a:.4g} s at λ = {lams[0]:g} to {b:.4g} s "
                         f"at λ = {lams[-1]:g} s kg⁻¹ m⁻²: t ∝ λ^{slope:.3f} (the flow's time scale is 1/λ).")
    dv = df["max |settling − reference| (s)"].dropna()
    if len(dv):
        worst = df.loc[dv.idxmax()]
        lines.append(f"- Settling times against the reference's, member by member (the members it ran): every "
                     f"method within {dv.max():.2g} s (largest: {worst['method']} at λ = "
                     f"{worst['λ (s kg⁻¹ m⁻²)']:g} s kg⁻¹ m⁻²); " + "; ".join(
                         f"{lab} {df[df['method'] == lab]['max |settling − reference| (s)'].max():.2g} s"
                         for lab in labels if parse_method(lab)["method"] != "reference") + ".")
    return "\n".join(lines)


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _energy_figure(dss, allpts, labels, opt, outdir: Path) -> Path:
    """K(t) of the traced members with their floors |μ|²/(2 I_max), and the excess ratio."""
    plt = _plt()
    lam_c = float(opt["casimir_lambda"])
    lams = list(dict.fromkeys(float(p[SWEEP_KEY]) for p in allpts))
    lam = min(lams, key=lambda x: abs(math.log(x / lam_c)))
    lab = labels[0]
    d = next(d for p, d in zip(allpts, dss) if float(p[SWEEP_KEY]) == lam and p["scheme"] == lab)
    t = d["node_time"].values
    fig, (a, b) = plt.subplots(1, 2, figsize=(11.0, 4.4), layout="constrained")
    for i in range(d.sizes["trace"]):
        K = d["kinetic_energy_trace"].values[i]
        F = d["kinetic_floor_trace"].values[i]
        a.plot(t, K * 1e3, color=f"C{i}", lw=1.3)
        a.plot(t, F * 1e3, color=f"C{i}", lw=1.0, ls=":")
    a.plot([], [], color="k", lw=1.3, label="K (one colour per member)")
    a.plot([], [], color="k", lw=1.0, ls=":", label="floor |μ|²/(2 I_max)")
    a.set_xscale("symlog", linthresh=1.0)
    a.set_xlim(0.0, float(t[-1]))
    a.set_xlabel("t (s)")
    a.set_ylabel("kinetic energy (mJ), node values")
    a.set_title(f"{lab}, λ = {lam:g} s kg⁻¹ m⁻²")
    a.grid(True, alpha=0.3)
    a.legend(fontsize=8, loc="upper right")
    for j, (p, dd) in enumerate(zip(allpts, dss)):
        if p["scheme"] != lab:
            continue
        lj = lams.index(float(p[SWEEP_KEY]))
        qv = dd["excess_ratio_quantiles"].values
        tt = dd["node_time"].values
        b.semilogy(tt, np.clip(qv[1], 1e-16, None), color=f"C{lj}", lw=1.3, label=f"λ = {float(p[SWEEP_KEY]):g}")
        b.fill_between(tt, np.clip(qv[0], 1e-16, None), np.clip(qv[2], 1e-16, None), color=f"C{lj}", alpha=0.15,
                       lw=0)
    b.axhline(float(opt["settle_fraction"]), color="k", lw=0.8, ls="--", label="settled")
    b.set_xscale("symlog", linthresh=1.0)
    b.set_xlim(0.0, max(float(dd["node_time"].values[-1]) for dd in dss))
    b.set_xlabel("t (s)")
    b.set_ylabel("(K − |μ|²/(2 I_max)) / its initial value (1)")
    b.set_title(f"{lab}: excess kinetic energy, median and 5–95 % band", fontsize=10)
    b.grid(True, which="both", alpha=0.3)
    b.legend(fontsize=8, title="λ (s kg⁻¹ m⁻²)", title_fontsize=8)
    path = outdir / "flat_spin_energy.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _label(lab: str, d: xr.Dataset) -> str:
    n = int((d["status"].values >= 0).sum())
    return lab if n == d.sizes["member"] else f"{lab} (first {n} members)"


def _casimir_figure(dss, allpts, labels, cdf, opt, outdir: Path) -> Path:
    plt = _plt()
    lam_c = float(opt["casimir_lambda"])
    lams = list(dict.fromkeys(float(p[SWEEP_KEY]) for p in allpts))
    lam = min(lams, key=lambda x: abs(math.log(x / lam_c)))
    fig, (a, b) = plt.subplots(1, 2, figsize=(11.0, 4.4), layout="constrained")
    for p, d in zip(allpts, dss):
        if float(p[SWEEP_KEY]) != lam:
            continue
        i = labels.index(p["scheme"])
        t = d["node_time"].values
        med = d["casimir_drift_quantiles"].values[1]
        ok = t > 0
        a.semilogy(t[ok], np.clip(med[ok], 1e-17, None), color=f"C{i}", lw=1.3, label=_label(p["scheme"], d))
    a.set_xlabel("t (s)")
    a.set_ylabel("median ||μ_k| − |μ₀|| / |μ₀| (1)")
    a.set_title(f"Casimir drift, λ = {lam:g} s kg⁻¹ m⁻² (values below 1e-17 drawn at 1e-17)", fontsize=9)
    a.grid(True, which="both", alpha=0.3)
    for i, lab in enumerate(labels):
        g = cdf[cdf["method"] == lab].sort_values("h (s)")
        b.loglog(g["h (s)"], np.clip(g["max Casimir drift (1)"], 1e-17, None), "o-", color=f"C{i}")
    hs = sorted(cdf["h (s)"].unique())
    b.set_xticks(hs, [f"{h:g}" for h in hs])
    b.minorticks_off()
    b.set_xlabel("h (s)")
    b.set_ylabel("max over members of max_k ||μ_k| − |μ₀|| / |μ₀| (1)")
    b.set_title(f"Casimir drift against h, λ = {lam_c:g} s kg⁻¹ m⁻²", fontsize=10)
    b.grid(True, which="both", alpha=0.3)
    fig.legend(*a.get_legend_handles_labels(), loc="outside lower center", ncol=len(labels), fontsize=8)
    path = outdir / "flat_spin_casimir.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _settling_figure(df, labels, outdir: Path) -> Path:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.8, 4.6), layout="constrained")
    lams = np.array(sorted(df["λ (s kg⁻¹ m⁻²)"].unique()))
    n = len(labels)
    for i, lab in enumerate(labels):
        g = df[df["method"] == lab].sort_values("λ (s kg⁻¹ m⁻²)")
        x = g["λ (s kg⁻¹ m⁻²)"].values * 1.03 ** (i - (n - 1) / 2)  # side by side
        med = g["median settling time (s)"].values
        lo, hi = g["5% settling time (s)"].values, g["95% settling time (s)"].values
        lab_n = lab if int(g["members"].min()) == int(df["members"].max()) else \
            f"{lab} (first {int(g['members'].min())} members)"
        ax.errorbar(x, med, yerr=[med - lo, hi - med], fmt="o", ms=4, capsize=2, color=f"C{i}", label=lab_n)
    g0 = df[df["method"] == labels[0]].sort_values("λ (s kg⁻¹ m⁻²)")
    ref = g0["median settling time (s)"].values[0] * lams[0] / lams
    ax.loglog(lams, ref, "k--", lw=0.8, label="∝ 1/λ")
    ax.set_xticks(lams, [f"{v:g}" for v in lams])
    ax.minorticks_off()
    ax.set_xlabel("internal friction λ (s kg⁻¹ m⁻²)")
    ax.set_ylabel("settling time (s): median, 5–95 %")
    ax.set_title("time to the flat spin against λ")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    path = outdir / "flat_spin_settling.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
