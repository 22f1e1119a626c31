"""The long_drift study in its reduced mode: files, finite drift rates, the
equal-cost plan, the structure the variational integrators keep exactly, and
the drift of the VI against RK2 at zero viscosity."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from liethermo import cf

from liethermo.cli import main
from liethermo.methods import METHODS
from liethermo.studies import get_study
from liethermo.studies.common import StudyError, parse_method
from liethermo.studies.long_drift import equal_cost_steps, options, step_cost
from liethermo.studies.runner import load_study, validate_study

STUDIES = Path(__file__).resolve().parents[1] / "studies"


@pytest.fixture(scope="module")
def ld(tmp_path_factory):
    out = tmp_path_factory.mktemp("long_drift")
    study = load_study(STUDIES / "long_drift.toml")
    validate_study(study)
    report = get_study("long_drift").run(study, out, reduced=True, progress=False)
    return out, report, cf.load_dataset(out / "long_drift.nc"), pd.read_csv(out / "long_drift.csv")


def test_files_and_units(ld):
    out, report, ds, df = ld
    for f in ("long_drift_error.png", "long_drift_rate.png", "long_drift.csv", "report.md"):
        assert (out / f).is_file(), f
    for v in ds.data_vars:
        assert "units" in ds[v].attrs and "long_name" in ds[v].attrs, v
    text = report.read_text()
    assert "node values" in text and "Equal cost" in text and "Finding" in text
    assert 0.0 in ds["fluid_viscosity"].values


def test_drift_rates_finite_and_no_failures(ld):
    _, _, ds, df = ld
    assert int((ds["status"] != 0).sum()) == 0
    assert np.all(np.isfinite(ds["drift_rate"].values))
    assert np.all(ds["oscillation_amplitude"].values >= 0)


def test_equal_cost_plan(ld):
    """Every method simulates the same time at the same counted cost per simulated second."""
    _, _, ds, df = ld
    study = load_study(STUDIES / "long_drift.toml")
    opt = options({**study, **study["reduced"], "options": {**study["options"], **study["reduced"]["options"]}})
    specs = [parse_method(m) for m in study["methods"]]
    plan = equal_cost_steps(specs, opt)
    per_second = {lab: step_cost(s, opt) / plan[lab][0] for lab, s in zip(plan, specs)}
    assert max(per_second.values()) == pytest.approx(min(per_second.values()), rel=1e-12)
    assert step_cost(parse_method("rk4"), opt) == METHODS["rk4"].evaluations_per_step
    for lab, (h, steps, every) in plan.items():
        assert steps % every == 0 and abs(steps * h - opt["t_end"]) <= h
        np.testing.assert_allclose(ds["step"].sel(scheme=lab).values, h)


def test_structure_kept_by_the_variational_integrators(ld):
    """|Γ| = 1 and the discrete Kelvin–Noether law (Γ·μ conserved at μ = 0) to round-off."""
    _, _, ds, _ = ld
    for m in ("vi", "vi4", "vi6"):
        assert float(ds["gamma_defect"].sel(scheme=m).max()) < 1e-12, m
        assert float(ds["kelvin_noether_discrete"].sel(scheme=m, fluid_viscosity=0.0).max()) < 1e-13, m
    # with friction the discrete law is checked for the plain VI
    mu = float(ds["fluid_viscosity"].values.max())
    assert mu > 0 and float(ds["kelvin_noether_discrete"].sel(scheme="vi", fluid_viscosity=mu).max()) < 1e-13
    # explicit RK keeps neither |Γ| nor Γ·μ exactly
    assert float(ds["gamma_defect"].sel(scheme="rk2").max()) > 1e-8
    assert float(ds["kelvin_noether_continuous"].sel(scheme="rk2", fluid_viscosity=0.0).max()) > 1e-10


def test_vi_drifts_less_than_rk2_at_equal_cost_without_friction(ld):
    _, _, ds, _ = ld
    vi = np.median(np.abs(ds["drift_rate"].sel(scheme="vi", fluid_viscosity=0.0).values))
    rk2 = np.median(np.abs(ds["drift_rate"].sel(scheme="rk2", fluid_viscosity=0.0).values))
    assert vi < rk2, (vi, rk2)


def test_resume_recomputes_nothing(ld, monkeypatch, capsys):
    out, _, _, _ = ld
    from liethermo.studies import long_drift

    def boom(*a, **k):
        raise AssertionError("a finished point was recomputed")

    monkeypatch.setattr(long_drift, "point", boom)
    assert main(["study", str(STUDIES / "long_drift.toml"), "--reduced", "-o", str(out), "--no-progress"]) == 0
    assert "| 0 | vi |" in capsys.readouterr().out


def test_invalid_long_drift_rejected(tmp_path):
    src = (STUDIES / "long_drift.toml").read_text().replace('cost_base = "vi"', 'cost_base = "vi9"')
    p = tmp_path / "bad.toml"
    p.write_text(src)
    with pytest.raises(StudyError, match="cost_base"):
        validate_study(load_study(p))
