"""Long-drift study: what "energy drift" means for a structure-preserving method.

At low viscosity (``fluid.viscosity`` swept from 1e-3 kg m⁻¹ s⁻¹ down to 0,
where the top is conservative) an ensemble of the paper's body with random
initial conditions (:func:`liethermo.initial.initial_conditions`) is
integrated over a long horizon (10⁴–10⁶ steps) by the variational
integrators (``vi``, ``vi4``, ``vi6``) and by RK2 and RK4 **at equal cost per
simulated second**: each method's step is

    h_m = h_base × cost_m / cost_base,

with the cost of a step counted in right-hand-side evaluations —
``evaluations_per_step`` of :mod:`liethermo.methods` for RK (2 for RK2, 4 for
RK4) and, for the variational integrators, their Newton solves per step (1, 3,
9) × ``options.newton_cost`` rhs-evaluation equivalents per solve (a Newton
iteration evaluates the residual and its 3×3 Jacobian, about one rhs; a
solve takes 3–4 iterations).  The study also measures the kernels' wall time
per simulated second of every run and reports it beside, so the reader sees
whether the counted costs matched on the machine that ran it.

Per member, on NODE values (E_k from Ω(t_k), Γ_k, S_k; relative to
E_mech,0 = K₀ + V₀ + mgℓ):

* the drift rate — least-squares slope of (E_k − E₀)/E_mech,0 against t (s⁻¹);
* the bounded-oscillation amplitude — the RMS of (E_k − E₀)/E_mech,0 about
  that line;
* max |E_k − E₀|/E_mech,0, and max ||Γ_k| − 1| (the |Γ| defect);
* the Kelvin–Noether residual, from a window of ``kn_steps`` steps stored
  with every = 1: for the variational integrators the discrete law
  J_{k+1} − J_k = −h(w_LΓ_k + w_RΓ_{k+1})·CX_k, J = Γ·μ (checked for ``vi``
  with friction and for every VI method without it), and for every method the
  continuous law d(Γ·μ)/dt = −Γ·CΩ integrated by the trapezoid rule between
  stored nodes (which includes that quadrature's own O(h²) error).
"""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path

import numpy as np
import xarray as xr

from ..initial import initial_conditions
from ..methods import METHODS
from ..physics import physics_of_scene
from .common import (StudyError, cached_point, dim_name, expand_sweep, parse_method, point_key, progress_bar,
                     stack_points, start_study, study_history, study_name, study_netcdf_path, study_options,
                     study_scene, write_netcdf_atomic, write_report, write_table)
from .tools import (NODE_VALUES_NOTE, continuous_kelvin_noether_residual, drift_fit, energy_errors,
                    kelvin_noether_residual, run_spec)

EXTRA_KEYS = ()
SWEEP_KEY = "fluid.viscosity"
DEFAULT_OPTIONS = {
    "h_base": 0.01,         # s, the step of the cost reference method
    "cost_base": "vi",      # the method whose step is h_base
    "t_end": 1000.0,        # s, simulated time (the same for every method)
    "outputs": 2000,        # stored nodes per run (about)
    "newton_cost": 4.0,     # rhs-evaluation equivalents per Newton solve
    "kn_steps": 2000,       # steps of the every = 1 window for the Kelvin–Noether residual
}


def options(study: dict) -> dict:
    return study_options(study, DEFAULT_OPTIONS, "long_drift")


def validate(study: dict) -> None:
    opt = options(study)
    sweep = study.get("sweep", {}) or {}
    if list(sweep) != [SWEEP_KEY]:
        raise StudyError(f"sweep: a long_drift study sweeps exactly one key, {SWEEP_KEY!r}")
    if any(not isinstance(v, (int, float)) or v < 0 for v in sweep[SWEEP_KEY]):
        raise StudyError(f"sweep.{SWEEP_KEY}: viscosities must be ≥ 0")
    methods = study.get("methods") or []
    if not methods:
        raise StudyError("methods: a long_drift study needs at least one method")
    labels = [parse_method(m)["label"] for m in methods]
    if opt["cost_base"] not in labels:
        raise StudyError(f"options.cost_base: {opt['cost_base']!r} must be one of the study's methods")
    for m in methods:
        if parse_method(m)["method"] == "reference":
            raise StudyError("methods: 'reference' is the ground truth, not a compared method")
    for k in ("h_base", "t_end", "newton_cost"):
        if not (isinstance(opt[k], (int, float)) and opt[k] > 0):
            raise StudyError(f"options.{k}: must be a number > 0")
    for k in ("outputs", "kn_steps"):
        if not (isinstance(opt[k], int) and opt[k] >= 10):
            raise StudyError(f"options.{k}: must be an integer ≥ 10")


def step_cost(spec: dict, opt: dict) -> float:
    """Cost of one step in rhs-evaluation equivalents."""
    m = METHODS[spec["method"]]
    return m.evaluations_per_step * (float(opt["newton_cost"]) if m.family == "vi" else 1.0)


def equal_cost_steps(specs: list, opt: dict) -> dict:
    """label → (h, steps, every): h ∝ cost per step, the same simulated time."""
    base = next(s for s in specs if s["label"] == opt["cost_base"])
    out = {}
    for s in specs:
        h = float(opt["h_base"]) * step_cost(s, opt) / step_cost(base, opt)
        steps = int(round(float(opt["t_end"]) / h))
        every = max(1, steps // int(opt["outputs"]))
        steps = max(every, (steps // every) * every)
        out[s["label"]] = (h, steps, every)
    return out


def point(scene, spec: dict, h: float, steps: int, every: int, kn_steps: int) -> xr.Dataset:
    """One (viscosity, method) point: long run (every-th node) and the every = 1 window."""
    N = int(scene["ensemble"]["members"])
    phys = physics_of_scene(scene, N)
    om, R = initial_conditions(scene)
    tr = run_spec(phys, om, R, h, steps, spec, every=every)
    err = energy_errors(tr, om, R)
    rel = err["node"] / err["scale"][:, None]
    slope, spread = drift_fit(tr.times, rel)
    with np.errstate(invalid="ignore"):
        gdef = np.nanmax(np.abs(np.linalg.norm(tr.gamma, axis=-1) - 1.0), axis=1)
        arel = np.abs(rel)
    win = run_spec(phys, om, R, h, min(kn_steps, steps), spec, every=1)
    t = tr.times
    q = np.array([0.05, 0.5, 0.95])
    band = np.quantile(np.where(np.isfinite(arel), arel, np.inf), q, axis=0, method="inverted_cdf")
    return xr.Dataset({
        "drift_rate": ("member", slope),
        "oscillation_amplitude": ("member", spread),
        "max_relative_energy_error": ("member", np.where(tr.status == 0, np.nanmax(arel, axis=1), np.inf)),
        "final_relative_energy_error": ("member", arel[:, -1]),
        "gamma_defect": ("member", gdef),
        "kelvin_noether_discrete": ("member", kelvin_noether_residual(win)),
        "kelvin_noether_continuous": ("member", continuous_kelvin_noether_residual(win)),
        "status": ("member", tr.status.astype(np.int8)),
        "relative_energy_error_quantiles": (("quantile", "time"), band),
        "kernel_time": ((), tr.wall_time),
    }, coords={"member": np.arange(N), "quantile": q, "time": t},
        attrs={"h": h, "steps": steps, "every": every})


UNITS = {
    "drift_rate": ("s-1", "least-squares slope of (E_k - E_0)/E_mech,0 against t, node values"),
    "oscillation_amplitude": ("1", "RMS of (E_k - E_0)/E_mech,0 about its least-squares line, node values"),
    "max_relative_energy_error": ("1", "max_k |E_k - E_0| / E_mech,0, node values (failed: inf)"),
    "final_relative_energy_error": ("1", "|E_K - E_0| / E_mech,0 at t_end, node values"),
    "gamma_defect": ("1", "max_k ||Gamma_k| - 1|"),
    "kelvin_noether_discrete": ("1", "max residual of the discrete Kelvin-Noether law / max |mu| (every = 1 "
                                     "window; NaN where it does not apply)"),
    "kelvin_noether_continuous": ("1", "max defect of d(Gamma.mu)/dt = -Gamma.C Omega by the trapezoid rule "
                                       "between nodes / max |mu| (every = 1 window)"),
    "status": ("1", "member status (0 ok, 1 newton_not_converged, 2 non_finite)"),
    "relative_energy_error_quantiles": ("1", "quantiles over members of |E_k - E_0| / E_mech,0, node values"),
    "kernel_time": ("s", "kernel wall time of the long run"),
    "step": ("s", "time step h of the method (equal cost per simulated second)"),
    "steps": ("1", "steps of the long run"),
}


def run(study: dict, outdir: Path, *, reduced: bool, progress: bool | None, dask: str | None = None,
        history: str | None = None) -> Path:
    import pandas as pd

    s, outdir, opt = start_study(study, outdir, reduced, validate, options)
    specs = [parse_method(m) for m in s["methods"]]
    plan = equal_cost_steps(specs, opt)
    points = expand_sweep(s["sweep"])
    t_wall = time.perf_counter()
    tasks = []
    for pt in points:
        for spec in specs:
            h, steps, every = plan[spec["label"]]
            sc = study_scene(s, dict(pt, **{"integrator.h": h}))
            key = point_key({"study": "long_drift", "scene": sc, "spec": spec, "h": h, "steps": steps,
                             "every": every, "kn": opt["kn_steps"]})
            tasks.append((pt, spec, key, (sc, spec, h, steps, every, int(opt["kn_steps"]))))
    if dask is not None:
        from ..distributed import map_cached_points

        map_cached_points(outdir, [(k, point, a) for _, _, k, a in tasks], dask, progress=progress)
    bar = progress_bar(len(tasks), progress, study_name(s))
    dss = []
    try:
        for _, _, key, args in tasks:
            dss.append(cached_point(outdir, key, partial(point, *args)))
            bar.update(1)
    finally:
        bar.close()
    # the long runs have different time grids: keep the bands per method on a normalised index
    allpts = [dict(pt, scheme=spec["label"]) for pt, spec, _, _ in tasks]
    per = []
    for d in dss:
        per.append(d.drop_vars(["relative_energy_error_quantiles", "time"]).assign(
            step=((), float(d.attrs["h"])), steps=((), int(d.attrs["steps"]))))
    ds = stack_points(per, allpts, [SWEEP_KEY, "scheme"])
    for k, (u, ln) in UNITS.items():
        if k in ds:
            ds[k].attrs.update(units=u, long_name=ln)
    dim = dim_name(SWEEP_KEY)
    ds[dim].attrs.update(units="kg m-1 s-1", long_name="fluid viscosity mu (sweep)")
    scene0 = study_scene(s, points[0])
    ds.attrs.update(study=study_name(s), kind="long_drift", reduced=int(reduced), t_end=float(opt["t_end"]),
                    cost="equal rhs-evaluation equivalents per simulated second",
                    newton_cost=float(opt["newton_cost"]), members=int(scene0["ensemble"]["members"]),
                    seed=int(scene0["ensemble"]["seed"]), values="node values")
    nc = write_netcdf_atomic(ds, study_netcdf_path(s, outdir),
                             history=study_history("long_drift", s, outdir, reduced, history))

    rows = []
    for (pt, spec, _, _), d in zip(tasks, dss):
        h, steps, every = plan[spec["label"]]
        dr = d["drift_rate"].values
        ok = d["status"].values == 0
        rows.append({
            "μ (kg m⁻¹ s⁻¹)": float(pt[SWEEP_KEY]), "method": spec["label"], "h (s)": h, "steps": steps,
            "cost/step (rhs eval.)": step_cost(spec, opt),
            "median drift rate (s⁻¹)": float(np.median(dr[ok])) if ok.any() else float("nan"),
            "median |drift rate| (s⁻¹)": float(np.median(np.abs(dr[ok]))) if ok.any() else float("nan"),
            "median oscillation amplitude (1)": float(np.median(d["oscillation_amplitude"].values[ok]))
            if ok.any() else float("nan"),
            "median max|dE|/Emech0 (1)": float(np.median(d["max_relative_energy_error"].values)),
            "max ||Γ|−1| (1)": float(np.nanmax(d["gamma_defect"].values)),
            "max discrete KN residual (1)": _nanmax(d["kelvin_noether_discrete"].values),
            "max continuous KN defect (1)": _nanmax(d["kelvin_noether_continuous"].values),
            "kernel wall per simulated s (s)": float(d["kernel_time"]) / float(opt["t_end"]),
            "failed": int((~ok).sum()),
        })
    df = pd.DataFrame(rows)
    _error_figure(dss, tasks, outdir, opt)
    _rate_figure(df, outdir)
    wall = time.perf_counter() - t_wall
    members = int(scene0["ensemble"]["members"])
    sections = [
        write_table(df, outdir, "long_drift", f"Energy drift at equal cost per simulated second "
                    f"({members} members, t_end = {opt['t_end']:g} s, node values)"),
        _finding(df),
        f"Scene `{scene0['scene']['name']}` (the paper's body), {members} members with random initial "
        f"conditions (seed {int(scene0['ensemble']['seed'])}), swept over the viscosity. **Equal cost:** each "
        f"method's h is h_base × cost/step ÷ cost/step of `{opt['cost_base']}` (h_base = {opt['h_base']:g} s), "
        f"the cost of a step counted in right-hand-side evaluations (RK2 2, RK4 4; a Newton solve of the "
        f"variational integrators = {opt['newton_cost']:g} evaluations, and vi / vi4 / vi6 take 1 / 3 / 9 solves "
        f"per step). The column *kernel wall per simulated s* is what the runs cost on the machine that "
        f"produced this report: where it differs between methods, the counted cost did not match the measured "
        f"one. Drift rate: per-member least-squares slope of (E_k − E₀)/E_mech,0 against t; oscillation "
        f"amplitude: RMS about that line. Kelvin–Noether residuals from a window of {opt['kn_steps']} steps "
        f"stored with every = 1 (discrete law: variational integrators; continuous law by the trapezoid rule: "
        f"every method).",
        NODE_VALUES_NOTE,
        "![energy error against time](long_drift_error.png)\n\n![drift rate against viscosity](long_drift_rate.png)",
        f"netCDF: `{nc.name}`. Study wall time {wall:.1f} s.",
    ]
    return write_report(outdir, "Long drift: energy error of structure-preserving and Runge–Kutta methods "
                        "at equal cost" + (" (reduced)" if reduced else ""), sections)


def _nanmax(a) -> float:
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(a.max()) if a.size else float("nan")


def _finding(df) -> str:
    lines = ["**Finding (node values, equal cost).**", ""]
    for mu, g in df.groupby("μ (kg m⁻¹ s⁻¹)", sort=False):
        g = g.sort_values("median |drift rate| (s⁻¹)")
        lines.append(f"- μ = {mu:g} kg m⁻¹ s⁻¹: median |drift rate| " + "; ".join(
            f"{r['method']} {r['median |drift rate| (s⁻¹)']:.2e} s⁻¹ (oscillation {r['median oscillation amplitude (1)']:.1e})"
            + (f", {r['failed']} failed" if r["failed"] else "") for _, r in g.iterrows()) + ".")
    vi = df[df["method"].str.startswith("vi")]
    rk = df[~df["method"].str.startswith("vi")]
    for mu in df["μ (kg m⁻¹ s⁻¹)"].unique():
        a = vi[vi["μ (kg m⁻¹ s⁻¹)"] == mu]["median |drift rate| (s⁻¹)"]
        b = rk[rk["μ (kg m⁻¹ s⁻¹)"] == mu]["median |drift rate| (s⁻¹)"]
        if len(a) and len(b):
            better = a.min() < b.min()
            lines.append(f"- At μ = {mu:g}: the best variational integrator drifts "
                         f"{'less' if better else 'more'} than the best Runge–Kutta method "
                         f"({a.min():.2e} vs {b.min():.2e} s⁻¹).")
    return "\n".join(lines)


def _error_figure(dss, tasks, outdir: Path, opt) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mus = list(dict.fromkeys(float(pt[SWEEP_KEY]) for pt, _, _, _ in tasks))
    labels = list(dict.fromkeys(spec["label"] for _, spec, _, _ in tasks))
    fig, axes = plt.subplots(1, len(mus), figsize=(5.0 * len(mus) + 1.5, 4.6), sharey=True, squeeze=False,
                             layout="constrained")
    for (pt, spec, _, _), d in zip(tasks, dss):
        ax = axes[0, mus.index(float(pt[SWEEP_KEY]))]
        t = d["time"].values
        med = d["relative_energy_error_quantiles"].sel(quantile=0.5).values
        i = labels.index(spec["label"])
        ok = t > 0
        ax.semilogy(t[ok], np.clip(med[ok], 1e-17, None), color=f"C{i}", lw=1.2,
                    label=f"{spec['label']} (h = {float(d.attrs['h']):.3g} s)")
    for ax, mu in zip(axes[0], mus):
        ax.set_title(f"μ = {mu:g} kg m⁻¹ s⁻¹")
        ax.set_xlabel("t (s)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0, 0].set_ylabel("median |E_k − E_0| / E_mech,0 (1), node values")
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="outside right center", fontsize=8)
    fig.suptitle("energy error at equal cost per simulated second (node values, median over members)")
    path = Path(outdir) / "long_drift_error.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _rate_figure(df, outdir: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mus = sorted(df["μ (kg m⁻¹ s⁻¹)"].unique())
    x = {mu: i for i, mu in enumerate(mus)}
    fig, ax = plt.subplots(figsize=(6.8, 4.6), layout="constrained")
    for i, (m, g) in enumerate(df.groupby("method", sort=False)):
        xs = [x[mu] for mu in g["μ (kg m⁻¹ s⁻¹)"]]
        ax.semilogy(xs, np.clip(g["median |drift rate| (s⁻¹)"], 1e-20, None), "o-", color=f"C{i}",
                    label=f"{m} (h = {g['h (s)'].iloc[0]:.3g} s)")
    ax.set_xticks(range(len(mus)), [f"{mu:g}" for mu in mus])
    ax.set_xlabel("viscosity μ (kg m⁻¹ s⁻¹)")
    ax.set_ylabel("median |drift rate| (s⁻¹), node values")
    ax.set_title("energy drift rate against viscosity, equal cost")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    path = Path(outdir) / "long_drift_rate.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
