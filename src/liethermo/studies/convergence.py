"""Convergence study: observed orders per variable and method against the reference.

For each sweep point (any scene keys; often none) and each method spec
(``vi`` = legendre start, ``vi:node:explicit`` = the paper's choices,
``vi:staggered``, ``vi:endpoint``, ``vi4``, ``vi6``, ``rk2``, ``rk4``), the
scene is integrated to ``t_end`` with h = h0, h0/2, …, h0/2^(levels−1) and
compared at the common times t_j = j·h0 with the high-accuracy reference
(fixed-step DOP853, ~1e-15), on NODE values for every method:

* Ω: max_j |Ω(t_k) − Ω_ref(t_k)|, with Ω(t_k) the node velocity (for the
  variational integrators 𝕀(S_k)⁻¹μ_k from the node momentum);
* Γ: max_j |Γ_k − Γ_ref(t_k)|;  S: max_j |S_k − S_ref(t_k)|;
* total energy: max_j |E_k − E_ref(t_k)|, E_k from the node values.

The observed order is the least-squares slope of log(error) against log(h)
over the levels from the coarsest down to the round-off floor (a level
whose error is below ``floor_rel`` × the variable's scale, or that no longer
decreases, ends the fit); the error constant is C in error ≈ C h^p.
"""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path

import numpy as np
import xarray as xr

from ..dataset import status_flags
from ..initial import initial_conditions
from ..methods import METHODS, ORDER_TOLERANCE, ORDER_TOLERANCE_REL, judge_order
from ..physics import physics_of_scene
from ..simulate import simulate
from .common import (study_options, StudyError, cached_point, dim_name, expand_sweep, parse_method, point_is_cached, point_key,
                     progress_bar, stack_points, study_name, study_netcdf_path, study_scene,
                     write_netcdf_atomic, write_report, write_table, start_study, study_history,
                     closing_section)
from .tools import NODE_VALUES_NOTE, energy_errors, fit_order, run_spec

EXTRA_KEYS = ()
VARIABLES = ("omega", "gamma", "entropy", "total_energy")
UNITS = {"omega": "rad s-1", "gamma": "1", "entropy": "J K-1", "total_energy": "J"}
TITLES = {"omega": "body angular velocity Ω", "gamma": "gravity direction Γ", "entropy": "entropy S",
          "total_energy": "total energy E"}
MARKERS = ("o", "s", "^", "v", "D", "P", "X", "*")
LINESTYLES = ("-", "--", "-.", ":")
DEFAULT_OPTIONS = {"h0": 0.1, "levels": 7, "t_end": 5.0, "floor_rel": 1e-12}


def options(study: dict) -> dict:
    return study_options(study, DEFAULT_OPTIONS, "convergence")


def validate(study: dict) -> None:
    opt = options(study)
    if not (isinstance(opt["levels"], int) and opt["levels"] >= 5):
        raise StudyError(f"options.levels: must be an integer ≥ 5 (h halving over ≥ 5 levels), got {opt['levels']!r}")
    n0 = opt["t_end"] / opt["h0"]
    if opt["h0"] <= 0 or opt["t_end"] <= 0 or abs(n0 - round(n0)) > 1e-9 or round(n0) < 1:
        raise StudyError("options.t_end: must be a positive multiple of options.h0")
    if not study.get("methods"):
        raise StudyError("methods: a convergence study needs at least one method")


def _levels(opt) -> list[float]:
    return [opt["h0"] / 2**i for i in range(opt["levels"])]


def _reference(scene, opt: dict) -> xr.Dataset:
    """Reference values at every t = j·h_f (h_f = finest h / 2) up to t_end + h0."""
    h_f = _levels(opt)[-1] / 2
    n = int(round((opt["t_end"] + opt["h0"]) / h_f))
    om0, R0 = initial_conditions(scene, 0, 1)
    phys = physics_of_scene(scene)
    tr = simulate(phys, om0, R0, h_f, n, "reference")
    dE = energy_errors(tr, om0, R0)["node"]
    return xr.Dataset({"omega": (("t", "axis"), tr.omega[0]), "gamma": (("t", "axis"), tr.gamma[0]),
                       "sigma": (("t",), tr.sigma[0]), "energy_error": (("t",), dE[0]),
                       "status": ((), int(tr.status[0]))},
                      coords={"t": tr.times}, attrs={"h_fine": h_f, "substeps": tr.reference_substeps})


def _errors(scene, spec: dict, h: float, opt: dict, ref: xr.Dataset) -> xr.Dataset:
    """Errors of one method spec at one h on node values (max over the common times j·h0)."""
    steps = int(round(opt["t_end"] / h))
    every = int(round(opt["h0"] / h))
    om0, R0 = initial_conditions(scene, 0, 1)
    phys = physics_of_scene(scene)
    t0 = time.perf_counter()
    tr = run_spec(phys, om0, R0, h, steps, spec, every=every)
    wall = time.perf_counter() - t0
    om = tr.omega[0]
    dE = energy_errors(tr, om0, R0)["node"][0]
    h_f = float(ref.attrs["h_fine"])
    i_ref = np.rint(tr.times[1:] / h_f).astype(int)  # t = j h0, j ≥ 1
    r = {k: ref[k].values for k in ("omega", "gamma", "sigma", "energy_error")}
    err = {
        "omega": np.max(np.linalg.norm(om[1:] - r["omega"][i_ref], axis=-1)),
        "gamma": np.max(np.linalg.norm(tr.gamma[0][1:] - r["gamma"][i_ref], axis=-1)),
        "entropy": np.max(np.abs(tr.sigma[0][1:] - r["sigma"][i_ref])),
        "total_energy": np.max(np.abs(dE[1:] - r["energy_error"][i_ref])),
    }
    if tr.status[0] != 0:
        err = {k: np.inf for k in err}
    data = {f"error_{k}": ((), float(v)) for k, v in err.items()}
    # the final state (node values)
    data["omega"] = (("axis",), om[-1])
    data["gamma"] = (("axis",), tr.gamma[0][-1])
    data["entropy"] = ((), float(scene["thermo"]["S0"] + tr.sigma[0][-1]))
    data["energy_error"] = ((), float(dE[-1]))
    data["status"] = ((), int(tr.status[0]))
    data["wall_time"] = ((), wall)
    data["kernel_time"] = ((), tr.wall_time)
    return xr.Dataset(data, coords={"axis": ["x", "y", "z"]})


def _dask_points(outdir, dask, progress, opt, specs, hs, points, scenes, ref_keys, err_keys) -> None:
    """Compute the missing points as Dask tasks into the cache: the references
    first, then the errors (each needs its sweep point's reference)."""
    from ..distributed import client_for, map_cached_points

    with client_for(dask) as client:
        map_cached_points(outdir, [(k, _reference, (sc, opt)) for k, sc in zip(ref_keys, scenes)], client,
                          progress=progress)
        tasks = []
        for pt, scene, ref_key, ekeys in zip(points, scenes, ref_keys, err_keys):
            todo = [(i, h) for i in range(len(specs)) for h in hs if not point_is_cached(outdir, ekeys[i, h])]
            if not todo:
                continue
            ref = cached_point(outdir, ref_key, partial(_reference, scene, opt))
            if int(ref["status"]) != 0:
                raise RuntimeError(f"the reference failed at sweep point {pt}")
            tasks += [(ekeys[i, h], _errors, (scene, specs[i], h, opt, ref)) for i, h in todo]
        map_cached_points(outdir, tasks, client, progress=progress)


def run(study: dict, outdir: Path, *, reduced: bool, progress: bool | None, dask: str | None = None,
        history: str | None = None) -> Path:
    study, outdir, opt = start_study(study, outdir, reduced, validate, options)
    hs = _levels(opt)
    specs = [parse_method(m) for m in study["methods"]]
    points = expand_sweep(study.get("sweep"))
    keys = list(points[0])
    per_point = []
    tables = []
    t_start = time.perf_counter()
    scenes = [study_scene(study, pt) for pt in points]
    ref_keys = [point_key({"ref": pt, "opt": opt, "scene": scene}) for pt, scene in zip(points, scenes)]
    err_keys = [{(i, h): point_key({"pt": pt, "spec": spec, "h": h, "opt": opt, "scene": scene})
                 for i, spec in enumerate(specs) for h in hs} for pt, scene in zip(points, scenes)]
    if dask is not None:
        _dask_points(outdir, dask, progress, opt, specs, hs, points, scenes, ref_keys, err_keys)
    bar = progress_bar(len(points) * (1 + len(specs) * len(hs)), progress, f"{study_name(study)} points")
    try:
        for pt, scene, ref_key, ekeys in zip(points, scenes, ref_keys, err_keys):
            ref = cached_point(outdir, ref_key, partial(_reference, scene, opt))
            bar.update(1)
            if int(ref["status"]) != 0:
                raise RuntimeError(f"the reference failed at sweep point {pt}")
            by_method = []
            for i, spec in enumerate(specs):
                by_h = []
                for h in hs:
                    by_h.append(cached_point(outdir, ekeys[i, h], partial(_errors, scene, spec, h, opt, ref)))
                    bar.update(1)
                by_method.append(xr.concat(by_h, dim="h", data_vars="all", coords="minimal", compat="override"))
            ds = xr.concat(by_method, dim="scheme", data_vars="all", coords="minimal", compat="override")
            ds = ds.assign_coords(scheme=[s["label"] for s in specs], h=hs)
            scales = {"omega": float(np.abs(ref["omega"]).max()), "gamma": 1.0,
                      "entropy": float(np.abs(ref["sigma"]).max()) or 1.0,
                      "total_energy": float(np.abs(ref["sigma"]).max() * float(scene["thermo"]["T0"])
                                            + np.abs(ref["energy_error"]).max()) or 1.0}
            # total energy: its natural scale is the energy that moves (≈ mechanical energy)
            rows = []
            orders = {v: [] for v in VARIABLES}
            consts = {v: [] for v in VARIABLES}
            nused = {v: [] for v in VARIABLES}
            for i, spec in enumerate(specs):
                m = METHODS[spec["method"]]
                vi = m.family == "vi"
                row = {"method": spec["label"], "start": spec["start"] if vi else "—",
                       "friction": spec["friction"] if vi else "—",
                       "entropy update": spec["entropy"] if vi else "—",
                       "declared order": m.order(spec["start"] or "legendre", spec["friction"] or "trapezoid")}
                for v in VARIABLES:
                    p_, c_, n_ = fit_order(hs, ds[f"error_{v}"].values[i], scales[v], opt["floor_rel"])
                    orders[v].append(p_)
                    consts[v].append(c_)
                    nused[v].append(n_)
                    row[f"order {v}"] = p_
                for v in VARIABLES:
                    row[f"C {v}"] = consts[v][-1]
                row["levels fitted (Omega, Gamma, S, E)"] = ", ".join(str(nused[v][-1]) for v in VARIABLES)
                rows.append(row)
            for v in VARIABLES:
                ds[f"observed_order_{v}"] = (("scheme",), np.array(orders[v]))
                ds[f"error_constant_{v}"] = (("scheme",), np.array(consts[v]))
                ds[f"levels_fitted_{v}"] = (("scheme",), np.array(nused[v], dtype=np.int64))
            per_point.append(ds)
            if len(per_point) == 1:
                first_scales = scales
            label = ", ".join(f"{k} = {v}" for k, v in pt.items()) or "base scene"
            suffix = ("_" + point_key(pt)[:8]) if keys else ""
            tables.append(write_table(rows, outdir, f"orders{suffix}",
                                      f"Observed orders and error constants ({label}; error ≈ C h^p)"))
            err_rows = []
            for i, spec in enumerate(specs):
                for j, h in enumerate(hs):
                    err_rows.append({"method": spec["label"], "h (s)": h,
                                     **{f"error {v} ({UNITS[v]})": float(ds[f"error_{v}"].values[i, j])
                                        for v in VARIABLES}})
            tables.append(write_table(err_rows, outdir, f"errors{suffix}", f"Errors per level ({label})"))
    finally:
        bar.close()
    ds = stack_points(per_point, points, keys) if keys else per_point[0]
    for v in VARIABLES:
        ds[f"error_{v}"].attrs.update(units=UNITS[v], long_name=f"max over t = j h0 of the error in {v} "
                                      "against the reference")
        ds[f"observed_order_{v}"].attrs.update(units="1", long_name=f"observed order of convergence of {v}")
        ds[f"error_constant_{v}"].attrs.update(units=UNITS[v], long_name=f"C in error_{v} = C h^p")
        ds[f"levels_fitted_{v}"].attrs.update(units="1", long_name=f"number of levels h in the fit of the "
                                              f"order of {v}")
    ds["status"].attrs.update(units="1", long_name="status of the run at this h",
                              **status_flags(ds["status"].dtype))
    ds["wall_time"].attrs.update(units="s", long_name="wall time of the run at this h")
    if "kernel_time" in ds:
        ds["kernel_time"].attrs.update(units="s", long_name="kernel wall time of the run at this h "
                                       "(compilation excluded)")
    ds["omega"].attrs.update(units="rad s-1", long_name="body angular velocity at t_end (node value)")
    ds["gamma"].attrs.update(units="1", long_name="direction of gravity in the body frame at t_end")
    ds["entropy"].attrs.update(units="J K-1", long_name="entropy at t_end")
    ds["energy_error"].attrs.update(units="J", long_name="total energy error E_k - E_0 at t_end")
    ds["h"].attrs.update(units="s", long_name="time step")
    ds.attrs.update({"title": "liethermo convergence study: errors against a DOP853 reference",
                     "study": study_name(study), "kind": "convergence", "reduced": int(reduced),
                     "t_end": opt["t_end"], "h0": opt["h0"], "levels": opt["levels"],
                     "comparison": "max over t = j*h0 of node values against the reference at t_k"})
    nc = write_netcdf_atomic(ds, study_netcdf_path(study, outdir),
                             history=study_history("convergence", study, outdir, reduced, history))
    figs = _figures(ds, outdir, keys)
    notes = (f"Scene: `{study.get('study', {}).get('base_scene', 'paper')}`, t_end = {opt['t_end']} s, "
             f"h = {opt['h0']} s halved {opt['levels'] - 1} times; errors are the max over t = j·{opt['h0']} s "
             "against the fixed-step DOP853 reference (~1e-15), on **node values** for every method (Ω(t_k), Γ_k, "
             "S_k and E_k from them). **Start:** the `start` column says which start each VI row used "
             "(legendre: μ₀ = 𝕀Ω(0); node: the paper's Ω₀ := Ω(0) as first step velocity; staggered: "
             "Ω₀ := Ω(h/2) from the reference); vi4 and vi6 always use legendre. The fit stops at the round-off "
             f"floor (error < {opt['floor_rel']:g} × scale) or where the error stops decreasing; "
             f"'levels fitted' says how many levels entered each fit. Wall time "
             f"{time.perf_counter() - t_start:.1f} s.")
    files = f"netCDF: `{nc.name}`; figures: " + ", ".join(f"`{f.name}`" for f in figs)
    return write_report(outdir, f"Convergence study: {study_name(study)}" + (" (reduced)" if reduced else ""),
                        tables[:1] + [_finding(per_point[0], specs), notes, NODE_VALUES_NOTE] + tables[1:]
                        + [files, _closing(per_point[0], specs, hs, first_scales, opt, outdir)])


def _closing(ds: xr.Dataset, specs: list, hs: list, scales: dict, opt: dict, outdir) -> str:
    """Cheapest (method, h) per error level of the state (Ω relative to its scale, Γ), first sweep point."""
    cost = ds["kernel_time"] if "kernel_time" in ds else ds["wall_time"]
    pts = []
    for i, spec in enumerate(specs):
        for j, h in enumerate(hs):
            e = max(float(ds["error_omega"].values[i, j]) / scales["omega"], float(ds["error_gamma"].values[i, j]))
            pts.append({"method": spec["label"], "error": e, "cost": float(cost.values[i, j]),
                        "setting": f"h = {h:g} s"})
    return closing_section(pts, regime=f"one member, t_end = {opt['t_end']} s, first sweep point", unit="s",
                           error="max over t = j h0 of max(|ΔΩ|/max|Ω_ref|, |ΔΓ|), node values (1)",
                           cost="kernel wall time of the one-member run (s; at coarse h a call's fixed cost "
                                "dominates — cost per member-step of large runs: the work_precision study)",
                           outdir=outdir)


def _finding(ds: xr.Dataset, specs: list) -> str:
    """One plain line per method: declared and observed orders (first sweep point).

    A method passes when every observed order is at least its declared order
    (less :func:`liethermo.methods.order_tolerance`); an order above the declared one is said, not
    counted as a failure (e.g. the first-order starts' energy error, often of
    higher order)."""
    names = ("Ω", "Γ", "S", "E")
    lines = ["**Finding (node values, first sweep point).** A method passes when each observed order is at "
             f"least its declared order p less max({ORDER_TOLERANCE:g}, {ORDER_TOLERANCE_REL:g} p); an order "
             "above the declared one is no failure (the error falls faster than promised on this scene).", ""]
    for i, spec in enumerate(specs):
        m = METHODS[spec["method"]]
        declared = m.order(spec["start"] or "legendre", spec["friction"] or "trapezoid")
        obs = [float(ds[f"observed_order_{v}"].values[i]) for v in VARIABLES]
        verdicts = [judge_order(o, declared) for o in obs]
        if all(v == "not fitted" for v in verdicts):
            lines.append(f"- {spec['label']}: no order could be fitted (fewer than 3 levels above the "
                         "round-off floor).")
            continue
        below = [f"{n} {o:.2f}" for n, o, v in zip(names, obs, verdicts) if v == "below declared"]
        above = [f"{n} {o:.2f}" for n, o, v in zip(names, obs, verdicts) if v == "above declared"]
        if below:
            verdict = f"BELOW the declared order in {', '.join(below)}"
        else:
            verdict = "at least as declared" + (f" (above it in {', '.join(above)})" if above else "")
        lines.append(f"- {spec['label']}" + (f" (start {spec['start']})" if spec["start"] else "")
                     + f": observed orders {', '.join(f'{o:.2f}' for o in obs)} (Ω, Γ, S, E); declared "
                     f"{declared} — {verdict}.")
    return "\n".join(lines)


def _figures(ds: xr.Dataset, outdir: Path, keys) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if keys:
        ds = ds.isel({dim_name(k): 0 for k in keys})
    from matplotlib.ticker import NullFormatter

    fig, axes = plt.subplots(2, 2, figsize=(11, 8.5), layout="constrained")
    hs = ds["h"].values
    # x ticks at the step sizes themselves, at most 5 labelled (log axes over ~1 decade
    # otherwise label their minor ticks too, and 3×10⁻³4×10⁻³ run into each other)
    every = -(-len(hs) // 5)
    xlabels = [f"{h:.3g}" if i % every == 0 else "" for i, h in enumerate(hs)]
    for ax, v in zip(axes.ravel(), VARIABLES):
        for i, m in enumerate(ds["scheme"].values):
            e = ds[f"error_{v}"].values[i]
            p = float(ds[f"observed_order_{v}"].values[i])
            ok = np.isfinite(e) & (e > 0)
            # a marker, a line style and a size of its own for each scheme, hollow markers:
            # schemes with the same errors (vi and vi:staggered) stay visible one over the other
            ax.loglog(hs[ok], e[ok], color=f"C{i % 10}", ls=LINESTYLES[i % len(LINESTYLES)],
                      marker=MARKERS[i % len(MARKERS)], ms=9 - 4 * (i % 2), mfc="none", mew=1.2, lw=1.2,
                      label=f"{m} (p = {p:.2f})")
        ax.set_xticks(hs, xlabels)
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("h (s)")
        ax.set_ylabel(f"max error ({UNITS[v]})")
        ax.set_title(f"{TITLES[v]} (node values)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("convergence against the reference, node values at t = j h0")
    path = Path(outdir) / "convergence.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]
