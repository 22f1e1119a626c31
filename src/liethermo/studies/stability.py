"""Stability study: where each method stays bounded and accurate, plus named hard cases.

**Map.**  Over a grid of (h|Ω₀|, κ = c h / I_min) at a fixed step h, each grid
cell is one ensemble member with its own physical parameters (spin magnitude
|Ω₀| = (h|Ω₀|)/h along the scene's spin direction, Stokes coefficient
c = κ I_min / h, i.e. the viscosity), all cells in a single ``simulate`` call
per method.  Every cell is classified, never hiding a failure:

* ``accurate``            status ok, bounded, error ≤ ``error_threshold``;
* ``bounded``             status ok, bounded, error above the threshold;
* ``unbounded``           status ok but the mechanical energy above rest grew by
                          more than ``growth_limit``× (or ||Γ| − 1| > 0.1);
* ``newton_not_converged`` the VI's Newton iteration failed at some step;
* ``non_finite``          the state overflowed to inf/NaN.

Error = max over the run of max(|Ω_k − Ω_ref|/|Ω₀|, |Γ_k − Γ_ref|); the VI
uses the staggered start and is compared at t_k + h/2 (Ω) and t_k (Γ).
A method written ``"vi:endpoint"`` runs the VI with endpoint friction.

**Named cases** (``[[options.cases]]``: name, description, h, steps, scene
overrides): each run with every method against the reference; the table
records status, failure step and time, max h|Ω|, Newton iterations (max,
mean), the max condition number of the VI's Newton Jacobian along the
accepted steps, errors, the energy growth and the |Γ| defect.
"""

from __future__ import annotations

import math
import time
from functools import partial
from pathlib import Path

import numpy as np
import xarray as xr

from ..initial import initial_conditions, initial_states
from ..kernels.model import P_C, P_GX, P_GY, P_GZ, P_I1, P_I2, P_I3
from ..methods import FRICTION
from ..scene import physical_parameters
from ..simulate import simulate
from .common import (study_options, StudyError, cached_point, point_key, progress_bar, study_name,
                     study_netcdf_path, study_scene, write_netcdf_atomic, write_report, write_table, start_study,
                     study_history)

EXTRA_KEYS = ()

CLASSES = ["accurate", "bounded", "unbounded", "newton_not_converged", "non_finite"]
DEFAULT_OPTIONS = {
    "h": 0.1,
    "steps": 100,
    "h_omega": [0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0],
    "kappa": [0.001, 0.01, 0.1, 0.5, 1.0, 2.0, 5.0, 10.0],
    "error_threshold": 0.05,
    "growth_limit": 2.0,
    "cases": [],
    "map_scene": {},
}


def options(study: dict) -> dict:
    return study_options(study, DEFAULT_OPTIONS, "stability")


def parse_method(m: str) -> tuple[str, str]:
    name, _, friction = m.partition(":")
    return name, friction or "trapezoid"


def validate(study: dict) -> None:
    opt = options(study)
    for k in ("h", "error_threshold", "growth_limit"):
        if not (isinstance(opt[k], (int, float)) and opt[k] > 0):
            raise StudyError(f"options.{k}: must be a number > 0")
    if not (isinstance(opt["steps"], int) and opt["steps"] >= 1):
        raise StudyError("options.steps: must be an integer ≥ 1")
    for k in ("h_omega", "kappa"):
        if not isinstance(opt[k], list) or not opt[k] or not all(isinstance(x, (int, float)) and x > 0 for x in opt[k]):
            raise StudyError(f"options.{k}: must be a non-empty list of numbers > 0")
    for m in study.get("methods", []):
        name, fr = parse_method(m)
        if name == "reference":
            raise StudyError("methods: 'reference' is the ground truth, not a compared method")
        if fr not in FRICTION:
            raise StudyError(f"methods: unknown friction {fr!r} in {m!r}; known: {', '.join(FRICTION)}")
    study_scene(study, opt["map_scene"])
    for i, c in enumerate(opt["cases"]):
        for k in ("name", "h", "steps"):
            if k not in c:
                raise StudyError(f"options.cases[{i}]: missing key {k!r}")
        study_scene(study, c.get("scene", {}))


# ----------------------------------------------------------------------------- numerics

class single_thread:
    """Run numba kernels on one thread: the members here are few, and waking a
    thread pool for every chunk costs milliseconds (more than the work)."""

    def __enter__(self):
        import numba

        self.old = numba.get_num_threads()
        numba.set_num_threads(1)

    def __exit__(self, *exc):
        import numba

        numba.set_num_threads(self.old)


def sim(y0, P, h, steps, method, **kw):
    """:func:`simulate` in one chunk (no per-chunk overhead)."""
    return simulate(y0, P, h, steps, method, chunk_steps=max(int(steps), 1), **kw)


def mech_energy(omega, gamma, P):
    """Mechanical energy above the resting state K + V + |g⃗| (J)."""
    I = P[..., [P_I1, P_I2, P_I3]]
    g = P[..., [P_GX, P_GY, P_GZ]]
    return (0.5 * np.sum(I * omega * omega, axis=-1) + np.sum(g * gamma, axis=-1)
            + np.linalg.norm(g, axis=-1))


def references(y0, P, h, steps):
    """Reference states at t_k (node) and t_k + h/2 (mid), k = 0..steps: (N, steps+1, 7) each."""
    node = sim(y0, P, h, steps, "reference").states
    half = sim(y0, P, 0.5 * h, 1, "reference").states[:, 1]
    mid = sim(half, P, h, steps, "reference").states
    return node, mid


def run_method(y0, P, h, steps, method: str, ref_node, ref_mid):
    """Simulate every member with one method; per-member diagnostics (dict of arrays)."""
    name, friction = parse_method(method)
    start = "staggered" if name == "vi" else "node"
    tr = sim(y0, P, h, steps, name, friction=friction, start=start)
    om_ref = ref_mid if name == "vi" else ref_node
    w0 = np.linalg.norm(y0[:, 0:3], axis=1)
    with np.errstate(invalid="ignore", over="ignore"):
        e = np.maximum(np.linalg.norm(tr.omega - om_ref[..., 0:3], axis=-1) / w0[:, None],
                       np.linalg.norm(tr.gamma - ref_node[..., 3:6], axis=-1))
        e = np.where(np.isfinite(e), e, np.inf)
        err_max = e.max(axis=1)
        err_end = e[:, -1]
        Em = mech_energy(tr.omega, tr.gamma, P[:, None, :])
        Em0 = mech_energy(y0[:, 0:3], y0[:, 3:6], P)
        growth = np.nanmax(np.where(np.isfinite(Em), Em, np.nan), axis=1) / Em0
        gdef = np.nanmax(np.abs(np.linalg.norm(tr.gamma, axis=-1) - 1.0), axis=1)
    return tr, dict(error_max=err_max, error_end=err_end, energy_growth=growth, gamma_defect=gdef)


def classify(status, error_max, growth, gdef, threshold, growth_limit):
    cls = np.zeros(status.shape, dtype=np.int8)
    bounded = (growth <= growth_limit) & (gdef <= 0.1)
    cls[~bounded] = 2
    cls[bounded & (error_max > threshold)] = 1
    cls[status == 1] = 3
    cls[status == 2] = 4
    return cls


def jacobian_condition(tr, h: float, friction: str) -> np.ndarray:
    """Max over accepted steps of cond₂ of the VI's Newton Jacobian at the solution Ω_{k+1}."""
    from ..kernels.vi import momentum_jacobian

    alpha = FRICTION[friction][0]
    J = np.empty((3, 3))
    out = np.full(tr.states.shape[0], np.nan)
    for m in range(tr.states.shape[0]):
        best = 0.0
        for k in range(1, tr.states.shape[1]):
            X = tr.states[m, k, 0:3]
            if not np.all(np.isfinite(X)):
                break
            momentum_jacobian(np.ascontiguousarray(X), tr.params[m], h, alpha, J)
            best = max(best, float(np.linalg.cond(J)))
        out[m] = best if best > 0 else np.nan
    return out


def map_point(scene: dict, opt: dict, method: str) -> xr.Dataset:
    h = float(opt["h"])
    steps = int(opt["steps"])
    hw = np.asarray(opt["h_omega"], float)
    ka = np.asarray(opt["kappa"], float)
    p = physical_parameters(scene)
    d = np.asarray(scene["initial"]["omega"], float)
    d = d / np.linalg.norm(d)
    R = np.asarray(scene["initial"]["R"], float)
    HW, KA = np.meshgrid(hw, ka, indexing="ij")
    N = HW.size
    om0 = (HW.ravel() / h)[:, None] * d[None]
    y0 = initial_states(om0, np.repeat(R[None], N, 0), False)
    P = np.repeat(p[None], N, 0)
    Imin = p[[P_I1, P_I2, P_I3]].min()
    P[:, P_C] = KA.ravel() * Imin / h
    ref_node, ref_mid = references(y0, P, h, steps)
    tr, dg = run_method(y0, P, h, steps, method, ref_node, ref_mid)
    cls = classify(tr.status, dg["error_max"], dg["energy_growth"], dg["gamma_defect"],
                   float(opt["error_threshold"]), float(opt["growth_limit"]))
    shape = HW.shape
    fail = np.where(tr.status != 0, tr.fail_step, -1)
    dims = ("h_omega", "kappa")
    return xr.Dataset({
        "regime": (dims, cls.reshape(shape)),
        "status": (dims, tr.status.reshape(shape)),
        "error_max": (dims, dg["error_max"].reshape(shape)),
        "error_end": (dims, dg["error_end"].reshape(shape)),
        "energy_growth": (dims, dg["energy_growth"].reshape(shape)),
        "gamma_defect": (dims, dg["gamma_defect"].reshape(shape)),
        "newton_max": (dims, tr.newton_max.reshape(shape)),
        "newton_mean": (dims, (tr.newton_iterations / np.maximum(tr.steps_done, 1)).reshape(shape)),
        "failed_at_step": (dims, fail.reshape(shape)),
        "max_h_omega": (dims, tr.max_h_omega.reshape(shape)),
        "viscosity_equivalent": (dims, (P[:, P_C] / (8 * math.pi * float(scene["body"]["radius"]) ** 3)).reshape(shape)),
    }, coords={"h_omega": hw, "kappa": ka})


def case_point(scene: dict, case: dict, method: str) -> xr.Dataset:
    h = float(case["h"])
    steps = int(case["steps"])
    p = physical_parameters(scene)
    om, R = initial_conditions(scene, 0, 1)
    y0 = initial_states(om, R, False)
    P = p[None].copy()
    ref_node, ref_mid = references(y0, P, h, steps)
    t0 = time.perf_counter()
    tr, dg = run_method(y0, P, h, steps, method, ref_node, ref_mid)
    wall = time.perf_counter() - t0
    name, friction = parse_method(method)
    cond = jacobian_condition(tr, h, friction)[0] if name == "vi" else float("nan")
    return xr.Dataset({k: ("one", np.atleast_1d(v)) for k, v in {
        "status": tr.status[0], "failed_at_step": tr.fail_step[0] if tr.status[0] else -1,
        "steps_done": tr.steps_done[0], "max_h_omega": tr.max_h_omega[0],
        "h_omega0": h * np.linalg.norm(om[0]),
        "newton_max": tr.newton_max[0], "newton_mean": tr.newton_iterations[0] / max(tr.steps_done[0], 1),
        "jacobian_cond_max": cond, "error_max": dg["error_max"][0], "error_end": dg["error_end"][0],
        "energy_growth": dg["energy_growth"][0], "gamma_defect": dg["gamma_defect"][0],
        "kappa": p[P_C] * h / p[[P_I1, P_I2, P_I3]].min(), "wall": wall,
    }.items()})


def newton_limit(scene: dict, h: float, method: str = "vi", h_omegas=None, steps: int = 20) -> xr.Dataset:
    """Push the VI's h|Ω₀| far beyond the map (up to 1000): Newton iterations and failures."""
    h_omegas = np.asarray(h_omegas if h_omegas is not None else [1, 2, 5, 10, 100, 1e3, 1e4, 3e4, 1e5, 1e6], float)
    name, friction = parse_method(method)
    p = physical_parameters(scene)
    d = np.asarray(scene["initial"]["omega"], float)
    d = d / np.linalg.norm(d)
    R = np.asarray(scene["initial"]["R"], float)
    N = h_omegas.size
    y0 = initial_states((h_omegas / h)[:, None] * d[None], np.repeat(R[None], N, 0), False)
    P = np.repeat(p[None], N, 0)
    tr = sim(y0, P, h, steps, name, friction=friction, start="node")
    cond = jacobian_condition(tr, h, friction)
    return xr.Dataset({"status": ("h_omega", tr.status), "newton_max": ("h_omega", tr.newton_max),
                       "newton_mean": ("h_omega", tr.newton_iterations / np.maximum(tr.steps_done, 1)),
                       "failed_at_step": ("h_omega", np.where(tr.status != 0, tr.fail_step, -1)),
                       "max_h_omega": ("h_omega", tr.max_h_omega), "jacobian_cond_max": ("h_omega", cond)},
                      coords={"h_omega": h_omegas})


def newton_analysis(limit: xr.Dataset, vi_maps: list) -> str:
    """A paragraph explaining, from the measured numbers, where and why Newton stops converging."""
    hw = limit["h_omega"].values
    nm = limit["newton_max"].values.astype(float)
    st = limit["status"].values
    ok = (st == 0) & (hw >= 10)
    slope = float(np.polyfit(np.log10(hw[ok]), nm[ok], 1)[0]) if ok.sum() >= 2 else float("nan")
    fail = hw[st != 0]
    cond = float(np.nanmax(limit["jacobian_cond_max"].values))
    first_fail = f"h|Ω₀| = {fail.min():g}" if fail.size else "nowhere in the tested range"
    last_ok = hw[st == 0].max() if np.any(st == 0) else float("nan")
    map_max = max(int(np.max(d["newton_max"].values)) for d in vi_maps) if vi_maps else 0
    map_fail = sum(int(np.sum(d["status"].values == 1)) for d in vi_maps)
    map_hw = max(float(np.max(d["h_omega"].values)) for d in vi_maps) if vi_maps else float("nan")
    return (
        f"**Where and why the VI's Newton iteration stops converging.** The Jacobian is never the problem: "
        f"its 2-norm condition number at the accepted solutions stays ≤ {cond:.3g} at every h|Ω| tested "
        f"(for h|X| ≫ 1 the dominant term (h/4)(2X(𝕀X)ᵀ + (X·𝕀X)Id) has eigenvalue ratio ≈ 3, and the "
        f"gyroscopic part is only O(h|X|)). What grows is the distance of the starting guess: the explicit-Euler "
        f"predictor adds h(Π×Ω)/𝕀 ~ h|Ω|², i.e. it overshoots the root by a factor ~h|Ω|, and far from the root "
        f"the cubic term (h/4)(X·𝕀X)X dominates, where Newton only contracts by 2/3 per iteration "
        f"(x ← x − x³/(3x²)). Hence the iteration count grows logarithmically: {slope:.1f} iterations per decade "
        f"of h|Ω| (log(10)/log(3/2) = 5.7 predicted), reaching the cap of "
        f"{int(nm.max())} iterations between h|Ω₀| = {last_ok:g} (last converged) and {first_fail} (first "
        f"failure). On the map (h|Ω₀| ≤ {map_hw:g}) the VI's Newton iteration failed in {map_fail} cell(s) and "
        f"needed at most {map_max} iterations in a step; what degrades there is "
        f"accuracy, not solvability: the Cayley map turns by 2·atan(h|Ω|/2) < π per step instead of h|Ω|, so "
        f"the discrete rotation saturates (aliasing) while |Γ| = 1 and the energy stay bounded. A predictor "
        f"Ω_k (or a Cayley-consistent one) instead of explicit Euler would remove this growth."
    )


# ----------------------------------------------------------------------------- study

UNITS = {
    "regime": ("1", "regime: 0 accurate, 1 bounded but inaccurate, 2 unbounded, 3 newton_not_converged, 4 non_finite"),
    "status": ("1", "member status (0 ok, 1 newton_not_converged, 2 non_finite)"),
    "error_max": ("1", "max over the run of max(|dOmega|/|Omega0|, |dGamma|) against the reference"),
    "error_end": ("1", "error at the final step"),
    "energy_growth": ("1", "max over the run of the mechanical energy above rest / its initial value"),
    "gamma_defect": ("1", "max over the run of ||Gamma| - 1|"),
    "newton_max": ("1", "max Newton iterations in one step (vi)"),
    "newton_mean": ("1", "mean Newton iterations per step (vi)"),
    "failed_at_step": ("1", "step whose computation failed (-1: none)"),
    "max_h_omega": ("rad", "max over accepted steps of h |Omega_k|"),
    "viscosity_equivalent": ("kg m-1 s-1", "viscosity mu = c / (8 pi a^3) of the cell"),
    "jacobian_cond_max": ("1", "max over accepted steps of the 2-norm condition number of the Newton Jacobian"),
}


def _attrs(ds: xr.Dataset) -> xr.Dataset:
    for k in ds.data_vars:
        if k in UNITS:
            ds[k].attrs.update(units=UNITS[k][0], long_name=UNITS[k][1])
    return ds


def _one_thread(func, *args):
    """``func(*args)`` with numba on one thread (a Dask task: module level)."""
    with single_thread():
        return func(*args)


def run(study: dict, outdir: Path, *, reduced: bool, progress: bool | None, dask: str | None = None,
        history: str | None = None) -> Path:
    import pandas as pd

    s, outdir, opt = start_study(study, outdir, reduced, validate, options)
    methods = list(s.get("methods", ["vi", "vi:endpoint", "rk2", "rk4"]))
    scene = study_scene(s, opt["map_scene"])
    h = float(opt["h"])
    t_wall = time.perf_counter()
    cases = opt["cases"]
    # every point: (key, func, args), module-level func (Dask tasks)
    map_tasks = {}
    for m in methods:
        key = point_key({"study": study_name(s), "kind": "map", "scene": scene, "method": m,
                         **{k: opt[k] for k in ("h", "steps", "h_omega", "kappa", "error_threshold", "growth_limit")}})
        map_tasks[m] = (key, map_point, (scene, opt, m))
    case_tasks = []
    for c in cases:
        sc = study_scene(s, c.get("scene", {}))
        for m in methods:
            key = point_key({"study": study_name(s), "kind": "case", "scene": sc, "case": c, "method": m})
            case_tasks.append((c, m, (key, case_point, (sc, c, m))))
    vi_methods = [m for m in methods if parse_method(m)[0] == "vi"]
    limit_task = None
    if vi_methods:
        key = point_key({"study": study_name(s), "kind": "newton_limit", "scene": scene, "h": h})
        limit_task = (key, newton_limit, (scene, h, vi_methods[0]))
    if dask is not None:  # compute the missing points as Dask tasks (one numba thread each) into the cache
        from ..distributed import map_cached_points

        alltasks = list(map_tasks.values()) + [t for _, _, t in case_tasks] + ([limit_task] if limit_task else [])
        map_cached_points(outdir, [(k, _one_thread, (f, *a)) for k, f, a in alltasks], dask, progress=progress)
    bar = progress_bar(len(methods) * (1 + len(cases)) + 1, progress, study_name(s))
    maps = {}
    case_rows = []
    case_ds = []
    threads = single_thread()
    threads.__enter__()
    try:
        for m, (key, f, a) in map_tasks.items():
            maps[m] = cached_point(outdir, key, partial(f, *a))
            if bar:
                bar.update(1)
        for c, m, (key, f, a) in case_tasks:
            ds = cached_point(outdir, key, partial(f, *a))
            case_ds.append((c["name"], m, ds))
            v = {k: ds[k].values[0] for k in ds.data_vars}
            st = int(v["status"])
            name = parse_method(m)[0]
            case_rows.append({
                "case": c["name"], "method": m, "h (s)": float(c["h"]), "steps": int(c["steps"]),
                "h|Ω₀|": float(v["h_omega0"]), "κ = ch/I_min": float(v["kappa"]),
                "status": ["ok", "newton_not_converged", "non_finite"][st],
                "failed at step": int(v["failed_at_step"]) if st else "—",
                "max h|Ω|": float(v["max_h_omega"]),
                "Newton max": int(v["newton_max"]) if name == "vi" else "—",
                "Newton mean": float(v["newton_mean"]) if name == "vi" else float("nan"),
                "cond(J) max": float(v["jacobian_cond_max"]),
                "error max": float(v["error_max"]), "error end": float(v["error_end"]),
                "E_mech growth": float(v["energy_growth"]), "||Γ|−1| max": float(v["gamma_defect"]),
            })
            if bar:
                bar.update(1)
        limit = None
        if limit_task is not None:
            key, f, a = limit_task
            limit = cached_point(outdir, key, partial(f, *a))
        if bar:
            bar.update(1)
    finally:
        threads.__exit__()
        if bar:
            bar.close()

    # --- dataset
    mp = xr.concat([maps[m] for m in methods], dim="method", coords="minimal", compat="override")
    mp = mp.assign_coords(method=("method", np.array(methods, dtype=object)))
    mp["h_omega"].attrs.update(units="rad", long_name="h |Omega_0| (step angle of the initial spin)")
    mp["kappa"].attrs.update(units="1", long_name="kappa = c h / I_min (friction per step)")
    mp = _attrs(mp)
    mp.attrs.update({"title": "liethermo stability study: stability map, named cases and Newton limit",
                     "study": study_name(s), "h": h, "steps": int(opt["steps"]),
                     "error_threshold": float(opt["error_threshold"]),
                     "growth_limit": float(opt["growth_limit"]),
                     "regime_flag_meanings": " ".join(CLASSES), "vi_start": "staggered"})
    if limit is not None:
        lim = _attrs(limit.rename({"h_omega": "limit_h_omega"}).rename(
            {k: f"limit_{k}" for k in limit.data_vars}))
        for k in limit.data_vars:
            lim[f"limit_{k}"].attrs.update(units=UNITS[k][0], long_name=f"h|Omega| push (vi, node start): {UNITS[k][1]}")
        lim["limit_h_omega"].attrs.update(units="rad", long_name="h |Omega_0| of the Newton-limit push")
        mp = xr.merge([mp, lim])
    if case_ds:
        cnames = list(dict.fromkeys(c for c, _, _ in case_ds))
        for var in ("status", "error_max", "energy_growth", "newton_max", "max_h_omega", "jacobian_cond_max"):
            a = np.full((len(cnames), len(methods)), np.nan)
            for c, m, ds in case_ds:
                a[cnames.index(c), methods.index(m)] = float(ds[var].values[0])
            mp[f"case_{var}"] = (("case", "method"), a, {"units": UNITS[var][0], "long_name": f"named case: {UNITS[var][1]}"})
        mp = mp.assign_coords(case=("case", np.array(cnames, dtype=object)))
    nc = write_netcdf_atomic(mp, study_netcdf_path(s, outdir),
                             history=study_history("stability", study, outdir, reduced, history))

    # --- tables
    count_rows = []
    for m in methods:
        r = maps[m]["regime"].values
        row = {"method": m}
        for i, c in enumerate(CLASSES):
            row[c] = int(np.sum(r == i))
        hw_ok = maps[m]["h_omega"].values[np.all(r <= 1, axis=1)]
        row["largest h|Ω₀| bounded at every κ"] = float(hw_ok.max()) if hw_ok.size else float("nan")
        hw_acc = maps[m]["h_omega"].values[np.all(r == 0, axis=1)]
        row["largest h|Ω₀| accurate at every κ"] = float(hw_acc.max()) if hw_acc.size else float("nan")
        count_rows.append(row)
    regime_rows = []
    for m in methods:
        ds = maps[m]
        for i, hwv in enumerate(ds["h_omega"].values):
            regime_rows.append({"method": m, "h|Ω₀|": float(hwv),
                                **{f"κ={k:g}": CLASSES[int(ds['regime'].values[i, j])]
                                   for j, k in enumerate(ds["kappa"].values)}})
    sections = [write_table(pd.DataFrame(count_rows), outdir, "stability_summary",
                            f"Stability map summary: cells per regime ({len(opt['h_omega'])}×{len(opt['kappa'])} grid, "
                            f"h = {h:g} s, {opt['steps']} steps)")]
    sections.append(
        f"Map scene `{scene['scene']['name']}` with overrides {opt['map_scene'] or 'none'} "
        f"(|g⃗| = {np.linalg.norm(physical_parameters(scene)[[P_GX, P_GY, P_GZ]]):.3g} N m); each cell of the map is one member with Ω₀ = (h|Ω₀|/h)·Ω̂_scene and "
        f"c = κ I_min/h (its own parameter row; one `simulate` call per method). Error = max over the run of "
        f"max(|Ω_k − Ω_ref|/|Ω₀|, |Γ_k − Γ_ref|) against the fixed-step DOP853 reference (VI: staggered start, Ω "
        f"compared at t_k + h/2). Regimes: *accurate* (error ≤ {opt['error_threshold']:g}), *bounded* (ok, "
        f"mechanical energy above rest ≤ {opt['growth_limit']:g}× its initial value and ||Γ|−1| ≤ 0.1, but "
        f"inaccurate), *unbounded*, *newton_not_converged*, *non_finite* — failures are counted, never hidden. "
        f"`vi:endpoint` is the VI with endpoint friction (SPEC E3).")
    sections.append("![stability map](stability_map.png)")
    if case_rows:
        sections.append(write_table(pd.DataFrame(case_rows), outdir, "named_cases",
                                    "Named hard cases (every method against the reference)"))
        sections.append("\n".join(f"- **{c['name']}**: {c.get('description', '')} (h = {c['h']:g} s, "
                                  f"{c['steps']} steps)" for c in cases))
    if limit is not None:
        lrows = [{"h|Ω₀|": float(limit["h_omega"].values[i]),
                  "status": ["ok", "newton_not_converged", "non_finite"][int(limit["status"].values[i])],
                  "failed at step": int(limit["failed_at_step"].values[i]),
                  "max h|Ω_k| attempted": float(limit["max_h_omega"].values[i]),
                  "Newton max": int(limit["newton_max"].values[i]),
                  "Newton mean": float(limit["newton_mean"].values[i]),
                  "cond(J) max": float(limit["jacobian_cond_max"].values[i])}
                 for i in range(limit.sizes["h_omega"])]
        sections.append(write_table(pd.DataFrame(lrows), outdir, "newton_limit",
                                    f"VI Newton iteration far beyond the map ({vi_methods[0]}, node start, "
                                    f"h = {h:g} s, 20 steps)"))
        sections.append(newton_analysis(limit, [maps[m] for m in vi_methods]))
    sections.append(write_table(pd.DataFrame(regime_rows), outdir, "stability_regimes", "Regime of every map cell"))
    _figure(maps, methods, outdir, opt)
    wall = time.perf_counter() - t_wall
    sections.append(f"netCDF: `{nc.name}`. Study wall time {wall:.1f} s.")
    return write_report(outdir, "Stability: bounded and accurate regimes, hard cases, Newton limits", sections)


def _figure(maps: dict, methods: list, outdir: Path, opt: dict) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import BoundaryNorm, ListedColormap

    n = len(methods)
    # every panel has the same (h|Omega_0|, kappa) grid: shared axes, labels on the outer
    # panels only, and constrained layout so that titles, labels and colorbars do not collide
    fig, axes = plt.subplots(2, n, figsize=(3.6 * n, 6.6), squeeze=False, sharex=True, sharey=True,
                             layout="constrained")
    cmap = ListedColormap(["#2ca02c", "#bcbd22", "#ff7f0e", "#9467bd", "#d62728"])
    norm = BoundaryNorm(np.arange(-0.5, 5.5), cmap.N)
    for j, m in enumerate(methods):
        ds = maps[m]
        hw = ds["h_omega"].values
        ka = ds["kappa"].values
        xi = np.arange(hw.size)
        yi = np.arange(ka.size)
        ax = axes[0, j]
        im = ax.pcolormesh(xi, yi, ds["regime"].values.T, cmap=cmap, norm=norm, shading="nearest")
        if parse_method(m)[0] == "vi":
            for a in range(hw.size):
                for b in range(ka.size):
                    ax.text(a, b, str(int(ds["newton_max"].values[a, b])), ha="center", va="center", fontsize=6)
        ax.set_title(f"{m}" + (" (numbers: max Newton it.)" if parse_method(m)[0] == "vi" else ""), fontsize=9)
        ax2 = axes[1, j]
        err = np.log10(np.clip(ds["error_max"].values, 1e-16, 1e3))
        im2 = ax2.pcolormesh(xi, yi, err.T, cmap="viridis", vmin=-8, vmax=1, shading="nearest")
        ax2.set_title(f"{m}: log10 error (max over run)", fontsize=9)
        ax2.set_xticks(xi, [f"{v:g}" for v in hw], fontsize=7, rotation=45)
        ax2.set_xlabel("h|Ω₀| (rad)")
    for ax in axes[:, 0]:
        ax.set_yticks(yi, [f"{v:g}" for v in ka], fontsize=7)
        ax.set_ylabel("κ = c h / I_min")
    cb = fig.colorbar(im, ax=axes[0, :].tolist(), ticks=range(5), fraction=0.02)
    cb.ax.set_yticklabels(CLASSES, fontsize=7)
    fig.colorbar(im2, ax=axes[1, :].tolist(), fraction=0.02, label="log10 error")
    path = Path(outdir) / "stability_map.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
