"""A run resolves its scene once: the runner, its member chunks, the time probe
and preflight read one ResolvedRun."""

from __future__ import annotations

import numpy as np

import liethermo
from liethermo.top import physics
from liethermo.top.resolve import _resolve, resolve
from liethermo.scene import load_scene


def test_a_chunked_run_with_preflight_resolves_its_scene_once(tmp_path, monkeypatch):
    calls = []
    real = physics.physics_of_scene

    def counting(scene, members=1):
        calls.append(members)
        return real(scene, members)

    monkeypatch.setattr("liethermo.top.resolve.physics_of_scene", counting)
    monkeypatch.setattr("liethermo.top.physics.physics_of_scene", counting)
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


def test_one_method_choice_from_a_scene_a_label_or_keywords():
    """A study label, the scene it makes and simulate's keywords give one
    MethodChoice, the effective variants worked out once: vi4 ignores the
    start it is asked for, an explicit method has none of the VI's, and the
    resolved run and its trajectory carry the same choice."""
    import pytest

    from liethermo.top.methods import MethodChoice
    from liethermo.top.simulate import simulate
    from liethermo.studies.common import StudyError
    from liethermo.top.studies.tools import method_choice

    for label, want in [("vi:node:explicit", ("vi", "node", "trapezoid", "explicit", None)),
                        ("vi4:staggered:triple_jump", ("vi4", "legendre", "trapezoid", "symmetric", "triple_jump")),
                        ("rk4", ("rk4", "node", None, None, None))]:
        c = MethodChoice.parse(label)
        assert (c.name, c.start, c.friction, c.entropy, c.composition) == want and c.label == label
        assert method_choice(label) == c
        sc = load_scene("paper", {**c.overrides(), "integrator.steps": 4, "output.compare": []})
        run = resolve(sc)
        assert run.choice == MethodChoice.from_scene(sc) and (run.choice.name, run.choice.start,
                                                              run.choice.friction, run.choice.entropy,
                                                              run.choice.composition) == want
        om0, R0 = liethermo.top.initial.initial_conditions(sc, 0, 1)
        assert run.simulate(om0, R0).choice == run.choice
    with pytest.raises(StudyError, match="unknown variant 'fast'"):
        method_choice("vi:fast")
    for kw in ("friction", "start", "entropy", "composition"):  # the variants come in a MethodChoice only
        with pytest.raises(TypeError, match=kw):
            simulate(resolve(load_scene("paper")).physics, np.ones((1, 3)), np.eye(3)[None], 0.1, 1, "vi",
                     **{kw: "node"})
    with pytest.raises(ValueError, match="unknown integrator.start 'nodes'"):
        MethodChoice.of("vi", start="nodes")
    egg = resolve(load_scene("coupled_egg"))  # the coupled top's rule, the one its scene keys obey
    om0, R0 = liethermo.top.initial.initial_conditions(egg.scene, 0, 1)
    for kw, needle in ((dict(start="node"), "starts from its node momentum"),
                       (dict(friction="endpoint"), "trapezoid friction only")):
        with pytest.raises(ValueError, match=needle):
            simulate(egg.physics, om0, R0, 0.01, 1, MethodChoice.of("vi", **kw))
        key = "integrator." + next(iter(kw))
        with pytest.raises(liethermo.SceneError, match=needle):
            load_scene("coupled_egg", {key: next(iter(kw.values()))})
