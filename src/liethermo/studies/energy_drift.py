"""Energy-drift study: total-energy error over an ensemble of initial conditions.

Members are drawn by :func:`liethermo.initial.initial_conditions` (random
attitudes, uniform on SO(3); random spin directions; spin magnitudes in
``ensemble.spin_range`` × |initial.omega|).  Each method (``vi`` = the
paper's VI with node start, ``rk2``, ``rk4``, …) runs at every swept h to
``t_end``.  The total energy E = K + V + U is conserved by the continuous
system, so E_k − E₀ (computed without cancellation, SPEC §4; for the VI from
the stored Ω_k, as in SPEC §7) is pure error; it is measured relative to the
initial mechanical energy above the resting state, E_mech,0 = K₀ + V₀ + mgℓ.

Per method and h the study reports the median and 5–95 % band over members
of max_k |E_k − E₀| / E_mech,0, the median final error, a fitted drift rate
(least-squares slope of (E_k − E₀)/E_mech,0 against t, per member) and the
fraction of members that failed (status ≠ 0) or diverged (max relative error
> ``diverged_above``).  Failed members count as +inf in every quantile.
Figures show the quantile bands of |E_k − E₀| / E_mech,0 over time.
"""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path

import numpy as np
import xarray as xr

from ..dataset import energies
from ..initial import initial_conditions, initial_states
from ..kernels.model import P_GX, P_GY, P_GZ
from ..scene import physical_parameters
from .common import (study_options, StudyError, cached_point, dim_name, expand_sweep, parse_method, point_key, progress_bar,
                     stack_points, study_name, study_netcdf_path, study_scene, write_netcdf_atomic,
                     write_report, write_table, start_study, study_history)

EXTRA_KEYS = ()
DEFAULT_OPTIONS = {"t_end": 30.0, "band_dt": 0.2, "member_chunk": 1024, "diverged_above": 1.0}
QUANTILES = (0.05, 0.5, 0.95)
CLIP = 1e3  # relative energy errors above this are drawn at the top of the band figure


def options(study: dict) -> dict:
    return study_options(study, DEFAULT_OPTIONS, "energy_drift")


def validate(study: dict) -> None:
    opt = options(study)
    hs = study.get("sweep", {}).get("integrator.h")
    if not hs:
        raise StudyError('sweep."integrator.h": an energy-drift study sweeps the time step')
    for h in hs:
        for what, T in (("t_end", opt["t_end"]), ("band_dt", opt["band_dt"])):
            r = T / h
            if abs(r - round(r)) > 1e-9 or round(r) < 1:
                raise StudyError(f"options.{what} = {T} must be a multiple of every swept h (h = {h})")
    if not study.get("methods"):
        raise StudyError("methods: an energy-drift study needs at least one method")


def _point(scene: dict, spec: dict, opt: dict) -> xr.Dataset:
    h = float(scene["integrator"]["h"])
    steps = int(round(opt["t_end"] / h))
    band_every = int(round(opt["band_dt"] / h))
    N = int(scene["ensemble"]["members"])
    p = physical_parameters(scene)
    t = np.arange(steps + 1) * h
    tb = t[::band_every]
    band = np.empty((N, tb.size))
    max_rel = np.empty(N)
    final_rel = np.empty(N)
    drift = np.empty(N)
    emech = np.empty(N)
    status = np.empty(N, np.int8)
    newton = np.full(N, np.nan)
    wall = 0.0
    from ..simulate import simulate

    for lo in range(0, N, int(opt["member_chunk"])):
        hi = min(N, lo + int(opt["member_chunk"]))
        om0, R0 = initial_conditions(scene, lo, hi)
        y0 = initial_states(om0, R0, False)
        P = np.repeat(p[None], hi - lo, 0)
        tr = simulate(y0, P, h, steps, spec["method"], friction=spec["friction"], start=spec["start"])
        wall += tr.wall_time
        with np.errstate(over="ignore", invalid="ignore"):  # members blowing up before they fail
            K, V, dU = energies(tr.omega, tr.gamma, tr.sigma, P[:, None, :])
            K0, V0, _ = energies(om0, R0[:, 2, :], np.zeros(hi - lo), P)
            em = K0 + V0 + np.linalg.norm(P[:, [P_GX, P_GY, P_GZ]], axis=1)
            rel = ((K - K0[:, None]) + (V - V0[:, None]) + dU) / em[:, None]
        ok = tr.status == 0
        arel = np.abs(rel)
        arel[~np.isfinite(arel)] = np.inf  # after a failure: counts as +inf
        band[lo:hi] = arel[:, ::band_every]
        max_rel[lo:hi] = np.where(ok, arel.max(axis=1), np.inf)
        final_rel[lo:hi] = arel[:, -1]
        # least-squares slope of rel(t) per member (1/s)
        tc = t - t.mean()
        with np.errstate(invalid="ignore"):
            slope = (rel - rel.mean(axis=1, keepdims=True)) @ tc / (tc @ tc)
        drift[lo:hi] = np.where(ok, slope, np.nan)
        emech[lo:hi] = em
        status[lo:hi] = tr.status
        if spec["method"] == "vi":
            newton[lo:hi] = tr.newton_iterations / np.maximum(tr.steps_done, 1)
    q = np.asarray(QUANTILES)
    bandq = np.quantile(band, q, axis=0, method="inverted_cdf")
    return xr.Dataset(
        {
            "relative_energy_error_quantiles": (("quantile", "time"), bandq),
            "max_relative_energy_error": (("member",), max_rel),
            "final_relative_energy_error": (("member",), final_rel),
            "energy_drift_rate": (("member",), drift),
            "mechanical_energy_initial": (("member",), emech),
            "status": (("member",), status),
            "newton_iterations_mean": (("member",), newton),
            "kernel_time": ((), wall),
        },
        coords={"quantile": q, "time": tb, "member": np.arange(N)},
    )


def _summary_row(ds: xr.Dataset, label: str, h: float, opt: dict) -> dict:
    mx = ds["max_relative_energy_error"].values
    fin = ds["final_relative_energy_error"].values
    dr = ds["energy_drift_rate"].values
    st = ds["status"].values
    q05, q50, q95 = np.quantile(mx, QUANTILES, method="inverted_cdf")
    dr_ok = dr[np.isfinite(dr)]
    return {
        "method": label, "h (s)": h, "members": mx.size,
        "median max|dE|/Emech0": q50, "5% max|dE|/Emech0": q05, "95% max|dE|/Emech0": q95,
        "median final |dE|/Emech0": float(np.quantile(fin, 0.5, method="inverted_cdf")),
        "median drift rate (1/s)": float(np.median(dr_ok)) if dr_ok.size else float("nan"),
        "median |drift rate| (1/s)": float(np.median(np.abs(dr_ok))) if dr_ok.size else float("nan"),
        "failed": float(np.mean(st != 0)),
        "diverged or failed": float(np.mean((st != 0) | ~(mx <= opt["diverged_above"]))),
    }


def run(study: dict, outdir: Path, *, reduced: bool, progress: bool | None, dask: str | None = None,
        history: str | None = None) -> Path:
    study, outdir, opt = start_study(study, outdir, reduced, validate, options)
    specs = [parse_method(m) for m in study["methods"]]
    points = expand_sweep(study.get("sweep"))
    keys = list(points[0])
    allpts = [dict(pt, scheme=s["label"]) for pt in points for s in specs]
    t_start = time.perf_counter()
    tasks = []  # (pt, spec, scene, key): one per point and method
    for pt in points:
        for spec in specs:
            scene = study_scene(study, dict(pt, **{"integrator.method": spec["method"],
                                                   "integrator.friction": spec["friction"],
                                                   "integrator.start": spec["start"],
                                                   "integrator.steps": int(round(opt["t_end"] / pt.get(
                                                       "integrator.h", 0.1)))}))
            tasks.append((pt, spec, scene, point_key({"pt": pt, "spec": spec, "opt": opt, "scene": scene})))
    if dask is not None:  # compute the missing points as Dask tasks into the same cache
        from ..distributed import map_cached_points

        map_cached_points(outdir, [(key, _point, (scene, spec, opt)) for _, spec, scene, key in tasks], dask,
                          progress=progress)
    bar = progress_bar(len(allpts), progress, f"{study_name(study)} points")
    dsets, rows = [], []
    try:
        for pt, spec, scene, key in tasks:
            ds = cached_point(outdir, key, partial(_point, scene, spec, opt))
            dsets.append(ds)
            rows.append(_summary_row(ds, spec["label"], float(scene["integrator"]["h"]), opt)
                        | {k: v for k, v in pt.items() if k != "integrator.h"})
            bar.update(1)
    finally:
        bar.close()
    ds = stack_points(dsets, allpts, keys + ["scheme"])
    ds["relative_energy_error_quantiles"].attrs.update(
        units="1", long_name="quantiles over members of |E_k - E_0| / E_mech,0 (failed members: +inf)")
    ds["max_relative_energy_error"].attrs.update(units="1", long_name="max_k |E_k - E_0| / E_mech,0")
    ds["final_relative_energy_error"].attrs.update(units="1", long_name="|E_K - E_0| / E_mech,0 at t_end")
    ds["energy_drift_rate"].attrs.update(units="s-1", long_name="least-squares slope of (E_k - E_0)/E_mech,0 in t")
    ds["mechanical_energy_initial"].attrs.update(units="J", long_name="initial mechanical energy above the "
                                                 "resting state K_0 + V_0 + m g l")
    ds["status"].attrs.update(units="1", long_name="member status", flag_values=np.array([0, 1, 2], np.int8),
                              flag_meanings="ok newton_not_converged non_finite")
    ds["newton_iterations_mean"].attrs.update(units="1", long_name="mean Newton iterations per step "
                                              "(NaN: explicit method)")
    ds["kernel_time"].attrs.update(units="s", long_name="kernel wall time of the point's ensemble")
    ds["time"].attrs.update(units="s", long_name="time t_k = k h (band grid)")
    ds["quantile"].attrs.update(units="1", long_name="quantile over members")
    ds["member"].attrs.update(units="1", long_name="ensemble member")
    ds.attrs.update({"title": "liethermo energy-drift study: energy error over a random ensemble",
                     "study": study_name(study), "kind": "energy_drift", "reduced": int(reduced),
                     "t_end": opt["t_end"], "members": int(ds.sizes["member"])})
    nc = write_netcdf_atomic(ds, study_netcdf_path(study, outdir),
                             history=study_history("energy_drift", study, outdir, reduced, history))
    figs = _figures(ds, outdir, keys)
    members = int(ds.sizes["member"])
    table = write_table(rows, outdir, "energy_drift",
                        f"Relative energy error over {members} members, t_end = {opt['t_end']} s")
    notes = (f"{members} initial conditions (random attitudes uniform on SO(3), random spin directions, "
             f"|Omega| in spin_range × |initial.omega|). Error: (E_k − E₀)/E_mech,0 with E_mech,0 = K₀ + V₀ + mgℓ; "
             "VI rows use the stored step velocity Ω_k (start as in the method label; 'vi' = node start, as in the "
             f"paper). 'diverged or failed': status ≠ 0 or max relative error > {opt['diverged_above']:g}. "
             f"Drift rate: per-member least-squares slope in t. Wall time {time.perf_counter() - t_start:.1f} s.")
    files = f"netCDF: `{nc.name}`; figures: " + ", ".join(f"`{f.name}`" for f in figs)
    return write_report(outdir, f"Energy-drift study: {study_name(study)}" + (" (reduced)" if reduced else ""),
                        [table, notes, files])


def _figures(ds: xr.Dataset, outdir: Path, keys) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    hdim = dim_name("integrator.h")
    other = {dim_name(k): 0 for k in keys if k != "integrator.h"}
    if other:
        ds = ds.isel(other)
    hs = ds[hdim].values
    methods = ds["scheme"].values
    fig, axes = plt.subplots(1, len(hs), figsize=(4.2 * len(hs), 4), sharey=True, squeeze=False)
    colors = {"vi": "C0", "rk2": "C3", "rk4": "C2"}
    for ax, h in zip(axes[0], hs):
        for i, m in enumerate(methods):
            q = ds["relative_energy_error_quantiles"].sel({hdim: h}).values[i]
            t = ds["time"].values
            c = colors.get(str(m).split(":")[0], f"C{i + 4}")
            # blown-up members (inf, or finite but astronomically large) are drawn at the top, CLIP
            lo, med, hi = (np.clip(np.where(np.isnan(x), CLIP, x), 1e-17, CLIP) for x in q)
            ax.fill_between(t, lo, hi, color=c, alpha=0.25, lw=0)
            ax.plot(t, med, color=c, label=f"{m} (median, 5–95 %)")
        ax.set_yscale("log")
        ax.set_ylim(1e-9, 3 * CLIP)
        ax.set_xlabel("t (s)")
        ax.set_title(f"h = {h:g} s")
        ax.grid(True, which="both", alpha=0.3)
    axes[0, 0].set_ylabel("|E_k − E_0| / E_mech,0")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"energy error over {ds.sizes['member']} members")
    fig.tight_layout()
    path = Path(outdir) / "energy_drift_bands.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]
