"""Reduced-size runs of the work_precision, stability and viscosity_sweep studies.

Each study runs once (module-scoped fixture, via the study runner's own
loading and validation) and the tests check the numbers it produced against
what is known to be true: convergence slopes, where explicit methods blow up,
where the VI's Newton iteration stops converging, and the physics of damping.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from liethermo import cf
from liethermo.studies.common import StudyError
from liethermo.studies.runner import load_study, validate_study

ROOT = Path(__file__).resolve().parents[1]
STUDIES = ROOT / "studies"


def _run(kind: str, outdir: Path, scene: str | None = None) -> Path:
    from liethermo.studies import get_study
    from liethermo.studies.common import with_scene

    study = load_study(STUDIES / f"{kind}.toml")
    study = with_scene(study, scene) if scene else study
    validate_study(study)
    mod = get_study(kind)
    return getattr(mod, "STUDY", mod).run(study, outdir, reduced=True, progress=False)


@pytest.fixture(scope="module")
def wp(tmp_path_factory):
    out = tmp_path_factory.mktemp("work_precision")
    return _run("work_precision", out), out


@pytest.fixture(scope="module")
def wpz(tmp_path_factory):
    out = tmp_path_factory.mktemp("work_precision_zeitlin")
    return _run("work_precision", out, "zeitlin_decay"), out


@pytest.fixture(scope="module")
def stab(tmp_path_factory):
    out = tmp_path_factory.mktemp("stability")
    return _run("stability", out), out


@pytest.fixture(scope="module")
def visc(tmp_path_factory):
    out = tmp_path_factory.mktemp("viscosity_sweep")
    return _run("viscosity_sweep", out), out


# ----------------------------------------------------------------------------- work–precision

def test_work_precision_outputs(wp):
    """The top's methods by default (its own, the reference aside), scipy's baselines, units on every variable,
    and every run's cost the minimum over at least ``repeats`` interleaved rounds, with its spread."""
    report, out = wp
    text = report.read_text()
    assert "serially" in text and "omega, gamma" in text and (out / "work_precision.png").is_file()
    ds = cf.open_dataset(out / "work_precision.nc")
    assert all("units" in ds[v].attrs and "long_name" in ds[v].attrs for v in ds.variables)
    assert list(ds["scheme"].values) == ["vi", "vi4", "vi6", "split", "split4", "split6", "rk2", "rk4"]
    assert list(ds["solver"].values) == ["RK45", "DOP853"] and list(ds["state"].values) == ["omega", "gamma"]
    assert (ds["cost_repeats"] >= 5).all() and (ds["cost_spread"] >= 0).all()
    assert (ds["timed_members"] * (2.0 / ds["h"]) >= 65536).all()
    ttr = pd.read_csv(out / "time_to_error.csv")
    assert list(ttr["method"]) == list(ds["scheme"].values) + ["scipy RK45", "scipy DOP853"]


def test_work_precision_costs_are_pinned_by_copying_its_points(wp, tmp_path):
    """The timed tasks are cached like every other: a new folder given the old one's
    points/ reads them back and writes the same numbers (docs/studies.md, "What a
    rerun reproduces"), where measuring again would not."""
    import shutil

    import xarray as xr

    report, out = wp
    shutil.copytree(out / "points", tmp_path / "points")
    _run("work_precision", tmp_path)
    name = next(out.glob("*.nc")).name
    with xr.open_dataset(out / name) as a, xr.open_dataset(tmp_path / name) as b:
        assert set(a.data_vars) == set(b.data_vars)
        for v in a.data_vars:
            assert np.array_equal(a[v].values, b[v].values, equal_nan=True), v
        assert any("time" in v or "cost" in v for v in a.data_vars)


def test_work_precision_closing_tables_agree(wp):
    """One computation: the cheapest per ε is the cheapest bracketed time to ε, each method named with it ties with
    it (not through a chain), every time is labelled by what it is, and a verdict holds only where no method with
    only a bound could be cheaper."""
    report, out = wp
    ttr, cheap = pd.read_csv(out / "time_to_error.csv").set_index("method"), pd.read_csv(out / "cheapest.csv")
    text = report.read_text()
    for _, row in cheap.iterrows():
        eps = f"{row['error ≤']:.0e}"
        how = ttr[f"({eps})"].str.split(" \\(").str[0]
        assert set(how) <= {"bracketed", "upper bound", "lower bound", "below the round-off floor", "not reached"}
        t = ttr[f"time/member to {eps} (s)"][how == "bracketed"].dropna()
        group, spread = row["cheapest"].split(" = "), ttr[f"spread ({eps})"]
        assert group[0] == t.idxmin() and row["time/member (s)"] == t.min()
        for b in group[1:]:
            assert t[b] / t[group[0]] - 1 <= max(spread[group[0]], spread[b], 0.02) + 1e-12
        bounds = [m for m in ttr.index if how[m] == "upper bound"]
        claim = next(ln for ln in text.splitlines() if ln.startswith("| ") and f"error {eps}" in ln)
        assert claim.endswith("| — |") or not bounds, claim
        assert all(m in row["possibly cheaper, not bracketed"] for m in bounds)
    assert "**bracketed**" in text and "— : not decided" in text


def test_work_precision_slopes(wp):
    """Errors on node values fall with h at the methods' orders; scipy's with its tolerance."""
    _, out = wp
    df = pd.read_csv(out / "work_precision.csv")
    assert (df["failed members"] == 0).all()
    for m, order in {"vi": 2.0, "vi4": 4.0, "vi6": 6.0, "rk2": 2.0, "rk4": 4.0, "split4": 4.0}.items():
        d = df[df["method"] == m]
        e, h = d["error at t_end (max)"].to_numpy(), d["h (s)"].to_numpy()
        assert np.all(np.diff(e) < 0), (m, e)
        assert abs(np.polyfit(np.log(h[-3:]), np.log(e[-3:]), 1)[0] - order) < (0.7 if order == 6 else 0.35), m
    for m in ("scipy RK45", "scipy DOP853"):
        e = df[df["method"] == m]["error at t_end (max)"].to_numpy()
        assert np.all(np.diff(e) < 0) and e[-1] < 1e-8, (m, e)


def test_work_precision_on_the_fluid(wpz):
    """The same study on a fluid scene: its own methods, the vorticity relative to |W(0)| (heat and entropy start at
    zero and have no relative scale), orders 2/4/6/4, and scipy skipped in one line."""
    report, out = wpz
    ds = cf.open_dataset(out / "work_precision_zeitlin_decay.nc")
    assert list(ds["scheme"].values) == ["split", "split4", "split6", "rk4"] and "solver" not in ds.dims
    assert list(ds["state"].values) == ["vorticity"] and ds.attrs["model"] == "zeitlin"
    assert "solve_ivp is skipped" in report.read_text()
    e = ds["error"].values
    orders = np.log2(e[:, -2] / e[:, -1])
    assert np.all(np.abs(orders - [2, 4, 6, 4]) < [0.3, 0.3, 0.7, 0.3]), orders


def test_work_precision_times_in_this_process():
    """The stages that time run serially (never on Dask workers); the error runs may be distributed."""
    from liethermo.studies.work_precision import STUDY

    assert {s.name: s.serial for s in STUDY.stages} == {"reference": False, "errors": False, "costs": True,
                                                       "extend": True, "scipy": True}


def test_work_precision_costs_are_the_kernels_cpu_time(monkeypatch):
    """A timed run's cost is the CPU time the model's stats give for its kernels (not their wall time), and the
    process's CPU time over the whole run where the stats give none; the top model's is positive and within the
    whole run's CPU time."""
    import time
    from types import SimpleNamespace

    from liethermo.scene import load_scene
    from liethermo.studies import work_precision as wp
    from liethermo.top.model import ChunkStats

    ctx = SimpleNamespace(scene=lambda point=None: load_scene("paper"), opt={"t_end": 0.5, "threads": 1})
    t = time.process_time()
    got = wp._cpu(ctx, None, "rk4", 0.01, 64)
    whole = time.process_time() - t
    assert 0 < got <= whole
    stats = wp._run(ctx, None, "rk4", 0.01, 64)[1]
    assert stats.kernel_cpu_time > 0 and stats.kernel_time > 0

    fake = {"stats": SimpleNamespace(kernel_time=5.0, kernel_cpu_time=0.125)}
    monkeypatch.setattr(wp, "_run", lambda *a: (None, fake["stats"]))
    assert wp._cpu(ctx, None, "rk4", 0.01, 64) == 0.125  # the CPU time, not the 5 s of wall time
    fake["stats"] = SimpleNamespace(kernel_time=5.0)  # a model whose stats give no CPU time
    assert 0 <= wp._cpu(ctx, None, "rk4", 0.01, 64) < 1.0
    # a chunk record written before the field loads with none measured, and chunks add up
    old = {k: v for k, v in ChunkStats(kernel_cpu_time=1.0).to_dict().items() if k != "kernel_cpu_time"}
    assert ChunkStats.from_dict(old).kernel_cpu_time == 0.0
    assert ChunkStats(kernel_cpu_time=1.0).merge(ChunkStats(kernel_cpu_time=0.5)).kernel_cpu_time == 1.5


def test_time_to_error_interpolation():
    from liethermo.studies.work_precision import time_to_error

    errs, times = [1e-2, 1e-4, 1e-6], [1.0, 10.0, 100.0]
    t, how, used, est = time_to_error(errs, times, 1e-3)
    assert how == "bracketed" and used == (0, 1) and t == pytest.approx(math.sqrt(10.0), rel=1e-12) and math.isnan(est)
    # the coarsest level already below: its cost is an upper bound, the line through the two coarsest an estimate
    t, how, used, est = time_to_error(errs, times, 1e-1)
    assert (t, how, used) == (1.0, "upper bound", (0,)) and est == pytest.approx(10 ** -0.5, rel=1e-12)
    # still falling at the finest level: a lower bound, and the line carried on
    t, how, used, est = time_to_error(errs, times, 1e-9)
    assert (t, how, used) == (100.0, "lower bound", (2,)) and est == pytest.approx(10 ** 3.5, rel=1e-12)
    # stopped gaining: below the round-off floor, no time
    t, how, used, est = time_to_error([1e-2, 1e-14, 0.8e-14], times, 1e-15)
    assert math.isnan(t) and how == "below the round-off floor" and used == ()
    assert time_to_error([np.inf, np.nan], [1.0, 2.0], 1e-3)[1] == "not reached"
    # a failed (inf or NaN) coarse level does not stop the interpolation
    assert time_to_error([np.inf, 1e-4], [1.0, 2.0], 1e-3)[:3] == (2.0, "bracketed", (1,))
    assert time_to_error([np.nan, 1e-4], [1.0, 2.0], 1e-3)[:3] == (2.0, "bracketed", (1,))


def test_a_verdict_rests_on_bracketed_times_only(monkeypatch):
    """rk4's 0.556 µs is bracketed at 1e-3, split6's 1.38 µs only an upper bound (its h^6 line: ~0.46 µs): no
    verdict.  At 1e-9 split6 alone brackets, rk4's finest level is still above at a lower cost: no verdict.  A
    method whose lower bound is dearer than the leader does not hold it up; a loaded machine does."""
    import xarray as xr

    from liethermo.studies import work_precision as wp
    from liethermo.timing import Cost

    class Ctx:
        opt, methods = {"epsilons": [1e-3, 1e-9]}, ["rk4", "split6"]

    h = np.array([0.1, 0.05])
    err = {"rk4": [2e-3, 1.25e-4], "split6": [6.7e-5, 1e-12]}
    cost = {"rk4": [0.3e-6, 0.6e-6], "split6": [1.38e-6, 2.76e-6]}
    spread = {"rk4": [0.02, 0.02], "split6": [0.03, 0.03]}

    def ds(err, cost, spread):
        return xr.Dataset({k: (("scheme", "h"), [v[m] for m in Ctx.methods]) for k, v in
                           (("error", err), ("cost", cost), ("cost_spread", spread))} | {
            "cost_repeats": (("scheme", "h"), np.full((2, 2), 5)), "failed": (("scheme", "h"), np.zeros((2, 2)))},
            coords={"scheme": Ctx.methods, "h": h})

    v = wp.verdicts(ds(err, cost, spread), Ctx)
    assert [x.holds for x in v] == [None, None]
    assert "split6 (≤ 1.38 µs, its h^p line:" in v[0].measured and "rk4" in v[1].measured
    # split6 bracketed at 1e-3 too, above rk4: rk4's verdict holds
    err2 = {"rk4": err["rk4"], "split6": [2e-3, 1e-12]}
    v = wp.verdicts(ds(err2, cost, spread), Ctx)
    assert v[0].claim == "rk4 is the cheapest to error 1e-03" and v[0].holds is True
    # the same numbers timed on a loaded machine: rk4's spread 300 % ties split6 and names the load; not decided
    v = wp.verdicts(ds(err2, cost, {"rk4": [3.0, 3.0], "split6": [0.03, 0.03]}), Ctx)
    assert v[0].holds is None and "loaded machine" in v[0].measured
    assert wp.timing.loaded({"a": Cost.of([1.0, 3.0, 3.0])}) == ["a"]


def test_work_precision_rejects_bad_options():
    from liethermo.studies.work_precision import STUDY

    study = load_study(STUDIES / "work_precision.toml")
    for opts, msg in (({"h": [0.3]}, "options.h"), ({"scipy_methods": ["LSODA"]}, "options.scipy_methods"),
                      ({"scipy_members": 99}, "options.scipy_members")):
        with pytest.raises(StudyError, match=msg):
            STUDY.validate({**study, "options": {**study["options"], **opts}})
    with pytest.raises(StudyError, match="methods"):
        STUDY.validate({**study, "methods": ["rk4", "reference"]})


# ----------------------------------------------------------------------------- stability

SMALL_STABILITY = {"methods": ["vi", "rk4"], "study": {"kind": "stability", "name": "small", "base_scene": "paper"},
                   "options": {"h": 0.1, "steps": 10, "h_omega": [0.05, 10.0], "kappa": [0.001, 5.0],
                               "map_scene": {"gravity": {"g": 0.0}}}}


@pytest.fixture(scope="module")
def stab_small(tmp_path_factory):
    from liethermo.top.studies.stability import STUDY

    out = tmp_path_factory.mktemp("stability_small")
    return STUDY.run(SMALL_STABILITY, out, reduced=False, progress=False), out


def test_stability_small_map(stab_small):
    """Two methods on a 2×2 map: the VI stays bounded in every cell, RK4 does not beyond its real-axis
    stability limit (κ = 5 > 2.79) nor at h|Ω₀| = 10; both are accurate at the smallest step angle and
    friction; the Newton push fails only far beyond the map, with a well-conditioned Jacobian."""
    report, out = stab_small
    ds = cf.open_dataset(out / "small.nc")
    reg = ds["regime"]
    assert (reg.sel(scheme="vi").values <= 1).all() and (ds["status"].sel(scheme="vi").values == 0).all()
    assert (reg.sel(scheme="rk4", kappa=5.0).values >= 2).all() and (reg.sel(scheme="rk4", h_omega=10.0).values >= 2).all()
    assert int(reg.sel(scheme="vi", h_omega=0.05, kappa=0.001)) == 0 == int(reg.sel(scheme="rk4", h_omega=0.05,
                                                                                       kappa=0.001))
    over = ds["status"].values == 2
    assert over.any() and np.isinf(ds["error_max"].values[over]).all()  # an overflow is inf: hatched, not coloured
    ok = ds["limit_status"].values == 0
    assert ok[0] and not ok.all() and ds["limit_h_omega"].values[~ok].min() > ds["limit_h_omega"].values[ok].max()
    assert np.nanmax(ds["limit_jacobian_cond_max"].values[ok]) < 3.2
    text = report.read_text()
    assert "| vi stays bounded on the map | 0 cells unbounded or failed | 0 | holds |" in text
    assert "| rk4 stays bounded on the map |" in text and "FAILS" in text
    assert not (out / "named_cases.csv").exists()  # no cases: no table, no failure
    assert {p.name for p in out.glob("*.png")} == {"regimes.png", "errors.png"}


@pytest.mark.slow
def test_stability_map(stab):
    report, out = stab
    ds = cf.open_dataset(out / "stability.nc")
    for v in ds.data_vars:
        assert "units" in ds[v].attrs and "long_name" in ds[v].attrs, v
    reg = ds["regime"]
    hw = ds["h_omega"].values
    ka = ds["kappa"].values
    big = hw.max()
    assert big >= 10
    # the plain VI stays bounded everywhere (both friction variants); Newton never fails on the map
    for m in ("vi", "vi:endpoint"):
        r = reg.sel({"scheme": m}).values
        assert np.all(r <= 1), (m, r)
        assert np.all(ds["status"].sel({"scheme": m}).values == 0)
        # and it is accurate at small step angles and small friction per step
        assert reg.sel({"scheme": m, "h_omega": hw.min(), "kappa": ka.min()}).item() == 0
    # RK2 and RK4 blow up (unbounded or non-finite) at the largest h|Ω| for every κ
    for m in ("rk2", "rk4"):
        assert np.all(reg.sel({"scheme": m, "h_omega": big}).values >= 2), m
        # and are non-finite beyond their real-axis stability limit (κ = 2, 2.79)
        assert np.all(ds["status"].sel({"scheme": m, "kappa": 5.0}).values == 2), m
    assert reg.sel({"scheme": "rk4", "h_omega": hw.min(), "kappa": 0.1}).item() == 0
    assert (out / "regimes.png").is_file() and (out / "errors.png").is_file()
    summ = pd.read_csv(out / "stability_summary.csv")
    assert summ[["accurate", "bounded", "unbounded", "newton_not_converged", "non_finite"]].sum(axis=1).eq(
        hw.size * ka.size).all()


@pytest.mark.slow
def test_stability_negative_substeps(stab):
    """vi4/vi6 (and vi4 with the triple jump): a substep of factor f < 0 makes the
    friction factor 1 + fκ/2 vanish at κ = −2/f; inside the growth band the composed
    step loses the small-step accuracy it has at small κ."""
    from liethermo.top.methods import METHODS, friction_amplification, negative_substep_limits

    _, out = stab
    ds = cf.open_dataset(out / "stability.nc")
    hw0 = ds["h_omega"].values.min()
    summ = pd.read_csv(out / "stability_summary.csv").set_index("method")
    for m in ("vi4", "vi6", "vi4:triple_jump"):
        name, comp = (m.split(":") + ["small_error"])[:2]
        lim = negative_substep_limits(name, "trapezoid", comp)
        assert lim["min_factor"] == pytest.approx(min(METHODS[name].substeps(comp)))
        lo, hi = lim["growth_band"]
        assert lo < -2.0 / lim["min_factor"] < hi
        assert summ.loc[m, "κ band where a friction mode grows"] == f"{lo:.3f} – {hi:.3f}"
        assert summ.loc[m, "unbounded or failed cells outside that band"] == 0
        assert abs(friction_amplification(name, np.array([0.5 * (lo + hi)]), "trapezoid", comp)[0]) > 1
        assert np.all(np.abs(friction_amplification(name, np.array([0.5 * lo, 3 * hi]), "trapezoid", comp)) <= 1)
        assert reg_at(ds, m, hw0, ds["kappa"].values.min()) == 0
        in_band = [k for k in ds["kappa"].values if lo <= k <= hi]
        assert in_band, "the reduced map must sample the growth band"
        for k in in_band:
            assert reg_at(ds, m, hw0, k) >= 1, (m, k)
    assert negative_substep_limits("vi")["growth_band"] is None


def reg_at(ds, m, hw, k):
    return int(ds["regime"].sel({"scheme": m, "h_omega": hw, "kappa": k}).item())


@pytest.mark.slow
def test_stability_named_cases(stab):
    _, out = stab
    df = pd.read_csv(out / "named_cases.csv")
    assert set(df["case"]) >= {"dzhanibekov", "sleeping_top", "near_flat", "high_viscosity", "cayley_10"}
    vi = df[df["scheme"].str.startswith("vi")]
    assert (vi["status"] == 0).all()
    assert (vi["gamma_defect"] < 1e-13).all()  # unit |Γ| to round-off, in every hard case
    hv = df[df["case"] == "high_viscosity"].set_index("scheme")
    assert hv.loc["rk2", "status"] == 2 and hv.loc["rk4", "status"] == 2
    # κ ≈ 4.7: the VI stays bounded, but on node values its trapezoid friction turns a decaying mode
    # by r(κ) = (1 − κ/2)/(1 + κ/2) ≈ −0.4 per step instead of e^(−κ): bounded, not accurate
    assert hv.loc["vi", "energy_growth"] <= 1.0 + 1e-9
    k = hv.loc["vi", "kappa"]
    assert 0.1 < hv.loc["vi", "error_max"] <= abs((1 - k / 2) / (1 + k / 2)) + 0.1
    c10 = df[df["case"] == "cayley_10"].set_index("scheme")
    assert c10.loc["rk2", "status"] == 2
    assert c10.loc["vi", "energy_growth"] <= 1.0 + 1e-9  # bounded, but the phase is lost
    assert c10.loc["vi", "error_max"] > 0.5
    assert ((df["status"] != 0) == (df["failed_at_step"] >= 0)).all()


@pytest.mark.slow
def test_stability_newton_limit(stab):
    """Newton fails only from a predictor far from the root, not from conditioning."""
    _, out = stab
    lim = pd.read_csv(out / "newton_limit.csv")
    ok = lim[lim["status"] == 0]
    bad = lim[lim["status"] != 0]
    assert ok["h_omega"].max() >= 1e3
    assert len(bad) >= 1 and bad["h_omega"].min() > ok["h_omega"].max()
    assert (bad["status"] == 1).all()  # newton_not_converged
    assert ok["jacobian_cond_max"].max() < 3.2
    # iterations grow only logarithmically in h|Ω|
    big = ok[ok["h_omega"] >= 10]
    slope = np.polyfit(np.log10(big["h_omega"]), big["newton_max"], 1)[0]
    assert 0.5 < slope < 7.0


# ----------------------------------------------------------------------------- viscosity sweep

def test_viscosity_sweep_physics(visc):
    report, out = visc
    ds = cf.open_dataset(out / "viscosity_sweep.nc")
    for v in ds.data_vars:
        assert "units" in ds[v].attrs and "long_name" in ds[v].attrs, v
    mu = ds["fluid_viscosity"].values
    assert list(mu) == sorted(mu) and mu.min() <= 0.01 and mu.max() >= 10
    assert int((ds["status"] != 0).sum()) == 0
    ts = ds["settling_time"].values
    assert np.all(np.isfinite(ts)), "no member may be censored at reduced size"
    med = np.median(ts, axis=1)
    np.testing.assert_array_equal(ds["settling_time_quartiles"].sel(quantile=0.5).values, med)
    under = mu <= 1.0
    assert float(ds["mu_crit"]) == pytest.approx(2.17, rel=0.01) and mu[under].max() < float(ds["mu_crit"]) / 2
    # under-damped: settling time falls like 1/μ (μ × t_settle constant to ±20 %)
    assert np.all(np.diff(med[under]) < 0)
    prod = mu[under] * med[under]
    assert prod.max() / prod.min() < 1.2
    # over-damped gravity mode (μ above μ_crit ≈ 2): settling time grows again
    assert med[mu == mu.max()][0] > med[mu == 1.0][0]
    # the entropy produced by settling is set by the initial data, not by μ
    S = ds["entropy_produced"].mean("member").values
    assert S.max() / S.min() - 1 < 0.02
    assert np.all(np.abs(ds["heat_ratio"].values[under] - 1) < 5e-3)
    # ...but it is produced faster with more viscosity (initial rate P/T ∝ μ exactly, P the model's
    # dissipated power; by t = 1 s more is produced at larger μ while under-damped)
    rate = ds["entropy_rate_initial"].values
    np.testing.assert_allclose(rate / mu[:, None], np.broadcast_to(rate[0] / mu[0], rate.shape), rtol=1e-12)
    s1 = ds["entropy_by_time_mean"].sel(entropy_time=1.0).values
    np.testing.assert_allclose(s1, ds["entropy_by_time"].sel(entropy_time=1.0).mean("member").values, rtol=1e-14)
    assert np.all(np.diff(s1[under]) > 0)
    assert (out / "settling_time.png").is_file() and (out / "viscosity_sweep.csv").is_file()
    assert report.read_text().count("| holds |") == 4


def test_resume_does_not_recompute(visc, monkeypatch):
    """A second run loads every sweep point from the cache."""
    from liethermo.top.studies import viscosity_sweep

    _, out = visc

    def boom(*a, **k):
        raise AssertionError("a finished sweep point was recomputed")

    monkeypatch.setattr(viscosity_sweep, "run_members", boom)
    study = load_study(STUDIES / "viscosity_sweep.toml")
    viscosity_sweep.STUDY.run(study, out, reduced=True, progress=False)


def test_invalid_options_rejected(tmp_path):
    src = (STUDIES / "stability.toml").read_text().replace("growth_limit = 2.0", "growth_limit = 2.0\nbogus = 1")
    p = tmp_path / "bad.toml"
    p.write_text(src)
    with pytest.raises(StudyError, match="options.bogus"):
        validate_study(load_study(p))
    src = (STUDIES / "viscosity_sweep.toml").read_text().replace("[0.01, 0.1, 1.0, 10.0]", "[0.0, 0.1]")
    p.write_text(src)
    with pytest.raises(StudyError, match="viscosit"):
        validate_study(load_study(p))


@pytest.mark.parametrize("which", ["wp", "stab_small", "visc"])
def test_study_netcdf_is_cf_clean(which, request):
    """compliance-checker at the declared CF version: no error, no check that
    raises, only the warnings docs/netcdf.md justifies."""
    pytest.importorskip("compliance_checker")
    from cfcheck import assert_cf_clean

    _, out = request.getfixturevalue(which)
    (nc,) = out.glob("*.nc")
    assert not assert_cf_clean(nc).warnings


@pytest.mark.parametrize("which", ["wp", "stab_small", "visc"])
def test_study_figures_were_checked_for_legibility(which, request):
    """Every PNG of the study went through the conftest layout check, with a layout engine."""
    from layout import SAVED_FIGURES

    _, out = request.getfixturevalue(which)
    pngs = sorted(out.glob("*.png"))
    assert pngs
    for png in pngs:
        assert SAVED_FIGURES.get(str(png.resolve())) in ("ConstrainedLayoutEngine", "TightLayoutEngine",
                                                         "PlaceHolderLayoutEngine"), png.name
