"""Stability: where each method stays bounded and accurate over a (h|Ω₀|, κ = c h / I_min) map at a fixed step (one
member per cell, node-value errors against the reference), named hard cases, and the VI's Newton limit; a negative
substep f h is singular at κ = −2/f, a friction mode grows around it (:func:`.methods.negative_substep_limits`)."""

from __future__ import annotations

import numpy as np
import xarray as xr
from numpy.linalg import norm

from ..initial import initial_conditions
from ..methods import negative_substep_limits
from ..physics import kinetic_energy, physics_of_scene, potential_energy
from ..methods import keeps_geometry
from ...studies.common import StudyError
from .tools import method_choice, run_members, status_units
from ...studies.framework import Figure, Option, Stage, Study, Table, Verdict
from ...timing import pinned_threads

CLASSES = ["accurate", "bounded", "unbounded", "newton_not_converged", "non_finite"]


def _check(ctx) -> None:
    if "reference" in ctx.methods:
        raise StudyError("methods: 'reference' is the ground truth, not a compared method")
    ctx.scene(ctx.opt["map_scene"])
    for i, c in enumerate(ctx.opt["cases"]):
        if not isinstance(c, dict) or any(k not in c for k in ("name", "h", "steps")):
            raise StudyError(f"options.cases[{i}]: needs name, h and steps, got {c!r}")
        ctx.scene(c.get("scene", {}))


def run(scene, phys, om, R, h, steps, method, ref=True):
    """Every member (its own ``phys`` row) of ``scene`` with one method (and against the reference): the trajectory
    and per-member diagnostics."""
    kw = dict(h=h, steps=int(steps), physics=phys, chunk_steps=max(int(steps), 1), threads=1)
    with pinned_threads(1):
        tr = run_members(scene, method, om, R, **kw)
        rf = run_members(scene, "reference", om, R, **kw) if ref else None
    d = {"status": tr.status, "newton_max": tr.newton_max, "newton_mean": tr.newton_iterations / np.maximum(
         tr.steps_done, 1), "failed_at_step": np.where(tr.status != 0, tr.fail_step, -1), "max_h_omega": tr.max_h_omega}
    if rf is not None:
        with np.errstate(invalid="ignore", over="ignore"):
            e = np.maximum(norm(tr.omega - rf.omega, axis=-1) / norm(om, axis=1)[:, None],
                           norm(tr.gamma - rf.gamma, axis=-1))
            e, E = np.where(np.isfinite(e), e, np.inf), [phys.mechanical_energy(kinetic_energy(phys, w, None),
                potential_energy(phys, g)) for w, g in ((tr.omega, tr.gamma), (om, R[:, 2]))]
            d.update(error_max=e.max(axis=1), error_end=e[:, -1], gamma_defect=np.nanmax(np.abs(norm(tr.gamma, axis=-1)
                - 1.0), axis=1), energy_growth=np.nanmax(np.where(np.isfinite(E[0]), E[0], np.nan), axis=1) / E[1])
    return tr, d


def _spun(scene, hw, h):
    """The scene, its physics, spins (h|Ω₀|)/h along its spin, and its attitude: one member per h|Ω₀|."""
    d, R = np.asarray(scene["initial"]["omega"], float), np.asarray(scene["initial"]["R"], float)
    return (scene, physics_of_scene(scene, hw.size), np.outer(hw / h, d / np.linalg.norm(d)),
            np.repeat(R[None], hw.size, 0))


def map_cells(ctx, coords) -> xr.Dataset:
    opt, h = ctx.opt, float(ctx.opt["h"])
    hw, ka = np.asarray(opt["h_omega"], float), np.asarray(opt["kappa"], float)
    HW, KA = np.meshgrid(hw, ka, indexing="ij")
    scene, phys, om, R = _spun(ctx.scene(opt["map_scene"]), HW.ravel(), h)
    C = phys.linear_resistance()[0]  # its shape kept, its largest entry c = κ I_min / h
    C = C / C.max() if C.max() > 0 else np.ones(3)
    phys = phys.with_linear_resistance((KA.ravel() * phys.inertia.min(axis=1) / h)[:, None] * C[None])
    _, d = run(scene, phys, om, R, h, int(opt["steps"]), coords["scheme"])
    bounded = (d["energy_growth"] <= opt["growth_limit"]) & (d["gamma_defect"] <= 0.1)
    d["regime"] = np.select([d["status"] == 2, d["status"] == 1, ~bounded, d["error_max"] > opt["error_threshold"]],
                            [4, 3, 2, 1], 0).astype(np.int8)
    return xr.Dataset({k: (("h_omega", "kappa"), v.reshape(HW.shape)) for k, v in d.items()},
                      coords={"h_omega": hw, "kappa": ka})


def case_run(ctx, coords) -> xr.Dataset:
    c = next(c for c in ctx.opt["cases"] if c["name"] == coords["case"])
    scene, h = ctx.scene(c.get("scene", {})), float(c["h"])
    phys, (om, R) = physics_of_scene(scene), initial_conditions(scene, 0, 1)
    tr, d = run(scene, phys, om, R, h, int(c["steps"]), coords["scheme"])
    d.update(h_omega0=h * np.linalg.norm(om, axis=1), kappa=phys.linear_resistance().max(axis=1) * h /
             phys.inertia.min(axis=1), jacobian_cond_max=tr.newton_condition() if tr.choice.method.solves_newton else [np.nan])
    return xr.Dataset({k: ((), np.asarray(v)[0]) for k, v in d.items()})


def newton_limit(ctx, coords) -> xr.Dataset:
    vi, h = [m for m in ctx.methods if method_choice(m).method.solves_newton], float(ctx.opt["h"])
    hw = np.array([1, 2, 5, 10, 100, 1e3, 1e4, 3e4, 1e5, 1e6])  # h|Ω₀| far beyond any map
    if not vi:
        return xr.Dataset()
    tr, d = run(*_spun(ctx.scene(ctx.opt["map_scene"]), hw, h), h, 20, vi[0], ref=False)
    d["jacobian_cond_max"] = tr.newton_condition()
    return xr.Dataset({k: ("limit_h_omega", v) for k, v in d.items()}, coords={"limit_h_omega": hw})


DIAG = {"status": status_units(), "error_max": ("1", "error, max over the run"), "h_omega0": ("rad", "h |Omega_0|"),
        "error_end": ("1", "error at the end"), "energy_growth": ("1", "max_k E_mech,k / E_mech,0 (above rest)"),
        "gamma_defect": ("1", "max_k ||Gamma_k| - 1|"), "newton_max": ("1", "max Newton iterations in one step"),
        "newton_mean": ("1", "mean Newton iterations per step"), "max_h_omega": ("rad", "max_k h |Omega_k|"),
        "failed_at_step": ("1", "step whose computation failed (-1: none)"),
        "jacobian_cond_max": ("1", "max over accepted steps of the 2-norm condition number of the Newton Jacobian"),
        "kappa": ("1", "kappa = c h / I_min (friction per step)")}
QUANTITIES = {**DIAG, **{f"case_{k}": (u, f"named case: {n}") for k, (u, n) in DIAG.items()},
              **{f"limit_{k}": (u, f"Newton limit push: {n}") for k, (u, n) in DIAG.items()},
              "regime": ("1", "regime code, 0 accurate ... 4 non-finite"),
              "h_omega": ("rad", "h |Omega_0| (step angle of the initial spin)"), "case": ("1", "named case"),
              "limit_h_omega": ("rad", "h |Omega_0| of the Newton limit push")}


def _summary(ds, ctx):
    hw, ka, rows = ds["h_omega"].values, ds["kappa"].values, []
    for m in ctx.methods:
        r, mc = ds["regime"].sel(scheme=m).values, method_choice(m)
        band = negative_substep_limits(mc.name, mc.friction, mc.composition or "small_error")["growth_band"] if (
            mc.method.solves_newton) else None  # the κ band where a friction mode of the VI grows
        ok, acc, bad = hw[np.all(r <= 1, axis=1)], hw[np.all(r == 0, axis=1)], np.any(r >= 2, axis=0)
        inband = (ka >= band[0]) & (ka <= band[1]) if band else np.zeros(ka.size, bool)
        rows.append({"method": m, **{c: int(np.sum(r == i)) for i, c in enumerate(CLASSES)},
                     "largest h|Ω₀| bounded at every κ": ok.max() if ok.size else np.nan,
                     "largest h|Ω₀| accurate at every κ": acc.max() if acc.size else np.nan,
                     "κ with an unbounded or failed cell": ", ".join(f"{k:g}" for k in ka[bad]) or "none",
                     "κ band where a friction mode grows": "—" if band is None else "{:.3f} – {:.3f}".format(*band),
                     "unbounded or failed cells outside that band": int(np.sum((r >= 2)[:, ~inband]))})
    return rows


def tables(ds, ctx) -> list[Table]:
    vi = next((m for m in ctx.methods if method_choice(m).method.solves_newton), None)
    return [Table("stability_summary", f"Cells per regime ({ds.sizes['h_omega']}×{ds.sizes['kappa']} grid, h = "
                  f"{ctx.opt['h']:g} s, {ctx.opt['steps']} steps)", _summary(ds, ctx))] + [Table(name, title, ds[[
                      v for v in ds.data_vars if v.startswith(prefix)]].to_dataframe().reset_index().rename(
                      columns=lambda c: c.removeprefix(prefix)).to_dict("records")) for name, title, prefix, dim in (
            ("named_cases", "Named hard cases, every method against the reference", "case_", "case"),
            ("newton_limit", f"The VI's Newton iteration far beyond the map ({vi}, h = {ctx.opt['h']:g} s, 20 steps)",
             "limit_", "limit_h_omega")) if dim in ds.dims]


def verdicts(ds, ctx) -> list[Verdict]:
    key, geo = "unbounded or failed cells outside that band", [m for m in ctx.methods if keeps_geometry(m)]
    out = [Verdict(f"{r['method']} stays bounded on the map" + (" outside its growth band" if r["κ band where a "
                   "friction mode grows"] != "—" else ""), f"{r[key]} cells unbounded or failed", "0", r[key] == 0)
           for r in _summary(ds, ctx)]
    if "case" in ds.dims and geo:
        worst = float(ds["case_gamma_defect"].sel(scheme=geo).max())
        out.append(Verdict(f"{', '.join(geo)} keep |Γ| = 1 in every named case", f"max ||Γ| − 1| = {worst:.1e}",
                           "≤ 1e-13", worst <= 1e-13))
    if "limit_h_omega" in ds.dims:
        cond = float(np.nanmax(ds["limit_jacobian_cond_max"].values[ds["limit_status"].values == 0]))
        out.append(Verdict("the VI's Newton failures far beyond the map are not ill conditioning", f"cond₂(J) ≤ "
                           f"{cond:.3g} wherever Newton converged", "≤ 4 (≈ 3 for h|X| ≫ 1)", cond <= 4))
    return out


def findings(ds, ctx) -> list[str]:
    rows, base, reg, out = _summary(ds, ctx), ctx.methods[-1], ds["regime"], []
    for key in ("largest h|Ω₀| accurate at every κ", "largest h|Ω₀| bounded at every κ"):
        best = max((r[key] for r in rows if np.isfinite(r[key])), default=None)
        out.append(f"The {key}: " + (f"{best:g} rad ({' and '.join(r['method'] for r in rows if r[key] == best)})."
                                     if best is not None else "none."))
    out.append("Accurate cells: " + ", ".join(f"{r['method']} {r['accurate']}" for r in rows) + f" of {reg[0].size}; "
               f"the baseline {base} is accurate where the others are not in " + ", ".join(
                   f"{int(((reg.sel(scheme=base) == 0) & (reg.sel(scheme=m) != 0)).sum())} cells ({m})"
                   for m in ctx.methods if m != base) + ".")
    if "limit_h_omega" in ds.dims:
        hw, st, nm = ds["limit_h_omega"].values, ds["limit_status"].values, ds["limit_newton_max"].values
        ok, fail = (st == 0) & (hw >= 10), ", ".join(f"{v:g}" for v in hw[st != 0][:1]) or "none tried"
        slope = np.polyfit(np.log10(hw[ok]), nm[ok], 1)[0] if ok.sum() > 1 else np.nan
        out.append(f"The VI's Newton iterations grow by {slope:.1f} per decade of h|Ω₀| (the step velocity solves a "
                   f"cubic); first failure at h|Ω₀| = {fail}.")
    return out


class _Table(Option):
    def check(self, v):  # a table or a list of tables; the study's _check reads them
        if not isinstance(v, (dict, list)):
            raise StudyError(f"options.{self.name}: must be a {self.rule}, got {v!r}")


STUDY = Study(
    kind="stability", title="Stability: bounded and accurate regimes, hard cases, Newton limits", models=("top",),
    description="Where each method stays bounded and accurate over (h|Ω₀|, κ); hard cases; Newton limit",
    options=(Option("h", 0.1, "number>0", "s", "the map's step"), Option("steps", 100, "int>=1", "1", "steps per run"),
             Option("h_omega", [0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0], "list[number>0]", "rad", "map's h|Ω₀|"),
             Option("kappa", [0.001, 0.01, 0.1, 0.5, 1.0, 2.0, 5.0, 10.0], "list[number>0]", "1", "map's κ"),
             Option("error_threshold", 0.05, "number>0", "1"), Option("growth_limit", 2.0, "number>0", "1"),
             _Table("cases", [], "list of tables", "", "name, description, h, steps, scene"),
             _Table("map_scene", {}, "table", "", "scene overrides of the map")),
    axes=lambda ctx: {"case": [c["name"] for c in ctx.opt["cases"]]}, check=_check,
    stages=(Stage("map", map_cells, ("scheme",)), Stage("cases", case_run, over=("case", "scheme"), prefix="case_"),
            Stage("limit", newton_limit, over=(), prefix="limit_")),
    quantities=QUANTITIES, tables=tables, verdicts=verdicts, findings=findings,
    figures=(Figure("regimes", kind="heatmap", x="h_omega", hue="kappa", facet="scheme", y=("regime",), logy=False,
                    categories=tuple(c.replace("_", " ") for c in CLASSES),
                    title="Stability: each method's regime per cell (h = {opt[h]} s, {opt[steps]} steps)", claim="each method's regime per cell (" + ", ".join(f"{i} {c}" for i, c in enumerate(CLASSES)) +
                    "): the VIs stay bounded outside their growth band, the explicit methods not at large h|Ω₀|"),
             Figure("errors", kind="heatmap", x="h_omega", hue="kappa", facet="scheme", y=("error_max",), logy=True,
                    select=lambda ds, ctx: ds.assign(error_max=ds["error_max"].where(~np.isfinite(ds["error_max"]) | (
                        ds["error_max"] <= 1e3), 1e3)), title="Stability: max error against the reference per cell",
                    claim="errors above 1e3 drawn at 1e3; hatched: not finite")),
    report=("Map scene `{scene}` (overrides {opt[map_scene]}), h = {opt[h]} s, {opt[steps]} steps. Error: max_k max("
            "|Ω_k − Ω_ref(t_k)|/|Ω₀|, |Γ_k − Γ_ref(t_k)|), node values against the reference; accurate: error ≤ "
            "{opt[error_threshold]}; bounded: E_mech above rest ≤ {opt[growth_limit]}× its start and ||Γ| − 1| ≤ 0.1. "
            "Baseline: the last method. Named cases: {cases}."),
    facts=lambda ds, ctx: {"cases": "; ".join(f"*{c['name']}* ({c.get('description', '')})" for c in ctx.opt["cases"])})
