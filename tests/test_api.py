"""The Python interface: docs/api.md's examples run as written, and the calls
keep their promises (in memory writes nothing, validation before work, the
accessor's definitions)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import liethermo
from liethermo.scene import SceneError

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_api_examples_run_as_written(tmp_path, monkeypatch):
    """Every ```python block of docs/api.md, in order, in one namespace, in a
    scratch folder (the examples write files relative to it)."""
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "api.md").read_text(), re.S)
    assert len(blocks) >= 6
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    for code in blocks:
        exec(compile(code, "docs/api.md", "exec"), ns)
    assert (tmp_path / "spherical.nc").is_file() and (tmp_path / "conv" / "report.md").is_file()
    assert abs(ns["res"].dataset.observed_order_omega.sel(scheme="vi4").item() - 4) < 0.3


def test_run_in_memory_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    ds = liethermo.run("spherical_top", {"integrator.steps": 10})
    assert list(tmp_path.iterdir()) == []
    assert ds.sizes == {"member": 1, "t": 11, "axis": 3, "row": 3, "col": 3} or ds.sizes["t"] == 11
    assert "liethermo.run" in ds.attrs["history"] and "scene 'spherical_top'" in ds.attrs["summary"]


def test_run_validates_before_any_work(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SceneError, match="integrator.h"):
        liethermo.run("paper", {"integrator.h": 0.0}, output="x.nc")
    with pytest.raises(liethermo.PreflightError, match="x.txt: the output file must end in .nc"):
        liethermo.run("paper", output="x.txt", compare=False)
    (tmp_path / "d.nc").mkdir()
    with pytest.raises(liethermo.PreflightError, match="cannot write d.nc: it is a folder"):
        liethermo.run("paper", output="d.nc", compare=False)
    (tmp_path / "notes.nc").write_text("mine")
    with pytest.raises(liethermo.PreflightError, match="notes.nc exists and is not a liethermo output"):
        liethermo.run("paper", output="notes.nc", compare=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.nc", "notes.nc"]
    assert (tmp_path / "notes.nc").read_text() == "mine"
    # the remedy is named in Python's words, not the command line's
    with pytest.raises(liethermo.PreflightError) as err:
        liethermo.run("paper", output="notes.nc", compare=False)
    assert str(err.value).endswith("pass force=True to replace it, or another output= to write elsewhere")
    assert "--" not in str(err.value)


def test_accessor_definitions():
    """relative_energy_error is energy_error over mechanical_energy_initial;
    the quantiles count a failed member's NaN as +inf; ok/failed partition
    the members."""
    ds = liethermo.run("paper", {"ensemble.members": 24, "integrator.steps": 150,
                                 "integrator.method": "rk2", "output.compare": [],
                                 "output.figures": False, "output.attitude": False})
    acc = ds.liethermo
    assert int(acc.ok.sum() + acc.failed.sum()) == 24 and int(acc.failed.sum()) > 0
    counts = acc.status_counts()
    assert sum(counts.values()) == 24 and counts["ok"] == int(acc.ok.sum())
    rel = acc.relative_energy_error()
    full = acc.derived()
    np.testing.assert_array_equal(rel.values, (full.energy_error / full.mechanical_energy_initial).values)
    q = acc.quantiles(abs(rel), q=(0.5, 1.0))
    assert np.isinf(q.sel(quantile=1.0).values[-1])  # the failed members are above every band
    q_ok = acc.quantiles(abs(rel), q=(1.0,), only_ok=True)
    assert np.isfinite(q_ok.values).all()
    with pytest.raises(KeyError, match="paper"):
        acc.relative_energy_error("paper")  # an explicit method has no step velocity
    with pytest.raises(ValueError):
        acc.relative_energy_error("step")


def test_package_exposes_the_interface():
    assert {"run", "study", "load_scene", "open_dataset"} <= set(liethermo.__all__)
    assert liethermo.load_scene("paper").integrator.start == "node"


def test_run_never_drops_the_scenes_compared_methods(tmp_path, monkeypatch):
    """The paper scene compares its VI with RK2: left unsaid, run() refuses and
    names both choices; compare=True returns both methods, files named as the
    command line names them, with the scene's figures beside them."""
    monkeypatch.chdir(tmp_path)
    small = {"ensemble.members": 2, "integrator.steps": 20}
    with pytest.raises(SceneError, match=r"compare=True .* compare=False") as err:
        liethermo.run("paper", small)
    assert "rk2" in str(err.value)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(SceneError, match="output.figures"):
        liethermo.run("paper", small, compare=False, figures=True)
    ds = liethermo.run("paper", small, compare=False)
    assert ds.attrs["method"] == "vi" and "none drawn (an in-memory run" in ds.attrs["summary"]
    quiet = liethermo.run("paper", {**small, "output.figures": False}, compare=False)
    assert "figures: none asked for" in quiet.attrs["summary"] and "in-memory" not in quiet.attrs["summary"]
    runs = liethermo.run("paper", small, output="p.nc", compare=True)
    assert list(runs) == ["vi", "rk2"] and runs["rk2"].attrs["method"] == "rk2"
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["p.nc", "p_center_of_mass.png", "p_energies.png", "p_entropy.png", "p_rk2.nc",
                     "p_total_energy.png"]
    assert "p_energies.png" in runs["vi"].attrs["summary"]
    for d in runs.values():
        d.close()
    one = liethermo.run("paper", small, output="q.nc", compare=False, figures=False)
    assert not list(tmp_path.glob("q_*")) and one.attrs["method"] == "vi"
    assert "figures: none asked for" in one.attrs["summary"]
    one.close()


def test_refusals_name_their_remedies_in_the_callers_words():
    """A refusal's remedies are spelled for the command line by default and for
    Python by the API, from one template (a path with braces stays literal)."""
    from liethermo.preflight import PYTHON_WORDS, PreflightError

    e = PreflightError.remedy("runs/{a}.nc exists and holds a run of another scene", "force", "elsewhere")
    assert str(e) == ("runs/{a}.nc exists and holds a run of another scene: pass --force to replace it, "
                      "or -o to write elsewhere")
    assert e.in_words(PYTHON_WORDS) == ("runs/{a}.nc exists and holds a run of another scene: pass force=True "
                                        "to replace it, or another output= to write elsewhere")
    assert PreflightError("plain").in_words(PYTHON_WORDS) == "plain"
