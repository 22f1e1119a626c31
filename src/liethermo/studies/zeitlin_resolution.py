"""Resolution of the Zeitlin fluid: one flow at N = 16 … 256.

Every member's initial field has the same spherical-harmonic coefficients at
every N (only its degrees l ≤ initial.lmax), so the runs of a sweep over
``zeitlin.N`` are one physical flow, resolved more finely as N grows.  Per N:
the energy spectrum E_l at the end against the finest N's (over the degrees
every N resolves) and against the next N, the energy and the heat, and the
cost.  At the finest N the run is repeated at half the step, so that the time
error is measured beside the differences it must stay below."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from ..io import write_netcdf_atomic
from ..zeitlin import run as zr
from ..zeitlin.plotting import save
from ._zeitlin import zeitlin_scene
from .common import (StudyError, cached_point, expand_sweep, point_key, progress_bar, start_study, study_history,
                     study_netcdf_path, study_options, write_report, write_table)

SWEEP_KEY = "zeitlin.N"
DEFAULT_OPTIONS = {"method": "rk4", "time_check": True}


def options(s: dict) -> dict:
    return study_options(s, DEFAULT_OPTIONS, "zeitlin_resolution")


def validate(s: dict) -> None:
    zeitlin_scene(s)
    if list((s.get("sweep") or {})) != [SWEEP_KEY]:
        raise StudyError(f"sweep: a zeitlin_resolution study sweeps exactly one key, {SWEEP_KEY!r}")
    Ns = s["sweep"][SWEEP_KEY]
    if not isinstance(Ns, list) or len(Ns) < 3 or Ns != sorted(set(Ns)):
        raise StudyError(f"sweep.{SWEEP_KEY}: at least three different N in increasing order, got {Ns!r}")
    lmax = zeitlin_scene(s, {SWEEP_KEY: Ns[0]})["initial"]["lmax"]
    if lmax > Ns[0] - 1:
        raise StudyError(f"sweep.{SWEEP_KEY}: the smallest N must resolve initial.lmax = {lmax} (N > lmax)")
    opt = options(s)
    if opt["method"] not in zr.METHOD_ORDER or opt["method"] == "reference":
        raise StudyError(f"options.method: one of {', '.join(m for m in zr.METHOD_ORDER if m != 'reference')}")
    if not isinstance(opt["time_check"], bool):
        raise StudyError("options.time_check: true or false")


def _spectrum_difference(a: np.ndarray, b: np.ndarray, H0: np.ndarray, L: int) -> np.ndarray:
    """Σ_{l ≤ L} |E_l^a − E_l^b| / H(0) per member and time (a, b: (member, t, l))."""
    return np.abs(a[..., :L] - b[..., :L]).sum(axis=-1) / H0[:, None]


def _timed_run(sc, method: str):
    """The scene's run, with its warm cost per member-step in ``attrs["seconds_per_member_step"]``."""
    # compile and build N's basis first, so that the cost is that of the steps
    zr.simulate(sc.with_overrides({"integrator.steps": sc["output"]["every"], "ensemble.members": 1}),
                method=method, progress=False)
    t0 = time.perf_counter()
    ds = zr.simulate(sc, method=method, progress=False)
    ds.attrs["seconds_per_member_step"] = ((time.perf_counter() - t0)
                                           / (sc["integrator"]["steps"] * sc["ensemble"]["members"]))
    return ds


def run(study: dict, outdir: Path, *, reduced: bool, progress=None, dask=None, history=None) -> Path:
    s, outdir, opt = start_study(study, outdir, reduced, validate, options)
    points = expand_sweep(s["sweep"])
    Ns = [int(p[SWEEP_KEY]) for p in points]
    L = Ns[0] - 1
    runs, cost = {}, {}
    jobs = len(points) + bool(opt["time_check"])
    bar = progress_bar(jobs, progress, "zeitlin_resolution")
    for N, pt in zip(Ns, points):
        sc = zeitlin_scene(s, pt)
        # each N is a point of the resume cache (its run and its cost): a stopped study goes on from them
        key = point_key({"kind": "zeitlin_resolution", "scene": sc.to_dict(), "method": opt["method"]})
        runs[N] = cached_point(outdir, key, lambda sc=sc: _timed_run(sc, opt["method"]))
        cost[N] = float(runs[N].attrs["seconds_per_member_step"])
        bar.update(1)
    time_error = None
    if opt["time_check"]:
        sc = zeitlin_scene(s, points[-1])
        itg, out = sc["integrator"], sc["output"]
        half = sc.with_overrides({"integrator.h": itg["h"] / 2, "integrator.steps": 2 * itg["steps"],
                                  "output.every": 2 * out["every"]})
        key = point_key({"kind": "zeitlin_resolution", "scene": half.to_dict(), "method": opt["method"]})
        fine = cached_point(outdir, key, lambda: zr.simulate(half, method=opt["method"], progress=False))
        ref = runs[Ns[-1]]
        time_error = float(np.nanmax(_spectrum_difference(ref["energy_spectrum"].values,
                                                          fine["energy_spectrum"].values,
                                                          ref["energy"].values[:, 0], L)[:, -1]))
        bar.update(1)
    bar.close()
    finest = runs[Ns[-1]]
    H0 = finest["energy"].values[:, 0]
    rows, dfin, dnext = [], {}, {}
    for i, N in enumerate(Ns):
        ds = runs[N]
        if (ds["status"] != 0).any():
            raise ArithmeticError(f"zeitlin.N = {N}: {int((ds['status'] != 0).sum())} member(s) failed; "
                                  f"take a smaller integrator.h")
        spec = ds["energy_spectrum"].values
        dfin[N] = _spectrum_difference(spec, finest["energy_spectrum"].values, H0, L)
        if i + 1 < len(Ns):
            dnext[N] = _spectrum_difference(spec, runs[Ns[i + 1]]["energy_spectrum"].values, H0, L)
        H, q = ds["energy"].values, ds["heat"].values
        rows.append({
            "N": N,
            "Σ|ΔE_l| to the next N / H(0), t end": float(np.max(dnext[N][:, -1])) if N in dnext else np.nan,
            "Σ|ΔE_l| to the finest N / H(0), t end": float(np.max(dfin[N][:, -1])) if N != Ns[-1] else np.nan,
            "|H − H(finest)| / H(0), t end": (float(np.max(np.abs(H[:, -1] - finest["energy"].values[:, -1]) / H0))
                                              if N != Ns[-1] else np.nan),
            "heat / H(0), t end": float(np.mean(q[:, -1] / H[:, 0])),
            "cost per member-step (ms)": 1e3 * cost[N],
        })
    df = pd.DataFrame(rows)
    nxt = df["Σ|ΔE_l| to the next N / H(0), t end"].values
    df["ratio to the previous N's difference"] = np.concatenate([[np.nan], nxt[1:] / nxt[:-1]])
    sc0 = zeitlin_scene(s, points[0])
    itg = sc0["integrator"]
    t_end = itg["h"] * itg["steps"]
    out = _dataset(runs, Ns, dfin, dnext, time_error)
    out.attrs.update(title="liethermo: Zeitlin fluid, resolution study (one flow at several N)",
                     method=opt["method"], h=float(itg["h"]), h_units="s",
                     scene=sc0.to_toml(), degrees_compared=f"1 ... {L}")
    write_netcdf_atomic(out, study_netcdf_path(s, outdir),
                        history=study_history("zeitlin_resolution", s, outdir, reduced, history))
    figs = _figures(out, Ns, L, time_error, outdir)
    table = write_table(df, outdir, "resolution",
                        f"Energy spectrum at t = {t_end:g} s per N (the largest over the members)")
    shrink = bool(np.all(np.diff(nxt[:-1]) < 0))
    verdict = (f"The differences to the next N shrink at every N ({', '.join(f'{v:.2g}' for v in nxt[:-1])})"
               if shrink else
               f"The differences to the next N do not shrink at every N ({', '.join(f'{v:.2g}' for v in nxt[:-1])})")
    text = (f"Scene {sc0.name!r}: {sc0['ensemble']['members']} members, ν = "
            f"{sc0['fluid']['kinematic_viscosity']:g} s⁻¹, initial degrees l ≤ {sc0['initial']['lmax']} (the same "
            f"coefficients at every N), method {opt['method']}, h = {itg['h']:g} s, t = {t_end:g} s.  "
            f"Differences are Σ_l |ΔE_l| over the degrees l ≤ {L} that every N resolves, over H(0).  "
            f"{verdict}."
            + (f"  The time error at the finest N (the same run at h/2) is {time_error:.2g}, "
               f"{'below' if time_error < np.nanmin(nxt) else 'not below'} every difference in the table."
               if time_error is not None else "")
            + "\n\n" + "\n\n".join(f"![{f.stem}]({f.name})" for f in figs))
    return write_report(outdir, "Zeitlin fluid: resolution", [text, table])


def _dataset(runs: dict, Ns: list[int], dfin: dict, dnext: dict, time_error) -> xr.Dataset:
    keep = ("energy", "heat", "total_energy", "energy_error", "enstrophy", "angular_momentum", "energy_spectrum",
            "status")
    parts = [runs[N][list(keep)].expand_dims({"N": [N]}) for N in Ns]
    out = xr.concat(parts, dim="N", join="outer", combine_attrs="drop_conflicts")
    for v in keep:
        out[v].attrs = dict(runs[Ns[-1]][v].attrs)
    for c in ("t", "l", "member", "axis"):
        out[c].attrs = dict(runs[Ns[-1]][c].attrs)
    out["N"].attrs = {"units": "1", "long_name": "matrix size N (sweep)", "scene_key": SWEEP_KEY}
    nan = np.full_like(dfin[Ns[0]], np.nan)
    out["spectrum_difference_finest"] = xr.Variable(
        ("N", "member", "t"), np.stack([dfin[N] if N != Ns[-1] else nan for N in Ns]),
        {"units": "1", "long_name": "spectrum difference to the finest N",
         "comment": "Σ_l |E_l − E_l(finest N)| / H(0) over the degrees every N resolves"})
    out["spectrum_difference_next"] = xr.Variable(
        ("N", "member", "t"), np.stack([dnext.get(N, nan) for N in Ns]),
        {"units": "1", "long_name": "spectrum difference to the next N",
         "comment": "Σ_l |E_l − E_l(next N)| / H(0) over the degrees every N resolves"})
    if time_error is not None:
        out.attrs["time_error_at_finest_N"] = time_error
    return out


def _figures(ds: xr.Dataset, Ns: list[int], L: int, time_error, outdir) -> list[Path]:
    import warnings

    with warnings.catch_warnings():  # the degrees a smaller N lacks, and the finest N's own differences, are NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        return _draw(ds, Ns, L, time_error, outdir)


def _draw(ds: xr.Dataset, Ns: list[int], L: int, time_error, outdir) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11.5, 4.2), layout="constrained")
    cmap = plt.get_cmap("viridis")
    t_end = float(ds["t"].values[-1])
    for i, N in enumerate(Ns):
        spec = np.nanmean(ds["energy_spectrum"].sel(N=N).values[:, -1], axis=0)
        ls = ds["l"].values
        ok = np.isfinite(spec) & (spec > 0)
        axes[0].loglog(ls[ok], spec[ok], color=cmap(i / max(len(Ns) - 1, 1)), label=f"N = {N}")
    axes[0].axvline(L, color="0.5", lw=0.8, ls=":", label=f"l = {L}: the degrees compared")
    axes[0].set_xlabel("degree l")
    axes[0].set_ylabel(f"E_l at t = {t_end:g} s (J), member mean")
    axes[0].legend(fontsize=8)
    axes[0].set_title("energy spectrum: one flow at each N", fontsize=10)
    nxt = ds["spectrum_difference_next"].values[:, :, -1]
    fin = ds["spectrum_difference_finest"].values[:, :, -1]
    Nn = np.array(Ns, dtype=float)
    for vals, label, style in ((nxt, "to the next N", "o-"), (fin, "to the finest N", "s--")):
        y = np.nanmax(vals, axis=1)
        ok = np.isfinite(y) & (y > 0)
        axes[1].loglog(Nn[ok], y[ok], style, label=label)
    if time_error is not None and time_error > 0:
        axes[1].axhline(time_error, color="0.3", lw=0.9, ls=":", label="time error at the finest N (h/2)")
    axes[1].set_xlabel("N")
    axes[1].set_ylabel(f"Σ_l≤{L} |ΔE_l| / H(0) at t = {t_end:g} s (1)")
    axes[1].set_xticks(Nn, [str(n) for n in Ns])
    axes[1].minorticks_off()
    axes[1].legend(fontsize=8)
    axes[1].set_title("spectrum differences (largest over the members)", fontsize=10)
    fig.suptitle("Zeitlin fluid: convergence in N", fontsize=10)
    return [save(fig, Path(outdir) / "resolution.png")]
