"""The coupling and flat_spin studies in their reduced mode.

Each study runs once (module-scoped fixture, through the study runner's own
loading and validation); one test per study checks what the physics
guarantees about its numbers, and that methods are compared with the
reference on the same members:

* flat spin (a friction that keeps |μ| on a free body): the variational
  integrators keep |μ| to round-off and explicit RK does not (its drift falls
  with h at the method's order); every member ends on the major axis; the
  reference turns the kinetic energy lost into heat; a larger λ settles sooner,
  as 1/λ;
* coupling (𝕀(S) = 𝕀₀(1 + α(θ − T₀))²): the reference conserves the coupled
  model's energy; the coupled top settles later than the decoupled one, the
  more so the larger α, and ends at the same temperature with inertia factor
  (1 + α(T − T₀))²; the variational integrators' energy error does not drift.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cfcheck import assert_cf_clean
from liethermo import cf
from liethermo.studies import get_study
from liethermo.studies.common import StudyError
from liethermo.top.studies.tools import method_choice
from liethermo.studies.runner import load_study, validate_study
from liethermo.analysis import direction_angle, rotation_angle, settling_time

STUDIES = Path(__file__).resolve().parents[1] / "studies"
VI = ("vi", "vi4", "vi6")
#: the tests that read a reduced study run: about ten seconds each with a warm kernel cache, a
#: minute or two when every model type is compiled afresh
SLOW = pytest.mark.slow


def _run(kind: str, out: Path):
    study = load_study(STUDIES / f"{kind}.toml")
    validate_study(study)
    report = get_study(kind).STUDY.run(study, out, reduced=True, progress=False)
    return out, report, cf.load_dataset(out / f"{kind}.nc")


@pytest.fixture(scope="module")
def fs(tmp_path_factory):
    return _run("flat_spin", tmp_path_factory.mktemp("flat_spin"))


@pytest.fixture(scope="module")
def cp(tmp_path_factory):
    return _run("coupling", tmp_path_factory.mktemp("coupling"))


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
def test_flat_spin_keeps_mu_ends_on_the_major_axis_and_meets_the_reference_member_by_member(fs):
    out, report, ds = fs
    assert_cf_clean(out / "flat_spin.nc")
    # |μ| is a Casimir: the variational integrators keep it to round-off, explicit RK drifts off the orbit
    # at its order in h
    for m in VI:
        assert float(ds["casimir_drift"].sel(scheme=m).max()) <= 2e-12, m
        assert float(ds["casimir_drift_h"].sel(scheme=m).max()) <= 1e-12, m
    c = pd.read_csv(out / "flat_spin_casimir.csv")
    for m, p in (("rk2", 2), ("rk4", 4)):
        assert float(ds["casimir_drift"].sel(scheme=m).max()) > 1e-12, m
        g = c[c["method"] == m].sort_values("casimir_step (s)")
        assert np.all(np.diff(g["median casimir_drift_h (1)"].values) > 0), m
        assert abs(g["observed order (median)"].dropna().values[-1] - p) < 0.5, m
    assert c[c["method"].isin(VI)]["observed order (median)"].isna().all()  # round-off: no order fitted
    # every member of every method ends on the major axis; the reference turns the energy lost into heat
    ran = ds["status"] >= 0
    assert int((ds["on_major_axis"] == 1).sum()) == int(ran.sum()) and int((ds["status"] > 0).sum()) == 0
    assert float(ds["energy_balance_error"].sel(scheme="reference").max()) <= 1e-10
    bal = [float(ds["energy_balance_error"].sel(scheme=m).max()) for m in VI]
    assert bal[0] > bal[1] > bal[2]
    # methods and reference on the same members: the medians agree where the method does (vi6 to 1e-6 s);
    # a median over all members would be off by seconds
    r = pd.read_csv(out / "flat_spin_reference.csv").set_index(["body_internal_friction (s kg-1 m-2)", "method"])
    same = r["members"].unique()
    assert len(same) == 1 and same[0] == int(ran.sel(scheme="reference").all("body_internal_friction").sum())
    for lam in ds["body_internal_friction"].values:
        t = r["median settling_time (s)"]
        assert abs(t[(lam, "vi6")] - t[(lam, "reference")]) < 1e-6
        assert r.loc[(lam, "vi6"), "max |…| settling_time_minus_reference (s)"] < 1e-6
    # a larger λ settles sooner, as 1/λ
    med = ds["settling_time"].median("member")
    lams = ds["body_internal_friction"].values
    for m in ds["scheme"].values:
        k = np.polyfit(np.log(lams), np.log(med.sel(scheme=m).values), 1)[0]
        assert abs(k + 1) < 0.05, (m, k)
    text = report.read_text()
    assert "| FAILS |" not in text and "No cost is reported" in text and not (out / "closing.csv").exists()
    import re  # an order verdict states its tolerance
    assert re.search(r"≥ \d − 0\.\d+ \(the declared order less the fitting tolerance\)", text)


@pytest.mark.parametrize("edit, needle", [
    ('"body.internal_friction" = [5.0, 10.0, 20.0, 40.0]', "over values > 0"),
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
def test_coupled_top_settles_later_at_the_same_temperature_and_methods_meet_the_reference(cp):
    """The heated top is heavier (𝕀 grows), so the friction slows it down more
    slowly: it settles later than the decoupled top, the more so the larger α,
    member by member; at rest the heat is the whole mechanical energy above
    rest whatever α, so the final temperature is the same and the inertia factor
    is (1 + α(T − T₀))²."""
    out, report, ds = cp
    assert_cf_clean(out / "coupling.nc")
    alphas = [float(a) for a in ds["body_thermal_expansion"].values]
    assert alphas[0] == 0.0 and len(alphas) >= 3 and int((ds["status"] > 0).sum()) == 0
    ref = ds.sel(scheme="reference")
    ran = _ran(ref.isel(body_thermal_expansion=0))
    assert float(ref["max_relative_energy_error"].values[:, ran].max()) <= 1e-10
    for m in ds["scheme"].values:
        d = ds["settling_time_change"].sel(scheme=m).values[:, _ran(ds.sel(scheme=m, body_thermal_expansion=0.0))]
        med = np.median(d, axis=1)
        assert med[0] == 0.0 and np.all(np.diff(med) > 0), (m, med)
    T = ref["final_temperature"].values[:, ran]
    np.testing.assert_allclose(T, np.broadcast_to(T[0], T.shape), rtol=0, atol=1e-6)
    f = ref["final_inertia_factor"].values[:, ran]
    np.testing.assert_allclose(f, (1 + ref["body_thermal_expansion"].values[:, None] * (T - 300.0)) ** 2, rtol=1e-9)
    assert np.all(f[0] == 1.0) and np.all(np.diff(f, axis=0) > 0)
    assert float(np.nanmax(ds["attitude_change"].sel(body_thermal_expansion=0.0).values)) == 0.0
    # the methods table compares every method on the reference's members: vi6's median final temperature is the
    # reference's to 1e-4 K (over all members it would differ by kelvins)
    t = pd.read_csv(out / "coupling_methods.csv").set_index(["body_thermal_expansion (K-1)", "method"])
    assert set(t["members"]) == {int(ran.sum())}
    for a in alphas:
        assert abs(t.loc[(a, "vi6"), "median final_temperature (K)"] - t.loc[(a, "reference"),
                                                                              "median final_temperature (K)"]) < 1e-4
    # the variational integrators' energy error falls with the order and does not grow faster than the heat
    med = [float(ds["max_relative_energy_error"].sel(scheme=m).median()) for m in VI]
    assert med[0] > med[1] > med[2]
    for m in VI:
        d = ds.sel(scheme=m)
        assert float(d["gamma_defect"].max()) < 1e-12
        first = d["drift_error_first_half"].values / d["drift_heat_half"].values
        second = d["drift_error_second_half"].values / d["drift_heat_end"].values
        assert np.all(second <= 1.5 * first), (m, first, second)
    text = report.read_text()
    assert "| vi6 meets the reference member by member" in text and "No cost is reported" in text
    assert not (out / "closing.csv").exists()


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
    for kind in ("coupling", "flat_spin", "coupling_convergence"):
        for m in load_study(STUDIES / f"{kind}.toml")["methods"]:
            method_choice(m)
