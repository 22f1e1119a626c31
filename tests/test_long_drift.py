"""The long_drift study in its reduced mode: files and units, the calibration's
secant, the structure the variational integrators keep exactly, the drift of
the VI against RK2 without dissipation, and the study on the fluid's scene."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from liethermo import cf
from liethermo.studies.common import StudyError
from liethermo.studies.long_drift import STUDY, plan_steps
from liethermo.timing import secant_step
from liethermo.studies.runner import load_study, validate_study

STUDIES = Path(__file__).resolve().parents[1] / "studies"


@pytest.fixture(scope="module")
def ld(tmp_path_factory):
    out = tmp_path_factory.mktemp("long_drift")
    study = load_study(STUDIES / "long_drift.toml")
    validate_study(study)
    report = STUDY.run(study, out, reduced=True, progress=False)
    return out, report, cf.load_dataset(out / "long_drift.nc"), pd.read_csv(out / "long_drift.csv")


def test_files_units_and_the_equal_cost_check(ld):
    out, report, ds, df = ld
    for f in ("long_drift.png", "long_drift.csv", "equal_cost.csv", "report.md"):
        assert (out / f).is_file(), f
    for v in ds.data_vars:
        assert "units" in ds[v].attrs and "long_name" in ds[v].attrs, v
    assert list(ds["dissipation"].values) == [0.01, 0.0] and ds.attrs["model"] == "top"
    text = report.read_text()
    assert "Equal cost, measured" in text and "fluid.viscosity = 0.1" in text and "### Verdicts" in text
    # the verdict on equal cost follows from the long runs' costs in the table
    for mu, g in df.groupby("dissipation (1)"):
        c = g["cost_per_simulated_s (s)"]
        holds = c.max() / c.min() <= 1.15
        assert f"dissipation × {mu:g}: the long runs cost the same per simulated second" in text
        assert (f"max / min {c.max() / c.min():.2f} | no pair > 15 % apart | {'holds' if holds else 'FAILS'}" in text)
        np.testing.assert_allclose(g["steps (1)"] * g["step (s)"], 200.0, rtol=0.02)
        assert (g.loc[g["scheme"] == "vi", "step (s)"] == 0.01).all()
    # the band time series the figure draws are in the netCDF, one per run
    t = ds["band_t"].sel(dissipation=0.0, scheme="vi").values
    assert np.nanmax(t) == pytest.approx(200.0) and ds["relative_energy_error_quantiles"].sizes["sample"] == 2000


def test_structure_kept_by_the_variational_integrators(ld):
    """|Γ| = 1 and the discrete Kelvin–Noether law (Γ·μ conserved without friction) to round-off."""
    _, _, ds, _ = ld
    for m in ("vi", "vi4", "vi6"):
        assert float(ds["defect_gamma_norm"].sel(scheme=m).max()) < 1e-12, m
        assert float(ds["defect_kelvin_noether_discrete"].sel(scheme=m, dissipation=0.0).max()) < 1e-13, m
    # with friction the discrete law is checked for the plain VI
    assert float(ds["defect_kelvin_noether_discrete"].sel(scheme="vi", dissipation=0.01).max()) < 1e-13
    # explicit RK keeps neither |Γ| nor Γ·μ exactly
    assert float(ds["defect_gamma_norm"].sel(scheme="rk2").max()) > 1e-8
    assert float(ds["defect_kelvin_noether_continuous"].sel(scheme="rk2", dissipation=0.0).max()) > 1e-10


def test_vi_drifts_less_than_rk2_at_equal_cost_without_dissipation(ld):
    _, _, ds, _ = ld
    rate = ds["median_abs_drift_rate"].sel(dissipation=0.0)
    assert float(rate.sel(scheme="vi")) < float(rate.sel(scheme="rk2"))


def test_a_drift_is_reported_only_where_it_stands_out_of_the_oscillation(ld):
    """Without dissipation the variational and splitting methods' energy errors oscillate with no trend over T:
    the report says "no measurable drift" and ranks none of them by drift; RK2's error grows steadily: a drift on
    every member, its slope inside its interval's reach of the median.  8 members rank nothing."""
    _, report, ds, _ = ld
    text = report.read_text()
    x = ds.sel(dissipation=0.0)
    for m in ("vi", "vi4", "vi6", "split4", "split6"):
        assert int(x["drifting_members"].sel(scheme=m)) <= 4, m
    assert int(x["drifting_members"].sel(scheme="rk2")) == 8
    r = x.sel(scheme="rk2")
    assert np.all(np.abs(r["drift_rate"]) > r["drift_half_width"]) and np.all(r["drift_rate"] * 200.0 > 2 * r["oscillation_range"])
    line = next(s for s in text.split("At dissipation × ") if s.startswith("0: "))
    assert "no measurable drift over T = 200 s for vi, vi4, vi6, split4, split6" in line and "rk2 drifts on 8 of 8" in line
    assert "drifts least" not in text and "too few for paired intervals" in line
    # the least median max error, named without a ranking: which method it is follows from the steps that
    # the timed calibration gives (rk4 on a quiet machine, not always under load), so read it from the data
    med = {}
    for m in x["scheme"].values:
        v = x["max_relative_energy_error"].sel(scheme=m).values
        med[str(m)] = float(np.median(np.where(np.isfinite(v), np.abs(v), np.inf)))
    assert f"max |relative energy error| {min(med, key=med.get)} (" in line


def test_the_findings_are_the_same_on_a_rerun(ld):
    """The paired bootstraps are seeded: the findings of the same numbers do not change."""
    from liethermo.studies.long_drift import findings

    _, _, ds, _ = ld
    ctx = STUDY.context(load_study(STUDIES / "long_drift.toml"), reduced=True)
    big = ds.copy()  # 16 members: enough for paired intervals, so the bootstrap runs
    m = [v for v in ds.data_vars if "member" in ds[v].dims]
    import xarray as xr
    big = xr.merge([xr.concat([ds[m], ds[m].assign_coords(member=ds["member"] + 8)], "member", data_vars="all"),
                    ds[[v for v in ds.data_vars if v not in m]]])
    a, b = findings(big, ctx), findings(big, ctx)
    assert a == b and "paired 95 % intervals over members" in a[0] and "95 % " in a[0]


def test_secant_step_reaches_equal_cost_on_an_injected_cost_model():
    """A VI-like cost per simulated second (Newton iterations fall as h shrinks) that a
    fixed-point step would overshoot: the secant of the closest bracket gets within 3 %."""
    def f(x):  # log(cost per simulated s / target) at h = e^x
        h = math.exp(x)
        return math.log(1.5e-8 * (2.0 + 0.02 / h) / h / 4e-6)

    tried = [(math.log(0.01), f(math.log(0.01)))]
    for _ in range(6):
        x = secant_step(tried)
        tried.append((x, f(x)))
        if abs(math.exp(tried[-1][1]) - 1) < 0.03:
            break
    assert abs(math.exp(tried[-1][1]) - 1) < 0.03 and len(tried) <= 7, tried


def test_plan_steps_cover_t_end():
    opt = {"t_end": 200.0, "outputs": 1000}
    for h in (0.01, 0.0325, 0.00167):
        hh, steps, every = plan_steps(h, opt)
        assert hh == h and steps % every == 0 and abs(steps * h - opt["t_end"]) <= every * h
        assert opt["outputs"] <= steps // every < 2 * opt["outputs"]


def test_the_same_study_on_the_fluid():
    """long_drift.toml on a fluid scene: its [model.zeitlin] table gives the fluid's methods, size and
    horizon, the other options are the top's; the fluid's model scales its viscosity and checks its laws."""
    from liethermo.studies.common import resolve_study, with_scene

    a = load_study(STUDIES / "long_drift.toml")
    b = with_scene(a, "zeitlin_decay")
    oa, ob = resolve_study(a, False)["options"], resolve_study(b, False)["options"]
    assert {k for k in {**oa, **ob} if oa.get(k) != ob.get(k)} == {"t_end", "outputs", "kn_steps", "calibration_horizon",
                                                                "calibration_repeats"}
    assert ob["t_end"] == 100.0 and ob["dissipation"] == oa["dissipation"]
    assert resolve_study(b, False)["methods"] == ["split", "split4", "split6", "rk4"]
    validate_study(b)
    ctx = STUDY.context(b, reduced=True)
    assert ctx.model.name == "zeitlin" and ctx.axes == {"dissipation": [0.01, 0.0]}
    sc = ctx.scene()
    assert ctx.model.dissipation_overrides(sc, 0.01) == {"fluid.kinematic_viscosity": 1e-5}
    ideal = sc.with_overrides({**ctx.model.dissipation_overrides(sc, 0.0), "integrator.steps": 20,
                               "output.every": 1, "integrator.method": "split"})
    ds, _, laws = ctx.model.run_with_laws(ideal)
    assert laws["casimirs"][0].max() < 1e-12 and laws["angular_momentum"][0].max() < 1e-12


@pytest.mark.parametrize("old, new, needle", [('methods = ["vi"', 'methods = ["vi9"', "methods"),
                                              ("kn_steps = 4000", "kn_steps = 4000\nthreads = 0", "threads"),
                                              ("t_end = 2000.0", "t_end = 0", "t_end"),
                                              ("dissipation = [0.01", "dissipation = [-0.01", "dissipation")])
def test_invalid_long_drift_rejected(tmp_path, old, new, needle):
    text = (STUDIES / "long_drift.toml").read_text()
    assert old in text
    p = tmp_path / "bad.toml"
    p.write_text(text.replace(old, new, 1))
    with pytest.raises(StudyError, match=needle):
        validate_study(load_study(p))


def test_equal_cost_is_timed_on_the_process_clock_after_the_runs(monkeypatch):
    """The check's cost is each whole long run timed by the process's CPU clock (the machine's other load
    does not enter it): with a clock that advances 0.5 s per reading, every run costs 0.5 s, spread 0."""
    import types

    import xarray as xr

    from liethermo.studies import long_drift

    ticks = iter(0.5 * np.arange(10_000))
    monkeypatch.setattr(long_drift, "time", types.SimpleNamespace(process_time=lambda: next(ticks)))
    ctx = STUDY.context(load_study(STUDIES / "long_drift.toml"), reduced=True)
    ctx.opt.update(t_end=1.0, outputs=10, calibration_repeats=2)
    ctx.methods = ["vi", "rk4"]
    cal = xr.Dataset({"step": ("scheme", [0.01, 0.03])}, coords={"scheme": ctx.methods}, attrs={"kernel": ""})
    got = long_drift.costs(ctx, {"point": None, "dissipation": 0.0}, cal)
    for m, h in (("vi", 0.01), ("rk4", 0.03)):
        _, steps, _ = plan_steps(h, ctx.opt)
        assert float(got["cost_per_simulated_s"].sel(scheme=m)) == pytest.approx(0.5 / (steps * h), rel=1e-12)
        assert float(got["cost_spread"].sel(scheme=m)) == 0.0
