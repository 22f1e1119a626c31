"""Energy-drift study: total-energy error over an ensemble of initial conditions.

Members are drawn by :func:`liethermo.initial.initial_conditions` (random
attitudes, uniform on SO(3); random spin directions; spin magnitudes in
``ensemble.spin_range`` × |initial.omega|).  Each method spec (``vi`` =
legendre start, ``vi4``, ``vi6``, ``rk2``, ``rk4``, the paper's
``vi:node:explicit``, …) runs at every swept h to ``t_end``.  The total
energy E = K + V + U is conserved by the continuous system, so E_k − E₀ is
pure error; it is computed on NODE values (Ω(t_k), Γ_k, S_k; the dataset's
``energy_error``) and measured relative to the initial mechanical energy
above the resting state, E_mech,0 = K₀ + V₀ + mgℓ.  For the specs listed in
``options.paper_convention`` the study also reports the paper's convention
(step velocity Ω_k with Γ_k, S_k; the dataset's ``energy_error_paper``) as
rows of their own, labelled "(paper convention)".

Per method and h the study reports the median and 5–95 % band over members
of max_k |E_k − E₀| / E_mech,0, the median final error, a fitted drift rate
(least-squares slope of (E_k − E₀)/E_mech,0 against t, per member) and the
number of members that failed (status ≠ 0) or diverged (max relative error
> ``diverged_above``).  Failed members count as +inf in every quantile.
The figure shows the quantile bands of |E_k − E₀| / E_mech,0 over time, one
panel per method and h; blown-up members are drawn at ``CLIP``.
"""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path

import numpy as np
import xarray as xr

from ..dataset import status_flags
from ..initial import initial_conditions
from ..physics import physics_of_scene
from .common import (method_overrides, study_options, StudyError, cached_point, dim_name, expand_sweep, parse_method, point_key, progress_bar,
                     stack_points, study_name, study_netcdf_path, study_scene, write_netcdf_atomic,
                     write_report, write_table, start_study, study_history, closing_section)
from .tools import NODE_VALUES_NOTE, energy_errors, run_spec

PAPER = " (paper convention)"

EXTRA_KEYS = ()
DEFAULT_OPTIONS = {"t_end": 30.0, "band_dt": 0.2, "member_chunk": 1024, "diverged_above": 1.0,
                   "paper_convention": ["vi:node:explicit"]}
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
    for m in opt["paper_convention"]:
        if m not in study["methods"] or parse_method(m)["family"] != "vi":
            raise StudyError(f"options.paper_convention: {m!r} must be a variational method of `methods`")


def _point(scene, spec: dict, opt: dict) -> xr.Dataset:
    h = float(scene["integrator"]["h"])
    steps = int(round(opt["t_end"] / h))
    band_every = int(round(opt["band_dt"] / h))
    N = int(scene["ensemble"]["members"])
    conventions = ["node"] + (["paper"] if spec["label"] in opt["paper_convention"] else [])
    t = np.arange(steps + 1) * h
    tb = t[::band_every]
    out = {c: {"band": np.empty((N, tb.size)), "max": np.empty(N), "final": np.empty(N),
               "drift": np.empty(N)} for c in conventions}
    emech = np.empty(N)
    status = np.empty(N, np.int8)
    newton = np.full(N, np.nan)
    wall = 0.0
    for lo in range(0, N, int(opt["member_chunk"])):
        hi = min(N, lo + int(opt["member_chunk"]))
        om0, R0 = initial_conditions(scene, lo, hi)
        phys = physics_of_scene(scene, hi - lo)
        tr = run_spec(phys, om0, R0, h, steps, spec)
        wall += tr.wall_time
        err = energy_errors(tr, om0, R0)
        ok = tr.status == 0
        em = err["scale"]
        for c in conventions:
            with np.errstate(over="ignore", invalid="ignore"):  # members blowing up before they fail
                rel = err[c] / em[:, None]
                arel = np.abs(rel)
            arel[~np.isfinite(arel)] = np.inf  # after a failure: counts as +inf
            o = out[c]
            o["band"][lo:hi] = arel[:, ::band_every]
            o["max"][lo:hi] = np.where(ok, arel.max(axis=1), np.inf)
            o["final"][lo:hi] = arel[:, -1]
            tc = t - t.mean()  # least-squares slope of rel(t) per member (1/s)
            with np.errstate(invalid="ignore", over="ignore"):
                slope = (rel - rel.mean(axis=1, keepdims=True)) @ tc / (tc @ tc)
            o["drift"][lo:hi] = np.where(ok, slope, np.nan)
        emech[lo:hi] = em
        status[lo:hi] = tr.status
        if tr.family == "vi":
            newton[lo:hi] = tr.newton_iterations / np.maximum(tr.steps_done, 1)
    q = np.asarray(QUANTILES)
    data = {}
    for c in ("node", "paper"):  # every point has both (NaN where a convention does not apply)
        o = out.get(c)
        nanN = np.full(N, np.nan)
        sfx = "" if c == "node" else "_paper"
        data[f"relative_energy_error_quantiles{sfx}"] = (
            ("quantile", "t"), np.quantile(o["band"], q, axis=0, method="inverted_cdf") if o
            else np.full((q.size, tb.size), np.nan))
        data[f"max_relative_energy_error{sfx}"] = (("member",), o["max"] if o else nanN)
        data[f"final_relative_energy_error{sfx}"] = (("member",), o["final"] if o else nanN)
        data[f"energy_drift_rate{sfx}"] = (("member",), o["drift"] if o else nanN)
    data.update({
        "mechanical_energy_initial": (("member",), emech),
        "status": (("member",), status),
        "newton_iterations_mean": (("member",), newton),
        "kernel_time": ((), wall),
    })
    return xr.Dataset(data, coords={"quantile": q, "t": tb, "member": np.arange(N)})


def _summary_row(ds: xr.Dataset, label: str, h: float, opt: dict, sfx: str = "") -> dict:
    mx = ds[f"max_relative_energy_error{sfx}"].values
    fin = ds[f"final_relative_energy_error{sfx}"].values
    dr = ds[f"energy_drift_rate{sfx}"].values
    st = ds["status"].values
    q05, q50, q95 = np.quantile(mx, QUANTILES, method="inverted_cdf")
    dr_ok = dr[np.isfinite(dr)]
    return {
        "method": label + (PAPER if sfx else ""), "energy": "paper convention" if sfx else "node values",
        "h (s)": h, "members": mx.size,
        "median max|dE|/Emech0": q50, "5% max|dE|/Emech0": q05, "95% max|dE|/Emech0": q95,
        "median final |dE|/Emech0": float(np.quantile(fin, 0.5, method="inverted_cdf")),
        "median drift rate (1/s)": float(np.median(dr_ok)) if dr_ok.size else float("nan"),
        "median |drift rate| (1/s)": float(np.median(np.abs(dr_ok))) if dr_ok.size else float("nan"),
        "failed members": int(np.sum(st != 0)),
        "diverged or failed members": int(np.sum((st != 0) | ~(mx <= opt["diverged_above"]))),
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
            scene = study_scene(study, dict(pt, **method_overrides(spec), **{
                "integrator.steps": int(round(opt["t_end"] / pt.get("integrator.h", 0.1))),
                "output.every": 1, "output.compare": []}))
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
            extra = {k: v for k, v in pt.items() if k != "integrator.h"}
            rows.append(_summary_row(ds, spec["label"], float(scene["integrator"]["h"]), opt) | extra)
            if spec["label"] in opt["paper_convention"]:
                rows.append(_summary_row(ds, spec["label"], float(scene["integrator"]["h"]), opt, "_paper")
                            | extra)
            bar.update(1)
    finally:
        bar.close()
    ds = stack_points(dsets, allpts, keys + ["scheme"])
    for sfx, what in (("", "on node values"),
                      ("_paper", "in the paper's convention (step velocity with Gamma_k, S_k; NaN where not "
                                 "requested or not a variational method)")):
        ds[f"relative_energy_error_quantiles{sfx}"].attrs.update(
            units="1", long_name=f"quantiles over members of |E_k - E_0| / E_mech,0 {what} (failed members: +inf)")
        ds[f"max_relative_energy_error{sfx}"].attrs.update(units="1", long_name=f"max_k |E_k - E_0| / E_mech,0 {what}")
        ds[f"final_relative_energy_error{sfx}"].attrs.update(units="1",
                                                             long_name=f"|E_K - E_0| / E_mech,0 at t_end {what}")
        ds[f"energy_drift_rate{sfx}"].attrs.update(
            units="s-1", long_name=f"least-squares slope of (E_k - E_0)/E_mech,0 in t {what}")
    ds["kernel_time"].attrs.update(units="s", long_name="kernel wall time of the point")
    ds["quantile"].attrs.update(units="1", long_name="quantile over members")
    ds["member"].attrs.update(units="1", long_name="ensemble member")
    ds["mechanical_energy_initial"].attrs.update(units="J", long_name="initial mechanical energy above the "
                                                 "resting state K_0 + V_0 + m g l")
    ds["status"].attrs.update(units="1", long_name="member status", **status_flags(np.int8))
    ds["newton_iterations_mean"].attrs.update(units="1", long_name="mean Newton iterations per step, summed "
                                              "over its solves (3 for vi4, 9 for vi6; NaN: explicit method)")
    ds["kernel_time"].attrs.update(units="s", long_name="kernel wall time of the point's ensemble")
    ds["t"].attrs.update(units="s", long_name="time since the start of the run, t_k = k h (band grid)")
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
             f"|Ω| in spin_range × |initial.omega|). Error: (E_k − E₀)/E_mech,0 with E_mech,0 = K₀ + V₀ + mgℓ "
             "(dimensionless). Rows marked *node values* use Ω(t_k), Γ_k, S_k for every method (`vi` = legendre "
             "start, symmetric entropy update; `vi:node:explicit` = the paper's start and entropy update); rows "
             "marked *paper convention* evaluate the same run's energy with the step velocity Ω_k instead "
             f"(`energy_error_paper`). 'failed members': members with status ≠ 0 (they blew up: the state "
             f"became non-finite, or Newton did not converge), out of 'members'; 'diverged or failed members': "
             f"those and the members whose max relative error passed {opt['diverged_above']:g}. Drift rate: per-member least-squares slope in t (s⁻¹). "
             f"Wall time {time.perf_counter() - t_start:.1f} s.")
    files = f"netCDF: `{nc.name}`; figures: " + ", ".join(f"`{f.name}`" for f in figs)
    return write_report(outdir, f"Energy-drift study: {study_name(study)}" + (" (reduced)" if reduced else ""),
                        [table, _finding(rows, ds), notes, NODE_VALUES_NOTE, files,
                         _closing(tasks, dsets, opt, members, outdir)])


def _closing(tasks, dsets, opt, members: int, outdir) -> str:
    """Cheapest (method, h) per level of the median max |E_k − E₀|/E_mech,0 (node values)."""
    pts = []
    for (pt, spec, scene, _), d in zip(tasks, dsets):
        mx = d["max_relative_energy_error"].values
        pts.append({"method": spec["label"], "error": float(np.quantile(mx, 0.5, method="inverted_cdf")),
                    "cost": float(d["kernel_time"]) / mx.size, "setting": f"h = {float(scene['integrator']['h']):g} s"})
    return closing_section(pts, regime=f"random ensemble of {members} members, t_end = {opt['t_end']} s", unit="s",
                           error="median over members of max_k |E_k − E₀|/E_mech,0, node values (1)",
                           cost="kernel wall time per member (s), as the study's runs measured it (default "
                                "kernel choice and threads)", outdir=outdir)


def _finding(rows: list, ds: xr.Dataset) -> str:
    """Per h: the methods ranked by the median of max |E_k − E_0|/E_mech,0, node values
    and paper convention apart."""
    out = ["**Finding.** Median over members of max_k |E_k − E₀| / E_mech,0, ranked per h (node values "
           "unless marked):", ""]
    by_h: dict = {}
    for r in rows:
        by_h.setdefault(r["h (s)"], []).append(r)
    for h, rs in by_h.items():
        rs = sorted(rs, key=lambda r: (not np.isfinite(r["median max|dE|/Emech0"]), r["median max|dE|/Emech0"]))
        out.append(f"- h = {h:g} s: " + "; ".join(
            f"{r['method']} {r['median max|dE|/Emech0']:.3g}"
            + (f" ({r['diverged or failed members']} of {r['members']} members diverged or failed)"
               if r["diverged or failed members"] > 0 else "")
            for r in rs))
    return "\n".join(out)


def _figures(ds: xr.Dataset, outdir: Path, keys) -> list[Path]:
    """One panel per method (rows) and h (columns), so that no band hides
    another: the 5–95 % band and the median over the members of
    |E_k − E₀|/E_mech,0 (node values; dashed: the median in the paper's
    convention).  A member that failed or whose error passed CLIP has blown
    up: it is drawn at CLIP (dotted line), and the panel's title counts them."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    hdim = dim_name("integrator.h")
    other = {dim_name(k): 0 for k in keys if k != "integrator.h"}
    if other:
        ds = ds.isel(other)
    hs = ds[hdim].values
    methods = [str(m) for m in ds["scheme"].values]
    N = int(ds.sizes["member"])
    t = ds["t"].values
    later = t > 0  # E_k − E₀ is 0 at t = 0: not on a log axis
    fig, axes = plt.subplots(len(methods), len(hs), figsize=(1.2 + 3.3 * len(hs), 1.0 + 1.75 * len(methods)),
                             sharex=True, sharey=True, squeeze=False, layout="constrained")
    positive, blown = [], False
    for r, m in enumerate(methods):
        for c, h in enumerate(hs):
            ax = axes[r, c]
            sel = {hdim: h, "scheme": m}
            q = ds["relative_energy_error_quantiles"].sel(sel).values
            lo, med, hi = (np.where(np.isnan(x), CLIP, np.minimum(x, CLIP)) for x in q)  # inf, NaN: blown up
            positive += [x[later & (x > 0)] for x in (lo, med)]
            ax.fill_between(t[later], lo[later], hi[later], color=f"C{r}", alpha=0.3, lw=0)
            ax.plot(t[later], med[later], "-", color=f"C{r}", lw=1.4)
            qp = ds["relative_energy_error_quantiles_paper"].sel(sel).values
            if not np.all(np.isnan(qp)):
                medp = np.minimum(np.where(np.isnan(qp[1]), CLIP, qp[1]), CLIP)
                ax.plot(t[later], medp[later], "--", color="k", lw=1.0)
            status = ds["status"].sel(sel).values
            mx = ds["max_relative_energy_error"].sel(sel).values
            n_blown = int(np.sum((status != 0) | ~(mx < CLIP)))
            blown |= bool(n_blown) or bool(np.any(hi >= CLIP))
            title = f"{m}, h = {h:g} s"
            if n_blown:
                title += f": {n_blown} of {N} blown up"
            ax.set_title(title, fontsize=9)
            ax.set_yscale("log")
            ax.grid(True, which="major", alpha=0.3)
    low = min((float(x.min()) for x in positive if x.size), default=1e-8)
    bottom = 10.0 ** np.floor(np.log10(max(low, 1e-16)))
    top = 3 * CLIP if blown else 10.0 ** np.ceil(np.log10(max(float(x.max()) for x in positive if x.size)))
    for ax in axes.ravel():
        ax.set_ylim(bottom, top)
        if blown:
            ax.axhline(CLIP, color="0.4", lw=0.8, ls=":")
    for ax in axes[-1]:
        ax.set_xlabel("t (s)")
    fig.supylabel("|E_k − E_0| / E_mech,0 (1), node values")
    handles = [Patch(color="0.5", alpha=0.3, label="5–95 % of the members"),
               Line2D([], [], color="0.3", lw=1.4, label="median"),
               Line2D([], [], color="k", ls="--", lw=1.0, label="median, paper's convention (step velocity)")]
    if blown:
        handles.append(Line2D([], [], color="0.4", ls=":", lw=0.8,
                              label=f"blown up: failed (non-finite), or the error above {CLIP:g}; drawn at {CLIP:g}"))
    fig.legend(handles=handles, loc="outside lower center", ncol=2, fontsize=8)
    fig.suptitle(f"energy error over {N} members per method and h")
    path = Path(outdir) / "energy_drift_bands.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]
