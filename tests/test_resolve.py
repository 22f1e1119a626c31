"""A run resolves its scene once: the runner, its member chunks, the time probe
and preflight read one ResolvedRun."""

from __future__ import annotations

import numpy as np

import liethermo
from liethermo import physics
from liethermo.resolve import _resolve, resolve
from liethermo.scene import load_scene


def test_a_chunked_run_with_preflight_resolves_its_scene_once(tmp_path, monkeypatch):
    calls = []
    real = physics.physics_of_scene

    def counting(scene, members=1):
        calls.append(members)
        return real(scene, members)

    monkeypatch.setattr("liethermo.resolve.physics_of_scene", counting)
    monkeypatch.setattr("liethermo.physics.physics_of_scene", counting)
    _resolve.cache_clear()
    sc = load_scene("paper", {"ensemble.members": 5, "output.member_chunk": 2, "integrator.steps": 20,
                              "output.compare": [], "output.figures": False})
    ds = liethermo.run(sc, output=tmp_path / "p.nc")  # preflight, three chunks, the summary
    assert ds.sizes["member"] == 5 and (ds["status"].values == 0).all()
    assert calls == [1]
    ds.close()


def test_the_resolved_physics_is_the_scenes_for_any_number_of_members():
    sc = load_scene("ellipsoid")
    run = resolve(sc)
    assert resolve(load_scene("ellipsoid")) is run  # the same scene is resolved once per process
    five = run.physics_for(5)
    ref = physics.physics_of_scene(sc, 5)
    for name, v in vars(ref).items():
        if isinstance(v, np.ndarray):
            assert np.array_equal(getattr(five, name), v), name
    assert run.terms == tuple(physics.build_model(ref).terms())
    assert run.simulate_options()["heat_bound"] == run.heat_bound > 0
