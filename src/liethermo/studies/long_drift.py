"""Long-drift study: what "energy drift" means for a structure-preserving method.

At low viscosity (``fluid.viscosity`` swept from 1e-3 kg m⁻¹ s⁻¹ down to 0,
where the top is conservative) an ensemble of the paper's body with random
initial conditions (:func:`liethermo.initial.initial_conditions`) is
integrated over a long horizon (10⁴–10⁶ steps) by the variational
integrators (``vi``, ``vi4``, ``vi6``) and by RK2 and RK4 **at equal measured
cost per simulated second**.  A calibration, before the long runs, times each
method's kernel on the study's ensemble (warm, the same kernel and threads as
the long runs, every run on ``options.threads`` numba threads, default one:
timings on one thread vary least on a shared machine; the minimum over
repeats of at least ``options.calibration_time`` s) and sets its step so that

    kernel wall per step (h_m) / h_m = kernel wall per step (h_base) / h_base

for the cost reference method ``options.cost_base`` at ``h_base``, to within
``options.calibration_rtol`` (:func:`calibrate`; the VI's cost per step
changes with h through its Newton iterations).  The
report gives the cost counted in right-hand-side evaluations beside it —
``evaluations_per_step`` of :mod:`liethermo.methods` for RK (2 for RK2, 4 for
RK4) and, for the variational integrators, their Newton solves per step (1, 3,
9) × ``options.newton_cost`` evaluation equivalents per solve — and the kernel
wall per simulated second of every long run, so the reader sees how far the
count is from the clock and whether the calibration held.

Per member, on NODE values (E_k from Ω(t_k), Γ_k, S_k; relative to
E_mech,0 = K₀ + V₀ + mgℓ):

* the drift rate — least-squares slope of (E_k − E₀)/E_mech,0 against t (s⁻¹);
* the bounded-oscillation amplitude — the RMS of (E_k − E₀)/E_mech,0 about
  that line;
* max |E_k − E₀|/E_mech,0, and max ||Γ_k| − 1| (the |Γ| defect);
* the Kelvin–Noether residual, from a window of ``kn_steps`` steps stored
  with every = 1: for the variational integrators the discrete law
  J_{k+1} − J_k = −h(w_LΓ_k + w_RΓ_{k+1})·F(X_k), J = Γ·μ, F the sum of the
  terms' discrete frictions (checked for ``vi`` with friction and for every VI
  method without it), and for every method the continuous law
  d(Γ·μ)/dt = Γ·f(Ω, Γ), f the sum of the terms' torques, integrated by the
  trapezoid rule between stored nodes (which includes that quadrature's own
  error).
"""

from __future__ import annotations

import math
import time
from functools import partial
from pathlib import Path

import numpy as np
import xarray as xr

from ..initial import initial_conditions
from ..methods import METHODS
from ..physics import physics_of_scene
from .common import (shared_units, status_units, StudyError, cached_point, closing_section, dim_name, expand_sweep, parse_method, point_key,
                     progress_bar, stack_points, step_text, start_study, study_history, study_name, study_netcdf_path, study_options,
                     study_scene, write_netcdf_atomic, write_report, write_table)
from ..kernels.terms import ROLE_LINEAR_FRICTION, key_of
from .tools import (NODE_VALUES_NOTE, continuous_kelvin_noether_residual, drift_fit, energy_errors,
                    kelvin_noether_residual, repeat_timing, run_spec)

EXTRA_KEYS = ()
#: the key swept: the strength of the friction linear in Ω
SWEEP_KEY = key_of(ROLE_LINEAR_FRICTION)
DEFAULT_OPTIONS = {
    "h_base": 0.01,         # s, the step of the cost reference method
    "cost_base": "vi",      # the method whose step is h_base
    "t_end": 1000.0,        # s, simulated time (the same for every method)
    "outputs": 2000,        # stored nodes per run (about)
    "newton_cost": 4.0,     # rhs-evaluation equivalents per Newton solve (the counted cost, reported)
    "kn_steps": 2000,       # steps of the every = 1 window for the Kelvin–Noether residual
    "calibration_steps": 2000,   # steps of a calibration run, at least
    "calibration_horizon": 1.0,  # simulated time of a calibration run, as a fraction of t_end
    "calibration_time": 0.3,     # s of timed repeats per calibration measurement, at least
    "calibration_rtol": 0.03,    # the calibration stops when the cost per simulated s is this close
    "threads": 1,                # numba threads of every run (timings on one thread vary least)
}
#: the calibration measures at most this many steps h per method
CALIBRATION_ITERATIONS = 6


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
    for k in ("h_base", "t_end", "newton_cost", "calibration_time", "calibration_rtol", "calibration_horizon"):
        if not (isinstance(opt[k], (int, float)) and opt[k] > 0):
            raise StudyError(f"options.{k}: must be a number > 0")
    if not (isinstance(opt["threads"], int) and opt["threads"] >= 1):
        raise StudyError("options.threads: must be an integer ≥ 1")
    for k in ("outputs", "kn_steps", "calibration_steps"):
        if not (isinstance(opt[k], int) and opt[k] >= 10):
            raise StudyError(f"options.{k}: must be an integer ≥ 10")


def step_cost(spec: dict, opt: dict) -> float:
    """Cost of one step in rhs-evaluation equivalents."""
    m = METHODS[spec["method"]]
    return m.evaluations_per_step * (float(opt["newton_cost"]) if m.family == "vi" else 1.0)


def counted_cost_steps(specs: list, opt: dict) -> dict:
    """label → h (s) at equal COUNTED cost per simulated second: h ∝ the
    counted cost of a step (the calibration's first guess)."""
    base = next(s for s in specs if s["label"] == opt["cost_base"])
    return {s["label"]: float(opt["h_base"]) * step_cost(s, opt) / step_cost(base, opt) for s in specs}


def calibrate(specs: list, opt: dict, cost_per_step) -> dict:
    """label → (h (s), measured cost per step at that h (s)): each method's
    step at equal measured cost per simulated second, ``cost_per_step(spec, h)``
    being the measurement.  The cost reference ``opt["cost_base"]`` keeps
    h_base; for the others f(h) = log(c(h) / h / C) (C: the reference's cost per
    simulated second) is driven to zero from the counted cost's step — a
    fixed-point step log h ← log h + f while f has one sign, the secant of the
    closest bracket once it has changed sign (the VI's cost per step falls as h
    grows, through its Newton iterations, enough to make plain fixed-point
    iteration oscillate) — until |c(h)/h/C − 1| < ``calibration_rtol``, at most
    :data:`CALIBRATION_ITERATIONS` measurements; else the best measured h."""
    guess = counted_cost_steps(specs, opt)
    base = next(s for s in specs if s["label"] == opt["cost_base"])
    hb = float(opt["h_base"])
    cb = float(cost_per_step(base, hb))
    target = cb / hb  # s of kernel per simulated s
    rtol = float(opt["calibration_rtol"])
    out = {base["label"]: (hb, cb)}
    for s in specs:
        if s["label"] == base["label"]:
            continue
        tried = []  # (log h, f, h, c)
        x = math.log(guess[s["label"]])
        for _ in range(CALIBRATION_ITERATIONS):
            h = math.exp(x)
            c = float(cost_per_step(s, h))
            f = math.log(c / h / target)
            tried.append((x, f, h, c))
            if abs(c / h / target - 1.0) < rtol:
                break
            below = [t for t in tried if t[1] > 0]  # h too small: costs more than C
            above = [t for t in tried if t[1] < 0]
            if below and above:
                (xa, fa, _, _), (xb, fb, _, _) = max(below), min(above)
                x = xa - fa * (xb - xa) / (fb - fa)
            else:
                x = x + f
        _, _, h, c = min(tried, key=lambda t: abs(t[1]))
        out[s["label"]] = (h, c)  # c was measured at this h
    return out


def plan_steps(h: float, opt: dict) -> tuple[float, int, int]:
    """(h, steps, every) of a long run with step h: about t_end simulated
    seconds, about ``outputs`` stored nodes."""
    steps = max(1, int(round(float(opt["t_end"]) / h)))
    every = max(1, steps // int(opt["outputs"]))
    steps = max(every, (steps // every) * every)
    return float(h), steps, every


def long_run_kernel(specs: list, members: int, opt: dict) -> str:
    """The kernel every run of the study uses (the calibration's too): the one
    the cost reference's long run would pick (:func:`liethermo.simulate.kernel_for`)."""
    from ..simulate import kernel_for

    base = next(s for s in specs if s["label"] == opt["cost_base"])
    return kernel_for(base["method"], members, int(round(float(opt["t_end"]) / float(opt["h_base"]))))


def measured_cost_per_step(scene, kernel: str, opt: dict):
    """``cost_per_step(spec, h)`` for :func:`calibrate`: the kernel wall time per
    step (s) of the scene's ensemble, warm, minimum over repeats.  A timed run
    covers ``calibration_horizon`` × t_end of simulated time — by default the
    long run's whole horizon: with friction the top slows and the VI's Newton
    iterations per step fall (3.0 in the first 20 s, 2.36 over 2000 s at
    μ = 1e-3 kg m⁻¹ s⁻¹ on the paper's body), so a short run overstates its
    cost — and at least ``calibration_steps`` steps, and more until it lasts a
    quarter of ``calibration_time`` (a long run is one or a few kernel calls:
    what a call costs besides its steps must not show here either)."""
    N = int(scene["ensemble"]["members"])
    phys = physics_of_scene(scene, N)
    om, R = initial_conditions(scene)

    def cost(spec: dict, h: float) -> float:
        n = max(int(opt["calibration_steps"]),
                int(round(float(opt["calibration_horizon"]) * float(opt["t_end"]) / h)))
        kw = dict(every=n, kernel=kernel, threads=opt["threads"])
        run_spec(phys, om, R, h, n, spec, compile_only=True, **kw)
        w = run_spec(phys, om, R, h, n, spec, **kw).wall_time
        want = 0.25 * float(opt["calibration_time"])
        if w < want:
            n = int(math.ceil(n * min(want / max(w, 1e-9), 1000.0)))
        kw["every"] = n
        walls = repeat_timing(lambda: run_spec(phys, om, R, h, n, spec, **kw),
                              float(opt["calibration_time"]), measure=lambda tr: tr.wall_time)
        return float(walls.min()) / n

    return cost


def calibration_point(scene, specs: list, opt: dict, kernel: str) -> xr.Dataset:
    """The calibration as a dataset (cached with the study's points: a resumed
    study keeps its steps)."""
    cal = calibrate(specs, opt, measured_cost_per_step(scene, kernel, opt))
    labels = [s["label"] for s in specs]
    return xr.Dataset({"h": ("scheme", [cal[lab][0] for lab in labels]),
                       "cost_per_step": ("scheme", [cal[lab][1] for lab in labels])},
                      coords={"scheme": labels}, attrs={"kernel": kernel})


def point(scene, spec: dict, h: float, steps: int, every: int, kn_steps: int, kernel: str = "auto",
          threads: int | None = None) -> xr.Dataset:
    """One (viscosity, method) point: long run (every-th node) and the every = 1 window."""
    N = int(scene["ensemble"]["members"])
    phys = physics_of_scene(scene, N)
    om, R = initial_conditions(scene)
    run_spec(phys, om, R, h, steps, spec, every=every, kernel=kernel, threads=threads, compile_only=True)
    tr = run_spec(phys, om, R, h, steps, spec, every=every, kernel=kernel, threads=threads)
    err = energy_errors(tr, om, R)
    rel = err["node"] / err["scale"][:, None]
    slope, spread = drift_fit(tr.times, rel)
    with np.errstate(invalid="ignore"):
        gdef = np.nanmax(np.abs(np.linalg.norm(tr.gamma, axis=-1) - 1.0), axis=1)
        arel = np.abs(rel)
    win = run_spec(phys, om, R, h, min(kn_steps, steps), spec, every=1, kernel=kernel, threads=threads)
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
        "relative_energy_error_quantiles": (("quantile", "t"), band),
        "kernel_time": ((), tr.wall_time),
    }, coords={"member": np.arange(N), "quantile": q, "t": t},
        attrs={"h": h, "steps": steps, "every": every})


UNITS = {
    **shared_units('gamma_defect', 'max_relative_energy_error', 'final_relative_energy_error', 'relative_energy_error_quantiles'),
    "drift_rate": ("s-1", "least-squares slope of (E_k - E_0)/E_mech,0 against t, node values"),
    "oscillation_amplitude": ("1", "RMS of (E_k - E_0)/E_mech,0 about its least-squares line, node values"),
    "kelvin_noether_discrete": ("1", "max residual of the discrete Kelvin-Noether law / max |mu| (every = 1 "
                                     "window; NaN where it does not apply)"),
    "kelvin_noether_continuous": ("1", "max defect of d(Gamma.mu)/dt = Gamma.f(Omega, Gamma), f the sum of the torques, by the trapezoid rule "
                                       "between nodes / max |mu| (every = 1 window)"),
    "status": status_units(),
    "kernel_time": ("s", "kernel wall time of the long run"),
    "step": ("s", "time step h of the method (equal measured cost per simulated second, calibrated)"),
    "calibrated_cost": ("s", "kernel wall time per simulated second of the calibration run at this step"),
    "steps": ("1", "steps of the long run"),
}


def run(study: dict, outdir: Path, *, reduced: bool, progress: bool | None, dask: str | None = None,
        history: str | None = None) -> Path:
    import pandas as pd

    s, outdir, opt = start_study(study, outdir, reduced, validate, options)
    specs = [parse_method(m) for m in s["methods"]]
    points = expand_sweep(s["sweep"])
    t_wall = time.perf_counter()
    scene0 = study_scene(s, points[0])
    kernel = long_run_kernel(specs, int(scene0["ensemble"]["members"]), opt)
    cal_opt = {k: opt[k] for k in ("h_base", "cost_base", "newton_cost", "calibration_steps", "calibration_time",
                                   "calibration_horizon", "t_end",
                                   "calibration_rtol")}
    plan: dict = {}  # (viscosity, label) → (h, steps, every)
    calibrated: dict = {}  # (viscosity, label) → kernel wall per simulated s of the calibration (s)
    tasks = []
    for pt in points:  # a calibration per viscosity: the cost of a step depends on the forces present
        mu = float(pt[SWEEP_KEY])
        sc_pt = study_scene(s, pt)
        cal = cached_point(outdir, point_key({"study": "long_drift", "calibration": cal_opt, "scene": sc_pt,
                                              "specs": specs, "kernel": kernel, "threads": opt["threads"]}),
                           partial(calibration_point, sc_pt, specs, opt, kernel))
        for spec in specs:
            lab = spec["label"]
            plan[mu, lab] = h, steps, every = plan_steps(float(cal["h"].sel(scheme=lab)), opt)
            calibrated[mu, lab] = float(cal["cost_per_step"].sel(scheme=lab)) / h
            sc = study_scene(s, dict(pt, **{"integrator.h": h}))
            key = point_key({"study": "long_drift", "scene": sc, "spec": spec, "h": h, "steps": steps,
                             "every": every, "kn": opt["kn_steps"], "kernel": kernel, "threads": opt["threads"]})
            tasks.append((pt, spec, key, (sc, spec, h, steps, every, int(opt["kn_steps"]), kernel, opt["threads"])))
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
    for (pt, spec, _, _), d in zip(tasks, dss):
        per.append(d.drop_vars(["relative_energy_error_quantiles", "t"]).assign(
            step=((), float(d.attrs["h"])), steps=((), int(d.attrs["steps"])),
            calibrated_cost=((), calibrated[float(pt[SWEEP_KEY]), spec["label"]])))
    ds = stack_points(per, allpts, [SWEEP_KEY, "scheme"])
    for k, (u, ln) in UNITS.items():
        if k in ds:
            ds[k].attrs.update(units=u, long_name=ln)
    dim = dim_name(SWEEP_KEY)
    ds[dim].attrs.update(units="kg m-1 s-1", long_name="fluid viscosity mu (sweep)")
    ds.attrs.update(study=study_name(s), kind="long_drift", reduced=int(reduced), t_end=float(opt["t_end"]),
                    cost="equal measured kernel wall time per simulated second (calibrated)", kernel=kernel,
                    kernel_threads=int(opt["threads"]),
                    newton_cost=float(opt["newton_cost"]), members=int(scene0["ensemble"]["members"]),
                    seed=int(scene0["ensemble"]["seed"]), values="node values")
    nc = write_netcdf_atomic(ds, study_netcdf_path(s, outdir),
                             history=study_history("long_drift", s, outdir, reduced, history))

    rows = []
    for (pt, spec, _, _), d in zip(tasks, dss):
        mu = float(pt[SWEEP_KEY])
        h, steps, every = plan[mu, spec["label"]]
        dr = d["drift_rate"].values
        ok = d["status"].values == 0
        rows.append({
            "μ (kg m⁻¹ s⁻¹)": float(pt[SWEEP_KEY]), "method": spec["label"], "h (s)": h, "steps": steps,
            "counted cost (rhs eval. per simulated s)": step_cost(spec, opt) / h,
            "calibrated cost (s per simulated s)": calibrated[mu, spec["label"]],
            "kernel wall per simulated s (s)": float(d["kernel_time"]) / (steps * h),
            "median drift rate (s⁻¹)": float(np.median(dr[ok])) if ok.any() else float("nan"),
            "median |drift rate| (s⁻¹)": float(np.median(np.abs(dr[ok]))) if ok.any() else float("nan"),
            "median oscillation amplitude (1)": float(np.median(d["oscillation_amplitude"].values[ok]))
            if ok.any() else float("nan"),
            "median max|dE|/Emech0 (1)": float(np.median(d["max_relative_energy_error"].values)),
            "max ||Γ|−1| (1)": float(np.nanmax(d["gamma_defect"].values)),
            "max discrete KN residual (1)": _nanmax(d["kelvin_noether_discrete"].values),
            "max continuous KN defect (1)": _nanmax(d["kelvin_noether_continuous"].values),
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
        _cost_note(df, opt["cost_base"]),
        f"Scene `{scene0['scene']['name']}` (the paper's body), {members} members with random initial "
        f"conditions (seed {int(scene0['ensemble']['seed'])}), swept over the viscosity. **Equal cost, measured:** "
        f"`{opt['cost_base']}` runs at h_base = {opt['h_base']:g} s; every other method's h comes from a "
        f"calibration at each viscosity (the forces present change the cost of a step) that times its kernel (`{kernel}`, warm, "
        f"the same members as the long runs, every run on {opt['threads']} numba thread(s); "
        f"{float(opt['calibration_horizon']) * float(opt['t_end']):g} s of simulated time, at least "
        f"{opt['calibration_steps']} steps — with friction the top slows and the VI's Newton iterations per step "
        f"fall, so a calibration shorter than the horizon would overstate its cost; minimum over repeats "
        f"of at least {float(opt['calibration_time']):g} s) and iterates h until its kernel wall time per "
        f"simulated second equals the reference's (*calibrated cost*). *Kernel wall per simulated s* is what "
        f"each long run then cost (one run, on a machine others share: expect a few per cent of noise, more "
        f"where the machine was busy). *Counted cost* is the same step's cost in right-hand-side evaluations "
        f"(RK2 2, RK4 4 per step; a Newton solve of the variational integrators counted as "
        f"{opt['newton_cost']:g} evaluations, vi / vi4 / vi6 taking 1 / {METHODS['vi4'].evaluations_per_step} / "
        f"{METHODS['vi6'].evaluations_per_step} solves per step; a Strang step of the splitting counted as one "
        f"evaluation, split4 / split6 taking {METHODS['split4'].evaluations_per_step} / "
        f"{METHODS['split6'].evaluations_per_step}): where it "
        f"differs between methods, counting would not have given equal cost. Drift rate: per-member least-squares slope of (E_k − E₀)/E_mech,0 against t; oscillation "
        f"amplitude: RMS about that line. Kelvin–Noether residuals from a window of {opt['kn_steps']} steps "
        f"stored with every = 1 (discrete law: variational integrators; continuous law by the trapezoid rule: "
        f"every method).",
        NODE_VALUES_NOTE,
        "![energy error against time](long_drift_error.png)\n\n![drift rate against viscosity](long_drift_rate.png)",
        f"netCDF: `{nc.name}`. Study wall time {wall:.1f} s.",
        _closing(df, opt, members),
    ]
    return write_report(outdir, "Long drift: energy error of structure-preserving and Runge–Kutta methods "
                        "at equal cost" + (" (reduced)" if reduced else ""), sections)


def _nanmax(a) -> float:
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(a.max()) if a.size else float("nan")


def _closing(df, opt, members: int) -> str:
    """The cheapest method per level of the energy error over the whole sweep
    (per method: its worst viscosity), at its measured cost per simulated second."""
    pts = []
    for m, g in df.groupby("method", sort=False):
        err = g["median max|dE|/Emech0 (1)"].max() if not g["failed"].any() else float("inf")
        pts.append({"method": m, "error": float(err), "cost": float(g["kernel wall per simulated s (s)"].mean()),
                    "setting": step_text(g["h (s)"])})
    mus = ", ".join(f"{mu:g}" for mu in df["μ (kg m⁻¹ s⁻¹)"].unique())
    return closing_section(pts, regime=f"μ ∈ {{{mus}}} kg m⁻¹ s⁻¹, t_end = {float(opt['t_end']):g} s, "
                                       f"{members} members",
                           error="median over members of max_k |E_k − E₀|/E_mech,0 (node values), at the "
                                 "method's worst viscosity (1)",
                           cost="kernel wall time per simulated second, mean over the viscosities (s) — equal "
                                "by calibration, so the methods reaching a level tie on cost within the noise")


def _cost_note(df, base: str) -> str:
    """One sentence per viscosity: the spread over the methods of the
    calibration's costs, of the long runs' kernel wall per simulated second
    (one run each: the machine's noise shows there), and of the counted cost."""
    lines = ["**Cost (measured and counted).**", ""]
    for mu, g in df.groupby("μ (kg m⁻¹ s⁻¹)", sort=False):
        w = g["kernel wall per simulated s (s)"]
        c = g["counted cost (rhs eval. per simulated s)"]
        k = g["calibrated cost (s per simulated s)"]
        lines.append(f"- μ = {mu:g} kg m⁻¹ s⁻¹: the calibration's costs spread {k.max() / k.min():.2f}×; the long "
                     f"runs' kernel wall per simulated second goes from {w.min():.3g} s "
                     f"({g.loc[w.idxmin(), 'method']}) to {w.max():.3g} s ({g.loc[w.idxmax(), 'method']}), "
                     f"a spread of {w.max() / w.min():.2f}×; the counted cost of the same steps spreads "
                     f"{c.max() / c.min():.2f}× (from {c.min():.3g} to {c.max():.3g} rhs evaluations per s).")
    return "\n".join(lines)


def _finding(df) -> str:
    lines = ["**Finding (node values, equal cost).**", ""]
    for mu, g in df.groupby("μ (kg m⁻¹ s⁻¹)", sort=False):
        g = g.sort_values("median |drift rate| (s⁻¹)")
        lines.append(f"- μ = {mu:g} kg m⁻¹ s⁻¹: median |drift rate| " + "; ".join(
            f"{r['method']} {r['median |drift rate| (s⁻¹)']:.2e} s⁻¹ (oscillation {r['median oscillation amplitude (1)']:.1e})"
            + (f", {r['failed']} failed" if r["failed"] else "") for _, r in g.iterrows()) + ".")
    fam = df["method"].map(lambda m: METHODS[parse_method(m)["method"]].family)
    groups = (("variational integrator", fam == "vi"), ("splitting", fam == "split"),
              ("Runge–Kutta method", fam == "rk"))
    for mu in df["μ (kg m⁻¹ s⁻¹)"].unique():
        at = df["μ (kg m⁻¹ s⁻¹)"] == mu
        best = [(what, df[at & sel]) for what, sel in groups if (at & sel).any()]
        best = [(what, g.loc[g["median |drift rate| (s⁻¹)"].idxmin()]) for what, g in best]
        if len(best) < 2:
            continue
        best.sort(key=lambda x: x[1]["median |drift rate| (s⁻¹)"])
        win, r = best[0]
        rest = "; ".join(f"the best {what}, {o['method']}, {o['median |drift rate| (s⁻¹)']:.2e} s⁻¹ "
                         f"({o['median |drift rate| (s⁻¹)'] / max(r['median |drift rate| (s⁻¹)'], 1e-300):.3g}×)"
                         for what, o in best[1:])
        lines.append(f"- At μ = {mu:g}: the {win} {r['method']} drifts least, {r['median |drift rate| (s⁻¹)']:.2e} s⁻¹, "
                     f"at h = {r['h (s)']:.3g} s; {rest}.")
    return "\n".join(lines)


def _error_figure(dss, tasks, outdir: Path, opt) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mus = list(dict.fromkeys(float(pt[SWEEP_KEY]) for pt, _, _, _ in tasks))
    labels = list(dict.fromkeys(spec["label"] for _, spec, _, _ in tasks))
    fig, axes = plt.subplots(1, len(mus), figsize=(5.0 * len(mus), 4.6), sharey=True, squeeze=False,
                             layout="constrained")
    for (pt, spec, _, _), d in zip(tasks, dss):
        ax = axes[0, mus.index(float(pt[SWEEP_KEY]))]
        t = d["t"].values
        med = d["relative_energy_error_quantiles"].sel(quantile=0.5).values
        i = labels.index(spec["label"])
        ok = t > 0
        # each viscosity calibrates its own steps: the legend of each panel gives them
        ax.semilogy(t[ok], np.clip(med[ok], 1e-17, None), color=f"C{i}", lw=1.2,
                    label=f"{spec['label']} (h = {float(d.attrs['h']):.3g} s)")
    for ax, mu in zip(axes[0], mus):
        ax.set_title(f"μ = {mu:g} kg m⁻¹ s⁻¹")
        ax.set_xlabel("t (s)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
    axes[0, 0].set_ylabel("median |E_k − E_0| / E_mech,0 (1), node values")
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
                    label=f"{m} ({step_text(g['h (s)'])})")
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
