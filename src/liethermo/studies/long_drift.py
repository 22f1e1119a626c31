"""Long drift: every method's energy error over a long horizon at equal measured cost (any model).

The base scene's dissipation is scaled by each factor of ``dissipation``
(:meth:`liethermo.models.Model.dissipation_overrides`; 0: conservative).  A
serial calibration per factor times every method (:func:`.timing.measure`:
interleaved, repeated, minimum, threads pinned; the long runs' kernel) and
moves its h until its kernel time per simulated second is the cost base's at
``h_base``.  Per member of each long run: the drift rate (least-squares slope
of the model's relative energy error in t), the oscillation about that line,
max and final |error|, and the defects of the model's exact laws
(:meth:`~liethermo.models.Model.run_with_laws`; laws that need every step from
a window of ``kn_steps``).  The long runs' costs are then checked for equality.
"""

from __future__ import annotations

import math

import numpy as np
import xarray as xr

from . import timing
from .common import StudyError
from .framework import Figure, Option, Stage, Study, Table, Verdict, first_point
from ..models import Model
from .tools import drift_fit

CALIBRATION_ITERATIONS = 6  # rounds of the calibration, at most
QUANTILES = (0.05, 0.5, 0.95)


def _base(ctx) -> str:
    return ctx.opt["cost_base"] or ctx.methods[0]


def _check(ctx) -> None:
    if ctx.model.relative_energy_error.__func__ is Model.relative_energy_error:
        raise StudyError(f"study.base_scene: runs of {ctx.model.name} record no energy error: no long_drift study")
    if _base(ctx) not in ctx.methods or "reference" in ctx.methods:
        raise StudyError(f"options.cost_base: {_base(ctx)!r} must be one of the methods, and 'reference' none")


def plan_steps(h: float, opt: dict) -> tuple[float, int, int]:
    """(h, steps, every) of a long run: about t_end simulated seconds, ``outputs`` to 2 × ``outputs`` nodes."""
    steps = max(1, int(round(float(opt["t_end"]) / h)))
    every = max(1, steps // int(opt["outputs"]))
    return float(h), max(every, (steps // every) * every), every


def _scene(ctx, coords, method=None, h=None, steps=None, every=None):
    base, model = ctx.scene(coords["point"]), ctx.model
    over = dict(model.dissipation_overrides(base, coords["dissipation"]))
    if method is not None:
        over.update({**model.method_overrides(method), "integrator.h": float(h), "integrator.steps": int(steps),
                     "output.every": int(every)})
    return model, base.with_overrides(over)


def secant_step(tried: list[tuple[float, float]]) -> float:
    """The next log h from the (log h, f = log(cost per simulated s / target)) tried: the
    secant of the closest bracket once f has changed sign, else x + f."""
    below, above = [t for t in tried if t[1] > 0], [t for t in tried if t[1] < 0]
    if below and above:
        (xa, fa), (xb, fb) = max(below), min(above)
        return xa - fa * (xb - xa) / (fb - fa)
    return tried[-1][0] + tried[-1][1]


def calibrate(ctx, coords) -> xr.Dataset:
    """Each method's h at the base's kernel time per simulated second: rounds time every method
    at its h, interleaved; the target is the base's least cost so far; each keeps its closest h."""
    opt, base, ms = ctx.opt, _base(ctx), ctx.methods
    model, sc = _scene(ctx, coords, base, *plan_steps(float(opt["h_base"]), opt))
    kernel, members = model.kernel_for(sc), int(sc["ensemble"]["members"])
    h, tried = {m: float(opt["h_base"]) for m in ms}, {m: [] for m in ms}  # tried: (h, Cost per simulated s)

    def candidate(m):
        n = max(int(opt["calibration_steps"]), int(round(opt["calibration_horizon"] * opt["t_end"] / h[m])))
        _, s = _scene(ctx, coords, m, h[m], n, n)
        return n * h[m], lambda: model.run_chunk(s, 0, members, kernel=kernel, threads=opt["threads"])[1].kernel_time

    def gap(m, i=-1):  # log(cost per simulated s / target)
        return math.log(tried[m][i][1].best / min(c.best for _, c in tried[base]))

    for rnd in range(CALIBRATION_ITERATIONS):
        cands = {m: candidate(m) for m in ms}
        costs = timing.measure({m: fn for m, (_, fn) in cands.items()}, repeats=int(opt["calibration_repeats"]),
                               min_time=float(opt["calibration_time"]), warm=int(rnd == 0), threads=opt["threads"])
        for m in ms:
            tried[m].append((h[m], costs[m].per(cands[m][0])))
        todo = [m for m in ms if m != base and abs(math.exp(gap(m)) - 1) >= opt["calibration_rtol"]]
        if not todo:
            break
        for m in todo:
            h[m] = math.exp(secant_step([(math.log(hh), gap(m, i)) for i, (hh, _) in enumerate(tried[m])]))
    pick = {m: min(range(len(tried[m])), key=lambda i: abs(gap(m, i))) for m in ms}
    pick[base] = min(range(len(tried[base])), key=lambda i: tried[base][i][1].best)
    got = [tried[m][pick[m]] for m in ms]
    return xr.Dataset({"step": ("scheme", [g[0] for g in got]), "calibrated_cost": ("scheme", [g[1].best for g in got]),
                       "calibration_spread": ("scheme", [g[1].spread for g in got]), "calibration_rounds": ((), rnd + 1)},
                      coords={"scheme": ms}, attrs={"kernel": kernel or ""})


def long_run(ctx, coords, calibration) -> xr.Dataset:
    """One method's long run at its calibrated step, and the window of every step."""
    opt, m = ctx.opt, coords["scheme"]
    h, steps, every = plan_steps(float(calibration["step"].sel(scheme=m)), opt)
    model, sc = _scene(ctx, coords, m, h, steps, every)
    kw = dict(kernel=calibration.attrs.get("kernel") or None, threads=opt["threads"])
    with timing.pinned_threads(opt["threads"]):
        ds, st, laws = model.run_with_laws(sc, **kw)
        _, win = _scene(ctx, coords, m, h, min(int(opt["kn_steps"]), steps), 1)
        laws = {**model.run_with_laws(win, **kw)[2], **laws}  # the long run's where it gives the law
    rel, t, status = model.relative_energy_error(ds), ds["t"].values, ds["status"].values
    slope, spread = drift_fit(t, rel)
    with np.errstate(invalid="ignore"):
        arel = np.abs(rel)
        band = np.quantile(np.where(np.isfinite(arel), arel, np.inf), QUANTILES, axis=0, method="inverted_cdf")
    pad = (0, 2 * int(opt["outputs"]) - t.size)  # every run's nodes on one "sample" axis
    return xr.Dataset({
        "drift_rate": ("member", slope), "oscillation_amplitude": ("member", spread),
        "max_relative_energy_error": ("member", np.where(status == 0, np.nanmax(arel, axis=1), np.inf)),
        "final_relative_energy_error": ("member", arel[:, -1]), "status": ("member", status.astype(np.int8)),
        "relative_energy_error_quantiles": (("quantile", "sample"), np.pad(band, ((0, 0), pad), constant_values=np.nan)),
        "band_t": ("sample", np.pad(t, pad, constant_values=np.nan)), "kernel_time": ((), st.kernel_time),
        "cost_per_simulated_s": ((), st.kernel_time / (steps * h)), "steps": ((), steps),
        **{f"defect_{k}": ("member", v[0], {"units": v[1], "long_name": v[2]}) for k, v in laws.items()}},
        coords={"member": ds["member"].values, "quantile": list(QUANTILES)})


QUANTITIES = {
    "dissipation": ("1", "factor on the base scene's dissipative coefficients"),
    "drift_rate": ("s-1", "least-squares slope of the relative energy error against t"),
    "oscillation_amplitude": ("1", "RMS of the relative energy error about its least-squares line"),
    "max_relative_energy_error": ("1", "max over t of |relative energy error| (failed members: inf)"),
    "final_relative_energy_error": ("1", "|relative energy error| at t_end"),
    "relative_energy_error_quantiles": ("1", "quantiles over members of |relative energy error| at band_t"),
    "band_t": ("s", "time of the stored node (NaN: past the run's last node)"), "sample": ("1", "stored node"),
    "quantile": ("1", "quantile over members"), "kernel_time": ("s", "kernel wall time of the long run"),
    "cost_per_simulated_s": ("s", "kernel wall time of the long run per simulated second"),
    "step": ("s", "time step h (calibrated to equal measured cost per simulated second)"),
    "steps": ("1", "steps of the long run"), "calibration_rounds": ("1", "rounds of the calibration"),
    "calibrated_cost": ("s", "calibration: min over repeats of kernel time per simulated second at this step"),
    "calibration_spread": ("1", "calibration: median / min - 1 of the repeats at this step"),
    "median_abs_drift_rate": ("s-1", "median over completed members of |drift rate|"),
}


def derive(ds, ctx) -> xr.Dataset:
    ds["median_abs_drift_rate"] = abs(ds["drift_rate"]).where(ds["status"] == 0).median("member")
    return ds


def _costs(d) -> dict:
    return {str(m): float(d["cost_per_simulated_s"].sel(scheme=m)) for m in d["scheme"].values}


def _med(x, ok) -> float:
    return float(np.median(x.values[ok])) if ok.any() else np.nan


def tables(ds, ctx) -> list[Table]:
    d, rows, pairs = first_point(ds, ctx), [], []
    laws = [v for v in d.data_vars if v.startswith("defect_")]
    for f in d["dissipation"].values:
        for m in ctx.methods:
            x = d.sel(dissipation=f, scheme=m)
            ok = x["status"].values == 0
            rows.append({"dissipation (× base scene)": float(f), "method": m, "h (s)": float(x["step"]),
                         "steps": int(x["steps"]), "calibrated cost (s per simulated s)": float(x["calibrated_cost"]),
                         "calibration spread (%)": 100 * float(x["calibration_spread"]),
                         "long-run cost (s per simulated s)": float(x["cost_per_simulated_s"]),
                         "median drift rate (s⁻¹)": _med(x["drift_rate"], ok),
                         "median |drift rate| (s⁻¹)": float(x["median_abs_drift_rate"]),
                         "median oscillation amplitude (1)": _med(x["oscillation_amplitude"], ok),
                         "median max |relative energy error| (1)": float(x["max_relative_energy_error"].median()),
                         **{f"max {v[7:]} defect ({d[v].attrs['units']})": float(x[v].max()) for v in laws},
                         "failed members": int((~ok).sum())})
        pairs += [{"dissipation (× base scene)": float(f), "cheaper": lo, "dearer": hi, "ratio": r}
                  for lo, hi, r in timing.equal_cost_check(_costs(d.sel(dissipation=f)))]
    return [Table("long_drift", f"Energy drift at equal measured cost per simulated second ({ds.sizes['member']} "
                  f"members, t_end = {ctx.opt['t_end']:g} s; law defects: NaN where the law does not apply)", rows),
            Table("equal_cost", "Long runs more than 15 % apart in kernel time per simulated second", pairs or
                  [{"dissipation (× base scene)": "any", "cheaper": "—", "dearer": "—", "ratio": np.nan}],
                  "Each long run ran once: a flagged pair is the calibration not carrying over to the long runs, "
                  "or the machine's load changing between them.")]


def verdicts(ds, ctx) -> list[Verdict]:
    d, out = first_point(ds, ctx), []
    for f in d["dissipation"].values:
        x, rtol = d.sel(dissipation=f), ctx.opt["calibration_rtol"]
        c, flagged = _costs(x), timing.equal_cost_check(_costs(x))
        out.append(Verdict(f"dissipation × {f:g}: the long runs cost the same per simulated second",
                           f"max / min {max(c.values()) / min(c.values()):.2f}", "no pair > 15 % apart", not flagged))
        dev = np.abs(x["calibrated_cost"].values / float(x["calibrated_cost"].sel(scheme=_base(ctx))) - 1).max()
        out.append(Verdict(f"dissipation × {f:g}: the calibration reached equal cost",
                           f"largest gap {100 * dev:.1f} %", f"every method within {100 * rtol:g} %", bool(dev < rtol)))
    return out


def findings(ds, ctx) -> list[str]:
    d, base, out = first_point(ds, ctx), _base(ctx), []
    for f in d["dissipation"].values:
        r = d["median_abs_drift_rate"].sel(dissipation=f).to_series().dropna().sort_values()
        if base in r:
            beats = [m for m in r.index if r[m] > r[base]]
            out.append(f"At dissipation × {f:g}, {r.index[0]} drifts least ({r.iloc[0]:.2e} s⁻¹); the baseline {base} "
                       f"({r[base]:.2e} s⁻¹) drifts less than " + (", ".join(beats) or "no other method") + ".")
    return out


def draw(d, ctx, fig):
    """One panel per dissipation (median |error| against t), then drift rate and long-run cost per dissipation."""
    fs = d["dissipation"].values

    def band(ax, m, f):
        t, med = d["band_t"].sel(dissipation=f, scheme=m).values, d["relative_energy_error_quantiles"].sel(
            dissipation=f, scheme=m, quantile=0.5).values
        ax.plot(t[t > 0], np.clip(med[t > 0], 1e-17, None), color=ctx.color(m), lw=1.2, label=m)

    def per_f(ax, m, v):
        ax.plot(range(len(fs)), np.clip(d[v].sel(scheme=m).values, 1e-20, None), "o-", color=ctx.color(m), mfc="none")
        ax.set_xticks(range(len(fs)), [f"{f:g}" for f in fs])
    panels = [(f"dissipation × {f:g}", "t (s)", "median |relative energy error| (1)", band, f) for f in fs] + [
        ("drift rate", "dissipation (× base scene)", "median |drift rate| (s⁻¹)", per_f, "median_abs_drift_rate"),
        ("cost", "dissipation (× base scene)", "long-run kernel time per simulated s (s)", per_f, "cost_per_simulated_s")]
    axes = fig.subplots(-(-len(panels) // 3), 3, squeeze=False).ravel()
    for ax, (title, xlabel, ylabel, plot, arg) in zip(axes, panels):
        for m in ctx.methods:
            plot(ax, m, arg)
        ax.set(title=title, xlabel=xlabel, ylabel=ylabel, yscale="log")
        ax.grid(True, which="major", alpha=0.3)
    for ax in axes[len(panels):]:
        ax.set_visible(False)
    fig.legend(*axes[0].get_legend_handles_labels(), title="scheme", loc="outside right upper", fontsize=8)


STUDY = Study(
    kind="long_drift", title="Long drift at equal measured cost", models=None,
    description="Drift rate, oscillation and law defects of every method over a long horizon at equal cost",
    options=(Option("h_base", 0.01, "number>0", "s", "step of the cost base"),
             Option("cost_base", None, "str", "", "the method at h_base (default: the first method)", optional=True),
             Option("dissipation", [1.0], "list[number>=0]", "1", "factors on the base scene's dissipation"),
             Option("t_end", 1000.0, "number>0", "s", "simulated time of every long run"),
             Option("outputs", 2000, "int>=1", "1", "stored nodes per long run, about"),
             Option("kn_steps", 2000, "int>=1", "1", "steps of the window stored at every step"),
             Option("calibration_steps", 2000, "int>=1", "1", "steps of a calibration run, at least"),
             Option("calibration_horizon", 1.0, "number>0", "1", "simulated time of a calibration run / t_end"),
             Option("calibration_time", 0.3, "number>=0", "s", "timed samples per method and round, at least"),
             Option("calibration_repeats", 3, "int>=1", "1", "timed samples per method and round, at least"),
             Option("calibration_rtol", 0.03, "number>0", "1", "calibration stops within this of equal cost"),
             Option("threads", 1, "int>=1", "1", "threads of every run (timings on one vary least)")),
    axes=lambda ctx: {"dissipation": ctx.opt["dissipation"]}, check=_check,
    stages=(Stage("calibration", calibrate, over=("point", "dissipation"), serial=True),
            Stage("runs", long_run, over=("point", "dissipation", "scheme"), needs=("calibration",))),
    quantities=QUANTITIES, derive=derive, tables=tables, verdicts=verdicts, findings=findings,
    figures=(Figure("long_drift", kind="custom", draw=draw, size=(15.5, 8.4), claim=(
        "each method's median energy error over time at equal cost (bounded or drifting); the drift rate per "
        "dissipation; what each long run cost per simulated second (equal by calibration; the equal-cost table "
        "flags pairs more than 15 % apart)")),),
    report=("Scene `{scene}` ({model}), {members} members, t_end = {opt[t_end]} s, dissipation × {factors} of the "
            "scene's ({coefficients}). **Equal cost, measured:** `{base}` at h = {opt[h_base]} s; each other h is "
            "calibrated per dissipation on the long runs' kernel ({opt[threads]} thread(s)) over {horizon:g} s "
            "simulated, in rounds of interleaved runs (≥ {opt[calibration_repeats]} each, minimum) until within "
            "{rtol:g} %. Drift rate: least-squares slope of the model's relative energy error; oscillation: RMS about "
            "it. Laws needing every step are checked on a window of {opt[kn_steps]} steps."),
    facts=lambda ds, ctx: {"members": ds.sizes["member"], "base": _base(ctx), "rtol": 100 * ctx.opt["calibration_rtol"],
                           "factors": ", ".join(f"{f:g}" for f in ctx.opt["dissipation"]),
                           "horizon": ctx.opt["calibration_horizon"] * ctx.opt["t_end"],
                           "coefficients": ", ".join(f"{k} = {v:g}" for k, v in ctx.model.dissipation_overrides(
                               ctx.scene(ctx.points[0] if ctx.points else None), 1.0).items()) or "none"},
)
