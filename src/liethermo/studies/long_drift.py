"""Long drift: every method's energy error over a long horizon at equal measured cost (any model). Per dissipation
factor a serial calibration (:func:`.timing.measure`) sets each h to the first method's CPU time per simulated
second; per member the long runs give the drift of the relative energy error and the defects of the model's exact
laws (``Model.run_with_laws``); after them the long runs are timed again, interleaved, and checked for equal cost.
Costs are the process's CPU time (one thread): the machine's other load does not enter them, as it enters wall time."""

from __future__ import annotations

import functools
import time

import numpy as np
import xarray as xr

from .. import timing
from .common import StudyError
from .framework import Figure, Option, Stage, Study, Table, Verdict, first_point
from ..models import StudyDefaults
from ..analysis import BOOTSTRAP_RESAMPLES, MIN_MEMBERS, ROUND_OFF, TREND_OVER_RANGE, drift_test, least_over_members

CALIBRATION_ITERATIONS = 6  # rounds of the calibration, at most
QUANTILES = (0.05, 0.5, 0.95)


def _check(ctx) -> None:
    if ctx.model.relative_energy_error.__func__ is StudyDefaults.relative_energy_error:
        raise StudyError(f"study.base_scene: runs of {ctx.model.name} record no energy error: no long_drift study")
    if "reference" in ctx.methods:
        raise StudyError("methods: 'reference' is the ground truth, not a compared method")


def plan_steps(h: float, opt: dict) -> tuple[float, int, int]:
    """(h, steps, every) of a long run: about t_end simulated seconds, ``outputs`` to 2 × ``outputs`` nodes."""
    steps = max(1, int(round(float(opt["t_end"]) / h)))
    every = max(1, steps // int(opt["outputs"]))
    return float(h), max(every, (steps // every) * every), every


def _scene(ctx, coords, method, h, steps, every):
    base, model = ctx.scene(coords["point"]), ctx.model
    return model, base.with_overrides({**model.dissipation_overrides(base, coords["dissipation"]),
                                       **model.method_overrides(method), "integrator.h": float(h),
                                       "integrator.steps": int(steps), "output.every": int(every)})


def _run(model, sc, kernel, threads) -> None:  # a run of scene sc, timed by measure's clock: CPU time
    model.run_chunk(sc, 0, int(sc["ensemble"]["members"]), kernel=kernel, threads=threads)


def _cpu_costs(ctx, coords, steps: dict, kernel, warm: int) -> dict:
    """{m: Cost per simulated second} of runs at ``steps[m] = (h, n)``, one stored node, CPU time, interleaved."""
    runs = {m: functools.partial(_run, *_scene(ctx, coords, m, h, n, n), kernel, ctx.opt["threads"])
            for m, (h, n) in steps.items()}
    c = timing.measure(runs, repeats=ctx.opt["calibration_repeats"], warm=warm, threads=ctx.opt["threads"], clock=time.process_time)
    return {m: c[m].per(n * h) for m, (h, n) in steps.items()}


def calibrate(ctx, coords) -> xr.Dataset:
    """Each method's h at the first method's CPU time per simulated second (:func:`.timing.equalize_steps`)."""
    opt, ms = ctx.opt, ctx.methods
    model, sc = _scene(ctx, coords, ms[0], *plan_steps(opt["h_base"], opt))
    kernel, warm = model.kernel_for(sc), iter([1])

    def cost_of(h):  # the first measurement warms every run (compilation)
        n = {m: max(opt["calibration_steps"], round(opt["calibration_horizon"] * opt["t_end"] / h[m])) for m in ms}
        return _cpu_costs(ctx, coords, {m: (h[m], n[m]) for m in ms}, kernel, warm=next(warm, 0))
    got, rounds = timing.equalize_steps(cost_of, {m: float(opt["h_base"]) for m in ms}, {m: ms[0] for m in ms[1:]},
                                        rtol=opt["calibration_rtol"], rounds=CALIBRATION_ITERATIONS)
    return xr.Dataset({"step": ("scheme", [got[m][0] for m in ms]), "calibrated_cost": ("scheme", [got[m][1].best for m in ms]),
                       "calibration_spread": ("scheme", [got[m][1].spread for m in ms]), "calibration_rounds": ((), rounds)},
                      coords={"scheme": ms}, attrs={"kernel": kernel or ""})


def costs(ctx, coords, calibration) -> xr.Dataset:
    """After the long runs: each method's whole run (one stored node) timed again, interleaved with the others'."""
    c = _cpu_costs(ctx, coords, {m: plan_steps(float(calibration["step"].sel(scheme=m)), ctx.opt)[:2]
                                 for m in ctx.methods}, calibration.attrs.get("kernel") or None, warm=0)
    return xr.Dataset({"cost_per_simulated_s": ("scheme", [x.best for x in c.values()]),
                       "cost_spread": ("scheme", [x.spread for x in c.values()])}, coords={"scheme": list(c)})


def long_run(ctx, coords, calibration) -> xr.Dataset:
    """One method's long run at its calibrated step, and the window of every step."""
    opt, m = ctx.opt, coords["scheme"]
    h, steps, every = plan_steps(float(calibration["step"].sel(scheme=m)), opt)
    (model, sc), kw = _scene(ctx, coords, m, h, steps, every), dict(kernel=calibration.attrs.get("kernel") or None,
                                                                    threads=opt["threads"])
    with timing.pinned_threads(opt["threads"]):
        ds, _, laws = model.run_with_laws(sc, **kw)
        _, win = _scene(ctx, coords, m, h, min(int(opt["kn_steps"]), steps), 1)
        laws = {**model.run_with_laws(win, **kw)[2], **laws}  # the long run's where it gives the law
    rel, t, status = model.relative_energy_error(ds), ds["t"].values, ds["status"].values
    d = drift_test(t, rel)
    with np.errstate(invalid="ignore"):
        arel = np.abs(rel)
        band = np.quantile(np.where(np.isfinite(arel), arel, np.inf), QUANTILES, axis=0, method="inverted_cdf")
    pad = (0, 2 * int(opt["outputs"]) - t.size)  # every run's nodes on one "sample" axis
    return xr.Dataset({
        "drift_rate": ("member", d["slope"]), "drift_half_width": ("member", d["half_width"]),
        "oscillation_amplitude": ("member", d["amplitude"]), "oscillation_range": ("member", d["range"]),
        "drift_measurable": ("member", d["measurable"].astype(np.int8)),
        "max_relative_energy_error": ("member", np.where(status == 0, np.nanmax(arel, axis=1), np.inf)),
        "status": ("member", status.astype(np.int8)),
        "relative_energy_error_quantiles": (("quantile", "sample"), np.pad(band, ((0, 0), pad), constant_values=np.nan)),
        "band_t": ("sample", np.pad(t, pad, constant_values=np.nan)), "steps": ((), steps),
        **{f"defect_{k}": ("member", v[0], {"units": v[1], "long_name": v[2]}) for k, v in laws.items()}},
        coords={"member": ds["member"].values, "quantile": list(QUANTILES)})


QUANTITIES = {
    "dissipation": ("1", "factor on the base scene's dissipative coefficients"), "sample": ("1", "stored node"),
    "drift_rate": ("s-1", "least-squares slope of the relative energy error against t"),
    "oscillation_amplitude": ("1", "RMS of the relative energy error about its least-squares line"),
    "oscillation_range": ("1", "peak-to-peak of the relative energy error about its least-squares line"),
    "drift_half_width": ("s-1", "half the 95 % Newey-West interval of the drift rate"),
    "drift_measurable": ("1", f"1: the interval excludes 0 and |drift rate| x record > {TREND_OVER_RANGE:g} x range"),
    "drifting_members": ("1", "members whose drift is measurable (completed)"),
    "median_drift_half_width": ("s-1", "median half-width of the drift rate's 95 % interval (completed)"),
    "max_relative_energy_error": ("1", "max over t of |relative energy error| (failed members: inf)"),
    "relative_energy_error_quantiles": ("1", "quantiles over members of |relative energy error| at band_t"),
    "band_t": ("s", "time of the stored node (NaN: past the run's last node)"), "steps": ("1", "steps of the run"),
    "quantile": ("1", "quantile over members"), "cost_spread": ("1", "median / min - 1 of the long run's repeats"),
    "cost_per_simulated_s": ("s", "CPU time per simulated second of the long run (timed after the runs, interleaved, min)"),
    "step": ("s", "time step h (calibrated to equal measured cost per simulated second)"),
    "calibrated_cost": ("s", "calibration: min over repeats of CPU time per simulated second at this step"),
    "calibration_spread": ("1", "calibration: median / min - 1 of the repeats at this step"),
    "calibration_rounds": ("1", "rounds of the calibration"), "failed_members": ("1", "members whose run failed"),
    "median_drift_rate": ("s-1", "median drift rate (completed)"), "median_abs_drift_rate": ("s-1", "median |drift rate| (completed)"),
    "median_oscillation_amplitude": ("1", "median oscillation amplitude (completed members)"),
    "median_max_relative_energy_error": ("1", "median max |relative energy error| (failed: inf)")}
#: the table's columns, by their netCDF names
COLUMNS = ("step", "steps", "calibrated_cost", "calibration_spread", "cost_per_simulated_s", "cost_spread",
           "median_drift_rate", "median_drift_half_width", "drifting_members", "median_abs_drift_rate",
           "median_oscillation_amplitude", "median_max_relative_energy_error", "failed_members")


def derive(ds, ctx) -> xr.Dataset:
    ok, dr = ds["status"] == 0, ds["drift_rate"]
    return ds.assign(median_drift_rate=dr.where(ok).median("member"), median_abs_drift_rate=abs(dr).where(ok).median(
        "member"), median_oscillation_amplitude=ds["oscillation_amplitude"].where(ok).median("member"),
        median_max_relative_energy_error=ds["max_relative_energy_error"].median("member"), failed_members=(~ok).sum("member"),
        median_drift_half_width=ds["drift_half_width"].where(ok).median("member"),
        drifting_members=(ds["drift_measurable"].where(ok, 0) > 0).sum("member"))


def _costs(d) -> dict:  # {dissipation: {method: CPU time per simulated second of its long run}}
    return {f: d["cost_per_simulated_s"].sel(dissipation=f).to_series().to_dict() for f in d["dissipation"].values}


def tables(ds, ctx) -> list[Table]:
    d, rows = first_point(ds, ctx), []
    u, laws = {v: f" ({d[v].attrs['units']})" for v in d.data_vars}, [v for v in d.data_vars if v.startswith("defect_")]
    for f, m in ((f, m) for f in d["dissipation"].values for m in ctx.methods):
        x = d.sel(dissipation=f, scheme=m)
        rows.append({"dissipation (1)": float(f), "scheme": m, **{v + u[v]: x[v].item() for v in COLUMNS},
                     **{f"max {v}{u[v]}": float(x[v].max()) for v in laws}})
    pairs = [{"dissipation (1)": float(f), "cheaper": lo, "dearer": hi, "ratio (1)": r}
             for f, c in _costs(d).items() for lo, hi, r in timing.equal_cost_check(c)]
    return [Table("long_drift", f"Energy drift at equal measured cost per simulated second ({ds.sizes['member']} "
                  f"members, t_end = {ctx.opt['t_end']:g} s; law defects: NaN where the law does not apply)", rows),
            Table("equal_cost", "Long runs more than 15 % apart in CPU time per simulated second (timed after the runs)",
                  pairs or [{"dissipation (1)": "any", "cheaper": "—", "dearer": "—", "ratio (1)": np.nan}])]


def verdicts(ds, ctx) -> list[Verdict]:
    return [Verdict(f"dissipation × {f:g}: the long runs cost the same per simulated second",
                    f"max / min {max(c.values()) / min(c.values()):.2f}", "no pair > 15 % apart",
                    not timing.equal_cost_check(c)) for f, c in _costs(first_point(ds, ctx)).items()]


def _least(values: dict, what: str, floor: float = ROUND_OFF) -> str:
    """A clause on which of ``values`` ({method: per-member values}) is least, by seeded paired intervals."""
    if len(values) < 2:
        return ""
    med = {m: float(np.median(np.where(np.isfinite(v), np.abs(v), np.inf))) for m, v in values.items()}
    best = min(med, key=med.get)
    at_floor = [m for m in values if med[m] <= floor]
    if len(at_floor) > 1:
        above = ", ".join(f"{m} {med[m]:.1e}" for m in values if m not in at_floor)
        return f"{what} {', '.join(at_floor)} tie at round-off (median ≤ {floor:g})" + (f", above it {above}" if above else "")
    least, cmp = least_over_members(values, floor=floor)
    if not least:
        return f"{what} {best} ({med[best]:.2e})"
    if len(least) == len(values):
        return f"{what} no method below another (every paired interval contains 1)"
    nxt = min((m for m in cmp if m not in least), key=med.get)
    return (f"{what} {' = '.join(least)} ({med[best]:.2e}{'; the others tie with it' if len(least) > 1 else ''}; "
            f"next {cmp[nxt].text(nxt, best)})")


def findings(ds, ctx) -> list[str]:
    """Per dissipation: which methods drift measurably over T, which do not (and are not ranked), then the least
    |drift rate| among those that drift, the least max energy error and the least defect of each law, each
    ranked by seeded paired intervals over members (or said to be unranked where members are too few)."""
    d, out, T = first_point(ds, ctx), [], float(ctx.opt["t_end"])
    laws, members = [v for v in d.data_vars if v.startswith("defect_")], d.sizes["member"]
    for f in d["dissipation"].values:
        x = d.sel(dissipation=f)
        ok = {m: x["status"].sel(scheme=m).values == 0 for m in ctx.methods}
        n = {m: int(ok[m].sum()) for m in ctx.methods}
        k = {m: int(((x["drift_measurable"].sel(scheme=m).values > 0) & ok[m]).sum()) for m in ctx.methods}
        drifts = [m for m in ctx.methods if n[m] and 2 * k[m] > n[m]]
        still = [m for m in ctx.methods if n[m] and m not in drifts]
        words, least = [], []
        if still:
            words.append(f"no measurable drift over T = {T:g} s for {', '.join(still)} (on most members |drift| × T "
                         f"is not {TREND_OVER_RANGE:g}× the oscillation's range, or the drift's 95 % interval "
                         "contains 0): not ranked by drift")
        for m in drifts:
            y = x.sel(scheme=m)
            words.append(f"{m} drifts on {k[m]} of {n[m]} members (median "
                         f"{float(y['median_drift_rate']):.2e} s⁻¹, interval ± {float(y['median_drift_half_width']):.1e})")
        if len(drifts) > 1:
            least.append(_least({m: np.where(ok[m], x["drift_rate"].sel(scheme=m).values, np.inf) for m in drifts},
                                "|drift rate|", floor=0.0))
        least.append(_least({m: x["max_relative_energy_error"].sel(scheme=m).values for m in ctx.methods},
                            "max |relative energy error|"))
        for v in laws:
            vals = {m: x[v].sel(scheme=m).values for m in ctx.methods if np.isfinite(x[v].sel(scheme=m).values).any()}
            least.append(_least(vals, f"{v[len('defect_'):]} defect"))
        least = [w for w in least if w]
        head = (f"Least medians ({members} members, too few for paired intervals (≥ {MIN_MEMBERS}), so not ranked): "
                if members < MIN_MEMBERS else "Least, by paired 95 % intervals over members: ")
        out.append(f"At dissipation × {f:g}: " + "; ".join(words) + (f". {head}" + "; ".join(least) if least
                                                                    else "") + ".")
    failed = [m for m in ctx.methods if int(d["failed_members"].sel(scheme=m).sum())]
    if failed:
        out.append(f"Failed members (counted as the worst in every comparison): {', '.join(failed)}.")
    return out


def draw(d, ctx, fig):
    """A panel per dissipation (median |error| against t), then drift rate and long-run cost per dissipation."""
    fs, q = d["dissipation"].values, d["relative_energy_error_quantiles"].sel(quantile=0.5)
    panels = [(f"dissipation × {f:g}", f) for f in fs] + [("median |drift rate| (filled: a measurable drift)",
                                                             "median_abs_drift_rate"), (
        "CPU time per simulated s", "cost_per_simulated_s")]
    axes = fig.subplots(-(-len(panels) // 3), 3, squeeze=False).ravel()
    for ax, (title, f) in zip(axes, panels):
        for m in ctx.methods:
            if not isinstance(f, str):
                t, y = d["band_t"].sel(dissipation=f, scheme=m).values, q.sel(dissipation=f, scheme=m).values
                ax.plot(t[t > 0], np.clip(y[t > 0], 1e-17, None), color=ctx.color(m), lw=1.2, label=m)
            else:  # categories (the dissipation factors) side by side, not joined: no trend between them is drawn
                y = np.clip(d[f].sel(scheme=m).values, 1e-20, None)
                j = ctx.methods.index(m)
                x = np.arange(len(fs)) + 0.5 * (j - (len(ctx.methods) - 1) / 2) / max(len(ctx.methods), 1)
                if f == "median_abs_drift_rate":  # filled: the method drifts measurably; open: no measurable drift
                    ok = d["status"].sel(scheme=m) == 0
                    drifts = (2 * d["drifting_members"].sel(scheme=m) > ok.sum("member")).values
                    ax.plot(x[drifts], y[drifts], "o", color=ctx.color(m))
                    ax.plot(x[~drifts], y[~drifts], "o", color=ctx.color(m), mfc="none")
                else:
                    ax.plot(x, y, "o", color=ctx.color(m), mfc="none")
                ax.set_xticks(range(len(fs)), [f"{x:g}" for x in fs])
                ax.set_xlim(-0.5, len(fs) - 0.5)
        ax.set(title=title, yscale="log", xlabel="dissipation (× scene's)" if isinstance(f, str) else "t (s)",
               ylabel=f"{title.split(' (')[0]} ({d[f].attrs['units']})" if isinstance(f, str) else
               "median |relative energy error| (1)")
        ax.grid(True, which="major", alpha=0.3)
    for ax in axes[len(panels):]:
        ax.set_visible(False)
    fig.legend(*axes[0].get_legend_handles_labels(), title="scheme", loc="outside right center", fontsize=8)


STUDY = Study(
    kind="long_drift", title="Long drift at equal measured cost", models=None,
    description="Drift rate, oscillation and law defects of every method over a long horizon at equal cost",
    options=(Option("h_base", 0.01, "number>0", "s", "step of the first method, the cost base"),
             Option("dissipation", [1.0], "list[number>=0]", "1", "factors on the scene's dissipative coefficients"),
             Option("t_end", 1000.0, "number>0", "s", "simulated time"), Option("outputs", 2000, "int>=1", "1", "nodes"),
             Option("kn_steps", 2000, "int>=1", "1", "steps of the window stored at every step"),
             Option("calibration_steps", 2000, "int>=1", "1", "steps of a calibration run, at least"),
             Option("calibration_horizon", 1.0, "number>0", "1", "simulated time of a calibration run / t_end"),
             Option("calibration_repeats", 5, "int>=1", "1", "samples per method and round, at least"),
             Option("calibration_rtol", 0.03, "number>0", "1", "calibration stops within this of equal cost"),
             Option("threads", 1, "int>=1", "1", "threads of every run (timings on one vary least)")),
    axes=lambda ctx: {"dissipation": ctx.opt["dissipation"]}, check=_check,
    stages=(Stage("calibration", calibrate, over=("point", "dissipation"), serial=True),
            Stage("runs", long_run, over=("point", "dissipation", "scheme"), needs=("calibration",)),
            Stage("costs", costs, over=("point", "dissipation"), needs=("calibration",), serial=True)),
    quantities=QUANTITIES, derive=derive, tables=tables, verdicts=verdicts, findings=findings,
    figures=(Figure("long_drift", kind="custom", draw=draw, size=(15.5, 8.4), title="Long drift at equal measured cost: "
                    "energy error, drift rate and CPU time per dissipation", claim=(
        "each method's median energy error over time at equal cost (bounded or drifting); per dissipation the drift "
        "rate (filled: the method drifts measurably; open: no measurable drift over T, the slope is the oscillation's) "
        "and the long runs' CPU time per simulated second (the equal-cost table flags pairs > 15 % apart)")),),
    report=("Scene `{scene}` ({model}), {members} members, t_end = {opt[t_end]} s, dissipation × {factors} of the "
            "scene's ({coefficients}). **Equal cost, measured:** `{base}` at h = {opt[h_base]} s; each other h is "
            "calibrated per dissipation in CPU time on the long runs' kernel ({opt[threads]} thread(s), {horizon:g} s "
            "simulated, interleaved, ≥ {opt[calibration_repeats]} repeats, minimum) to within {rtol:g} %; after the long "
            "runs each is timed again the same way, and the equal-cost check uses those times. Drift rate: "
            "least-squares slope of the relative energy error, with its 95 % Newey–West interval (Bartlett weights over "
            "a tenth of the record's nodes: the oscillation's residuals are correlated over many nodes); "
            "oscillation: RMS and peak-to-peak range about that line. A member **drifts** when the interval excludes "
            "0 and |drift rate| × t_end exceeds {trend:g}× the range (an oscillation with a whole period in the record "
            "never does), a method when most of its members do; otherwise the findings say \"no measurable drift "
            "over T\" and do not rank it. Rankings over members (smallest |drift|, max energy error, law defects) "
            "compare medians by a paired bootstrap over members (95 %, seeded, {resamples} resamples): a method ties "
            "with the least when its interval of the ratio contains 1, values below {floor:g} are equal (round-off), "
            "and fewer than {min_members} members rank nothing. Laws needing every step: {opt[kn_steps]} steps."),
    facts=lambda ds, ctx: {
        "members": ds.sizes["member"], "base": ctx.methods[0], "trend": TREND_OVER_RANGE, "floor": ROUND_OFF,
        "resamples": BOOTSTRAP_RESAMPLES, "min_members": MIN_MEMBERS, "rtol": 100 * ctx.opt["calibration_rtol"],
        "factors": ", ".join(f"{f:g}" for f in ctx.opt["dissipation"]), "horizon": ctx.opt["calibration_horizon"]
        * ctx.opt["t_end"], "coefficients": ", ".join(f"{k} = {v:g}" for k, v in ctx.model.dissipation_overrides(
            ctx.scene(ctx.points[0] if ctx.points else None), 1.0).items()) or "none"},
)
