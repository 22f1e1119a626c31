"""Property-based fuzzing of the command line: any scene file and any
``--set`` string ends with exit status 0 or 2, never a traceback, one line on
stderr when refused, and no file left behind when refused.

Scene values run for real (tiny runs: the size keys are drawn small);
``--set`` strings go through validation and the checks before a run
(``--check``), which is where they matter.
"""

from __future__ import annotations

import contextlib
import io
import tempfile
import warnings
from pathlib import Path

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, example, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

import tomli_w  # noqa: E402

from liethermo.cli import main  # noqa: E402
from liethermo.top.scene import DEFAULTS  # noqa: E402

# reproducible in CI; no deadline: the first valid example compiles the kernels
FUZZ = dict(deadline=None, derandomize=True, database=None,
            suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

scalars = st.one_of(
    st.integers(min_value=-3, max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.booleans(),
    st.text(max_size=10),
    st.sampled_from(["paper", "hemispheres", "vi", "rk2", "rk4", "reference", "endpoint", "staggered", ""]),
)
values = st.recursive(scalars, lambda inner: st.lists(inner, max_size=4), max_leaves=12)
small_int = st.one_of(st.integers(min_value=1, max_value=6), st.integers(min_value=1, max_value=6),
                      st.integers(min_value=-1, max_value=6), st.sampled_from([1.5, "3", True, [2]]))
floats = lambda lo, hi: st.floats(min_value=lo, max_value=hi)  # noqa: E731
vec = lambda n, lo, hi: st.lists(floats(lo, hi), min_size=n, max_size=n)  # noqa: E731
METHODS = ["vi", "vi4", "vi6", "rk2", "rk4", "reference"]
# plausible values of every key (mostly valid, some just outside the rules),
# drawn more often than arbitrary ones
PLAUSIBLE = {
    ("scene", "name"): st.text(max_size=8), ("scene", "description"): st.text(max_size=20),
    ("body", "shape"): st.sampled_from(["hemispheres", "ellipsoid", "cube"]),
    ("body", "semi_axes"): vec(3, -0.01, 0.2),
    ("body", "mass"): st.one_of(st.just("shape"), floats(-0.1, 10.0)),
    ("body", "thermal_expansion"): floats(-1e-5, 1e-2), ("body", "internal_friction"): floats(-1.0, 50.0),
    ("thermo", "heat_capacity"): st.one_of(st.just("material"), floats(-1.0, 1e4)),
    ("integrator", "entropy"): st.sampled_from(["symmetric", "explicit", "implicit"]),
    ("body", "radius"): floats(-0.001, 0.2), ("body", "density"): floats(-1.0, 2e4),
    ("body", "molar_mass"): floats(-1e-4, 0.2), ("body", "upper_mass_fraction"): floats(-0.01, 1.01),
    ("body", "inertia"): st.one_of(st.just("paper"), vec(3, -1e-5, 3e-3)),
    ("body", "center_of_mass"): st.one_of(st.just("hemispheres"), vec(3, -0.05, 0.05)),
    ("fluid", "viscosity"): floats(-0.01, 20.0), ("gravity", "g"): floats(-0.1, 30.0),
    ("thermo", "T0"): floats(-1.0, 2000.0), ("thermo", "S0"): floats(-1e3, 1e3),
    ("initial", "omega"): vec(3, -20.0, 20.0),
    ("initial", "R"): st.sampled_from([[[1, 0, 0], [0, 1, 0], [0, 0, 1]], [[1, 0, 0], [0, 0, -1], [0, 1, 0]],
                                       [[0, 1, 0], [1, 0, 0], [0, 0, 1]], [[1, 0, 0], [0, 1, 0]]]),
    ("integrator", "method"): st.sampled_from(METHODS + ["rk5"]), ("integrator", "h"): floats(-0.001, 2.0),
    ("integrator", "friction"): st.sampled_from(["trapezoid", "endpoint", "midpoint"]),
    ("integrator", "start"): st.sampled_from(["node", "staggered", "legendre", "late"]),
    ("integrator", "newton_tol"): floats(0.0, 1.1e-3),
    ("ensemble", "seed"): st.integers(min_value=-1, max_value=2**64), ("ensemble", "spin_range"): vec(2, -0.1, 3.0),
    ("output", "attitude"): st.booleans(),
}
# keys that set the size of a run: drawn small, so that every valid scene is a tiny run
SIZE = {
    ("integrator", "steps"): st.one_of(st.sampled_from([4, 6, 12]), st.integers(min_value=-1, max_value=12),
                                       st.sampled_from([2.0, "8"])),
    ("ensemble", "members"): small_int,
    ("output", "every"): st.one_of(st.sampled_from([1, 2]), small_int),
    ("output", "member_chunk"): small_int,
    # (not 2**40: with a tolerance below round-off, valid, the Newton loop would run for hours)
    ("integrator", "newton_maxiter"): st.one_of(st.integers(min_value=-1, max_value=40),
                                                st.sampled_from([10**4, 2**70, 0.5])),
    ("output", "compare"): st.one_of(st.lists(st.sampled_from(METHODS + ["rk9", 3]), max_size=3), values),
    ("output", "figures"): st.just(False),  # drawing is slow and tested elsewhere
}
KEYS = [(s, k) for s, table in DEFAULTS.items() for k in table]


@st.composite
def scenes(draw):
    """A scene table: some known keys with arbitrary values, sometimes an unknown key."""
    scene: dict = {}
    for s, k in draw(st.lists(st.sampled_from(KEYS), max_size=6, unique=True)):
        if (s, k) in SIZE:
            v = draw(SIZE[(s, k)])
        else:
            v = draw(st.one_of(*[PLAUSIBLE.get((s, k), values)] * 8, values))
        scene.setdefault(s, {})[k] = v
    for (s, k), strat in SIZE.items():  # keep every valid run tiny
        if k not in scene.get(s, {}):
            scene.setdefault(s, {})[k] = {"steps": 8, "members": 2, "every": 4, "member_chunk": 2,
                                          "newton_maxiter": 30, "compare": [], "figures": False}[k]
    if draw(st.booleans()) and draw(st.booleans()):
        scene.setdefault(draw(st.sampled_from(["integrator", "physics"])), {})[draw(st.text(min_size=1, max_size=6))] = 1
    return scene


def run_cli(argv) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err), warnings.catch_warnings():
        warnings.simplefilter("default")  # as a user sees them: printed, not raised
        rc = main(argv)
    return rc, err.getvalue()


def check_outcome(rc: int, err: str, folder: Path, *, check: bool = False) -> None:
    """A run refused in one line; a ``--check`` may list several problems
    (after its estimates and their warnings), each a line of its own."""
    hypothesis.event(f"exit {rc}")  # (see them with --hypothesis-show-statistics)
    assert rc in (0, 2), (rc, err)
    assert "Traceback" not in err, err
    if rc == 2:
        if check and err.count("\n") > 1:
            lines = err.splitlines()
            assert all(line.startswith(("liethermo: error: ", "liethermo: warning: ")) for line in lines), err
            assert lines[-1].startswith("liethermo: error: "), err
        else:
            assert err.count("\n") == 1 and err.startswith("liethermo: error: "), err
        assert list(folder.iterdir()) == [], list(folder.iterdir())


def _toml(scene) -> str | None:
    try:
        return tomli_w.dumps(scene)
    except (TypeError, ValueError):  # not expressible in TOML (e.g. mixed-type arrays in old writers)
        return None


@settings(max_examples=60, **FUZZ)
@given(scenes())
def test_fuzzed_scene_files(scene):
    text = _toml(scene)
    if text is None:
        return
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        (d / "in").mkdir()
        (d / "out").mkdir()
        f = d / "in" / "fuzz.toml"
        f.write_text(text)
        rc, err = run_cli(["run", str(f), "-o", str(d / "out" / "x.nc"), "--no-progress"])
        check_outcome(rc, err, d / "out")


junk_values = st.one_of(
    st.text(max_size=20),
    st.integers().map(str),
    st.floats().map(repr),
    st.sampled_from(["nan", "inf", "-inf", "[1,2,3]", "[[1,0,0],[0,1,0],[0,0,1]]", "'rk4'", "true", "1e400",
                     "{a = 1}", "1979-05-27", "[1, 'a']", "\"\"", "0x10", "1_000", "[]", "", "="]),
)


def _toml_value(v) -> str:
    return tomli_w.dumps({"v": v})[len("v = "):].strip()


@st.composite
def set_strings(draw):
    """``SECTION.KEY=VALUE``: mostly a known key with a plausible TOML value,
    else junk values, unknown keys, or any text at all."""
    kind = draw(st.integers(min_value=0, max_value=9))
    if kind == 0:
        return draw(st.text(max_size=30))
    key = draw(st.sampled_from(KEYS + [("integrator", "wobble"), ("physics", "g"), ("a.b", "c"), ("", "")]))
    name = f"{key[0]}.{key[1]}" if kind != 1 else key[0]
    if kind < 7 and key in PLAUSIBLE:
        return f"{name}={_toml_value(draw(PLAUSIBLE[key]))}"
    if kind < 7 and key in SIZE:
        return f"{name}={_toml_value(draw(SIZE[key]))}"
    return f"{name}={draw(junk_values)}"


@settings(max_examples=200, **FUZZ)
@given(st.lists(set_strings(), min_size=1, max_size=3))
@example(sets=["integrator.steps=165322123"])  # a check that meets more than one problem (disk, memory)
def test_fuzzed_set_strings(sets):
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        argv = ["run", "paper", "-o", str(d / "x.nc"), "--check"]
        argv += [f"--set={s}" for s in sets]  # (a value starting with '-' needs the '=' form)
        rc, err = run_cli(argv)
        check_outcome(rc, err, d, check=True)
        if rc == 0:  # a check writes nothing either
            assert list(d.iterdir()) == []


def test_fuzz_strategies_reach_valid_and_invalid_scenes():
    """The scene strategy is not degenerate: among its first examples some
    scenes are valid (they run) and some are refused."""
    from hypothesis import find, settings

    from liethermo.scene import SceneError, load_scene

    def valid(scene):
        try:
            load_scene(scene)
            return True
        except SceneError:
            return False

    quiet = settings(database=None, derandomize=True)
    assert valid(find(scenes(), lambda sc: valid(sc) and len(sc) >= 4, settings=quiet))
    assert not valid(find(scenes(), lambda sc: not valid(sc), settings=quiet))
