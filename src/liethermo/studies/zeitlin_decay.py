"""Viscous decay of the Zeitlin fluid: a viscosity sweep over an ensemble.

Per viscosity: the heat against the energy lost (their difference is the
method's total-energy error), the entropy produced (never decreasing, in
every member and every output), the enstrophy's decay, the spectrum's
evolution and the angular momentum kept."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from ..io import write_netcdf_atomic
from ..zeitlin import run as zr
from ..zeitlin.plotting import save, spectrum_lines
from ._zeitlin import zeitlin_scene
from .common import (StudyError, cached_point, expand_sweep, point_key, start_study, study_history,
                     study_netcdf_path, study_options, write_report, write_table)

EXTRA_KEYS = ()
SWEEP_KEY = "fluid.kinematic_viscosity"
DEFAULT_OPTIONS = {"method": "split"}


def options(s: dict) -> dict:
    return study_options(s, DEFAULT_OPTIONS, "zeitlin_decay")


def validate(s: dict) -> None:
    zeitlin_scene(s)
    if list((s.get("sweep") or {})) != [SWEEP_KEY]:
        raise StudyError(f"sweep: a zeitlin_decay study sweeps exactly one key, {SWEEP_KEY!r}")
    if options(s)["method"] not in zr.METHOD_ORDER:
        raise StudyError(f"options.method: one of {', '.join(zr.METHOD_ORDER)}")


def run(study: dict, outdir: Path, *, reduced: bool, progress=None, dask=None, history=None) -> Path:
    s, outdir, opt = start_study(study, outdir, reduced, validate, options)
    points = expand_sweep(s["sweep"])
    rows, dss = [], []
    for pt in points:
        sc = zeitlin_scene(s, pt)
        # each viscosity's ensemble is a point of the resume cache: a stopped study goes on from it
        key = point_key({"kind": "zeitlin_decay", "scene": sc.to_dict(), "method": opt["method"]})
        ds = cached_point(outdir, key, lambda sc=sc: zr.simulate(sc, method=opt["method"], progress=progress))
        nu = float(pt[SWEEP_KEY])
        H, q = ds["energy"].values, ds["heat"].values
        lost = H[:, :1] - H
        L = ds["angular_momentum"].values
        Z = ds["enstrophy"].values
        dS = np.diff(ds["entropy"].values, axis=1)
        rows.append({"viscosity (s-1)": nu, "heat / H(0) at the end": float(np.mean(q[:, -1] / H[:, 0])),
                     "max |q − (H(0) − H)| / H(0)": float(np.max(np.abs(q - lost) / H[:, :1])),
                     "entropy produced (J K-1)": float(np.mean(ds["entropy"].values[:, -1])),
                     "smallest entropy change per output (J K-1)": float(dS.min()),
                     "enstrophy Z(t_end) / Z(0)": float(np.mean(Z[:, -1] / Z[:, 0])),
                     "angular momentum drift (relative)": float(np.max(np.abs(L - L[:, :1])) / np.abs(L).max()),
                     "members failed": int((ds["status"] != 0).sum())})
        dss.append(ds.drop_vars([v for v in ("vorticity_real", "vorticity_imag") if v in ds])
                   .expand_dims({"viscosity": [nu]}))
    df = pd.DataFrame(rows)
    out = xr.concat(dss, dim="viscosity")
    out["viscosity"].attrs = {"units": "s-1", "long_name": "kinematic viscosity nu (sweep)", "scene_key": SWEEP_KEY}
    sc0 = zeitlin_scene(s, points[0])
    ref = zr.simulate(sc0.with_overrides({"integrator.steps": sc0["output"]["every"]}), method=opt["method"],
                      progress=False)
    for v in ref.data_vars:
        if v in out:
            out[v].attrs = dict(ref[v].attrs)
    for c in ("t", "k", "l", "member"):
        out[c].attrs = dict(ref[c].attrs)
    out.attrs.update(title="liethermo: Zeitlin fluid, viscous decay (viscosity sweep)", method=opt["method"],
                     N=int(sc0["zeitlin"]["N"]), h=float(sc0["integrator"]["h"]))
    write_netcdf_atomic(out, study_netcdf_path(s, outdir),
                        history=study_history("zeitlin_decay", s, outdir, reduced, history))
    figs = _figures(out, outdir)
    table = write_table(df, outdir, "decay", "Energy into heat, entropy, enstrophy and angular momentum per viscosity")
    text = (f"Scene {sc0.name!r}: N = {sc0['zeitlin']['N']}, {sc0['ensemble']['members']} members, method "
            f"{opt['method']}, h = {sc0['integrator']['h']:g} s, t = "
            f"{sc0['integrator']['h'] * sc0['integrator']['steps']:g} s.  The heat equals the energy lost up "
            f"to the method's total-energy error; the entropy change per output is never negative; the "
            f"angular momentum (the l = 1 modes) is not damped.\n\n" + "\n\n".join(f"![{f.stem}]({f.name})" for f in figs))
    return write_report(outdir, "Zeitlin fluid: viscous decay", [text, table])


def _figures(ds, outdir) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = ds["t"].values
    nus = ds["viscosity"].values
    out = []
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2), layout="constrained")
    for nu in nus:
        d = ds.sel(viscosity=nu)
        H0 = d["energy"].values[:, :1]
        lost = np.nanmean((H0 - d["energy"].values) / H0, axis=0)
        heat = np.nanmean(d["heat"].values / H0, axis=0)
        axes[0].plot(lost, heat, label=f"ν = {nu:g}")
        axes[1].plot(t, np.nanmean(d["entropy"].values, axis=0), label=f"ν = {nu:g}")
        Z = d["enstrophy"].values
        axes[2].semilogy(t, np.nanmean(Z / Z[:, :1], axis=0), label=f"ν = {nu:g}")
    lim = axes[0].get_xlim()
    axes[0].plot(lim, lim, "k:", lw=0.8, label="q = H(0) − H")
    axes[0].set_xlabel("energy lost (H(0) − H)/H(0)")
    axes[0].set_ylabel("heat q / H(0)")
    axes[1].set_xlabel("time t (s)")
    axes[1].set_ylabel("entropy produced (J K⁻¹)")
    axes[1].ticklabel_format(axis="y", style="sci", scilimits=(-2, 3))
    axes[2].set_xlabel("time t (s)")
    axes[2].set_ylabel("enstrophy Z(t)/Z(0)")
    for a in axes:
        a.legend(fontsize=8)
    fig.suptitle("Zeitlin fluid: energy into heat, entropy, enstrophy (member means)", fontsize=10)
    out.append(save(fig, Path(outdir) / "decay.png"))
    fig, axes = plt.subplots(1, len(nus), figsize=(3.8 * len(nus) + 0.6, 3.6), sharey=True, squeeze=False,
                             layout="constrained")
    for a, nu in zip(axes[0], nus):
        spectrum_lines(a, ds["l"].values, t, np.nanmean(ds["energy_spectrum"].sel(viscosity=nu).values, axis=0), 5)
        a.set_title(f"ν = {nu:g} s⁻¹", fontsize=9)
        a.set_xlabel("degree l")
    axes[0][0].set_ylabel("E_l (J)")
    axes[0][-1].legend(fontsize=7)
    fig.suptitle("energy spectrum over time", fontsize=10)
    out.append(save(fig, Path(outdir) / "spectrum.png"))
    return out
