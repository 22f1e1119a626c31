"""Scene values from numpy (a sweep over ``np.arange``, values read from a
dataset) are accepted where the Python value is, and stored as plain TOML."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import liethermo
from liethermo.scene import SceneError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def test_numpy_integers_floats_and_booleans_are_accepted_and_stored_plain():
    sc = liethermo.load_scene("paper", {"integrator.steps": np.int64(10), "integrator.h": np.float32(0.05),
                                        "ensemble.members": np.int32(3), "body.radius": np.int64(1),
                                        "output.attitude": np.bool_(True),
                                        "initial.omega": np.array([0.0, 1.0, 1.0])})
    assert sc.integrator.steps == 10 and type(sc.integrator.steps) is int
    assert type(sc.integrator.h) is float and sc.integrator.h == pytest.approx(0.05)
    assert sc.body.radius == 1.0 and type(sc.body.radius) is float
    assert sc.output.attitude is True
    text = sc.to_toml()
    assert "steps = 10\n" in text and "attitude = true\n" in text and "np." not in text
    assert tomllib.loads(text)["integrator"]["steps"] == 10


def test_a_sweep_over_np_arange_runs_through_the_api():
    for steps in np.arange(2, 5):
        ds = liethermo.run("spherical_top", {"integrator.steps": steps}, compare=False)
        assert ds.sizes["t"] == steps + 1


def test_numpy_values_in_a_zeitlin_scene():
    sc = liethermo.load_scene("zeitlin_decay", {"zeitlin.N": np.int64(16), "integrator.h": np.float64(0.02),
                                                "output.vorticity": np.bool_(False)})
    assert sc["zeitlin"]["N"] == 16 and type(sc["zeitlin"]["N"]) is int
    assert "N = 16\n" in sc.to_toml() and "vorticity = false\n" in sc.to_toml()


@pytest.mark.parametrize("key, value, rule", [
    ("integrator.steps", 10.0, "must be an integer"),
    ("integrator.steps", np.float64(10.0), "must be an integer"),
    ("integrator.steps", np.bool_(True), "must be an integer"),
    ("integrator.h", np.bool_(True), "must be a number"),
    ("integrator.h", np.complex128(1.0), "must be a number"),
    ("output.attitude", np.int64(1), "must be true or false"),
    ("initial.omega", np.array([True, False, True]), "must be an array of numbers"),
])
def test_what_numpy_does_not_make_right_stays_refused(key, value, rule):
    with pytest.raises(SceneError, match=rule):
        liethermo.load_scene("paper", {key: value})


def test_api_md_lists_every_built_in_scene():
    from pathlib import Path

    from liethermo.scene import builtin_scenes

    api = (Path(__file__).resolve().parents[1] / "docs" / "api.md").read_text(encoding="utf-8")
    para = api[api.index("The built-in scenes are"):].split("\n\n")[0]
    for name in builtin_scenes():
        assert f"`{name}`" in para, name


def test_the_initial_degree_follows_a_smaller_n_unless_a_scene_sets_it():
    sc = liethermo.load_scene("zeitlin_ideal", {"zeitlin.N": 6})  # only N changed
    assert (sc["initial"]["lmax"], sc["initial"]["m"]) == (5, 4)
    assert (liethermo.load_scene("zeitlin_ideal")["initial"]["lmax"], liethermo.load_scene("zeitlin_ideal")["initial"]["m"]) == (6, 4)
    sc = liethermo.load_scene({"zeitlin": {"N": 4}, "initial": {"kind": "rossby_haurwitz"}})
    assert (sc["initial"]["lmax"], sc["initial"]["m"]) == (3, 3)
    assert liethermo.load_scene({"zeitlin": {"N": 64}})["initial"]["lmax"] == 6  # a larger N: the default
    # a scene (or an override) that sets the degree keeps it, and the refusal says what to do
    with pytest.raises(SceneError, match=r"'initial.lmax': must be at most zeitlin.N − 1 = 5 .*set initial.lmax ≤ 5 "
                                         r"too \(it follows zeitlin.N only where neither the scene nor an override"):
        liethermo.load_scene("zeitlin_decay", {"zeitlin.N": 6})
    with pytest.raises(SceneError, match=r"'initial.m': must be at most initial.lmax = 2 .*set initial.m ≤ 2 too"):
        liethermo.load_scene("zeitlin_ideal", {"initial.lmax": 2, "initial.m": 4})
    assert liethermo.load_scene("zeitlin_ideal", {"initial.lmax": 2})["initial"]["m"] == 2
    assert liethermo.load_scene("zeitlin_decay", {"zeitlin.N": 6, "initial.lmax": 5})["initial"]["lmax"] == 5


def test_every_rossby_haurwitz_member_starts_with_the_energy_the_scene_gives():
    """initial.energy is H(0) of every member, the noise included, at every N."""
    for N, energy in ((16, 1.0), (32, 2.5)):
        ds = liethermo.run("zeitlin_ideal", {"zeitlin.N": N, "ensemble.members": 16, "integrator.steps": 2,
                                             "output.every": 1, "initial.energy": energy, "initial.noise": 0.05,
                                             "output.compare": [], "output.figures": False}, compare=False)
        H0 = ds["energy"].isel(t=0).values
        assert np.abs(H0 / energy - 1).max() < 1e-13, H0
