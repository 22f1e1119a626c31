"""The coupling and flat_spin studies in their reduced mode.

Each study runs once (module-scoped fixture, through the study runner's own
loading and validation); the tests check its files and what the physics
guarantees about its numbers:

* flat spin (double-bracket friction on a free body): |μ| is a Casimir the
  variational integrators keep to round-off and explicit RK does not (its
  drift falls with h at the method's order); every member ends on the major
  axis; the heat gained equals the kinetic energy lost (reference); a larger
  λ settles sooner;
* coupling (𝕀(S) = 𝕀₀(1 + α(θ − T₀))²): the reference conserves the coupled
  model's energy; the coupled top, heavier as it heats, settles later than
  the decoupled one and ends at the same temperature; its inertia factor is
  (1 + α(θ − T₀))²; vi, vi4, vi6 reach their orders against the reference and
  their energy error is bounded.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cfcheck import assert_cf_clean
from liethermo import cf
from liethermo.cli import main
from liethermo.methods import METHODS
from liethermo.studies import get_study
from liethermo.studies.common import StudyError, parse_method
from liethermo.studies.runner import load_study, validate_study
from liethermo.studies.tools import direction_angle, rotation_angle, settling_time

STUDIES = Path(__file__).resolve().parents[1] / "studies"
VI = ("vi", "vi4", "vi6")
#: the tests that read a reduced study run: a few seconds with a warm kernel cache, about two
#: minutes for both studies when every model type is compiled afresh
SLOW = pytest.mark.slow


def _run(kind: str, out: Path) -> Path:
    study = load_study(STUDIES / f"{kind}.toml")
    validate_study(study)
    return get_study(kind).run(study, out, reduced=True, progress=False)


@pytest.fixture(scope="module")
def fs(tmp_path_factory):
    out = tmp_path_factory.mktemp("flat_spin")
    report = _run("flat_spin", out)
    return out, report, cf.load_dataset(out / "flat_spin.nc"), pd.read_csv(out / "flat_spin.csv")


@pytest.fixture(scope="module")
def cp(tmp_path_factory):
    out = tmp_path_factory.mktemp("coupling")
    report = _run("coupling", out)
    return out, report, cf.load_dataset(out / "coupling.nc"), pd.read_csv(out / "coupling.csv")


def _ran(d):
    return d["status"].values >= 0


# ----------------------------------------------------------------------------- tools

def test_settling_time_interpolates_log_linearly_and_says_never():
    t = np.arange(5.0)
    r = np.array([[1.0, 1e-1, 1e-2, 1e-3, 1e-4],     # crosses 1e-3 exactly at t = 3
                  [1.0, 1e-1, 1e-2, 1e-4, 1e-5],     # between 2 and 3: log-linear → 2.5
                  [1.0, 0.5, 0.4, 0.3, 0.2],         # never
                  [1e-4, 1e-5, 1e-5, 1e-5, 1e-5]])   # starts settled
    np.testing.assert_allclose(settling_time(t, r, 1e-3)[[0, 1, 3]], [3.0, 2.5, 0.0], rtol=1e-12)
    assert np.isnan(settling_time(t, r, 1e-3)[2])


def test_angles_are_accurate_for_small_rotations():
    a = 1e-9
    Rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    assert rotation_angle(Rz, np.eye(3)) == pytest.approx(a, rel=1e-6)
    assert direction_angle(np.array([1.0, a, 0.0]), np.array([2.0, 0.0, 0.0])) == pytest.approx(a, rel=1e-12)
    assert direction_angle(np.array([1.0, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0])) == pytest.approx(np.pi)


# ----------------------------------------------------------------------------- flat spin

@SLOW
def test_flat_spin_files_units_and_cf(fs):
    out, report, ds, df = fs
    for f in ("report.md", "flat_spin.csv", "flat_spin_casimir.csv", "flat_spin_energy.png",
              "flat_spin_casimir.png", "flat_spin_settling.png"):
        assert (out / f).is_file(), f
    for v in ds.data_vars:
        assert "units" in ds[v].attrs and "long_name" in ds[v].attrs, v
    assert_cf_clean(out / "flat_spin.nc")
    text = report.read_text()
    assert "node values" in text.lower() and "Findings" in text and "Casimir" in text
    assert "|μ|²/(2 I_max)" in text and "s kg⁻¹ m⁻²" in text


@SLOW
def test_flat_spin_every_member_ends_on_the_major_axis(fs):
    """The double-bracket flow takes every generic spin to the major axis: all
    members of every method, at every λ, settled and on the axis."""
    _, _, ds, df = fs
    for lab in ds["scheme"].values:
        d = ds.sel(scheme=lab)
        ran = d["status"].values >= 0
        assert np.all(d["on_major_axis"].values[ran] == 1), lab
        assert np.all(d["status"].values[ran] == 0), lab
        assert np.all(np.isfinite(d["settling_time"].values[ran])), lab
    assert "Every member of every method ends on the major axis" in fs[1].read_text()


@SLOW
def test_flat_spin_casimir_kept_by_the_vi_family_only(fs):
    """|μ| is a Casimir: vi, vi4, vi6 keep it to round-off (≤ 2e-12 over up to
    10⁵ Newton-solved substeps, each solved to a relative 1e-14); explicit RK2
    and RK4 drift off the orbit by more."""
    _, _, ds, _ = fs
    cas = ds["casimir_drift"]
    for m in VI:
        assert float(cas.sel(scheme=m).max()) <= 2e-12, m
    for m in ("rk2", "rk4"):
        assert float(cas.sel(scheme=m).max()) > 1e-12, m
    assert float(cas.sel(scheme="rk2").median()) > float(cas.sel(scheme="rk4").median())


@SLOW
def test_flat_spin_casimir_drift_of_rk_falls_at_its_order(fs):
    out, _, ds, _ = fs
    c = pd.read_csv(out / "flat_spin_casimir.csv")
    for m in ("rk2", "rk4"):
        g = c[c["method"] == m].sort_values("h (s)")
        assert np.all(np.diff(g["median Casimir drift (1)"].values) > 0), m  # larger h, larger drift
        p = g["observed order (median)"].dropna().values
        assert p.size and abs(p[-1] - METHODS[m].order_base) < 0.5, (m, p)
    for m in VI:
        assert c[c["method"] == m]["max Casimir drift (1)"].max() <= 1e-12, m
        assert c[c["method"] == m]["observed order (median)"].isna().all(), m  # round-off: no order fitted


@SLOW
def test_flat_spin_heat_gained_equals_energy_lost(fs):
    """U(S) − U(S₀) = K₀ − K: to ≤ 1e-10 K₀ for the reference; the variational
    integrators' O(h^p) mismatch falls with their order."""
    _, _, ds, _ = fs
    bal = ds["energy_balance_error"]
    ref = ds.sel(scheme="reference")
    ran = _ran(ref)
    assert float(bal.sel(scheme="reference").max()) <= 1e-10
    K0 = ref["initial_kinetic_energy"].values[ran]
    np.testing.assert_allclose(ref["heat_gained"].values[ran], ref["kinetic_energy_lost"].values[ran],
                               rtol=0, atol=1e-10 * K0.max())
    assert np.all(ref["heat_gained"].values[ran] > 0)
    # the kinetic energy ends on its floor |μ₀|²/(2 I_max)
    Kend = K0 - ref["kinetic_energy_lost"].values[ran]
    np.testing.assert_allclose(Kend, ref["kinetic_energy_floor"].values[ran], rtol=1e-6)
    m = [float(bal.sel(scheme=s).max()) for s in VI]
    assert m[0] > m[1] > m[2]


@SLOW
def test_flat_spin_settles_sooner_with_more_friction(fs):
    _, _, ds, df = fs
    lams = sorted(df["λ (s kg⁻¹ m⁻²)"].unique())
    assert len(lams) >= 2
    for m, g in df.groupby("method"):
        med = g.set_index("λ (s kg⁻¹ m⁻²)").loc[lams, "median settling time (s)"].values
        assert np.all(np.diff(med) < 0), m


@SLOW
def test_flat_spin_resume_recomputes_nothing(fs, monkeypatch, capsys):
    out = fs[0]
    from liethermo.studies import flat_spin

    def boom(*a, **k):
        raise AssertionError("a finished point was recomputed")

    monkeypatch.setattr(flat_spin, "point", boom)
    monkeypatch.setattr(flat_spin, "casimir_point", boom)
    assert main(["study", str(STUDIES / "flat_spin.toml"), "--reduced", "-o", str(out), "--no-progress"]) == 0
    assert re.search(r"^10 +vi ", capsys.readouterr().out, re.M)  # the table, printed as plain text


@pytest.mark.parametrize("edit, needle", [
    ('"body.internal_friction" = [5.0, 10.0, 20.0, 40.0]', 'internal friction'),
    ("[options]", "gravity"),
])
def test_flat_spin_invalid_studies_are_rejected(tmp_path, edit, needle):
    src = (STUDIES / "flat_spin.toml").read_text()
    if "internal_friction" in edit:
        src = src.replace(edit, '"body.internal_friction" = [0.0, 10.0]')
    else:
        # gravity with a lever arm (the centre of mass off the pivot) exerts a torque
        src = src.replace("[options]", "[scene.gravity]\ng = 9.81\n\n[scene.body]\ncenter_of_mass = [0.0, 0.0, 0.01]\n\n"
                          "[options]")
    p = tmp_path / "bad.toml"
    p.write_text(src)
    with pytest.raises(StudyError, match=needle):
        validate_study(load_study(p))


# ----------------------------------------------------------------------------- coupling

@SLOW
def test_coupling_files_units_and_cf(cp):
    out, report, ds, df = cp
    for f in ("report.md", "coupling.csv", "coupling_methods.csv", "coupling_order.csv", "coupling_energy.csv",
              "coupling_settling.png", "coupling_traces.png", "coupling_attitude.png", "coupling_energy.png"):
        assert (out / f).is_file(), f
    for v in ds.data_vars:
        assert "units" in ds[v].attrs and "long_name" in ds[v].attrs, v
    assert_cf_clean(out / "coupling.nc")
    text = report.read_text()
    for needle in ("node values", "Findings", "𝕀(S_k)⁻¹μ_k", "settles later", "K⁻¹"):
        assert needle in text, needle
    assert 0.0 in ds["body_thermal_expansion"].values


@SLOW
def test_coupling_reference_conserves_the_coupled_energy(cp):
    _, _, ds, _ = cp
    ref = ds.sel(scheme="reference")
    ran = _ran(ref.isel(body_thermal_expansion=0))
    assert float(ref["max_relative_energy_error"].values[:, ran].max()) <= 1e-10
    assert int((ds["status"] > 0).sum()) == 0


@SLOW
def test_coupled_top_settles_later_and_later_with_alpha(cp):
    """The heated top is heavier (𝕀 grows), so Stokes friction slows it down
    more slowly: the coupled top settles later than the decoupled one, the
    more so the larger α — for every method, in the median over members."""
    _, _, ds, df = cp
    alphas = sorted(float(a) for a in ds["body_thermal_expansion"].values)
    assert alphas[0] == 0.0 and len(alphas) >= 3
    for lab in ds["scheme"].values:
        d = ds["settling_time_change"].sel(scheme=lab)
        ran = _ran(ds.sel(scheme=lab, body_thermal_expansion=0.0))
        med = [float(np.median(d.sel(body_thermal_expansion=a).values[ran])) for a in alphas]
        assert med[0] == 0.0 and np.all(np.diff(med) > 0), (lab, med)
    assert np.all(df.loc[df["α (K⁻¹)"] > 0, "median Δ settling time vs α = 0 (s)"] > 0)


@SLOW
def test_coupled_top_ends_at_the_decoupled_temperature_with_larger_inertia(cp):
    """At rest the heat is the whole mechanical energy above rest, whatever α:
    the reference's final temperature is the same (to 1e-6 K); its inertia
    factor is (1 + α(T − T₀))² with T = θ at rest, > 1 for α > 0 and growing with α."""
    _, _, ds, _ = cp
    ref = ds.sel(scheme="reference")
    ran = _ran(ref.isel(body_thermal_expansion=0))
    T = ref["final_temperature"].values[:, ran]
    np.testing.assert_allclose(T, np.broadcast_to(T[0], T.shape), rtol=0, atol=1e-6)
    a = ref["body_thermal_expansion"].values[:, None]
    f = ref["final_inertia_factor"].values[:, ran]
    np.testing.assert_allclose(f, (1 + a * (T - 300.0)) ** 2, rtol=1e-9)
    assert np.all(f[0] == 1.0) and np.all(np.diff(f, axis=0) > 0)
    # the final attitude of the decoupled run compared with itself
    assert float(np.nanmax(ds["attitude_difference"].sel(body_thermal_expansion=0.0).values)) == 0.0


@SLOW
def test_coupling_vi_family_orders_and_bounded_energy(cp):
    """vi, vi4, vi6 reach their declared orders against the reference on the
    coupled top (finest pair within 0.5); their node-energy error is bounded:
    it ends no higher than its maximum, stops changing once the top is at rest,
    falls with the order, and over the long low-viscosity horizon, where the
    heating goes on, its maximum per unit of heat released is no larger in the
    second half than 1.5 × the first."""
    out, _, ds, _ = cp
    o = pd.read_csv(out / "coupling_order.csv")
    for m in VI:
        g = o[o["method"] == m].sort_values("h (s)", ascending=False)
        p = g["observed order"].dropna().values
        assert p.size and abs(p[-1] - METHODS[m].order_base) < 0.5, (m, p)
    t_end = float(ds["t"].values[-1])
    for m in VI:
        d = ds.sel(scheme=m)
        mx = d["max_relative_energy_error"].values
        assert np.all(d["final_relative_energy_error"].values <= mx)
        assert np.all(np.abs(d["late_energy_drift_rate"].values) * t_end / 2 < 1e-2 * mx)
        assert float(d["gamma_defect"].max()) < 1e-12
    med = [float(ds["max_relative_energy_error"].sel(scheme=m).median()) for m in VI]
    assert med[0] > med[1] > med[2]
    for m in VI:  # per unit of heat released, the error does not grow from the first half to the second
        d = ds.sel(scheme=m)
        first = d["drift_error_first_half"].values / d["drift_heat_half"].values
        second = d["drift_error_second_half"].values / d["drift_heat_end"].values
        assert np.all(second <= 1.5 * first), (m, first, second)


@SLOW
def test_coupling_resume_recomputes_nothing(cp, monkeypatch, capsys):
    out = cp[0]
    from liethermo.studies import coupling

    def boom(*a, **k):
        raise AssertionError("a finished point was recomputed")

    for name in ("point", "order_point", "drift_point"):
        monkeypatch.setattr(coupling, name, boom)
    assert main(["study", str(STUDIES / "coupling.toml"), "--reduced", "-o", str(out), "--no-progress"]) == 0
    assert re.search(r"^0\.001 ", capsys.readouterr().out, re.M)  # the table, printed as plain text


@pytest.mark.parametrize("old, new, needle", [
    ('"body.thermal_expansion" = [0.0, 1e-3, 2e-3]', '"body.thermal_expansion" = [1e-3, 2e-3]', "must include 0"),
    ('motion_method = "vi6"', 'motion_method = "rk4"', "motion_method"),
    ('methods = ["vi", "vi4", "vi6", "reference"]', 'methods = ["vi:node", "vi6", "reference"]', "legendre"),
])
def test_coupling_invalid_studies_are_rejected(tmp_path, old, new, needle):
    src = (STUDIES / "coupling.toml").read_text()
    assert old in src
    p = tmp_path / "bad.toml"
    p.write_text(src.replace(old, new))
    with pytest.raises(StudyError, match=needle):
        validate_study(load_study(p))


def test_method_specs_of_the_study_files_parse():
    for kind in ("coupling", "flat_spin"):
        for m in load_study(STUDIES / f"{kind}.toml")["methods"]:
            parse_method(m)


@pytest.mark.parametrize("which", ["fs", "cp"])
def test_flat_spin_and_coupling_close_with_the_cheapest_method(which, request):
    """The closing table's winner at each level has an error at most that level and
    is the least costly such method; the reference is never a candidate."""
    out, report, _, _ = request.getfixturevalue(which)
    text = report.read_text()
    assert "**Cheapest here**" in text[text.rindex("### Closing"):]
    cl = pd.read_csv(out / "closing.csv")
    assert not cl["cheapest method"].str.startswith("reference").any()
    won = cl[cl["cheapest method"] != "not reached"]
    assert not won.empty and (won["error"] <= won["error ≤"]).all()
    for eps, g in won.groupby("error ≤"):
        assert g["cost (s)"].max() <= 1.1 * g["cost (s)"].min()
