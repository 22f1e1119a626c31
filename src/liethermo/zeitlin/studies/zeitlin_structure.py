"""Long runs of the Zeitlin fluid: Casimir and energy drift of the split family against RK4 at equal measured CPU cost
(one thread): RK4, whose cost per step does not depend on the state, at the step making its run cost the splitting's."""

import time

import numpy as np
import xarray as xr

from ... import timing
from ...studies.common import StudyError
from ...studies.framework import MARKERS, Figure, Option, Stage, Study, Table, Verdict, run_scene

RUN = {"h": ("s", "time step of the run", "h (s)"), "steps": ("1", "steps of the run", "steps"),
       "cost_per_simulated_second": ("s s-1", "CPU time per simulated second", "CPU time per simulated second (s)"),
       "casimir2_drift": ("1", "max over members of |relative change of tr W^2|", "tr W² drift"),
       "casimir4_drift": ("1", "max over members of |relative change of tr W^4|", "tr W⁴ drift"),
       "energy_drift": ("1", "max over members of |H + q - H(0)| / H(0)", "|H + q − H(0)|/H(0)"),
       "angular_momentum_drift": ("1", "max |L - L(0)| / max |L(0)|", "angular momentum drift"),
       "iterations_per_step": ("1", "mean fixed-point iterations per step (0 for rk4)", "fixed-point its/step")}
SIDES = ("splitting", "rk4")


def _check(ctx):
    if "rk4" not in ctx.methods or len(ctx.methods) < 2:
        raise StudyError("methods: rk4 and at least one split method (the comparison is against RK4)")
    nus = ctx.opt["kinematic_viscosity"]
    for coords in ({"N": N, "kinematic_viscosity": nu} for N in ctx.opt["N"] for nu in nus):
        _setup(ctx, coords, ctx.opt["h"])  # the scene's own rules


def _setup(ctx, coords, h):  # the scene, the steps per sample and the step near h at which the samples end at t_end
    sc = ctx.scene(None, zeitlin__N=int(coords["N"]), fluid__kinematic_viscosity=float(coords["kinematic_viscosity"]))
    per = max(int(round(ctx.opt["t_end"] / h / ctx.opt["samples"])), 1)
    return sc, per, ctx.opt["t_end"] / (per * ctx.opt["samples"])


def _cpu(sc, m, h, n, every):  # a run and its CPU time (one thread: the machine's other load does not enter)
    t = time.process_time()
    return run_scene(sc, m, h=h, steps=n, every=every, threads=1, output__vorticity=False)[0], time.process_time() - t


def _run_setup(ctx, coords, calibrate, side):  # scene, steps per sample, step of one run of the pair
    return _setup(ctx, coords, ctx.opt["h"] if side == "splitting" else float(calibrate["rk4_step"]))


def _costs(ctx, coords, h: dict) -> dict:
    """{side: Cost per simulated second}, one thread, interleaved, min over ≥ 2 repeats and ≥ 1 s of CPU time each: the
    splitting's whole run (its iterations per step grow along a run) and RK4's first as many steps (a fixed cost per
    step), so that a run's fixed cost weighs the same on both sides."""
    sc, per, _ = _setup(ctx, coords, ctx.opt["h"])
    m, n = {"splitting": coords["pair"], "rk4": "rk4"}, per * ctx.opt["samples"]
    [_cpu(sc, m[k], h[k], 1, 1) for k in h]  # load or compile the kernels before timing
    c = timing.measure({k: lambda k=k: _cpu(sc, m[k], h[k], n, n)[1] for k in h}, repeats=2, min_time=1.0, warm=0)
    return {k: c[k].per(n * h[k]) for k in h}


def calibrate(ctx, coords) -> xr.Dataset:
    """RK4's step at the splitting's CPU time per simulated second: RK4's is a fixed cost per step over its step."""
    h = _setup(ctx, coords, ctx.opt["h"])[2]
    c = _costs(ctx, coords, dict.fromkeys(SIDES, h))
    return xr.Dataset({"rk4_step": h * c["rk4"].best / c["splitting"].best, "calibrated_cost": ("side", [c[s].best for s in SIDES]),
                       "calibration_spread": ("side", [c[s].spread for s in SIDES])}, coords={"side": list(SIDES)})


def long_run(ctx, coords, calibrate) -> xr.Dataset:
    """One run of a pair to t_end, one thread: the splitting at h, RK4 at its calibrated step."""
    m, n = (coords["pair"] if coords["side"] == "splitting" else "rk4"), ctx.opt["samples"]
    sc, per, h = _run_setup(ctx, coords, calibrate, coords["side"])
    with timing.pinned_threads(1):
        ds = _cpu(sc, m, h, per * n, per)[0]
    L, ma, dC = ds["angular_momentum"], ("member", "axis"), abs(ds["casimir_drift"]).max("member")
    curves = {"casimir2_drift": dC.sel(k=2), "casimir4_drift": dC.sel(k=4), "energy_drift": abs(ds["energy_error"]).max(
        "member"), "angular_momentum_drift": abs(L - L.isel(t=0)).max(ma) / abs(L.isel(t=0)).max(ma)}
    return xr.Dataset({k: ("t", v.values) for k, v in curves.items()}, coords={"t": np.arange(n + 1) * (ctx.opt[
        "t_end"] / n)}).assign(h=h, steps=per * n, iterations_per_step=float(ds["fixed_point_iterations"].isel(
            t=slice(1, None)).mean()))


def costs(ctx, coords, calibrate) -> xr.Dataset:
    """After the long runs: the splitting's run and as many steps of RK4's, each at its run's step, timed again."""
    c = _costs(ctx, coords, {s: _run_setup(ctx, coords, calibrate, s)[2] for s in SIDES})
    return xr.Dataset({"cost_per_simulated_second": ("side", [c[s].best for s in SIDES]),
                       "cost_spread": ("side", [c[s].spread for s in SIDES])}, coords={"side": list(SIDES)})


def tables(ds, ctx):
    df = ds[list(RUN)].isel(t=-1, drop=True).to_dataframe().reset_index()
    df["side"] = np.where(df["side"] == "rk4", "rk4", df["pair"])  # the method of the run
    df = df.rename(columns={"side": "method", "kinematic_viscosity": "kinematic viscosity (s-1)",
                            **{k: v[2] for k, v in RUN.items()}})
    return [Table("drift", "Drift after t_end at equal measured cost per simulated second", df.to_dict("records"))]


def verdicts(ds, ctx):
    w = ds["cost_per_simulated_second"].stack(run=("N", "kinematic_viscosity", "pair")).transpose("run", "side")
    bad = "".join(f"; flagged N = {N}, ν = {nu:g}, {p}" for (N, nu, p), v in zip(w["run"].values, w.values)
                  if timing.equal_cost_check(dict(zip(("splitting", "rk4"), v))))
    c_s, c_r = ds["casimir2_drift"].isel(t=-1).where(ds["kinematic_viscosity"] == 0).transpose("side", ...)  # split, rk4
    ratio = float((w.max("side") / w.min("side")).max())
    return [Verdict("each pair ran at equal measured cost", f"largest ratio {ratio:.2f}{bad}",
                    "timed again after the runs: within 15 % (equal_cost_check)", not bad),
            Verdict("at ν = 0 the splitting keeps tr W², RK4 at its cost does not", f"splitting ≤ "
                    f"{float(c_s.max()):.2g}, RK4 ≥ {float(c_r.min()):.2g}", "splitting < 1e-12, RK4 > 100 × it",
                    bool(c_s.max() < 1e-12 and (c_r > 100 * c_s).sum() == c_s.count()) if c_s.count() else None)]


def findings(ds, ctx):
    sp, rk = (ds.isel(t=-1).sel(side=s).where(ds["kinematic_viscosity"] == 0) for s in ("splitting", "rk4"))
    hr = ds["h"].sel(side="rk4")
    steps = "; ".join(f"N = {N}, ν = {nu:g}: " + ", ".join(f"{p} {float(hr.sel(N=N, kinematic_viscosity=nu, pair=p)):.3g} s"
                                                          for p in ds["pair"].values)
                      for N in ds["N"].values for nu in ds["kinematic_viscosity"].values)
    return [f"RK4's step at the cost of each splitting at h = {ctx.opt['h']:g} s (CPU time, one thread): {steps}.",
            f"At ν = 0 the splitting wins the Casimirs (tr W² drift ≤ {float(sp['casimir2_drift'].max()):.1e}, RK4 ≥ "
            f"{float(rk['casimir2_drift'].min()):.1e}); RK4, the baseline, wins the energy (|H + q − H(0)|/H(0) ≤ "
            f"{float(rk['energy_drift'].max()):.1e}, the splitting ≥ {float(sp['energy_drift'].min()):.1e})."]


def draw(ds, ctx, fig):
    cases = [(N, nu) for N in ds["N"].values for nu in ds["kinematic_viscosity"].values]
    fig.set_size_inches(10.5, 0.8 + 2.9 * len(cases))
    axes = fig.subplots(len(cases), 2, squeeze=False, sharex=True)
    for i, (row, (N, nu)) in enumerate(zip(axes, cases)):
        for a, var in zip(row, ("casimir2_drift", "energy_drift")):
            for j, p in enumerate(ds["pair"].values):
                for s, m in zip(("splitting", "rk4"), (p, "rk4")):
                    y = ds[var].sel(N=N, kinematic_viscosity=nu, pair=p, side=s)
                    a.semilogy(ds["t"], y.where(y > 0), color=ctx.color(m), ls=("-", "--", ":", "-.")[j % 4], ms=3,
                               marker=MARKERS[j % len(MARKERS)], label=m if m != "rk4" else f"rk4 at {p}'s cost")
            a.set(title=f"N = {N}, ν = {nu:g} s⁻¹", ylabel=f"{RUN[var][2]} (1)",
                  xlabel="time t (s)" if i == len(cases) - 1 else "")
            a.grid(True, alpha=0.3)
    fig.legend(*axes[0][0].get_legend_handles_labels(), fontsize=8, loc="outside right center")
    return axes.ravel()


STUDY = Study(
    kind="zeitlin_structure", title="Zeitlin fluid: structure over long runs", models=("zeitlin",), tables=tables,
    description="Casimir and energy drift, split family against RK4 at equal measured cost", verdicts=verdicts,
    options=(Option("N", [32, 64], "list[int>=3]", "1", "matrix sizes"), Option("h", 0.02, "number>0", "s", "step"),
             Option("kinematic_viscosity", [0.0, 1e-4], "list[number>=0]", "s-1", "viscosities"),
             Option("t_end", 100.0, "number>0", "s", "run length"), Option("samples", 50, "int>=1", "1", "samples")),
    axes=lambda ctx: {"N": ctx.opt["N"], "kinematic_viscosity": ctx.opt["kinematic_viscosity"],
                      "pair": [m for m in ctx.methods if m != "rk4"], "side": ["splitting", "rk4"]}, check=_check,
    stages=(Stage("calibrate", calibrate, over=("N", "kinematic_viscosity", "pair"), serial=True),
            Stage("long", long_run, over=("N", "kinematic_viscosity", "pair", "side"), needs=("calibrate",)),
            Stage("costs", costs, over=("N", "kinematic_viscosity", "pair"), needs=("calibrate",), serial=True)),
    quantities={"N": ("1", "matrix size N"), "kinematic_viscosity": ("s-1", "kinematic viscosity nu"),
                "pair": ("1", "the splitting RK4 is compared with"), "side": ("1", "run of the pair"),
                "rk4_step": ("s", "RK4's step at the splitting's cost (calibrated)"),
                "calibrated_cost": ("s s-1", "calibration: CPU time per simulated second at h"), "calibration_spread":
                ("1", "its spread"), "cost_spread": ("1", "spread of cost_per_simulated_second's repeats"),
                **{k: v[:2] for k, v in RUN.items()}},
    figures=(Figure("drift", kind="custom", draw=draw, select=lambda ds, ctx: ds, claim="at ν = 0 the splitting "
                    "keeps tr W² to round-off (zeros not drawn), RK4 at its cost does not; RK4 keeps H + q better"),),
    report=("{members} members of `{scene}` per N, t_end = {opt[t_end]:g} s, {opt[samples]} samples, splitting at h = "
            "{opt[h]:g} s; Casimirs over tr((−iW)²)(0)^(k/2). Costs: CPU time per simulated second, one thread, interleaved, "
            "minimum over ≥ 2 repeats and ≥ 1 s, of the splitting's whole run (its fixed-point iterations per step grow "
            "along the run) and of RK4's first as many steps (a fixed cost per step); RK4's step set "
            "from them before the runs, both timed again after them. **Timed:** RK4's step and drifts, the costs."),
    facts=lambda ds, ctx: {"members": ctx.scene()["ensemble"]["members"]}, findings=findings,
)
