"""Long runs of the Zeitlin fluid: Casimir and energy drift of the split family
against RK4 at equal *measured* cost.

Per (N, ν): one step of each method is timed warm on the ensemble; RK4's step
is then chosen so that its measured wall time per simulated second equals the
split method's (``h_rk4 = h · cost_rk4 / cost_split``, both at least 0.2 s of
timing).  Both run to ``t_end``; while the two runs' measured kernel times
differ by more than 10 %, RK4 runs again with its step corrected by their
ratio (at most three runs).  The report gives the measured cost of each run
per simulated second next to the drifts, so the equality is checked, not
assumed."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from ..io import write_netcdf_atomic
from ..zeitlin import kernels as zk
from ..zeitlin import run as zr
from ..zeitlin.plotting import save
from ._zeitlin import advance, check_methods, step_seconds, zeitlin_scene
from .common import (StudyError, cached_point, point_key, start_study, study_history, study_netcdf_path, study_options,
                     write_report, write_table)

EXTRA_KEYS = ()
DEFAULT_OPTIONS = {"N": [32, 64], "viscosity": [0.0, 1e-4], "h": 0.02, "t_end": 100.0, "samples": 50}


def options(s: dict) -> dict:
    return study_options(s, DEFAULT_OPTIONS, "zeitlin_structure")


def validate(s: dict) -> None:
    zeitlin_scene(s)
    methods = check_methods(s)
    if "rk4" not in methods or len(methods) < 2:
        raise StudyError("methods: rk4 and at least one split method (the comparison is against RK4)")
    opt = options(s)
    if not all(isinstance(n, int) and 3 <= n <= 1024 for n in opt["N"]):
        raise StudyError("options.N: a list of integers in [3, 1024]")


def _drifts(W0, W, q, b):
    a, z = zk.diagnostics(W0, b), zk.diagnostics(W, b)
    change = np.abs(zk.casimir_change(z["cas"], a["cas"], b))  # as the dataset's casimir_drift
    return {"cas2": np.max(change[:, 0]), "cas4": np.max(change[:, 2]),
            "energy": np.max(np.abs(z["H"] + q - a["H"]) / a["H"]),
            "L": np.max(np.abs(z["L"] - a["L"])) / np.abs(a["L"]).max()}


def _long_run(meth, W0, h, T, samples, nu, b):
    """(kernel wall, h, steps, final drifts, iterations per step, [drifts at each sample])."""
    per = max(int(round(T / h / samples)), 1)
    h = T / (per * samples)
    W, q = W0.copy(), np.zeros(W0.shape[0])
    wall, its, seg = 0.0, [], []
    state: dict = {}
    for j in range(samples):
        t0 = time.perf_counter()
        W, q, it = advance(meth, W, q, h, per, nu, b, state=state)
        wall += time.perf_counter() - t0
        its.append(it)
        d = _drifts(W0, W, q, b)
        seg.append({"t": (j + 1) * per * h, **d})
    return wall, h, per * samples, d, float(np.mean(its)), seg


def _pair(m: str, W0, h: float, T: float, samples: int, nu: float, b, N: int) -> tuple[list, list]:
    """A splitting and RK4 at the same measured cost: (table rows, drift curves)."""
    rows, curves = [], []
    c_split = step_seconds(m, W0, h, nu, b)
    c_rk4 = step_seconds("rk4", W0, h, nu, b)
    wall_split = None
    for meth, hm in ((m, h), ("rk4", h * c_rk4 / c_split)):
        for attempt in range(3):  # RK4 again with a corrected step while the costs differ by > 10 %
            res = _long_run(meth, W0, hm, T, samples, nu, b)
            if wall_split is None or abs(res[0] / wall_split - 1.0) <= 0.1:
                break
            hm = res[1] * res[0] / wall_split
        wall, hm, steps, d, its, seg = res
        wall_split = wall if wall_split is None else wall_split
        curves += [{"N": N, "viscosity": nu, "pair": m, "method": meth, **c} for c in seg]
        rows.append({"N": N, "viscosity (s-1)": nu, "pair": m, "method": meth, "h (s)": hm,
                     "steps": steps, "wall per simulated second (s)": wall / T,
                     "tr W² drift": d["cas2"], "tr W⁴ drift": d["cas4"],
                     "|H + q − H(0)|/H(0)": d["energy"], "angular momentum drift": d["L"],
                     "fixed-point its/step": its})
    return rows, curves


def _records_dataset(rows: list, curves: list) -> xr.Dataset:
    """Table rows and curve points as a dataset (columns by position: their names are no netCDF names)."""
    data, attrs = {}, {}
    for prefix, records in (("row", rows), ("curve", curves)):
        df = pd.DataFrame(records)
        attrs[f"{prefix}_columns"] = json.dumps(list(df.columns))
        for i, c in enumerate(df.columns):
            v = df[c].to_numpy()
            data[f"{prefix}{i}"] = ((prefix,), v.astype(str) if v.dtype == object else v)
    return xr.Dataset(data, attrs=attrs)


def _dataset_records(ds: xr.Dataset) -> tuple[list, list]:
    out = []
    for prefix in ("row", "curve"):
        cols = json.loads(ds.attrs[f"{prefix}_columns"])
        vals = [ds[f"{prefix}{i}"].values for i in range(len(cols))]
        out.append([{c: (v[k].item() if hasattr(v[k], "item") else v[k]) for c, v in zip(cols, vals)}
                    for k in range(ds.sizes[prefix])])
    return out[0], out[1]


def run(study: dict, outdir: Path, *, reduced: bool, progress=None, dask=None, history=None) -> Path:
    s, outdir, opt = start_study(study, outdir, reduced, validate, options)
    methods = check_methods(s)
    split_methods = [m for m in methods if m != "rk4"]
    rows, curves = [], []
    T, samples = float(opt["t_end"]), int(opt["samples"])
    for N in opt["N"]:
        for nu in opt["viscosity"]:
            sc = zeitlin_scene(s, {"zeitlin.N": int(N), "fluid.kinematic_viscosity": float(nu)})
            b = zk.basis(int(N))
            W0 = zr.initial_fields(sc)
            for m in split_methods:
                # each pair is a point of the resume cache (its rows, curves and measured costs):
                # a stopped study goes on from the pairs it finished
                key = point_key({"kind": "zeitlin_structure", "scene": sc.to_dict(), "pair": m, "h": float(opt["h"]),
                                 "t_end": T, "samples": samples})
                pt = cached_point(outdir, key, lambda m=m, b=b, W0=W0, N=N, nu=nu: _records_dataset(
                    *_pair(m, W0, float(opt["h"]), T, samples, float(nu), b, int(N))))
                r, c = _dataset_records(pt)
                rows += r
                curves += c
    df = pd.DataFrame(rows)
    cv = pd.DataFrame(curves)
    ds = xr.Dataset.from_dataframe(cv.rename(columns={"viscosity": "viscosity"})).rename({"index": "row"})
    units = {"N": "1", "viscosity": "s-1", "t": "s", "cas2": "1", "cas4": "1", "energy": "1", "L": "1"}
    for v, u in units.items():
        ds[v].attrs["units"] = u
    ds.attrs.update(title="liethermo: Zeitlin fluid, Casimir and energy drift at equal measured cost", t_end=T)
    write_netcdf_atomic(ds, study_netcdf_path(s, outdir),
                        history=study_history("zeitlin_structure", s, outdir, reduced, history))
    fig = _figure(cv, outdir)
    table = write_table(df, outdir, "drift", "Drift after t_end at equal measured cost per simulated second")
    sc0 = zeitlin_scene(s)
    text = (f"{sc0['ensemble']['members']} members of scene {sc0.name!r} (its initial field, at each N), "
            f"t = {T:g} s.  Drifts are the maxima over members at t_end: Casimirs relative to tr((−iW)²)(0)^(k/2), "
            f"angular momentum relative to its size.  At ν > 0 the Casimirs decay physically: their columns "
            f"then show that change, which every method gets alike; the angular momentum is undamped at every ν.  "
            f"RK4's step is set from warm timings so that both methods "
            f"cost the same wall time per simulated second; the measured cost of each whole run is in the "
            f"table.\n\n![drift]({fig.name})")
    return write_report(outdir, "Zeitlin fluid: structure over long runs", [text, table])


def _figure(cv, outdir) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = list(cv.groupby(["N", "viscosity"]).groups)
    fig, axes = plt.subplots(2, len(keys), figsize=(3.9 * len(keys) + 0.8, 6.2), squeeze=False, sharex=True,
                             layout="constrained")
    for j, (N, nu) in enumerate(keys):
        g = cv[(cv["N"] == N) & (cv["viscosity"] == nu)]
        for (pair, meth), gg in g.groupby(["pair", "method"], sort=False):
            lab = meth if meth != "rk4" else f"rk4 (cost of {pair})"
            axes[0][j].semilogy(gg["t"], np.maximum(gg["cas2"], 1e-17), label=lab)
            axes[1][j].semilogy(gg["t"], np.maximum(gg["energy"], 1e-17), label=lab)
        axes[0][j].set_title(f"N = {N}, ν = {nu:g} s⁻¹", fontsize=9)
        if nu > 0:
            axes[0][j].text(0.04, 0.06, "viscosity dissipates tr W²:\nthe change is physical", fontsize=7,
                            transform=axes[0][j].transAxes)
        axes[1][j].set_xlabel("time t (s)")
    axes[0][0].set_ylabel("tr W² drift (relative)")
    axes[1][0].set_ylabel("|H + q − H(0)| / H(0)")
    axes[0][-1].legend(fontsize=7)
    fig.suptitle("Zeitlin fluid: split family against RK4 at equal measured cost", fontsize=10)
    return save(fig, Path(outdir) / "drift.png")
