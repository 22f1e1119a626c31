"""The entropy-rate study: entropy produced and its rate against the spherical top's exact solution."""

from __future__ import annotations

from pathlib import Path

import pytest

from liethermo import cf
from liethermo.cli import main
from liethermo.studies import get_study
from liethermo.studies.runner import load_study

STUDIES = Path(__file__).resolve().parents[1] / "studies"


@pytest.fixture(scope="module")
def entropy_rate(tmp_path_factory):
    out = tmp_path_factory.mktemp("entropy_rate")
    report = get_study("entropy_rate").STUDY.run(load_study(STUDIES / "entropy_rate.toml"), out, reduced=True,
                                                progress=False)
    return out, report, cf.load_dataset(out / "entropy_rate.nc")


def test_the_splitting_is_exact_and_the_others_converge(entropy_rate):
    """For a spherical top the splitting's flows are the exact ones: its entropy and
    rate match the analytic ones to round-off at every grid point; RK4's error is
    that of a fourth-order method at h |Ω| ≤ 0.2, RK2's of a second-order one."""
    _, _, ds = entropy_rate
    err = ds["entropy_error"]
    assert float(err.sel(scheme="split").max()) < 1e-13 and float(ds["rate_error"].sel(scheme="split").max()) < 1e-13
    assert 1e-12 < float(err.sel(scheme="rk4").max()) < 1e-7
    assert 1e-6 < float(err.sel(scheme="rk2").max()) < 1e-3
    assert float(ds["entropy_min_increment"].min()) > 0  # the entropy never falls
    # the analytic curves are in the file, and the produced entropy follows them
    d = ds.isel(fluid_viscosity=0, initial_omega=0, thermo_heat_capacity=-1).sel(scheme="split")
    assert abs(float(d["entropy_produced"][-1] / d["entropy_produced_exact"][-1]) - 1) < 1e-13


def test_verdicts_follow_from_the_table(entropy_rate):
    out, report, ds = entropy_rate
    text = report.read_text()
    for m in ds["scheme"].values:
        ok = float(ds["entropy_error"].sel(scheme=m).max()) <= 1e-4 and float(ds["rate_error"].sel(scheme=m).max()) <= 1e-4
        row = next(ln for ln in text.splitlines() if ln.startswith(f"| {m} produces the analytic entropy"))
        assert row.endswith("| holds |" if ok else "| FAILS |"), row


def test_the_grid_raises_the_temperature_and_ignoring_it_fails_the_check(entropy_rate, monkeypatch):
    """At heat_capacity = 1e-3 J/K the temperature rises by tens of kelvin.  A run whose entropy ignored the rise
    (S − S₀ = Q/T₀, T held at T₀) passes the study's check where T hardly moves and fails it there."""
    import numpy as np

    from liethermo.top.studies import entropy_rate as er

    out, report, ds = entropy_rate
    hot = ds["temperature_rise"].sel(scheme="split") >= 10.0
    assert bool(hot.any()) and float(ds["temperature_rise"].max()) > 40.0
    assert float(ds["entropy_error_ignoring_T"].where(hot).max()) > 0.05
    assert "| the grid can tell the temperature's rise" in report.read_text()

    real = er.run_scene

    def ignoring_T(scene, method, **kw):  # the same run, its entropy computed as if T stayed at T0
        d, stats = real(scene, method, **kw)
        T, cv = d["temperature"].values, float(er.physics_of_scene(scene).heat_capacity[0])
        T0 = T[:, :1]
        d["entropy"].values[:] = d["entropy"].values[:, :1] + cv * (T - T0) / T0
        d["temperature"].values[:] = T0
        return d, stats

    monkeypatch.setattr(er, "run_scene", ignoring_T)
    study = load_study(STUDIES / "entropy_rate.toml")
    ctx = er.STUDY.context(study, reduced=True)
    tol = ctx.opt["tolerance"]
    errs = {}
    for pt in ctx.points:
        got = er.run(ctx, {"point": pt, "scheme": "split"})
        errs[pt["thermo.heat_capacity"]] = max(errs.get(pt["thermo.heat_capacity"], 0.0), float(got["entropy_error_t"].max()))
    assert errs[1e3] <= tol < errs[1e-3], errs  # the shipped cold grid alone could not tell
    assert np.isclose(errs[1e-3], float(ds["entropy_error_ignoring_T"].max()), rtol=0.05)


def test_rk2s_verdict_is_the_fixed_tolerances(entropy_rate):
    """rk2 passes 1e-4 where T hardly moves and misses it where T rises 50 K: its verdict fails, and the findings
    say where, at the tolerance every method shares."""
    _, report, ds = entropy_rate
    hot = ds["temperature_rise"].sel(scheme="split") >= 10.0
    e = ds["entropy_error"].sel(scheme="rk2")
    assert float(e.where(~hot).max()) <= 1e-4 < float(e.where(hot).max())
    text = report.read_text()
    assert "| rk2 produces the analytic entropy |" in text and "rk2 passes the 0.0001 tolerance where T hardly moves" in text
    assert "split and split4, tied at round-off" in text


def test_a_scene_without_the_exact_solution_is_refused(tmp_path, capsys):
    f = tmp_path / "s.toml"
    f.write_text('methods = ["rk4"]\n[study]\nkind = "entropy_rate"\nbase_scene = "paper"\n')
    assert main(["study", str(f), "-o", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "spherical-decay law" in err and err.count("\n") == 1 and not (tmp_path / "o").exists()
