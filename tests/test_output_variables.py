"""``output.variables``: what a run file holds, and the accessor's derived variables.

A top's file holds the integrated state by default; ``ds.liethermo.derived()``
must give every other variable bit for bit as a run storing every variable
(``output.variables = "all"``) writes it: for a Runge-Kutta method, a variational
integrator (start node) and a splitting, with the attitude on and off, and
with members that fail (NaN from their failure on).
"""

from __future__ import annotations

import numpy as np
import pytest

import liethermo
from liethermo import cf
from liethermo.runner import run_scene
from liethermo.scene import SceneError

BASE = {"ensemble.members": 8, "integrator.steps": 40, "output.every": 10, "output.compare": [],
        "output.figures": False, "ensemble.spin_range": [0.1, 4.0]}
#: rk2 at h = 0.15 s: most members blow up (non_finite), one completes; the vi with at most
#: 7 Newton iterations: some solves fail (newton_not_converged)
CASES = {
    "rk2": {"integrator.method": "rk2", "integrator.h": 0.15},
    "vi_node": {"integrator.method": "vi", "integrator.start": "node", "integrator.h": 0.5,
                "integrator.newton_maxiter": 7},
    "split": {"integrator.method": "split", "integrator.h": 0.2},
}


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    if a.dtype != b.dtype or a.shape != b.shape:
        return False
    if a.dtype.kind == "f":  # NaN in the same places, and every other bit equal
        return np.array_equal(a, b, equal_nan=True) and np.array_equal(np.signbit(a), np.signbit(b))
    return np.array_equal(a, b)


def _runs(tmp_path, case: str, attitude: bool):
    sc = liethermo.load_scene("paper", {**BASE, **CASES[case], "output.attitude": attitude})
    paths = tmp_path / f"{case}_default.nc", tmp_path / f"{case}_all.nc"
    run_scene(sc, paths[0], progress=False, history="test")
    run_scene(sc.with_overrides({"output.variables": "all"}), paths[1], progress=False, history="test")
    with cf.open_dataset(paths[0]) as d, cf.open_dataset(paths[1]) as a:
        return d.load(), a.load()


@pytest.mark.parametrize("attitude", [False, True], ids=["no_attitude", "attitude"])
@pytest.mark.parametrize("case", list(CASES))
def test_derived_equal_stored_bit_for_bit(tmp_path, case, attitude):
    small, full = _runs(tmp_path, case, attitude)
    assert len(small.data_vars) < len(full.data_vars)
    assert ("attitude" in small) == attitude and "kinetic_energy" not in small and "center_of_mass" not in small
    if case == "rk2":
        assert set(small["status"].values.tolist()) == {0, 2}  # completed and blown-up members
    if case == "vi_node":
        assert 1 in small["status"].values  # a Newton solve that failed
    derived = small.liethermo.derived()
    assert sorted(derived.variables) == sorted(full.variables)
    for name in full.variables:
        assert _same(derived[name].values, full[name].values), name
        assert derived[name].dims == full[name].dims, name
    if case != "split":
        assert np.isnan(full["kinetic_energy"].values).any()  # the failed members' NaNs were compared too
    assert _same(small.liethermo["center_of_mass" if attitude else "energy_error"].values,
                 full["center_of_mass" if attitude else "energy_error"].values)


def test_one_ulp_in_the_state_changes_derived_values(tmp_path):
    small, full = _runs(tmp_path, "vi_node", True)
    ok = int(np.flatnonzero(small["status"].values == 0)[0])
    assert _same(small.liethermo.derived()["energy_error"].values, full["energy_error"].values)
    # one ulp of a stored value moves a derived one (an ulp of σ moves T by less than its
    # own ulp, but the energy error, computed without cancellation, moves)
    derived = ("omega", "kinetic_energy", "total_energy", "energy_error", "energy_error_paper",
               "angular_momentum_norm", "vertical_angular_momentum", "temperature", "center_of_mass")
    for name, must_move in (("entropy_change", "energy_error"), ("angular_momentum", "omega"),
                            ("attitude", "center_of_mass"),
                            ("gamma", "vertical_angular_momentum")):
        bumped = small.copy(deep=True)
        v = bumped[name].values
        v[ok, 1] = np.nextafter(v[ok, 1], np.inf)  # one member's value at one time, each component one ulp
        d = bumped.liethermo.derived()
        moved = [n for n in derived if not _same(d[n].values, full[n].values)]
        assert must_move in moved, (name, moved)


def test_derived_of_a_subset_of_members_and_times(tmp_path):
    small, full = _runs(tmp_path, "rk2", True)
    part = small.isel(member=[2, 5, 6], t=[0, 3]).liethermo.derived()
    ref = full.isel(member=[2, 5, 6], t=[0, 3])
    for name in ("energy_error", "center_of_mass", "initial_omega", "temperature"):
        assert _same(part[name].values, ref[name].values), name
    with liethermo.open_runs([tmp_path / "rk2_default.nc"], derived=True, lazy=False) as both:
        assert _same(both["energy_error"].isel(method=0).values, full["energy_error"].values)


def test_unknown_variable_is_refused_naming_it():
    with pytest.raises(SceneError) as exc:
        liethermo.load_scene("paper", {"output.variables": ["kinetic_energy", "kinetc_energy"]})
    msg = str(exc.value)
    assert "'kinetc_energy'" in msg and "output.variables" in msg and "center_of_mass" in msg
    assert "\n" not in msg
    with pytest.raises(SceneError, match="'entropy_field'"):  # the torus's group is not the sphere's
        liethermo.load_scene("zeitlin_ideal", {"output.variables": ["entropy_field"]})
    assert liethermo.load_scene("paper", {"output.variables": "all"})["output"]["variables"] == ("all",)


def test_the_old_switches_are_shorthands():
    top = liethermo.load_scene("paper", {"output.attitude": False, "output.variables": ["center_of_mass"]})
    assert top["output"]["attitude"] is True  # naming the centre of mass integrates R
    top = liethermo.load_scene("paper", {"output.attitude": False, "output.variables": "all"})
    assert top["output"]["attitude"] is False  # "all" stores everything, integrates nothing more
    z = liethermo.load_scene("zeitlin_ideal", {"output.variables": ["vorticity"]})
    assert z["output"]["vorticity"] is True
    assert liethermo.load_scene("zeitlin_ideal", {"output.variables": "all"})["output"]["vorticity"] is True
    assert liethermo.load_scene("zeitlin_ideal", {"output.vorticity": False})["output"]["vorticity"] is False
    z = liethermo.load_scene("zeitlin_ideal", {"output.vorticity": False, "output.variables": ["vorticity"]})
    assert z["output"]["vorticity"] is True
    t = liethermo.load_scene("torus_decay", {"output.vorticity": False, "output.entropy_field": False,
                                             "output.variables": ["entropy_density_real"]})
    assert t["output"]["entropy_field"] is True and t["output"]["vorticity"] is False


def test_estimate_counts_the_stored_variables():
    from liethermo.preflight import estimate

    sc = liethermo.load_scene("paper", {"ensemble.members": 1000, "integrator.steps": 100, "output.every": 100,
                                        "integrator.method": "rk2"})
    small, full = estimate(sc).file_per_member, estimate(sc.with_overrides({"output.variables": "all"})).file_per_member
    # omega, gamma, entropy_change and the attitude at 2 times, the members' run (25 bytes)
    # and the member coordinate (8 bytes)
    assert small == 2 * 8 * (3 + 3 + 1 + 9) + 1 + 8 + 8 + 8 + 8
    assert full > 2 * small
    assert estimate(sc).variables == ("attitude", "entropy_change", "failed_at_step", "gamma", "max_h_omega",
                                      "omega", "status", "steps_done")
