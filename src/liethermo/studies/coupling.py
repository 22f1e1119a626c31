"""Coupling study: the fully coupled top, whose inertia grows with its entropy,
against the decoupled top, over an ensemble of random initial conditions.

The body (built-in scene ``coupled_egg``: the paper's top with a small heat
capacity) has the inertia 𝕀(S) = 𝕀₀ (1 + α(θ − T₀))², θ = T₀ exp((S − S₀)/c_v),
α = ``body.thermal_expansion`` (K⁻¹), swept from 0 (the decoupled top).  The
friction heats the top, its inertia grows, and the motion changes.  Members
are drawn by :func:`liethermo.initial.initial_conditions` (attitudes uniform
on SO(3), spin directions uniform, |Ω₀| uniform in ``ensemble.spin_range`` ×
|initial.omega|); member i has the same initial condition at every α, so the
coupled and decoupled runs of a member are compared one to one.  Every method
of the study runs every member at every α, except the reference (DOP853 with
substeps), which runs the first ``options.reference_members``.

Per member, on node values (Ω(t_k), Γ_k, S_k; the variational integrators'
node velocity is 𝕀(S_k)⁻¹μ_k):

* **settling time**: the first t at which the mechanical energy above rest,
  E_mech = K + V + |g⃗| (K = ½Ω·𝕀(S)Ω, V = g⃗·Γ, rest at Γ = −g⃗/|g⃗|), falls
  to ``options.settle_fraction`` × its initial value (log-linear between
  nodes).  E_mech only decreases in the continuous model (the total energy
  K + V + U is conserved and U grows);
* **final attitude** at t_end: the tilt (angle of Γ from the resting
  direction −g⃗/|g⃗|), and against the decoupled run (α = 0) of the same
  member and method: the angle between the final Γ, and the angle of the
  rotation R_coupled R_decoupledᵀ between the final attitudes (Γ fixes the
  attitude only up to a turn about the vertical);
* **final temperature** T = −∂L/∂S (= θ at rest) and the inertia factor
  s = 𝕀(S)/𝕀₀ = (1 + α(θ − T₀))² at t_end;
* **energy balance**: E_k − E₀ on node values (the dataset's
  ``energy_error``), relative to E_mech,0 = K₀ + V₀ + |g⃗|: its maximum, its
  final value and its least-squares slope over the second half of the
  horizon (s⁻¹).

Two checks run at α = ``options.check_alpha``: **order** — each method at the
steps ``options.order_h`` over ``options.order_t_end`` against the reference
at the same step (the first ``reference_members`` members), max over nodes and
members of |ΔΩ|/max|Ω_ref|, |ΔΓ| and |ΔS|/max|S − S₀|_ref; and **energy over
a long horizon** — ``options.drift_members`` members at the low viscosity
``options.drift_viscosity`` for ``options.drift_t_end`` (the motion lasts and
the heating goes on), the relative energy error in each half of the horizon
and its slope over the second half.
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
from ..methods import METHODS
from ..kernels.terms import ROLE_LINEAR_FRICTION, ROLE_POTENTIAL, ROLE_THERMAL_COUPLING, key_of
from ..physics import inertia_scale, internal_energy_change, physics_of_scene
from ..simulate import simulate
from .common import (shared_units, status_units, StudyError, cached_point, closing_fact, closing_section, dim_name, expand_sweep,
                     method_overrides, parse_method, point_key,
                     progress_bar, stack_points, start_study, study_history, study_name, study_netcdf_path,
                     study_options, study_scene, write_netcdf_atomic, write_report, write_table)
from .tools import (NODE_VALUES_NOTE, band_text, direction_angle, display_table, drift_fit, energy_errors,
                    observed_orders, quantile_band, rotation_angle, run_spec, settling_time)

EXTRA_KEYS = ()
#: the key swept: how the inertia grows with the temperature (α)
SWEEP_KEY = key_of(ROLE_THERMAL_COUPLING)
DEFAULT_OPTIONS = {
    "t_end": 60.0,               # s
    "settle_fraction": 1e-3,     # settled: E_mech below this fraction of its initial value
    "motion_method": "vi6",      # the method of the key table
    "reference_members": 16,     # members the reference (DOP853) runs
    "trace_members": 4,          # members whose T(t), s(t) are kept
    "check_alpha": 1e-3,         # 1/K, alpha of the order and long-horizon checks
    "order_h": [0.04, 0.02, 0.01, 0.005],  # s
    "order_t_end": 10.0,         # s
    "drift_viscosity": 1e-4,     # kg m-1 s-1
    "drift_t_end": 2000.0,       # s
    "drift_members": 8,
    "drift_nodes": 1000,
}
QUANTILES = np.array([0.05, 0.5, 0.95])
DEG = 180.0 / math.pi


def options(study: dict) -> dict:
    return study_options(study, DEFAULT_OPTIONS, "coupling")


def _multiple(T: float, h: float) -> bool:
    r = T / h
    return abs(r - round(r)) <= 1e-9 * max(1.0, r) and round(r) >= 1


def validate(study: dict) -> None:
    opt = options(study)
    sweep = study.get("sweep", {}) or {}
    if list(sweep) != [SWEEP_KEY]:
        raise StudyError(f"sweep: a coupling study sweeps exactly one key, {SWEEP_KEY!r}")
    alphas = sweep[SWEEP_KEY]
    if any(not isinstance(v, (int, float)) or v < 0 for v in alphas):
        raise StudyError(f"sweep.{SWEEP_KEY}: thermal expansions must be ≥ 0 (1/K)")
    if 0.0 not in [float(a) for a in alphas]:
        raise StudyError(f"sweep.{SWEEP_KEY}: must include 0 (the decoupled top every member is compared with)")
    methods = study.get("methods") or []
    if not methods:
        raise StudyError("methods: a coupling study needs at least one method")
    labels = [parse_method(m)["label"] for m in methods]
    if opt["motion_method"] not in labels:
        raise StudyError(f"options.motion_method: {opt['motion_method']!r} must be one of the study's methods")
    for m in methods:
        sp = parse_method(m)
        if sp["family"] == "vi" and sp["start"] != "legendre":
            raise StudyError(f"methods: {m!r}: the coupled top needs the legendre start")
    for k in ("t_end", "settle_fraction", "check_alpha", "order_t_end", "drift_t_end"):
        if not (isinstance(opt[k], (int, float)) and opt[k] > 0):
            raise StudyError(f"options.{k}: must be a number > 0")
    if not (isinstance(opt["drift_viscosity"], (int, float)) and opt["drift_viscosity"] > 0):
        raise StudyError("options.drift_viscosity: must be > 0 (kg m-1 s-1): the coupled top needs friction")
    if not opt["settle_fraction"] < 1:
        raise StudyError("options.settle_fraction: must be < 1")
    for k in ("reference_members", "trace_members", "drift_members", "drift_nodes"):
        if not (isinstance(opt[k], int) and opt[k] >= 1):
            raise StudyError(f"options.{k}: must be an integer ≥ 1")
    hs = opt["order_h"]
    if not (isinstance(hs, list) and len(hs) >= 2 and all(isinstance(h, (int, float)) and h > 0 for h in hs)):
        raise StudyError("options.order_h: must list at least two steps > 0 (s)")
    for h in hs:
        if not _multiple(float(opt["order_t_end"]), float(h)):
            raise StudyError(f"options.order_t_end = {opt['order_t_end']} must be a multiple of every order_h "
                             f"(h = {h})")
    scene = study_scene(study, {SWEEP_KEY: float(opt["check_alpha"])})
    h = float(scene["integrator"]["h"])
    for k in ("t_end", "drift_t_end"):
        if not _multiple(float(opt[k]), h):
            raise StudyError(f"options.{k} = {opt[k]} must be a multiple of integrator.h = {h}")
    phys = physics_of_scene(scene)
    if float(phys.linear_resistance().max()) <= 0:
        raise StudyError(f"scene: {key_of(ROLE_LINEAR_FRICTION)} must be > 0: without friction nothing heats the top")
    if float(phys.potential_span().max()) == 0.0:
        raise StudyError(f"scene: {key_of(ROLE_POTENTIAL)} must be ≠ 0 (the settling and the tilt are measured "
                         f"from rest)")
    n = int(scene["ensemble"]["members"])
    if opt["trace_members"] > min(n, opt["reference_members"]):
        raise StudyError("options.trace_members: at most min(ensemble.members, options.reference_members)")


def _pad(a: np.ndarray, n: int, fill=np.nan) -> np.ndarray:
    out = np.full((n,) + a.shape[1:], fill, dtype=np.result_type(a.dtype, type(fill)))
    out[:a.shape[0]] = a
    return out


def _ensemble(scene, n: int):
    N = int(scene["ensemble"]["members"])
    phys = physics_of_scene(scene, N).take(slice(0, n))
    om, R = initial_conditions(scene, 0, n)
    return phys, om, R


def _scale(phys, sigma: np.ndarray) -> np.ndarray:
    s = inertia_scale(phys, sigma)
    return np.broadcast_to(np.asarray(s, float), sigma.shape).copy()


def point(scene, spec: dict, opt: dict) -> xr.Dataset:
    """One (α, method) point: per-member settling, final attitude, temperature, inertia, energy."""
    N = int(scene["ensemble"]["members"])
    n = min(N, int(opt["reference_members"])) if spec["method"] == "reference" else N
    h = float(scene["integrator"]["h"])
    steps = int(round(float(opt["t_end"]) / h))
    phys, om, R = _ensemble(scene, n)
    tr = run_spec(phys, om, R, h, steps, spec, attitude=True)
    ok = tr.status == 0
    rest = phys.resting_gamma()
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        e = node_energies(tr)
        emech = phys.mechanical_energy(e["K"], e["V"])
        ratio = emech / emech[:, :1]
        err = energy_errors(tr, om, R)
        rel = err["node"] / err["scale"][:, None]
        half = tr.times.size // 2
        late, _ = drift_fit(tr.times[half:], rel[:, half:])
        s = _scale(phys, tr.sigma)
        gdef = np.nanmax(np.abs(np.linalg.norm(tr.gamma, axis=-1) - 1.0), axis=1)
        arel = np.abs(rel)
        arel[~np.isfinite(arel)] = np.inf
    settle = settling_time(tr.times, ratio, float(opt["settle_fraction"]))
    Gf = tr.gamma[:, -1]
    nt = int(opt["trace_members"])
    data = {
        "settling_time": ("member", _pad(settle, N)),
        "final_gamma": (("member", "axis"), _pad(Gf, N)),
        "final_attitude": (("member", "row", "col"), _pad(tr.attitude[:, -1], N)),
        "final_tilt": ("member", _pad(direction_angle(Gf, rest) * DEG, N)),
        "final_temperature": ("member", _pad(e["T"][:, -1], N)),
        "final_inertia_factor": ("member", _pad(s[:, -1], N)),
        "heat": ("member", _pad(e["dU"][:, -1], N)),
        "mechanical_energy_initial": ("member", _pad(err["scale"], N)),
        "max_relative_energy_error": ("member", _pad(np.where(ok, arel.max(axis=1), np.inf), N)),
        "final_relative_energy_error": ("member", _pad(arel[:, -1], N)),
        "late_energy_drift_rate": ("member", _pad(late, N)),
        "gamma_defect": ("member", _pad(gdef, N)),
        "status": ("member", _pad(tr.status.astype(np.int8), N, np.int8(-1)).astype(np.int8)),
        "temperature_trace": (("trace", "t"), e["T"][:nt]),
        "inertia_factor_trace": (("trace", "t"), s[:nt]),
        "mechanical_energy_ratio_trace": (("trace", "t"), ratio[:nt]),
        "relative_energy_error_quantiles": (("quantile", "t"), np.quantile(arel, QUANTILES, axis=0)),
        "kernel_time": ((), tr.wall_time),
    }
    return xr.Dataset(data, coords={"member": np.arange(N), "trace": np.arange(nt), "t": tr.times,
                                    "quantile": QUANTILES, "axis": ["x", "y", "z"]})


def order_point(scene, specs: list, h: float, opt: dict) -> xr.Dataset:
    """Errors of every non-reference method at step h against the reference at the same step."""
    n = min(int(scene["ensemble"]["members"]), int(opt["reference_members"]))
    steps = int(round(float(opt["order_t_end"]) / h))
    phys, om, R = _ensemble(scene, n)
    ref = simulate(phys, om, R, h, steps, "reference")
    so = np.nanmax(np.abs(ref.omega))
    ss = np.nanmax(np.abs(ref.sigma))
    out = {k: np.full(len(specs), np.nan) for k in ("omega_error", "gamma_error", "entropy_error")}
    for i, sp in enumerate(specs):
        if sp["method"] == "reference":
            continue
        tr = run_spec(phys, om, R, h, steps, sp)
        if np.any(tr.status != 0):
            for k in out:
                out[k][i] = np.inf
            continue
        out["omega_error"][i] = np.max(np.abs(tr.omega - ref.omega)) / so
        out["gamma_error"][i] = np.max(np.abs(tr.gamma - ref.gamma))
        out["entropy_error"][i] = np.max(np.abs(tr.sigma - ref.sigma)) / ss
    data = {k: ("scheme", v) for k, v in out.items()}
    data["state_error"] = ("scheme", np.fmax(np.fmax(out["omega_error"], out["gamma_error"]), out["entropy_error"]))
    return xr.Dataset(data, coords={"scheme": [sp["label"] for sp in specs]})


def drift_point(scene, spec: dict, opt: dict) -> xr.Dataset:
    """Long horizon at low viscosity: the relative energy error in each half, and its late slope."""
    n = min(int(scene["ensemble"]["members"]), int(opt["drift_members"]))
    h = float(scene["integrator"]["h"])
    steps = int(round(float(opt["drift_t_end"]) / h))
    every = max(1, steps // int(opt["drift_nodes"]))
    steps = (steps // every) * every
    phys, om, R = _ensemble(scene, n)
    tr = run_spec(phys, om, R, h, steps, spec, every=every)
    with np.errstate(invalid="ignore", over="ignore"):
        err = energy_errors(tr, om, R)
        rel = err["node"] / err["scale"][:, None]
        heat = internal_energy_change(phys, tr.sigma) / err["scale"][:, None]
        half = tr.times.size // 2
        slope, _ = drift_fit(tr.times[half:], rel[:, half:])
        arel = np.abs(rel)
        arel[~np.isfinite(arel)] = np.inf
    return xr.Dataset({
        "drift_error_first_half": ("drift_member", arel[:, :half + 1].max(axis=1)),
        "drift_error_second_half": ("drift_member", arel[:, half:].max(axis=1)),
        "drift_rate_second_half": ("drift_member", slope),
        "drift_heat_half": ("drift_member", heat[:, half]),
        "drift_heat_end": ("drift_member", heat[:, -1]),
        "drift_error_median": ("drift_node", np.median(arel, axis=0)),
        "drift_time": ("drift_node", tr.times),
        "drift_kernel_time": ((), tr.wall_time),
    }, coords={"drift_member": np.arange(n), "drift_node": np.arange(tr.times.size)})


UNITS = {
    **shared_units('gamma_defect', 'max_relative_energy_error', 'final_relative_energy_error', 'relative_energy_error_quantiles'),
    "settling_time": ("s", "first t with (K + V + |g|)/(K_0 + V_0 + |g|) <= settle_fraction, node values "
                           "(NaN: not settled within t_end or member not run)"),
    "final_gamma": ("1", "Gamma = R^T e3 at t_end"),
    "final_attitude": ("1", "attitude R at t_end"),
    "final_tilt": ("degree", "angle between Gamma at t_end and the resting direction -g/|g|"),
    "final_temperature": ("K", "temperature T = -dL/dS at t_end"),
    "final_inertia_factor": ("1", "I(S)/I0 = (1 + alpha (theta - T0))^2 at t_end"),
    "heat": ("J", "U(S) - U(S_0) at t_end"),
    "mechanical_energy_initial": ("J", "initial mechanical energy above rest E_mech,0 = K_0 + V_0 + |g|"),
    "late_energy_drift_rate": ("s-1", "least-squares slope of (E_k - E_0)/E_mech,0 over the second half of the "
                                      "horizon, node values"),
    "status": status_units(not_run=True),
    "temperature_trace": ("K", "temperature T = -dL/dS of the first members, node values"),
    "inertia_factor_trace": ("1", "inertia factor I(S)/I0 of the first members"),
    "mechanical_energy_ratio_trace": ("1", "(K + V + |g|)/(K_0 + V_0 + |g|) of the first members"),
    "kernel_time": ("s", "kernel wall time of the point"),
    "settling_time_change": ("s", "settling time minus that of the decoupled run (alpha = 0) of the same member "
                                  "and method"),
    "attitude_difference": ("degree", "angle of R R_0^T between the attitudes at t_end of the run and of the "
                                      "decoupled run (alpha = 0) of the same member and method"),
    "gamma_difference": ("degree", "angle between Gamma at t_end of the run and of the decoupled run "
                                   "(alpha = 0) of the same member and method"),
    "omega_error": ("1", "max over nodes and members of |Omega - Omega_ref| / max |Omega_ref|"),
    "gamma_error": ("1", "max over nodes and members of |Gamma - Gamma_ref|"),
    "entropy_error": ("1", "max over nodes and members of |S - S_ref| / max |S_ref - S_0|"),
    "state_error": ("1", "max of omega_error, gamma_error and entropy_error"),
    "drift_error_first_half": ("1", "max |E_k - E_0| / E_mech,0 over the first half of the long low-viscosity run"),
    "drift_error_second_half": ("1", "max |E_k - E_0| / E_mech,0 over the second half of the long low-viscosity "
                                     "run"),
    "drift_rate_second_half": ("s-1", "least-squares slope of (E_k - E_0)/E_mech,0 over the second half of the "
                                      "long low-viscosity run"),
    "drift_heat_half": ("1", "(U(S) - U(S_0)) / E_mech,0 at half the long run's horizon"),
    "drift_heat_end": ("1", "(U(S) - U(S_0)) / E_mech,0 at the end of the long run"),
    "drift_error_median": ("1", "median over members of |E_k - E_0| / E_mech,0 in the long low-viscosity run"),
    "drift_time": ("s", "time t_k of the long low-viscosity run's stored nodes"),
    "drift_kernel_time": ("s", "kernel wall time of the long low-viscosity run"),
}
COORDS = {
    "member": ("1", "ensemble member"),
    "trace": ("1", "traced ensemble member"),
    "quantile": ("1", "quantile over members"),
    "drift_member": ("1", "ensemble member of the long low-viscosity run"),
    "drift_node": ("1", "index of the stored node of the long low-viscosity run"),
    "order_step": ("s", "time step h of the order check"),
}


def run(study: dict, outdir: Path, *, reduced: bool, progress: bool | None, dask: str | None = None,
        history: str | None = None) -> Path:
    s, outdir, opt = start_study(study, outdir, reduced, validate, options)
    specs = [parse_method(m) for m in s["methods"]]
    labels = [sp["label"] for sp in specs]
    points = expand_sweep(s["sweep"])
    t_wall = time.perf_counter()
    a_chk = float(opt["check_alpha"])
    tasks = []
    for pt in points:
        for sp in specs:
            sc = study_scene(s, dict(pt, **method_overrides(sp)))
            tasks.append((point_key({"study": "coupling", "scene": sc, "spec": sp, "opt": opt}), point, (sc, sp, opt)))
    sc_chk = study_scene(s, {SWEEP_KEY: a_chk})
    otasks = [(point_key({"study": "coupling/order", "scene": sc_chk, "specs": specs, "h": float(h), "opt": opt}),
               order_point, (sc_chk, specs, float(h), opt)) for h in opt["order_h"]]
    dtasks = []
    for sp in specs:
        sc = study_scene(s, dict({SWEEP_KEY: a_chk, key_of(ROLE_LINEAR_FRICTION): float(opt["drift_viscosity"])},
                                 **method_overrides(sp)))
        dtasks.append((point_key({"study": "coupling/drift", "scene": sc, "spec": sp, "opt": opt}),
                       drift_point, (sc, sp, opt)))
    alltasks = tasks + otasks + dtasks
    if dask is not None:
        from ..distributed import map_cached_points

        map_cached_points(outdir, alltasks, dask, progress=progress)
    bar = progress_bar(len(alltasks), progress, study_name(s))
    got = []
    try:
        for key, fn, args in alltasks:
            got.append(cached_point(outdir, key, partial(fn, *args)))
            bar.update(1)
    finally:
        bar.close()
    dss, ods, dds = got[:len(tasks)], got[len(tasks):len(tasks) + len(otasks)], got[len(tasks) + len(otasks):]
    allpts = [dict(pt, scheme=sp["label"]) for pt in points for sp in specs]
    ds = stack_points(dss, allpts, [SWEEP_KEY, "scheme"])
    dim = dim_name(SWEEP_KEY)
    # against the decoupled run of the same member and method
    d0 = ds.sel({dim: 0.0})
    ds["settling_time_change"] = ds["settling_time"] - d0["settling_time"]
    ds["attitude_difference"] = xr.apply_ufunc(
        lambda a, b: rotation_angle(a, b) * DEG, ds["final_attitude"], d0["final_attitude"],
        input_core_dims=[["row", "col"], ["row", "col"]])
    ds["gamma_difference"] = xr.apply_ufunc(
        lambda a, b: direction_angle(a, b) * DEG, ds["final_gamma"], d0["final_gamma"],
        input_core_dims=[["axis"], ["axis"]])
    oset = stack_points([o.drop_vars("scheme") for o in ods], [{"order_step": float(h)} for h in opt["order_h"]],
                        ["order_step"]).assign_coords(scheme=labels)
    dset = stack_points([d.drop_vars(["drift_time"]) for d in dds], [{"scheme": lab} for lab in labels], ["scheme"])
    dset["drift_time"] = dds[0]["drift_time"]
    full = xr.merge([ds, oset, dset], compat="override", join="outer")
    for k, (u, ln) in {**UNITS, **COORDS}.items():
        if k in full.variables:
            full[k].attrs.update(units=u, long_name=ln)
    full["t"].attrs.update(units="s", long_name="time since the start of the run, t_k = k h, of the "
                                             "ensemble runs")
    full[dim].attrs.update(units="K-1", long_name="linear thermal expansion alpha (sweep): I(S) = I0 (1 + alpha "
                                                  "(theta - T0))^2")
    full["final_temperature"].attrs["units_metadata"] = "temperature: on_scale"
    full["temperature_trace"].attrs["units_metadata"] = "temperature: on_scale"
    scene0 = study_scene(s, points[0])
    members = int(scene0["ensemble"]["members"])
    full.attrs.update(title="liethermo study: the coupled top (inertia growing with the entropy) against the decoupled top", study=study_name(s), kind="coupling", reduced=int(reduced), members=members,
                      seed=int(scene0["ensemble"]["seed"]), values="node values", t_end=float(opt["t_end"]),
                      settle_fraction=float(opt["settle_fraction"]), check_alpha=a_chk,
                      drift_viscosity=float(opt["drift_viscosity"]), drift_t_end=float(opt["drift_t_end"]))
    nc = write_netcdf_atomic(full, study_netcdf_path(s, outdir),
                             history=study_history("coupling", s, outdir, reduced, history))
    return _report(s, outdir, opt, reduced, ds, oset, dset, specs, labels, scene0, nc, dss,
                   time.perf_counter() - t_wall)


# ----------------------------------------------------------------------------- report

def _ran(ds: xr.Dataset) -> np.ndarray:
    return ds["status"].values >= 0


def _report(s, outdir, opt, reduced, ds, oset, dset, specs, labels, scene0, nc, dss, wall) -> Path:
    import pandas as pd

    dim = dim_name(SWEEP_KEY)
    alphas = [float(a) for a in ds[dim].values]
    mm = opt["motion_method"]
    members = int(scene0["ensemble"]["members"])
    nref = min(members, int(opt["reference_members"]))
    ref_lab = next((sp["label"] for sp in specs if sp["method"] == "reference"), None)

    # key table: per alpha, the motion method
    key_rows, key_disp = [], []
    for a in alphas:
        d = ds.sel({dim: a, "scheme": mm})
        r = _ran(d)
        st = d["settling_time"].values[r]
        dst = d["settling_time_change"].values[r]
        att = d["attitude_difference"].values[r]
        gam = d["gamma_difference"].values[r]
        tilt = d["final_tilt"].values[r]
        T = d["final_temperature"].values[r]
        fac = d["final_inertia_factor"].values[r]
        mx = d["max_relative_energy_error"].values[r]
        row = {"α (K⁻¹)": a, "method": mm, "members": int(r.sum()), "not settled": int(np.isnan(st).sum())}
        for name, v in (("settling time (s)", st), ("Δ settling time vs α = 0 (s)", dst),
                        ("final attitude difference vs α = 0 (deg)", att),
                        ("final Γ difference vs α = 0 (deg)", gam), ("final tilt (deg)", tilt),
                        ("final temperature (K)", T), ("final inertia factor (1)", fac),
                        ("max |ΔE|/E_mech,0 (1)", mx)):
            q = quantile_band(v)
            row.update({f"median {name}": q[1], f"5% {name}": q[0], f"95% {name}": q[2]})
        row["settling later than α = 0 (fraction)"] = float(np.mean(dst > 0)) if a > 0 else float("nan")
        T0 = ds.sel({dim: 0.0, "scheme": mm})["final_temperature"].values[r]
        row["max |T_final − T_final(α = 0)| (K)"] = float(np.nanmax(np.abs(T - T0)))
        key_rows.append(row)
        b = lambda name: band_text(row[f"median {name}"], row[f"5% {name}"], row[f"95% {name}"])  # noqa: E731
        key_disp.append({
            "α (K⁻¹)": a, "members": row["members"],
            "settling time (s)": b("settling time (s)"),
            "Δ settling vs α = 0 (s)": b("Δ settling time vs α = 0 (s)") if a > 0 else "—",
            "later": f"{int(np.sum(dst > 0))}/{dst.size}" if a > 0 else "—",
            "final attitude diff. vs α = 0 (deg)": b("final attitude difference vs α = 0 (deg)") if a > 0 else "—",
            "final T (K)": b("final temperature (K)"),
            "final 𝕀(S)/𝕀₀ (1)": b("final inertia factor (1)"),
            "final tilt (deg), median": row["median final tilt (deg)"],
        })
    kdf = pd.DataFrame(key_rows)
    write_table(kdf, outdir, "coupling", "Coupling")

    # methods: agreement with the reference and energy
    mrows = []
    for a in alphas:
        ref = ds.sel({dim: a, "scheme": ref_lab}) if ref_lab else None
        for lab in labels:
            d = ds.sel({dim: a, "scheme": lab})
            r = _ran(d)
            row = {"α (K⁻¹)": a, "method": lab, "members": int(r.sum()),
                   "median settling time (s)": quantile_band(d["settling_time"].values[r])[1],
                   "median final temperature (K)": quantile_band(d["final_temperature"].values[r])[1],
                   "median max|ΔE|/E_mech,0 (1)": float(np.median(d["max_relative_energy_error"].values[r])),
                   "max max|ΔE|/E_mech,0 (1)": float(np.max(d["max_relative_energy_error"].values[r])),
                   "median |late drift rate| (s⁻¹)": float(np.nanmedian(np.abs(d["late_energy_drift_rate"].values[r]))),
                   "max ||Γ|−1| (1)": float(np.nanmax(d["gamma_defect"].values[r])),
                   "failed": int((d["status"].values[r] > 0).sum())}
            if ref is not None and lab != ref_lab:
                m = _ran(ref)
                row["max |t_settle − ref| (s)"] = float(np.nanmax(np.abs(d["settling_time"].values[m]
                                                                          - ref["settling_time"].values[m])))
                row["max |T_final − ref| (K)"] = float(np.nanmax(np.abs(d["final_temperature"].values[m]
                                                                         - ref["final_temperature"].values[m])))
                row["max final attitude vs ref (deg)"] = float(np.nanmax(rotation_angle(
                    d["final_attitude"].values[m], ref["final_attitude"].values[m]) * DEG))
            else:
                row.update({"max |t_settle − ref| (s)": float("nan"), "max |T_final − ref| (K)": float("nan"),
                            "max final attitude vs ref (deg)": float("nan")})
            mrows.append(row)
    mdf = pd.DataFrame(mrows)
    mtable = write_table(mdf, outdir, "coupling_methods",
                         f"Every method: agreement with the reference (its {nref} members) and the energy balance "
                         f"(node values, t_end = {float(opt['t_end']):g} s)")

    # order check
    orows = []
    hs = [float(h) for h in oset["order_step"].values]
    for lab, sp in zip(labels, specs):
        if sp["method"] == "reference":
            continue
        e = oset["state_error"].sel(scheme=lab).values
        p = observed_orders(hs, e)
        for i, h in enumerate(hs):
            orows.append({"method": lab, "h (s)": h, "declared order": METHODS[sp["method"]].order(
                sp["start"] or "legendre", sp["friction"] or "trapezoid"),
                "Ω error (1)": float(oset["omega_error"].sel(scheme=lab).values[i]),
                "Γ error (1)": float(oset["gamma_error"].sel(scheme=lab).values[i]),
                "S error (1)": float(oset["entropy_error"].sel(scheme=lab).values[i]),
                "state error (1)": float(e[i]), "observed order": float(p[i - 1]) if i else float("nan")})
    odf = pd.DataFrame(orows)
    otable = write_table(odf, outdir, "coupling_order",
                         f"Order check against the reference at the same step (α = {float(opt['check_alpha']):g} K⁻¹, "
                         f"{nref} members, t_end = {float(opt['order_t_end']):g} s, node values)")

    # long-horizon energy
    drows = []
    for lab in labels:
        d = dset.sel(scheme=lab)
        drows.append({"method": lab, "members": int(d.sizes["drift_member"]),
                      "median max|ΔE|/E_mech,0, first half (1)": float(np.median(d["drift_error_first_half"].values)),
                      "median max|ΔE|/E_mech,0, second half (1)": float(np.median(d["drift_error_second_half"].values)),
                      "median |slope|, second half (s⁻¹)": float(np.nanmedian(np.abs(d["drift_rate_second_half"].values))),
                      "median heat/E_mech,0 at t_end/2 (1)": float(np.median(d["drift_heat_half"].values)),
                      "median heat/E_mech,0 at t_end (1)": float(np.median(d["drift_heat_end"].values))})
    ddf = pd.DataFrame(drows)
    dtable = write_table(ddf, outdir, "coupling_energy",
                         f"Energy over a long horizon at low viscosity (μ = {float(opt['drift_viscosity']):g} "
                         f"kg m⁻¹ s⁻¹, α = {float(opt['check_alpha']):g} K⁻¹, t_end = "
                         f"{float(opt['drift_t_end']):g} s, h = {float(scene0['integrator']['h']):g} s, node values)")

    _settling_figure(ds, labels, mm, outdir)
    _trace_figure(ds, opt, mm, outdir)
    _attitude_figure(ds, mm, outdir)
    _energy_figure(ds, dset, labels, opt, outdir)
    phys0 = physics_of_scene(scene0)
    sections = [
        display_table(pd.DataFrame(key_disp), f"Coupled against decoupled top ({mm}, {members} members, "
                      f"t_end = {float(opt['t_end']):g} s, node values; median [5 %, 95 %])", "coupling"),
        _finding(kdf, mdf, odf, ddf, opt, labels, ref_lab),
        f"Scene `{scene0['scene']['name']}`: the paper's top (principal moments 𝕀₀ = "
        f"{', '.join(f'{x:.4g}' for x in phys0.inertia[0])} kg m², Stokes friction c = "
        f"{float(phys0.linear_resistance()[0, 0]):.4g} N m s, |g⃗| = m g ℓ = {0.5 * float(phys0.potential_span()[0]):.4g} "
        f"N m) with heat capacity c_v = {float(phys0.heat_capacity[0]):.4g} J/K and 𝕀(S) = 𝕀₀(1 + α(θ − T₀))², "
        f"T₀ = {float(phys0.T0[0]):g} K. {members} members, random attitudes and spins (|Ω₀| in "
        f"{scene0['ensemble']['spin_range']} × {np.linalg.norm(scene0['initial']['omega']):.4g} rad/s, seed "
        f"{int(scene0['ensemble']['seed'])}), the same at every α; h = {float(scene0['integrator']['h']):g} s, "
        f"t_end = {float(opt['t_end']):g} s; the reference (DOP853 with substeps) on the first {nref} members.",
        "**Definitions.** *Settling time*: first t with E_mech(t) ≤ "
        f"{float(opt['settle_fraction']):g} E_mech(0), E_mech = K + V + |g⃗| the mechanical energy above rest "
        "(K = ½Ω·𝕀(S)Ω), log-linear between nodes; E_mech only falls in the continuous model. *Δ settling*: "
        "settling time at α minus that of the same member at α = 0 (same method). *Final attitude difference*: "
        "the angle of R_α R_0ᵀ at t_end (Γ = Rᵀe₃ fixes the attitude only up to a turn about the vertical; the "
        "angle between the final Γ is in the CSV). *Final tilt*: angle of Γ from the resting direction −g⃗/|g⃗|. "
        "*Final T*: T = −∂L/∂S at t_end (= θ at rest). *Inertia factor*: 𝕀(S)/𝕀₀ = (1 + α(θ − T₀))². *Energy*: "
        "E = K + V + U(S), conserved by the continuous model; E_k − E₀ on node values relative to E_mech,0.",
        "*Temperature while the top spins*: T = −∂L/∂S = θ − φφ′ Ω·𝕀₀Ω (φ = 1 + α(θ − T₀), φ′ = αθ/c_v) is below "
        "θ while the coupled top moves fast, which is why its temperature can dip at the start (figure); at "
        "rest T = θ.",
        "**Which energy.** Node values (`energy_error`, `liethermo.dataset.node_energies`): K_k = ½Ω_k·𝕀(S_k)Ω_k "
        "with the variational integrators' node velocity Ω_k = 𝕀(S_k)⁻¹μ_k from the node momentum μ_k. "
        + NODE_VALUES_NOTE,
        mtable, otable, dtable,
        "![settling time against alpha](coupling_settling.png)\n\n![temperature and inertia](coupling_traces.png)"
        "\n\n![final attitude difference](coupling_attitude.png)\n\n![energy error](coupling_energy.png)",
        f"netCDF: `{nc.name}`. Study wall time {wall:.1f} s (kernels of the ensemble runs "
        f"{sum(float(d['kernel_time']) for d in dss):.1f} s).",
        _closing(ds, mdf, labels, ref_lab, dim, scene0, outdir),
    ]
    return write_report(outdir, "Coupling: the top whose inertia grows with its entropy, against the decoupled top"
                        + (" (reduced)" if reduced else ""), sections)


def _closing(ds, mdf, labels, ref_lab, dim, scene0, outdir) -> str:
    """Cheapest method per level of the final-attitude disagreement with the
    reference (worst α), at the kernel wall time per member of the ensemble runs."""
    pts = []
    for lab in labels:
        if lab == ref_lab:
            continue
        g = mdf[mdf["method"] == lab]
        d = ds.sel(scheme=lab)
        cost = sum(float(d.sel({dim: a})["kernel_time"]) / max(int(r), 1)
                   for a, r in zip(g["α (K⁻¹)"], g["members"]))
        pts.append({"method": lab, "error": float(g["max final attitude vs ref (deg)"].max())
                    if not g["failed"].any() else float("inf"), "cost": cost,
                    "setting": f"h = {float(scene0['integrator']['h']):g} s"})
    if ref_lab is None:
        return closing_fact("coupled top", "Without a reference run the study measures no error: the table would "
                            "need the reference among the methods.")
    return closing_section(pts, regime="coupled top, every α of the sweep", unit="s",
                           error="max over α and the reference's members of the final attitude difference from "
                                 "the reference (deg)",
                           cost="kernel wall time per member of the ensemble runs, summed over α (s)", outdir=outdir)


def _finding(kdf, mdf, odf, ddf, opt, labels, ref_lab) -> str:
    lines = ["**Findings (node values).**", ""]
    k = kdf[kdf["α (K⁻¹)"] > 0]
    mm = opt["motion_method"]
    for _, r in k.iterrows():
        d, f = r["median Δ settling time vs α = 0 (s)"], r["settling later than α = 0 (fraction)"]
        base = float(kdf[kdf["α (K⁻¹)"] == 0]["median settling time (s)"].iloc[0])
        lines.append(
            f"- α = {r['α (K⁻¹)']:g} K⁻¹ ({mm}): the top settles {'later' if d > 0 else 'earlier'} by "
            f"{abs(d):.3g} s in the median ({100 * d / base:+.2g} % of {base:.4g} s; 5–95 %: "
            f"{r['5% Δ settling time vs α = 0 (s)']:.3g} to {r['95% Δ settling time vs α = 0 (s)']:.3g} s), "
            f"{100 * f:.0f} % of members later; final temperature {r['median final temperature (K)']:.4g} K, "
            f"inertia up {100 * (r['median final inertia factor (1)'] - 1):.2f} % (median); final attitude "
            f"{r['median final attitude difference vs α = 0 (deg)']:.2g}° from the decoupled one (median; 95 %: "
            f"{r['95% final attitude difference vs α = 0 (deg)']:.2g}°).")
    r0 = kdf[kdf["α (K⁻¹)"] == 0].iloc[0]
    dT = kdf["max |T_final − T_final(α = 0)| (K)"].max()
    lines.append(f"- Final temperature: {r0['median final temperature (K)']:.4g} K (median, α = 0); member by member "
                 f"the coupled top ends within {dT:.2g} K of the decoupled one at every α — the heat is the same "
                 "mechanical energy above rest (the top ends at rest in both); the coupling changes how fast it is "
                 "released, not how much.")
    if ref_lab is not None:
        g = mdf[mdf["method"] != ref_lab]
        lines.append("- Against the reference, member by member: settling time within " + "; ".join(
            f"{lab} {g[g['method'] == lab]['max |t_settle − ref| (s)'].max():.2g} s" for lab in labels
            if lab != ref_lab) + " (max over α and the reference's members).")
        big = g[g["max |t_settle − ref| (s)"] > 0.1 * abs(k["median Δ settling time vs α = 0 (s)"]).min()] \
            if len(k) else g.iloc[0:0]
        if len(big):
            lines.append("  Where that exceeds a tenth of the smallest median Δ settling time, the method's own error "
                         "is not small against the effect it measures: " + ", ".join(sorted(set(big["method"]))) + ".")
    vi = [lab for lab in labels if parse_method(lab)["family"] == "vi"]
    if vi and ref_lab is not None:
        ref_err = mdf[mdf["method"] == ref_lab]["max max|ΔE|/E_mech,0 (1)"].max()
        lines.append("- Energy (max over members and α of max_k |E_k − E₀|/E_mech,0): " + "; ".join(
            f"{lab} {mdf[mdf['method'] == lab]['max max|ΔE|/E_mech,0 (1)'].max():.1e}" for lab in labels)
            + f". The reference conserves the coupled model's energy to {ref_err:.1e}.")
    if len(ddf):
        lines.append(f"- Long horizon (μ = {float(opt['drift_viscosity']):g} kg m⁻¹ s⁻¹, "
                     f"{float(opt['drift_t_end']):g} s): median max relative energy error in the first half → "
                     "second half: " + "; ".join(
                         f"{r['method']} {r['median max|ΔE|/E_mech,0, first half (1)']:.1e} → "
                         f"{r['median max|ΔE|/E_mech,0, second half (1)']:.1e}" for _, r in ddf.iterrows())
                     + f"; meanwhile the heat grows from {ddf['median heat/E_mech,0 at t_end/2 (1)'].iloc[0]:.2f} to "
                     f"{ddf['median heat/E_mech,0 at t_end (1)'].iloc[0]:.2f} of E_mech,0.")
        for _, r in ddf.iterrows():
            if parse_method(r["method"])["family"] != "vi":
                continue
            a, b = r["median max|ΔE|/E_mech,0, first half (1)"], r["median max|ΔE|/E_mech,0, second half (1)"]
            hb = r["median heat/E_mech,0 at t_end (1)"] / max(r["median heat/E_mech,0 at t_end/2 (1)"], 1e-300)
            if b <= a * 1.05:
                verdict = "bounded: no larger in the second half"
            elif b / a <= hb * 1.05:
                verdict = (f"grows by {b / a:.2f}× while the heat grows by {hb:.2f}×: no faster than the heat "
                           "released (an O(h^p) error of the dissipated energy), no drift of its own")
            else:
                verdict = f"grows by {b / a:.2f}×, faster than the heat ({hb:.2f}×): a drift"
            lines.append(f"  {r['method']}: {verdict}.")
    for lab in labels:
        g = odf[odf["method"] == lab].dropna(subset=["observed order"])
        if len(g):
            lines.append(f"- Order check, {lab} (declared {int(g['declared order'].iloc[0])}): observed "
                         + ", ".join(f"{p:.2f}" for p in g["observed order"]) + " between the steps "
                         + ", ".join(f"{h:g}" for h in odf[odf["method"] == lab]["h (s)"]) + " s.")
    return "\n".join(lines)


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _settling_figure(ds, labels, mm, outdir: Path) -> Path:
    plt = _plt()
    dim = dim_name(SWEEP_KEY)
    alphas = np.array([float(a) for a in ds[dim].values])
    x = alphas * 1e3
    fig, (a, b) = plt.subplots(1, 2, figsize=(11.0, 4.4), layout="constrained")
    dx = 0.012 * (x.max() - x.min() if x.max() > x.min() else 1.0)
    n = len(labels)
    for i, lab in enumerate(labels):
        q = np.array([quantile_band(ds["settling_time"].sel({dim: al, "scheme": lab}).values) for al in alphas])
        nm = int((ds["status"].sel({dim: alphas[0], "scheme": lab}).values >= 0).sum())
        name = lab if nm == ds.sizes["member"] else f"{lab} (first {nm} members)"
        a.errorbar(x + dx * (i - (n - 1) / 2), q[:, 1], yerr=[q[:, 1] - q[:, 0], q[:, 2] - q[:, 1]], fmt="o",
                   ms=4, capsize=2, color=f"C{i}", label=name)
    a.set_xlabel("thermal expansion α (10⁻³ K⁻¹)")
    a.set_ylabel("settling time (s): median, 5–95 %")
    a.set_title("settling time against α")
    a.grid(True, alpha=0.3)
    a.legend(fontsize=8)
    q = np.array([quantile_band(ds["settling_time_change"].sel({dim: al, "scheme": mm}).values) for al in alphas])
    b.plot(x, q[:, 1], "o-", color="C0", label=f"{mm}: median")
    b.fill_between(x, q[:, 0], q[:, 2], color="C0", alpha=0.2, lw=0, label="5–95 % of members")
    b.axhline(0.0, color="k", lw=0.8)
    b.set_xlabel("thermal expansion α (10⁻³ K⁻¹)")
    b.set_ylabel("settling time − same member's at α = 0 (s)")
    b.set_title("change of the settling time, member by member")
    b.grid(True, alpha=0.3)
    b.legend(fontsize=8, loc="upper left")
    path = outdir / "coupling_settling.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _trace_figure(ds, opt, mm, outdir: Path) -> Path:
    plt = _plt()
    dim = dim_name(SWEEP_KEY)
    alphas = [float(a) for a in ds[dim].values]
    a_chk = min(alphas, key=lambda v: abs(v - float(opt["check_alpha"])) if v > 0 else math.inf)
    d = ds.sel({dim: a_chk, "scheme": mm})
    d0 = ds.sel({dim: 0.0, "scheme": mm})
    t = ds["t"].values
    fig, (a, b) = plt.subplots(1, 2, figsize=(11.0, 4.4), layout="constrained")
    for i in range(ds.sizes["trace"]):
        a.plot(t, d["temperature_trace"].values[i], color=f"C{i}", lw=1.3)
        a.plot(t, d0["temperature_trace"].values[i], color=f"C{i}", lw=1.0, ls="--")
        b.plot(t, d["inertia_factor_trace"].values[i], color=f"C{i}", lw=1.3, label=f"member {i}")
    a.plot([], [], color="k", lw=1.3, label=f"coupled, α = {a_chk:g} K⁻¹")
    a.plot([], [], color="k", lw=1.0, ls="--", label="decoupled, α = 0")
    a.set_xlabel("t (s)")
    a.set_ylabel("temperature T = −∂L/∂S (K)")
    a.set_title(f"{mm}: temperature of {ds.sizes['trace']} members (one colour each)", fontsize=10)
    a.grid(True, alpha=0.3)
    a.legend(fontsize=8, loc="lower right")
    b.set_xlabel("t (s)")
    b.set_ylabel("inertia factor 𝕀(S)/𝕀₀ (1)")
    b.set_title(f"{mm}: inertia factor, α = {a_chk:g} K⁻¹", fontsize=10)
    b.grid(True, alpha=0.3)
    b.legend(fontsize=8, loc="lower right")
    path = outdir / "coupling_traces.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _attitude_figure(ds, mm, outdir: Path) -> Path:
    plt = _plt()
    dim = dim_name(SWEEP_KEY)
    alphas = [float(a) for a in ds[dim].values if float(a) > 0]
    fig, (a, b) = plt.subplots(1, 2, figsize=(11.0, 4.4), layout="constrained")
    for ax, var, what in ((a, "attitude_difference", "angle of R_α R_0ᵀ at t_end (deg)"),
                          (b, "gamma_difference", "angle between Γ_α and Γ_0 at t_end (deg)")):
        vals = [ds[var].sel({dim: al, "scheme": mm}).values for al in alphas]
        allv = np.concatenate([v[np.isfinite(v) & (v > 0)] for v in vals]) if vals else np.array([])
        if allv.size:
            bins = np.geomspace(allv.min() * 0.9, allv.max() * 1.1, 25)
            for i, (al, v) in enumerate(zip(alphas, vals)):
                v = v[np.isfinite(v) & (v > 0)]
                ax.hist(v, bins=bins, histtype="step", lw=1.4, color=f"C{i}", label=f"α = {al:g} K⁻¹")
            ax.set_xscale("log")
            ax.legend(fontsize=8)
        ax.set_xlabel(what)
        ax.set_ylabel("members")
        ax.yaxis.get_major_locator().set_params(integer=True)
        ax.grid(True, alpha=0.3)
    a.set_title(f"{mm}: final attitude, coupled vs decoupled", fontsize=10)
    b.set_title(f"{mm}: final Γ, coupled vs decoupled", fontsize=10)
    path = outdir / "coupling_attitude.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _energy_figure(ds, dset, labels, opt, outdir: Path) -> Path:
    plt = _plt()
    dim = dim_name(SWEEP_KEY)
    alphas = [float(a) for a in ds[dim].values]
    a_chk = min(alphas, key=lambda v: abs(v - float(opt["check_alpha"])) if v > 0 else math.inf)
    t = ds["t"].values
    ok = t > 0
    fig, (a, b) = plt.subplots(1, 2, figsize=(11.0, 4.4), layout="constrained")
    for i, lab in enumerate(labels):
        med = ds["relative_energy_error_quantiles"].sel({dim: a_chk, "scheme": lab, "quantile": 0.5}).values
        a.semilogy(t[ok], np.clip(med[ok], 1e-17, None), color=f"C{i}", lw=1.3, label=lab)
        td = dset["drift_time"].values
        okd = td > 0
        b.semilogy(td[okd], np.clip(dset["drift_error_median"].sel(scheme=lab).values[okd], 1e-17, None),
                   color=f"C{i}", lw=1.3)
    a.set_title(f"α = {a_chk:g} K⁻¹, μ = scene's, median over members", fontsize=10)
    b.set_title(f"long horizon: μ = {float(opt['drift_viscosity']):g} kg m⁻¹ s⁻¹, α = "
                f"{float(opt['check_alpha']):g} K⁻¹, median", fontsize=10)
    for ax in (a, b):
        ax.set_xlabel("t (s)")
        ax.set_ylabel("|E_k − E_0| / E_mech,0 (1), node values")
        ax.grid(True, which="both", alpha=0.3)
    fig.legend(*a.get_legend_handles_labels(), loc="outside lower center", ncol=len(labels), fontsize=8)
    path = outdir / "coupling_energy.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
