"""Paper study: the paper's figures and what each erratum or choice changes.

Runs the paper scene (single member, h = 0.1 s, 30 s) with the methods of
the study (the paper compares its VI — ``vi:node:explicit``: first step
velocity Ω(0), explicit entropy update — with RK2) and writes the paper's
figures (centre of mass, energies, total energy, entropy) through
:func:`liethermo.plotting.scene_figures`.  Then it runs one VI variant per
choice — the variant differs from the paper's printed scheme in that one
respect — and the high-accuracy reference of both the printed and the
corrected inertia, and tabulates what changes:

* E3 friction: trapezoid (printed integrator) vs endpoint (the paper's f_d^±);
* E4 start: node (paper) vs staggered (Ω₀ = Ω(h/2)) vs legendre (μ₀ = 𝕀Ω(0));
* entropy update: explicit (paper) vs symmetric (U(S') − U(S) = friction work);
* E5 inertia: printed values vs the moments about the fixed centre
  (solid hemisphere 2/5 m₁a², thin shell 2/3 m₂a², on every axis).

E1 (singular printed R₀) and E2 (missing h in the Γ update) are not
runnable variants: the table shows the determinant of the printed R₀ and
the first-step change of Γ made by the missing factor h.  Every number is
on node values (Ω(t_k), Γ_k, S_k); the energy column of the paper's
convention is given beside it.
"""

from __future__ import annotations

import math
import time
from functools import partial
from pathlib import Path

import numpy as np
import xarray as xr

from ..runner import run_scene
from .common import (StudyError, cached_point, method_overrides, parse_method, point_key, progress_bar,
                     resolve_study, study_name, study_netcdf_path, study_scene, write_netcdf_atomic,
                     write_report, write_table, study_history, closing_fact, kept_laws)
from .tools import NODE_VALUES_NOTE

EXTRA_KEYS = ()

#: name → (erratum, what differs, scene overrides)
VARIANTS = {
    "paper": ("—", "the paper's printed scheme: trapezoid friction, node start, explicit entropy update, "
                   "printed inertia", {}),
    "endpoint_friction": ("E3", "friction = endpoint (c Ω_{k+1})", {"integrator.friction": "endpoint"}),
    "staggered_start": ("E4", "start = staggered (Ω₀ = Ω(h/2))", {"integrator.start": "staggered"}),
    "legendre_start": ("E4", "start = legendre (node momentum μ₀ = 𝕀Ω(0))", {"integrator.start": "legendre"}),
    "symmetric_entropy": ("—", "entropy update = symmetric (U(S') − U(S) = friction work of the step)",
                          {"integrator.entropy": "symmetric"}),
    "corrected_inertia": ("E5", "inertia about C: (2/5 m₁ + 2/3 m₂) a² on every axis", {"body.inertia": "corrected"}),
}
#: the paper's integrator choices, on which each variant changes one
PAPER_CHOICES = {"integrator.start": "node", "integrator.friction": "trapezoid", "integrator.entropy": "explicit"}


def validate(study: dict) -> None:
    for m in study.get("methods", []):
        parse_method(m)


def _corrected_inertia(scene: dict) -> list[float]:
    b = scene["body"]
    a = float(b["radius"])
    m = 4.0 / 3.0 * math.pi * a**3 * float(b["density"])
    m1 = float(b["upper_mass_fraction"]) * m
    m2 = m - m1
    I = (0.4 * m1 + 2.0 / 3.0 * m2) * a * a
    return [I, I, I]


def _variant_scene(study: dict, name: str, method: str = "vi"):
    over = dict(PAPER_CHOICES, **VARIANTS[name][2])
    if over.get("body.inertia") == "corrected":
        over["body.inertia"] = _corrected_inertia(study_scene(study))
    over["integrator.method"] = method
    over["output.compare"] = []
    over["output.figures"] = False
    return study_scene(study, over)


def _scene_dataset(scene) -> xr.Dataset:
    """One run of the study: the scene's dataset (module level: a Dask task)."""
    return run_scene(scene, progress=False)[0]


def run(study: dict, outdir: Path, *, reduced: bool, progress: bool | None, dask: str | None = None,
        history: str | None = None) -> Path:
    study = resolve_study(study, reduced)
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    specs = [parse_method(m) for m in study.get("methods", ["vi:node:explicit", "rk2"])]
    if study.get("sweep"):
        raise StudyError("sweep: the paper study has no sweep (it runs the paper scene and its errata variants)")
    # every run of the study: (name in runs, key, scene); the figure runs keep their file for the figures
    figure_runs, tasks = [], []
    for spec in specs:
        scene = study_scene(study, {**method_overrides(spec), "output.compare": [], "output.figures": False})
        key = point_key({"figure_run": spec, "scene": scene})
        figure_runs.append((spec, key))
        tasks.append((f"paper_{spec['label']}", key, scene))
    for name in VARIANTS:
        scene = _variant_scene(study, name)
        tasks.append((f"vi_{name}", point_key({"variant": name, "scene": scene}), scene))
    for name in ("paper", "corrected_inertia"):
        scene = _variant_scene(study, name, "reference")
        tasks.append((f"reference_{name}", point_key({"reference": name, "scene": scene}), scene))
    if dask is not None:  # compute the missing runs as Dask tasks into the same cache
        from ..distributed import map_cached_points

        map_cached_points(outdir, [(key, _scene_dataset, (scene,)) for _, key, scene in tasks if key], dask,
                          progress=progress)
    bar = progress_bar(sum(1 for t in tasks if t[1]), progress, f"{study_name(study)} runs")
    runs: dict[str, xr.Dataset] = {}
    try:
        for name, key, scene in tasks:
            runs[name] = cached_point(outdir, key, partial(_scene_dataset, scene)).isel(member=0)
            bar.update(1)
    finally:
        bar.close()
    # 1. the paper's figures: each method on the paper scene (full dataset, member kept)
    fig_paths = {spec["label"]: outdir / "points" / f"{key}.nc" for spec, key in figure_runs}

    from ..plotting import scene_figures

    figs = scene_figures(fig_paths, outdir, stem="paper")

    base = runs["vi_paper"]
    rows = []
    for name, (err, what, _) in VARIANTS.items():
        ds = runs[f"vi_{name}"]
        ref = runs["reference_corrected_inertia" if name == "corrected_inertia" else "reference_paper"]
        rel = np.abs(ds["energy_error"].values) / float(ds["mechanical_energy_initial"])
        relp = np.abs(ds["energy_error_paper"].values) / float(ds["mechanical_energy_initial"])
        rows.append({
            "variant": name, "erratum": err, "what differs": what,
            "Omega(t_end) (rad/s)": np.array2string(ds["omega"].values[-1], precision=4, separator=", "),
            "|ΔOmega| vs paper": float(np.linalg.norm(ds["omega"].values[-1] - base["omega"].values[-1])),
            "|ΔGamma| vs paper": float(np.linalg.norm(ds["gamma"].values[-1] - base["gamma"].values[-1])),
            "S(t_end) (J/K)": float(ds["entropy"].values[-1]),
            "max |E_k-E_0|/Emech0 (node values)": float(np.nanmax(rel)),
            "max |E_k-E_0|/Emech0 (paper convention)": float(np.nanmax(relp)),
            "max_t |Gamma - Gamma_ref|": float(np.nanmax(np.linalg.norm(ds["gamma"].values - ref["gamma"].values,
                                                                        axis=-1))),
        })
    R_printed = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 0, 1.0]])
    sc = study_scene(study)
    w0 = np.asarray(sc["initial"]["omega"], float)
    g0 = np.asarray(sc["initial"]["R"], float)[2]
    h = float(sc["integrator"]["h"])
    rows.append({"variant": "printed_R0", "erratum": "E1",
                 "what differs": f"printed R0 = [[1,0,0],[0,0,-1],[0,0,1]]: det = {np.linalg.det(R_printed):g}, "
                                 "not a rotation (not runnable)"})
    dg = np.linalg.norm(_cay(-w0, g0) - _cay(-h * w0, g0))
    rows.append({"variant": "printed_gamma_update", "erratum": "E2",
                 "what differs": f"Gamma update without h: after the first step Gamma is {dg:.3g} away from "
                                 f"cay(-h Omega_0) Gamma_0 (not runnable)"})
    table = write_table(rows, outdir, "errata", "What each erratum or choice changes (VI, paper scene; node "
                        "values: differences at t_end, error against the reference over all t_k)")

    # the netCDF: the run datasets' variables with a 'variant' dimension
    names = list(runs)
    keep = ["omega", "gamma", "entropy", "temperature", "kinetic_energy", "potential_energy", "internal_energy",
            "total_energy", "energy_error", "status", "mechanical_energy_initial"]
    parts = [runs[k][keep].drop_vars([c for c in runs[k][keep].coords if c not in ("t", "axis")])
             for k in names]
    ds = xr.concat(parts, dim="variant", data_vars="all", coords="minimal", compat="override", join="override")
    ds = ds.assign_coords(variant=names)
    ds.attrs.update({"title": "liethermo paper study: the paper's runs and what each erratum changes",
                     "study": study_name(study), "kind": "paper", "reduced": int(reduced),
                     "h": h, "steps": int(sc["integrator"]["steps"]),
                     "variants": "paper_<method>: the paper's figure runs; vi_<variant>: errata variants; "
                                 "reference_<inertia>: DOP853 reference"})
    nc = write_netcdf_atomic(ds, study_netcdf_path(study, outdir),
                             history=study_history("paper", study, outdir, reduced, history))
    summary_rows = []
    for k in names:
        r = runs[k]
        summary_rows.append({"run": k, "status": int(r["status"]),
                             "max |E_k-E_0|/Emech0 (node values)": float(
                                 np.nanmax(np.abs(r["energy_error"].values)) / float(r["mechanical_energy_initial"])),
                             "S(t_end) (J/K)": float(r["entropy"].values[-1])})
    runs_table = write_table(summary_rows, outdir, "runs", "All runs")
    notes = (f"Paper scene, h = {h} s, {sc['integrator']['steps']} steps; figure runs: "
             + ", ".join(f"`{s['label']}`" for s in specs) + ". Figures (node values): "
             + ", ".join(f"`{f.name}`" for f in figs) + f"; netCDF: `{nc.name}`. "
             f"Wall time {time.perf_counter() - t_start:.1f} s.")
    return write_report(outdir, f"Paper study: {study_name(study)}" + (" (reduced)" if reduced else ""),
                        [table, notes, NODE_VALUES_NOTE, runs_table,
                         _closing(runs, [sp["label"] for sp, _ in figure_runs], h)])


def _closing(runs: dict, labels: list, h: float) -> str:
    """The closing section: the paper's runs are not timed, so the analogous
    fact — each figure run's error against the reference at the paper's h."""
    ref = runs["reference_paper"]
    rows = []
    for lab in labels:
        d = runs[f"paper_{lab}"]
        if d["gamma"].shape != ref["gamma"].shape:
            continue
        e = float(np.nanmax(np.linalg.norm(d["gamma"].values - ref["gamma"].values, axis=-1)))
        rows.append({"method": lab, "max_t |Γ − Γ_ref| (1)": e if int(d["status"]) == 0 else float("inf"),
                     "keeps": kept_laws(lab)})
    ranked = sorted(rows, key=lambda r: r["max_t |Γ − Γ_ref| (1)"])
    sentence = ("**Most accurate at the paper's step:** " + "; then ".join(
        f"{r['method']} ({r['max_t |Γ − Γ_ref| (1)']:.2e})" for r in ranked) + ".") if ranked else ""
    return closing_fact("the paper's scene", f"The paper's runs record no wall time, so this study cannot name the "
                        f"method that reaches an error level at least cost (that needs timed runs at several steps: "
                        f"the work_precision study); what it measures is each method's error at the paper's "
                        f"h = {h:g} s:", rows, "Error of each figure run against the reference (node values)",
                        sentence)


def _cay(w: np.ndarray, v: np.ndarray) -> np.ndarray:
    """cay(ŵ)v = v + 4/(4+|w|²)(w×v + ½ w×(w×v))."""
    wv = np.cross(w, v)
    return v + 4.0 / (4.0 + w @ w) * (wv + 0.5 * np.cross(w, wv))

