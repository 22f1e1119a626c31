"""tools/golden.py: records a case's arrays and finds them identical on a
second run; reports every variable that differs (exit status 1), not only
the first; honours the allow-list; compares written netCDF files; and runs a
scene with its own model's methods, whichever model that is (a model it
has never heard of included)."""

import importlib.util
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).parent))


def _golden():
    spec = importlib.util.spec_from_file_location("golden", ROOT / "tools" / "golden.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["golden"] = mod  # its dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


CASE = "zeitlin_decay__split__-"


def _perturb(path: Path, names: list[str]) -> None:
    with np.load(path) as f:
        arrays = {k: f[k] for k in f.files}
    for name in names:
        arrays[name] = arrays[name].copy()
        old = arrays[name].flat[-1]
        arrays[name].flat[-1] = old + max(abs(old), 1.0) * 1e-3 if np.isfinite(old) else 0.0
    np.savez(path, **arrays)


def test_golden_reports_every_difference_and_honours_the_allow_list(tmp_path, capsys):
    golden = _golden()
    names = [c.name for c in golden.cases()]
    assert "paper__vi__fast" in names and CASE in names
    assert golden.main(["record", str(tmp_path), "--only", CASE]) == 0
    assert golden.main(["compare", str(tmp_path), "--only", CASE, "--attrs"]) == 0
    assert f"{CASE}: identical" in capsys.readouterr().out

    path = tmp_path / f"{CASE}.npz"
    with np.load(path) as f:
        floats = [k for k in sorted(f.files) if k.startswith("data:") and f[k].dtype.kind == "f" and f[k].size]
    two = floats[:2]
    _perturb(path, two)
    assert golden.main(["compare", str(tmp_path), "--only", CASE]) == 1
    out = capsys.readouterr().out
    assert f"{CASE}: DIFFERS in 2 variables" in out
    for name in two:  # every differing variable, each with its size of difference
        assert f"    {name}: max abs diff" in out
    assert out.count("1 of ") >= 2

    # one allowed (bare name, any case), one still differing: fails, names only the other
    bare = two[0].split(":", 1)[1]
    assert golden.main(["compare", str(tmp_path), "--only", CASE, "--allow", bare]) == 1
    out = capsys.readouterr().out
    assert f"{CASE}: DIFFERS in 1 variable" in out and f"moved, allowed: {two[0]}" in out
    # both allowed, by a case glob and by an allow file: passes, and still shows the moves
    allow = tmp_path / "moved.txt"
    allow.write_text(f"# moved on purpose\n{two[1]}\n")
    assert golden.main(["compare", str(tmp_path), "--only", CASE, "--allow", f"zeitlin_*:{bare}",
                        "--allow-file", str(allow)]) == 0
    out = capsys.readouterr().out
    assert f"{CASE}: identical but 2 allowed moves" in out
    # a case glob that does not match the case allows nothing
    assert golden.main(["compare", str(tmp_path), "--only", CASE, "--allow", f"paper__*:{bare}",
                        "--allow-file", str(allow)]) == 1
    capsys.readouterr()


def test_allow_patterns():
    golden = _golden()
    assert golden.allowed("zeitlin_ideal__split__-", "data:energy", ["energy"])
    assert golden.allowed("zeitlin_ideal__split__-", "data:energy", ["data:energy"])
    assert golden.allowed("zeitlin_ideal__split__-", "data:energy", ["zeitlin_ideal__*:energy"])
    assert golden.allowed("zeitlin_ideal__split__-", "data:energy_error", ["zeitlin_ideal__*:data:energy*"])
    assert not golden.allowed("zeitlin_decay__split__-", "data:energy", ["zeitlin_ideal__*:energy"])
    assert not golden.allowed("zeitlin_ideal__split__-", "data:energy_error", ["energy"])
    assert not golden.allowed("x", "data:energy", [])


def test_file_mode_compares_written_files(tmp_path, capsys):
    golden = _golden()
    assert golden.main(["record", str(tmp_path), "--only", CASE, "--files"]) == 0
    nc = tmp_path / "files" / f"{CASE}.nc"
    assert nc.is_file()
    assert golden.main(["compare", str(tmp_path), "--only", CASE, "--files"]) == 0
    assert f"{CASE}: identical" in capsys.readouterr().out

    # two files: one value and one attribute changed
    import netCDF4

    other = tmp_path / "other.nc"
    shutil.copyfile(nc, other)
    with netCDF4.Dataset(other, "a") as f:
        name = next(n for n, v in f.variables.items() if v.dtype != str and v.dtype.kind == "f" and v.ndim >= 2)
        v = f.variables[name]
        v[0, ...] = np.asarray(v[0, ...]) + 1.0
        f.variables["t"].setncattr("long_name", "changed")
        f.setncattr("created", "another day")  # when a file was made is not compared
    assert golden.main(["files", str(nc), str(other)]) == 1
    out = capsys.readouterr().out
    assert f"{name}: values: max abs diff" in out and "t: attributes long_name" in out
    assert "created" not in out
    assert golden.main(["files", str(nc), str(other), "--allow", name, "--allow", "t"]) == 0
    capsys.readouterr()
    # folders: by name
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir(), b.mkdir()
    shutil.copyfile(nc, a / "x.nc"), shutil.copyfile(nc, b / "x.nc")
    assert golden.main(["files", str(a), str(b)]) == 0
    assert "1 of 1 files identical" in capsys.readouterr().out


@pytest.fixture
def toy_registered():
    from toymodel import Toy

    from liethermo.models import register, unregister

    yield register(Toy())
    unregister("toy")


def test_a_scene_runs_with_its_own_models_methods(tmp_path, capsys, toy_registered):
    """Cases come from the registry, not from a table's name: a model golden has no
    entry for (the toy) runs its own method on its scenes, shortened, and the built-in
    scenes of the two models each get their own methods only."""
    golden = _golden()
    builtin = golden.cases()
    top = {c.method.split(".")[0] for c in builtin if c.model == "top"}
    fluid = {c.method for c in builtin if c.model == "zeitlin"}
    from liethermo.models import get_model

    assert top == set(get_model("top").methods()) and fluid == set(get_model("zeitlin").methods())
    assert all(c.model == "zeitlin" for c in builtin if c.name.startswith("zeitlin_"))
    assert not any(c.model == "top" and c.method in fluid - top for c in builtin)

    scene = tmp_path / "toy_scene.toml"
    scene.write_text('[scene]\nname = "toy_scene"\n[toy]\nrate = 2.0\n')
    toy_cases = golden.cases([scene])
    assert [(c.name, c.model, c.method) for c in toy_cases] == [("toy_scene__euler__-", "toy", "euler")]
    ds = golden.run_case(toy_cases[0])
    assert ds["y"].shape == (2, 6)  # golden's default size: 2 members, 50 steps stored every 10
    np.testing.assert_allclose(ds["y"].values[0, -1], (1 - 0.1 * 2.0) ** 50)
