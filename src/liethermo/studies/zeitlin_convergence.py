"""Observed orders of the Zeitlin fluid's methods against the DOP853 reference.

The members of the base scene are integrated to ``t_end`` with h = h0, h0/2, …;
the error is max |W − W_ref| / max |W_ref| over members, and the heat's error
|q − q_ref| / H(0).  Orders between neighbouring levels; the wall time is warm
(compiled first) per member-step."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from ..io import write_netcdf_atomic
from ..zeitlin import kernels as zk
from ..zeitlin import run as zr
from ..zeitlin.plotting import save
from ._zeitlin import advance, check_methods, zeitlin_scene
from .common import (cached_point, point_key, start_study, study_history, study_netcdf_path, study_options,
                     write_report, write_table)

EXTRA_KEYS = ()
DEFAULT_OPTIONS = {"h0": 0.1, "levels": 4, "t_end": 1.0}


def options(s: dict) -> dict:
    return study_options(s, DEFAULT_OPTIONS, "zeitlin_convergence")


def validate(s: dict) -> None:
    zeitlin_scene(s)
    check_methods(s)
    opt = options(s)
    if int(opt["levels"]) < 2:
        raise ValueError("options.levels: at least 2 (an order needs two levels)")


def run(study: dict, outdir: Path, *, reduced: bool, progress=None, dask=None, history=None) -> Path:
    s, outdir, opt = start_study(study, outdir, reduced, validate, options)
    sc = zeitlin_scene(s)
    b = zk.basis(sc["zeitlin"]["N"])
    nu = float(sc["fluid"]["kinematic_viscosity"])
    T = float(opt["t_end"])
    W0 = zr.initial_fields(sc)
    M = W0.shape[0]
    # the reference and every (method, h) are points of the resume cache: a stopped study goes on from them
    base = {"kind": "zeitlin_convergence", "scene": sc.to_dict(), "t_end": T}
    ref = cached_point(outdir, point_key({**base, "reference": True}), lambda: _reference(sc, W0, T, progress))
    Wr = ref["W_real"].values + 1j * ref["W_imag"].values
    qr = ref["q"].values
    H0 = zk.energy_of_modes(zk.to_modes(W0, b), b)
    rows = []
    hs = [float(opt["h0"]) / 2 ** k for k in range(int(opt["levels"]))]
    for m in check_methods(s):
        prev = None
        for h in hs:
            pt = cached_point(outdir, point_key({**base, "method": m, "h": h}),
                              lambda m=m, h=h: _errors(sc, W0, m, h, T, Wr, qr, H0))
            err = float(pt["error_W"])
            rows.append({"method": m, "h (s)": h, "error W": err, "order": np.log2(prev / err) if prev else np.nan,
                         "error q / H(0)": float(pt["error_q"]), "fixed-point its/step": float(pt["its"]),
                         "wall per member-step (s)": float(pt["wall"])})
            prev = err
    df = pd.DataFrame(rows)
    ds = xr.Dataset.from_dataframe(df.rename(columns=lambda c: c.split(" (")[0].replace(" ", "_").replace("/", "per")
                                             .replace("-", "_").replace("(", "").replace(")", "")))
    ds = ds.rename({"index": "row"})
    ds.attrs.update(title="liethermo: Zeitlin fluid, observed orders against DOP853", N=int(b.N), viscosity=nu,
                    t_end=T, members=M)
    for v in ds.data_vars:
        ds[v].attrs["units"] = "s" if v in ("h", "wall_per_member_step") else "1"
    write_netcdf_atomic(ds, study_netcdf_path(s, outdir), history=study_history("zeitlin_convergence", s, outdir,
                                                                                  reduced, history))
    fig = _figure(df, outdir, b.N, nu, T)
    table = write_table(df, outdir, "orders", "Errors and observed orders against the reference")
    text = (f"N = {b.N}, ν = {nu:g} s⁻¹, t = {T:g} s, {M} members of scene {sc.name!r}; reference: DOP853 at rtol "
            f"{zr.REFERENCE_RTOL:g}.  Error: max |W − W_ref| / max |W_ref|; order: log2 of the error ratio of "
            f"neighbouring levels.  Wall times are warm (compiled first).\n\n![errors]({fig.name})")
    return write_report(outdir, "Zeitlin fluid: convergence", [text, table])


def _reference(sc, W0, T: float, progress) -> xr.Dataset:
    """DOP853 of the members from W0 to T: W(T) and q(T)."""
    b = zk.basis(sc["zeitlin"]["N"])
    M = W0.shape[0]
    status = np.zeros(M, np.int8)
    Ws = np.empty((M, 2) + W0.shape[1:], complex)
    qs = np.empty((M, 2))
    zr.reference_run(W0, np.array([0.0, T]), float(sc["fluid"]["kinematic_viscosity"]), b, Ws, qs, status, progress)
    dims = ("member", "row", "col")
    return xr.Dataset({"W_real": (dims, Ws[:, 1].real), "W_imag": (dims, Ws[:, 1].imag),
                       "q": (("member",), qs[:, 1]), "status": (("member",), status)})


def _errors(sc, W0, m: str, h: float, T: float, Wr, qr, H0) -> xr.Dataset:
    """One method at one step: its errors against the reference, iterations and warm wall time."""
    b = zk.basis(sc["zeitlin"]["N"])
    nu = float(sc["fluid"]["kinematic_viscosity"])
    M = W0.shape[0]
    advance(m, W0[:1], np.zeros(1), h, 1, nu, b)  # warm
    n = int(round(T / h))
    t0 = time.perf_counter()
    W, q, its = advance(m, W0, np.zeros(M), h, n, nu, b, sc["integrator"]["composition"],
                        sc["integrator"]["tol"], sc["integrator"]["max_iter"])
    wall = (time.perf_counter() - t0) / (n * M)
    return xr.Dataset({"error_W": float(np.abs(W - Wr).max() / np.abs(Wr).max()),
                       "error_q": float(np.max(np.abs(q - qr) / H0)), "its": float(its), "wall": wall})


def _figure(df, outdir, N, nu, T) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.2, 4.2), layout="constrained")
    for m, g in df.groupby("method", sort=False):
        ax.loglog(g["h (s)"], g["error W"], "o-", label=m)
    ax.set_xlabel("step h (s)")
    ax.set_ylabel("max |W − W_ref| / max |W_ref|")
    ax.set_title(f"Zeitlin fluid, N = {N}, ν = {nu:g} s⁻¹, t = {T:g} s")
    ax.legend()
    return save(fig, Path(outdir) / "convergence.png")
