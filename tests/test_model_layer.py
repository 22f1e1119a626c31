"""One run layer for every model: the fluid's runs in member chunks (resume
after SIGKILL, refusals, --check), the old viscosity key, and a model that
exists only in the tests (tests/toymodel.py) run through liethermo.run and
the command line."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import netCDF4
import numpy as np
import pytest

import liethermo
from liethermo.cli import main
from liethermo.runner import run_scene
from liethermo.scene import SceneError, load_scene
from conftest import kill_and_resume
from ncsame import same_but_created

CLI = [sys.executable, "-m", "liethermo.cli"]
SRC = Path(liethermo.__file__).parent
#: a small fluid run in chunks of 3 members: 16 members, 6 chunks
FLUID = ["zeitlin.N=12", "initial.lmax=6", "ensemble.members=16", "output.member_chunk=3",
         "integrator.steps=40", "output.every=10", "output.compare=[]", "output.figures=false"]


def _sets(over):
    return [a for s in over for a in ("--set", s)]


def values(path: Path) -> dict:
    with netCDF4.Dataset(path) as nc:
        nc.set_auto_mask(False)
        return {n: np.asarray(v[...]) for n, v in nc.variables.items()}


def assert_same_values(a: Path, b: Path) -> None:
    va, vb = values(a), values(b)
    assert list(va) == list(vb)
    for n in va:
        assert va[n].dtype == vb[n].dtype and va[n].shape == vb[n].shape, n
        if va[n].dtype.kind in "fiu":
            assert va[n].tobytes() == vb[n].tobytes(), n
        else:
            assert np.array_equal(va[n], vb[n]), n


def test_no_entry_point_branches_on_a_model():
    for f in ("api.py", "cli.py", "runner.py", "preflight.py"):
        text = (SRC / f).read_text().lower()
        assert "zeitlin" not in text and not re.search(r"\btop\b", text), f


# ---------------------------------------------------------------- the fluid
def test_a_fluid_run_in_chunks_is_the_in_memory_run_and_one_batch_to_round_off(tmp_path):
    run_scene("zeitlin_decay", tmp_path / "chunked.nc", overrides=FLUID + ["output.vorticity=true"],
              progress=False)
    ds, summ = run_scene("zeitlin_decay", None, overrides=FLUID + ["output.vorticity=true"], progress=False)
    v = values(tmp_path / "chunked.nc")
    assert list(ds["member"].values) == list(range(16)) and summ.members == 16
    for name in ("energy", "energy_spectrum", "casimir", "vorticity_real", "status"):
        assert ds[name].values.tobytes() == v[name].tobytes(), name
    _, whole = run_scene("zeitlin_decay", tmp_path / "whole.nc", progress=False,
                         overrides=FLUID + ["output.vorticity=true", "output.member_chunk=16"])
    w = values(tmp_path / "whole.nc")
    # W is each member's own (its products are per member): the same bits in any chunk; the
    # diagnostics are BLAS products over the chunk's members: the same to round-off
    assert w["vorticity_real"].tobytes() == v["vorticity_real"].tobytes()
    for name in ("energy", "energy_spectrum", "casimir", "angular_momentum"):
        assert np.allclose(w[name], v[name], rtol=1e-14, atol=1e-16 * np.abs(w[name]).max()), name
    assert whole.stats.members == summ.stats.members == 16 and whole.stats.failed == summ.stats.failed == 0


def test_the_old_viscosity_key_is_refused_naming_the_new_one(capsys):
    with pytest.raises(SceneError, match="fluid.kinematic_viscosity"):
        load_scene("zeitlin_decay", {"fluid.viscosity": 1e-3})
    assert main(["run", "zeitlin_decay", "--set", "fluid.viscosity=1e-3", "--check"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'fluid.viscosity'" in err and "fluid.kinematic_viscosity (ν in s-1)" in err
    assert load_scene("zeitlin_decay", {"fluid.kinematic_viscosity": 2e-3})["fluid"]["kinematic_viscosity"] == 2e-3


def test_a_fluid_run_refuses_another_scenes_output_naming_the_key(tmp_path, capsys):
    out = tmp_path / "z.nc"
    small = FLUID + ["ensemble.members=2", "integrator.steps=10"]
    assert main(["run", "zeitlin_decay", "-o", str(out), "--no-progress", *_sets(small)]) == 0
    before = out.stat().st_mtime_ns
    capsys.readouterr()
    assert main(["run", "zeitlin_decay", "-o", str(out), "--no-progress", *_sets(small + ["zeitlin.N=10"])]) == 2
    err = capsys.readouterr().err
    assert "holds a run of another scene, differing in zeitlin.N (12 there, 10 here)" in err and "--force" in err
    assert out.stat().st_mtime_ns == before
    # a fluid's chunk sets the last bits of its diagnostics: another chunk is another run
    assert main(["run", "zeitlin_decay", "-o", str(out), "--no-progress",
                 *_sets(small + ["output.member_chunk=1"])]) == 2
    assert "differing in output.member_chunk (3 there, 1 here)" in capsys.readouterr().err
    assert main(["run", "zeitlin_decay", "-o", str(out), "--no-progress", *_sets(small)]) == 0  # same: replaced


def test_fluid_check_says_disk_memory_and_time(tmp_path, capsys):
    assert main(["run", "zeitlin_decay", "-o", str(tmp_path / "z.nc"), "--check", *_sets(FLUID)]) == 0
    out = capsys.readouterr().out
    assert re.search(r"about [\d.]+ \w+ on disk, [\d.]+ \w+ free; at most about [\d.]+ \w+ of memory "
                     r"\(member chunks of 3\), [\d.]+ \w+ available", out), out
    assert "split: about" in out and "basis of su(12)" in out
    assert not (tmp_path / "z.nc").exists()


def test_a_fluid_run_killed_and_resumed_gives_the_same_file(tmp_path):
    over = FLUID + ["zeitlin.N=16", "integrator.steps=400", "output.every=40", "output.member_chunk=2"]
    out, ref, stdout = kill_and_resume(tmp_path, ["run", "zeitlin_decay", "--no-progress", *_sets(over)])
    assert re.search(r"resumed: members 0-\d+ came from the interrupted run", stdout), stdout
    assert sorted(q.name for q in tmp_path.iterdir()) == ["ref", "ref.nc", "z.nc"]
    assert same_but_created(out, ref)


# ---------------------------------------------------------------- a model of the tests' own
@pytest.fixture
def toy():
    from liethermo.models import register, unregister
    from toymodel import Toy

    register(Toy())
    yield
    unregister("toy")


def test_a_model_of_the_tests_runs_through_the_api_and_the_command_line(toy, tmp_path, capsys):
    tables = {"toy": {"rate": 2.0}, "ensemble": {"members": 5}}
    ds = liethermo.run(tables, compare=False)
    y = ds["y"].values
    assert y.shape == (5, 11) and list(ds["member"].values) == [0, 1, 2, 3, 4]
    assert np.array_equal(y[:, 1], (1.0 + np.arange(5) / 10.0) * (1 - 0.1 * 2.0))
    assert "scene 'toy', method euler: 5 member(s) x 10 steps" in ds.attrs["summary"]
    assert "toy: max |y| 1.4" in ds.attrs["summary"]  # the chunks' stats merged by their rule (max)
    ds = liethermo.run(tables, compare=False, output=tmp_path / "a.nc")
    assert np.array_equal(ds["y"].values, y)
    ds.close()

    scene = tmp_path / "decay.toml"
    scene.write_text("[toy]\nrate = 2.0\n[ensemble]\nmembers = 5\n")
    out = tmp_path / "b.nc"
    assert main(["run", str(scene), "-o", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "scene 'decay', method euler: 5 member(s) x 10 steps" in printed and f"wrote {out}" in printed
    assert np.array_equal(values(out)["y"], y)
    assert main(["run", str(scene), "-o", str(out), "--check"]) == 0
    printed = capsys.readouterr().out  # a model without estimates: the plan, and no time
    assert "member chunks of 2" in printed and "the toy decay gives no estimate before a run" in printed
    assert main(["keys"]) == 0
    assert "toy.rate [s-1] = 0.5" in capsys.readouterr().out
    assert main(["run", str(scene), "--set", "toy.rate=-1", "--check"]) == 2
    assert "'toy.rate'" in capsys.readouterr().err
    # a generic study needs study support, which the toy does not offer: one line, exit 2
    study = tmp_path / "conv.toml"
    study.write_text(f'[study]\nkind = "convergence"\nbase_scene = "{scene}"\n')
    assert main(["study", str(study)]) == 2
    err = capsys.readouterr().err
    assert "the convergence study compares methods" in err and "the toy decay" in err and len(err.splitlines()) == 1


def test_the_fluid_decay_study_goes_on_from_its_finished_points(tmp_path, monkeypatch):
    from liethermo.zeitlin.studies import zeitlin_decay
    from liethermo.studies.runner import load_study, run_study

    study = load_study(Path(__file__).resolve().parents[1] / "studies" / "zeitlin_decay.toml")
    run_study(study, tmp_path / "a", reduced=True, progress=False)
    points = sorted((tmp_path / "a" / "points").glob("*.nc"))
    assert len(points) == 2  # one per viscosity of the reduced sweep
    first = values(next((tmp_path / "a").glob("*.nc")))
    points[0].unlink()  # as a study killed after its first point leaves it
    calls = []
    real = zeitlin_decay.run_scene
    monkeypatch.setattr(zeitlin_decay, "run_scene", lambda sc, *a, **kw: calls.append(sc) or real(sc, *a, **kw))
    run_study(study, tmp_path / "a", reduced=True, progress=False)
    assert len(calls) == 1  # the missing point only
    again = values(next((tmp_path / "a").glob("*.nc")))
    for name in ("energy", "heat", "entropy", "heat_fraction"):
        assert again[name].tobytes() == first[name].tobytes(), name


def test_the_fluid_structure_study_reruns_nothing_it_finished(tmp_path, monkeypatch):
    from liethermo.zeitlin.studies import zeitlin_structure
    from liethermo.studies.runner import load_study, run_study

    study = load_study(Path(__file__).resolve().parents[1] / "studies" / "zeitlin_structure.toml")
    run_study(study, tmp_path / "s", reduced=True, progress=False)
    table = (tmp_path / "s" / "drift.csv").read_text()

    def no_steps(*a, **k):
        raise AssertionError("a finished run or timing was made again")

    monkeypatch.setattr(zeitlin_structure, "run_scene", no_steps)  # the cached timings set RK4's step again
    run_study(study, tmp_path / "s", reduced=True, progress=False)
    assert (tmp_path / "s" / "drift.csv").read_text() == table


def test_figures_come_from_the_file_alone(tmp_path):
    """No cache sits between a run and its figures: member 0's vorticity for the
    maps is read from the file, or integrated again from the scene it stores, with
    the same values as in the run's chunk (a member's products are its own)."""
    from liethermo.zeitlin import model as zm

    over = FLUID + ["output.vorticity=false"]
    run_scene("zeitlin_decay", tmp_path / "plain.nc", overrides=over, progress=False)
    run_scene("zeitlin_decay", tmp_path / "kept.nc", overrides=FLUID + ["output.vorticity=true"], progress=False)
    assert not any(isinstance(v, dict) and v for k, v in vars(zm).items() if k.isupper() and k.startswith("_"))
    with liethermo.open_dataset(tmp_path / "plain.nc") as plain, liethermo.open_dataset(tmp_path / "kept.nc") as kept:
        assert "vorticity_real" not in plain
        again = zm.Fluid().member0(plain)
        stored = zm.Fluid().member0(kept)
    assert np.array_equal(again, stored)  # the same values (a zero may differ in its sign)


def test_a_stored_scene_without_a_model_table_is_the_tops(tmp_path):
    """The registry's one rule: every scene written before scenes named their
    model (no model's table) reads, and resumes, as the top's."""
    import tomllib

    from liethermo.models import UNMARKED_SCENES_MODEL, model_of, models

    out = tmp_path / "top.nc"
    run_scene("paper", out, overrides=["ensemble.members=3", "integrator.steps=20", "output.compare=[]"],
              progress=False)
    with liethermo.open_dataset(out) as ds:
        tables = tomllib.loads(ds.attrs["scene"])
    assert not any(m.scene_table and m.scene_table in tables for m in models())
    assert UNMARKED_SCENES_MODEL == "top" and model_of(tables).name == "top"
    assert model_of({}).name == "top" and model_of({"zeitlin": {}}).name == "zeitlin"
    assert type(liethermo.load_scene(tables)).__module__ == "liethermo.top.scene"
