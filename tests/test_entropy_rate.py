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
    d = ds.isel(fluid_viscosity=0, initial_omega=0).sel(scheme="split")
    assert abs(float(d["entropy_produced"][-1] / d["entropy_produced_exact"][-1]) - 1) < 1e-13


def test_verdicts_follow_from_the_table(entropy_rate):
    out, report, ds = entropy_rate
    text = report.read_text()
    for m in ds["scheme"].values:
        ok = float(ds["entropy_error"].sel(scheme=m).max()) <= 1e-4 and float(ds["rate_error"].sel(scheme=m).max()) <= 1e-4
        row = next(ln for ln in text.splitlines() if ln.startswith(f"| {m} produces the analytic entropy"))
        assert row.endswith("| holds |" if ok else "| FAILS |"), row


def test_a_scene_without_the_exact_solution_is_refused(tmp_path, capsys):
    f = tmp_path / "s.toml"
    f.write_text('methods = ["rk4"]\n[study]\nkind = "entropy_rate"\nbase_scene = "paper"\n')
    assert main(["study", str(f), "-o", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "spherical-decay law" in err and err.count("\n") == 1 and not (tmp_path / "o").exists()
