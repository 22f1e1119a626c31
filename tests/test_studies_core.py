"""Study runner, shared helpers and the paper / convergence / energy-drift studies.

Each study runs once per session in its reduced mode (module-scoped
fixtures); the tests check its numbers, not only that it ran:

* convergence: VI staggered order within ±0.15 of 2 on every variable (Ω
  compared at t_k + h/2), VI node-start order of Γ within ±0.15 of 1, RK2 ≈ 2,
  RK4 ≈ 4, and the table says which start each row used;
* energy drift: at the paper's h = 0.1 s the VI's energy error stays bounded
  (no member fails, the median stops growing) while RK2's grows by orders of
  magnitude and members blow up;
* paper: the errata table, the figures, and the staggered start closer to
  the reference than the paper's node start;
* resume: a second run recomputes nothing.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import xarray as xr

from liethermo import cf
from liethermo.cli import main
from liethermo.studies import KINDS, common, get_study
from liethermo.studies.runner import load_study

ROOT = Path(__file__).resolve().parents[1]
STUDIES = ROOT / "studies"


def _run(name: str, outdir: Path) -> Path:
    study = load_study(STUDIES / f"{name}.toml")
    return get_study(study["study"]["kind"]).run(study, outdir, reduced=True, progress=False)


@pytest.fixture(scope="module")
def convergence(tmp_path_factory):
    out = tmp_path_factory.mktemp("convergence")
    report = _run("convergence", out)
    return out, report, cf.load_dataset(out / "convergence.nc")


@pytest.fixture(scope="module")
def energy_drift(tmp_path_factory):
    out = tmp_path_factory.mktemp("energy_drift")
    report = _run("energy_drift", out)
    return out, report, cf.load_dataset(out / "energy_drift.nc")


@pytest.fixture(scope="module")
def paper(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper")
    report = _run("paper", out)
    return out, report, cf.load_dataset(out / "paper.nc")


# ----------------------------------------------------------------------------- helpers

def test_registry_lists_every_kind():
    assert KINDS == ("paper", "convergence", "energy_drift", "work_precision", "stability", "viscosity_sweep")
    with pytest.raises(ValueError, match="unknown study kind"):
        get_study("nope")


def test_expand_sweep_is_an_ordered_cartesian_product():
    pts = common.expand_sweep({"fluid.viscosity": [0.1, 0.2], "integrator.h": [0.1, 0.05, 0.025]})
    assert len(pts) == 6
    assert pts[0] == {"fluid.viscosity": 0.1, "integrator.h": 0.1}
    assert pts[1] == {"fluid.viscosity": 0.1, "integrator.h": 0.05}
    assert pts[-1] == {"fluid.viscosity": 0.2, "integrator.h": 0.025}
    assert common.expand_sweep({}) == [{}]


def test_point_key_is_stable_and_distinguishes_points():
    a = common.point_key({"integrator.h": 0.1, "method": "vi"})
    assert a == common.point_key({"method": "vi", "integrator.h": 0.1})
    assert a != common.point_key({"integrator.h": 0.05, "method": "vi"})


def test_cached_point_computes_once_and_writes_atomically(tmp_path):
    calls = []

    def compute():
        calls.append(1)
        return xr.Dataset({"x": ("time", np.arange(3.0))})

    a = common.cached_point(tmp_path, "k1", compute)
    b = common.cached_point(tmp_path, "k1", compute)
    assert len(calls) == 1
    xr.testing.assert_identical(a, b)
    assert [p.name for p in (tmp_path / "points").iterdir()] == ["k1.nc"]


def test_write_table_writes_csv_and_markdown(tmp_path):
    md = common.write_table([{"method": "vi", "order": 1.99123, "err": 1.5e-9}], tmp_path, "t", "Title")
    assert md.startswith("### Title")
    assert "| vi | 1.991 | 1.500e-09 |" in md
    df = pd.read_csv(tmp_path / "t.csv")
    assert list(df.columns) == ["method", "order", "err"] and df["order"][0] == pytest.approx(1.99123)


def test_stack_points_makes_sweep_keys_dimensions():
    pts = common.expand_sweep({"fluid.viscosity": [0.2, 0.1], "integrator.h": [0.1, 0.05]})
    dsets = [xr.Dataset({"s": ((), float(i))}) for i in range(len(pts))]
    ds = common.stack_points(dsets, pts)
    assert ds["s"].dims == ("fluid_viscosity", "integrator_h")
    assert list(ds["fluid_viscosity"].values) == [0.2, 0.1]  # the study file's order
    assert float(ds["s"].sel(fluid_viscosity=0.1, integrator_h=0.05)) == 3.0
    assert ds["integrator_h"].attrs["scene_key"] == "integrator.h"


def test_study_scene_applies_inline_scene_reduced_mode_and_overrides():
    study = {"study": {"kind": "convergence", "base_scene": "paper"},
             "scene": {"integrator": {"steps": 40}, "ensemble": {"members": 8}},
             "reduced": {"scene": {"ensemble": {"members": 2}}}}
    s = common.study_scene(common.resolve_study(study, True), {"integrator.h": 0.05})
    assert (s["integrator"]["steps"], s["ensemble"]["members"], s["integrator"]["h"]) == (40, 2, 0.05)
    assert common.study_scene(common.resolve_study(study, False))["ensemble"]["members"] == 8


# ----------------------------------------------------------------------------- runner errors

@pytest.mark.parametrize("text, needle", [
    ('[study]\nkind = "nope"\n', "unknown study kind"),
    ('[study]\nkind = "convergence"\nbogus = 1\n', "study.bogus"),
    ('methods = ["vi"]\n[study]\nkind = "convergence"\n[sweep]\n"fluid.viscosityy" = [0.1]\n', "fluid.viscosityy"),
    ('methods = ["vi"]\n[study]\nkind = "convergence"\n[sweep]\n"fluid.viscosity" = [-1.0]\n', "must be ≥ 0"),
    ('methods = ["rk3"]\n[study]\nkind = "convergence"\n', "unknown method"),
    ('[study]\nkind = "convergence"\n[extra]\nx = 1\n', "extra"),
    ('[study\n', "not valid TOML"),
])
def test_invalid_study_is_one_line_exit_2_and_no_output(tmp_path, capsys, text, needle):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    out = tmp_path / "out"
    assert main(["study", str(f), "-o", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("liethermo: error: ") and needle in err and err.count("\n") == 1
    assert "Traceback" not in err
    assert not out.exists()


def test_cli_prints_key_table_and_resumes(convergence, capsys, monkeypatch):
    """A second run into the same folder recomputes no sweep point."""
    out, _, _ = convergence
    from liethermo.studies import convergence as conv

    def boom(*a, **k):
        raise AssertionError("a finished sweep point was recomputed")

    monkeypatch.setattr(conv, "_errors", boom)
    monkeypatch.setattr(conv, "_reference", boom)
    before = sorted(p.name for p in (out / "points").iterdir())
    assert main(["study", str(STUDIES / "convergence.toml"), "--reduced", "-o", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "| vi:staggered | staggered |" in printed and "report.md" in printed
    assert sorted(p.name for p in (out / "points").iterdir()) == before


# ----------------------------------------------------------------------------- convergence

def _order(ds, scheme, var):
    return float(ds[f"observed_order_{var}"].sel(scheme=scheme))


def test_convergence_vi_staggered_is_second_order(convergence):
    _, _, ds = convergence
    assert ds.sizes["h"] >= 5
    assert np.allclose(ds["h"].values[:-1] / ds["h"].values[1:], 2.0)
    for var in ("omega", "gamma", "entropy", "total_energy"):
        assert abs(_order(ds, "vi:staggered", var) - 2.0) <= 0.15, var
        assert int(ds[f"levels_fitted_{var}"].sel(scheme="vi:staggered")) >= 5


def test_convergence_vi_node_start_is_first_order(convergence):
    _, _, ds = convergence
    assert abs(_order(ds, "vi", "gamma") - 1.0) <= 0.15
    assert abs(_order(ds, "vi", "entropy") - 1.0) <= 0.15
    assert abs(_order(ds, "vi", "total_energy") - 1.0) <= 0.15


def test_convergence_endpoint_friction_is_not_second_order(convergence):
    """Endpoint friction f = cX (E3) puts the friction half a step off the centre of the
    momentum equation: first order even with the staggered start (declared order 1)."""
    out, _, ds = convergence
    assert _order(ds, "vi:endpoint:staggered", "gamma") < 1.5
    assert _order(ds, "vi:staggered", "gamma") > 1.85
    df = pd.read_csv(out / "orders.csv").set_index("method")
    assert df.loc["vi:endpoint:staggered", "declared order"] == 1


def test_convergence_runge_kutta_orders(convergence):
    _, _, ds = convergence
    for var in ("omega", "gamma", "total_energy"):
        assert abs(_order(ds, "rk2", var) - 2.0) <= 0.15, var
        assert abs(_order(ds, "rk4", var) - 4.0) <= 0.3, var


def test_convergence_table_says_which_start(convergence):
    out, report, _ = convergence
    df = pd.read_csv(out / "orders.csv")
    row = df.set_index("method").loc["vi:staggered"]
    assert row["start"] == "staggered" and row["Omega compared at"] == "t_k + h/2"
    assert df.set_index("method").loc["vi", "start"] == "node"
    text = report.read_text()
    assert "round-off" in text and (out / "convergence.png").is_file()


def test_convergence_fit_stops_at_round_off_floor():
    from liethermo.studies.convergence import fit_order

    hs = 0.1 / 2.0 ** np.arange(8)
    err = np.maximum(3e-3 * hs**4, 1e-15)  # below 1e-12 from the 6th level on
    p, C, used = fit_order(hs, err, scale=1.0, floor_rel=1e-12)
    assert used == 5 and abs(p - 4.0) < 1e-6 and C == pytest.approx(3e-3)


# ----------------------------------------------------------------------------- energy drift

def _band(ds, scheme, h, q=0.5):
    return ds["relative_energy_error_quantiles"].sel(scheme=scheme, integrator_h=h, quantile=q)


def test_energy_drift_vi_bounded_rk2_grows_at_paper_h(energy_drift):
    _, _, ds = energy_drift
    vi = _band(ds, "vi", 0.1)
    rk2 = _band(ds, "rk2", 0.1)
    # VI: no member fails, the median error stops growing after the first seconds
    assert int((ds["status"].sel(scheme="vi", integrator_h=0.1) != 0).sum()) == 0
    assert float(vi.sel(time=30.0)) <= float(vi.sel(time=slice(0.0, 10.0)).max())
    assert float(ds["max_relative_energy_error"].sel(scheme="vi", integrator_h=0.1).median()) < 0.5
    # RK2: the median error grows by more than 10x between t = 2 s and t = 15 s, and members blow up
    assert float(rk2.sel(time=15.0)) > 10 * float(rk2.sel(time=2.0))
    assert float((ds["status"].sel(scheme="rk2", integrator_h=0.1) != 0).mean()) > 0.1
    # RK4 is accurate and never fails at this h
    assert float(_band(ds, "rk4", 0.1, 0.95).max()) < 0.01


def test_energy_drift_table_and_figure(energy_drift):
    out, report, ds = energy_drift
    df = pd.read_csv(out / "energy_drift.csv")
    assert set(df["method"]) == {"vi", "rk2", "rk4"} and set(df["h (s)"]) == set(ds["integrator_h"].values)
    row = df[(df["method"] == "vi") & (df["h (s)"] == 0.1)].iloc[0]
    assert row["diverged or failed"] == 0 and row["5% max|dE|/Emech0"] <= row["median max|dE|/Emech0"] \
        <= row["95% max|dE|/Emech0"]
    assert df[(df["method"] == "rk2") & (df["h (s)"] == 0.1)].iloc[0]["diverged or failed"] > 0.1
    assert (out / "energy_drift_bands.png").is_file()
    assert ds.sizes["member"] == int(load_study(STUDIES / "energy_drift.toml")["reduced"]["scene"]["ensemble"]["members"])
    assert load_study(STUDIES / "energy_drift.toml")["scene"]["ensemble"]["members"] >= 4096
    assert 0.1 in load_study(STUDIES / "energy_drift.toml")["sweep"]["integrator.h"]


# ----------------------------------------------------------------------------- paper

def test_paper_study_figures_and_errata(paper):
    out, report, ds = paper
    for stem in ("center_of_mass", "energies", "total_energy", "entropy"):
        assert (out / f"paper_{stem}.png").is_file()
    df = pd.read_csv(out / "errata.csv").set_index("variant")
    assert set(df["erratum"].dropna()) >= {"E1", "E2", "E3", "E4", "E5"}
    # E4: the staggered start is closer to the reference than the paper's node start
    col = "max_t |Gamma - Gamma_ref|"
    assert df.loc["staggered_start", col] < 0.6 * df.loc["paper", col]  # measured: 0.27 vs 0.54
    # E3 and E5 change the motion visibly
    assert df.loc["endpoint_friction", "|ΔOmega| vs paper"] > 1e-3
    assert df.loc["corrected_inertia", "|ΔOmega| vs paper"] > 1e-2
    assert {"omega", "gamma", "entropy", "total_energy", "energy_error", "status"} <= set(ds.data_vars)
    assert "vi_paper" in ds["variant"].values and "reference_paper" in ds["variant"].values



@pytest.mark.parametrize("which", ["convergence", "energy_drift", "paper"])
def test_study_netcdf_is_cf_clean(which, request):
    """compliance-checker at the declared CF version: no error, no check that
    raises, only the warnings docs/netcdf.md justifies; history names the call."""
    pytest.importorskip("compliance_checker")
    from cfcheck import assert_cf_clean

    out, _, ds = request.getfixturevalue(which)
    assert_cf_clean(out / f"{which}.nc")
    assert ds.attrs["history"].split(": ", 1)[1].startswith(f"liethermo.studies.{which}.run(load_study(")



@pytest.mark.parametrize("which", ["convergence", "energy_drift", "paper"])
def test_study_figures_were_checked_for_legibility(which, request):
    """Every PNG of the study went through the conftest layout check; the study's
    own figures use a layout engine (the paper study draws the run figures,
    which have explicit margins)."""
    from layout import SAVED_FIGURES

    out = request.getfixturevalue(which)[0]
    pngs = sorted(out.glob("*.png"))
    assert pngs
    for png in pngs:
        assert str(png.resolve()) in SAVED_FIGURES, png.name
        if which != "paper":
            assert SAVED_FIGURES[str(png.resolve())] in ("ConstrainedLayoutEngine", "TightLayoutEngine",
                                                         "PlaceHolderLayoutEngine"), png.name

if __name__ == "__main__":  # pragma: no cover
    sys.exit(pytest.main([__file__, "-q"]))
