"""The study framework: options and their errors, planning, stacking, labels, reports, resume."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from liethermo import cf
from liethermo.studies.common import StudyError
from liethermo.studies.framework import Figure, Option, Stage, Study, Table, Verdict

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("rule, good, bad, says", [
    ("number>0", 0.5, 0, "must be a number > 0 (s), got 0"),
    ("int>=3", 3, 2.5, "must be an integer ≥ 3, got 2.5"),
    ("fraction", 0.3, 1.0, "must be a number in (0, 1), got 1.0"),
    ("bool", True, 1, "must be true or false, got 1"),
    ("list[number>0]", [1, 2.0], [1, -2], "must be a non-empty list of number > 0s, got [1, -2]"),
    ("one of a|b", "b", "c", 'must be one of "a", "b", got \'c\''),
    ("list?[str]", [], ["a", 1], "must be a list of strings, got ['a', 1]"),
])
def test_option_rules_make_one_line_errors(rule, good, bad, says):
    o = Option("x", good, rule, "s" if rule == "number>0" else "1")
    o.check(good)
    with pytest.raises(StudyError) as exc:
        o.check(bad)
    assert str(exc.value) == f"options.x: {says}"


CALLS = []


def _square(ctx, coords):
    CALLS.append(("square", coords["scheme"], coords["k"]))
    return xr.Dataset({"value": ((), float(coords["k"]) ** 2 * (2 if coords["scheme"] == "b" else 1))})


def _shift(ctx, coords, square):
    return xr.Dataset({"shifted": ((), float(square["value"]) + ctx.opt["offset"]),
                       "series": ("t", np.arange(3.0) * float(square["value"]))}, coords={"t": [0.0, 1.0, 2.0]})


def _toy(quantities=None):
    q = {"value": ("m2", "k squared"), "shifted": ("m2", "k squared plus the offset"), "series": ("m2", "a series")}
    return Study(
        kind="toy", title="Toy", description="a toy study", needs_methods=True,
        options=(Option("offset", 1.0, "number", "m2"), Option("ks", [1, 2, 3], "list[number>0]", "1")),
        axes=lambda ctx: {"k": ctx.opt["ks"]},
        stages=(Stage("square", _square, over=("point", "scheme", "k")),
                Stage("shift", _shift, over=("point", "scheme", "k"), needs=("square",))),
        quantities=q if quantities is None else quantities,
        tables=lambda ds, ctx: [Table("values", "Values", [{"scheme": m, "sum": float(ds["value"].sel(scheme=m).sum())}
                                                           for m in ctx.methods])],
        verdicts=lambda ds, ctx: [Verdict("b doubles a", "ratio 2", "= 2",
                                          bool((ds["value"].sel(scheme="b") == 2 * ds["value"].sel(scheme="a")).all()))],
        findings=lambda ds, ctx: ["b is twice a."],
        figures=(Figure("values", kind="lines", x="k", y=("value", "shifted"), claim="b lies above a"),),
        report="Offset {opt[offset]} m2 on scene `{scene}`.")


def _toy_study(**opts):
    return {"study": {"kind": "toy", "name": "toy", "base_scene": "paper"}, "methods": ["a", "b"],
            "sweep": {"fluid.quadratic_drag": [0.0, 1e-6]}, "options": opts}


@pytest.fixture
def toy_methods(monkeypatch):
    from liethermo.top.model import HeavyTop
    from liethermo.models import MethodInfo

    monkeypatch.setattr(HeavyTop, "methods", lambda self: {m: MethodInfo(m, 1, (), "") for m in "ab"})
    monkeypatch.setattr(HeavyTop, "method_overrides", lambda self, m: {"integrator.method": m})


def test_a_declared_study_plans_stacks_labels_and_reports(tmp_path, toy_methods):
    CALLS.clear()
    report = _toy().run(_toy_study(offset=0.5), tmp_path, reduced=False, progress=False)
    ds = cf.load_dataset(tmp_path / "toy.nc")
    assert ds["value"].dims == ("fluid_quadratic_drag", "scheme", "k")
    assert ds["series"].dims == ("fluid_quadratic_drag", "scheme", "k", "t")
    assert float(ds["shifted"].sel(scheme="b", k=3).isel(fluid_quadratic_drag=1)) == 18.5
    assert ds["value"].attrs["units"] == "m2" and ds["value"].attrs["long_name"] == "k squared"
    assert ds.attrs["option_offset"] == 0.5 and ds.attrs["methods"] == "a, b" and ds.attrs["model"] == "top"
    assert ds["fluid_quadratic_drag"].attrs["scene_key"] == "fluid.quadratic_drag"
    assert len(CALLS) == 2 * 2 * 3
    text = report.read_text()
    assert "Offset 0.5 m2 on scene `paper`." in text and "| b doubles a | ratio 2 | = 2 | holds |" in text
    assert "**Findings.** b is twice a." in text and (tmp_path / "values.png").is_file()
    assert (tmp_path / "values.csv").read_text().splitlines()[1] == "a,28.0"
    # a rerun computes nothing: every task is a file
    _toy().run(_toy_study(offset=0.5), tmp_path, reduced=False, progress=False)
    assert len(CALLS) == 12


def test_bad_options_and_undeclared_quantities_are_refused(tmp_path, toy_methods):
    with pytest.raises(StudyError, match=r"options.offsett: unknown option of a toy study; known: ks, offset"):
        _toy().run(_toy_study(offsett=1), tmp_path, reduced=False)
    with pytest.raises(StudyError, match=r"options.ks: must be a non-empty list"):
        _toy().run(_toy_study(ks=[]), tmp_path, reduced=False)
    with pytest.raises(RuntimeError, match="writes 'shifted' without declaring its quantity"):
        _toy(quantities={"value": ("m2", "k squared"), "series": ("m2", "s")}).run(_toy_study(), tmp_path / "x",
                                                                                  reduced=False, progress=False)


def test_a_study_killed_and_rerun_writes_the_same_file(tmp_path):
    """SIGKILL in the middle of a study, then the same command: the finished tasks
    are kept, and the netCDF equals an uninterrupted run's."""
    sys.path.insert(0, str(ROOT / "tests"))
    from ncsame import same_but_created

    cmd = [sys.executable, "-m", "liethermo.cli", "study", str(ROOT / "studies" / "entropy_rate.toml"), "--reduced",
           "--no-progress"]
    env = dict(os.environ, PYTHONHASHSEED="0")
    out = tmp_path / "out"  # both runs write here (their history names the same folder)
    subprocess.run(cmd + ["-o", str(out)], check=True, env=env, capture_output=True)
    clean = (out / "entropy_rate.nc").rename(tmp_path / "clean.nc")
    for p in list((out / "points").glob("*.nc")):
        p.unlink()
    p = subprocess.Popen(cmd + ["-o", str(out)], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    points = out / "points"
    deadline = time.time() + 120
    while time.time() < deadline and len(list(points.glob("*.nc"))) < 5 and p.poll() is None:
        time.sleep(0.05)
    p.send_signal(signal.SIGKILL)
    p.wait()
    kept = len(list(points.glob("*.nc")))
    assert 0 < kept < 24 and not (out / "entropy_rate.nc").exists()
    subprocess.run(cmd + ["-o", str(out)], check=True, env=env, capture_output=True)
    assert same_but_created(clean, out / "entropy_rate.nc")


def test_one_study_file_runs_on_a_scene_of_either_model(tmp_path, capsys):
    """[model.<name>] applies for a base scene of that model (then its own [reduced]);
    ``--scene`` swaps the base scene and names the folder after it."""
    from liethermo.cli import main
    from liethermo.studies.common import resolve_study, with_scene

    study = {"study": {"kind": "convergence", "name": "c", "base_scene": "paper"}, "options": {"h0": 0.1, "levels": 4},
             "reduced": {"options": {"levels": 3}},
             "model": {"zeitlin": {"options": {"h0": 0.2, "members": 2}, "reduced": {"options": {"t_end": 0.4}}}}}
    assert resolve_study(study, True)["options"] == {"h0": 0.1, "levels": 3}
    fluid = with_scene(study, "zeitlin_decay")
    assert fluid["study"]["name"] == "c_zeitlin_decay"
    assert resolve_study(fluid, False)["options"] == {"h0": 0.2, "levels": 4, "members": 2}
    assert resolve_study(fluid, True)["options"] == {"h0": 0.2, "levels": 3, "members": 2, "t_end": 0.4}
    bad = tmp_path / "bad.toml"
    bad.write_text('methods = ["rk4"]\n[study]\nkind = "convergence"\n[model.fluid.options]\nh0 = 1.0\n')
    assert main(["study", str(bad), "-o", str(tmp_path / "o"), "--no-progress"]) == 2
    assert "model.fluid: must be a table named after a model (top, zeitlin, torus)" in capsys.readouterr().err


def _imports_simulate(source: str) -> list[str]:
    """The lines of ``source`` that import the integrator entry point ``simulate`` itself."""
    import ast

    return [f"line {n.lineno}" for n in ast.walk(ast.parse(source)) if isinstance(n, ast.ImportFrom)
            and any(a.name == "simulate" for a in n.names)
            or isinstance(n, ast.Import) and any(a.name.endswith(".simulate") for a in n.names)]


def test_studies_run_their_methods_through_the_run_layer():
    """No study module calls the integrator directly: each runs a scene's members through the
    resolved run (liethermo.top.resolve, or the framework's run_scene), as every run of the scene does."""
    pkg = ROOT / "src" / "liethermo"
    modules = sorted(pkg.glob("studies/*.py")) + sorted(pkg.glob("*/studies/*.py"))
    assert len(modules) >= 20
    bad = {str(p.relative_to(pkg)): hits for p in modules if (hits := _imports_simulate(p.read_text()))}
    assert not bad, bad
    assert _imports_simulate("from ..simulate import Trajectory, simulate\n") == ["line 1"]  # the check can fail
    assert _imports_simulate("def f():\n    from liethermo.top.simulate import simulate\n") == ["line 2"]
