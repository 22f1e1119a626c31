"""A user's own initial data: the fluid's vorticity as spherical-harmonic
coefficients from a file or from a function projected onto the basis, the
top's Ω₀ and attitudes per member from a file.  The file is identified by
its sha256 in the stored scene, its values are stored with the run, a
changed file refuses a resume, and bad files are refused in one line."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest
from scipy.special import sph_harm_y

import liethermo
from cfcheck import assert_cf_clean
from conftest import interrupt_at_chunk
from liethermo.cli import main
from liethermo.top.initial import quat_to_matrix
from liethermo.scene import SceneError, load_scene
from liethermo.zeitlin import kernels as zk
from liethermo.zeitlin.field import modes_to_triangle, project, write_initial

N = 8
FLUID = {"zeitlin.N": N, "initial.lmax": 4, "integrator.steps": 40, "output.every": 10,
         "output.compare": [], "output.figures": False}
TOP = {"integrator.steps": 20, "output.compare": [], "output.figures": False}


def _names(folder) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def _one_line(err: str) -> str:
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err.strip()


def _wave(lon, lat):
    """ω = 2 Re Y_3^2 + ½ Y_1^0 − 0.3 Re Y_5^4 (s⁻¹): degrees below N, exactly projectable."""
    th = np.pi / 2 - lat
    return (2 * sph_harm_y(3, 2, th, lon).real + 0.5 * sph_harm_y(1, 0, th, lon).real
            - 0.3 * sph_harm_y(5, 4, th, lon).real)


def _wave_coefficients(L: int = 6) -> np.ndarray:
    C = np.zeros((L + 1, L + 1), dtype=complex)
    C[3, 2], C[1, 0], C[5, 4] = 1.0, 0.5, -0.15
    return C


# ------------------------------------------------------------------ the fluid
def test_a_coefficient_file_reproduces_the_projected_function(tmp_path):
    """The run from a user's .npy coefficients (degrees up to 6) and the run
    from the same field given as a function on the sphere, projected onto
    the basis, agree to round-off; both store the coefficients they started from."""
    np.save(tmp_path / "c.npy", _wave_coefficients())
    write_initial(tmp_path / "f.nc", _wave, N=N)
    runs = {}
    for name in ("c.npy", "f.nc"):
        runs[name] = liethermo.run("zeitlin_decay", {**FLUID, "ensemble.members": 1, "initial.kind": "file",
                                                     "initial.file": str(tmp_path / name)}, compare=False)
    a, b = runs["c.npy"], runs["f.nc"]
    Ca = a["initial_vorticity_real"].values + 1j * a["initial_vorticity_imag"].values
    Cb = b["initial_vorticity_real"].values + 1j * b["initial_vorticity_imag"].values
    assert Ca.shape == (1, N, N)
    np.testing.assert_allclose(Ca[0, :7, :7], _wave_coefficients(), atol=1e-14)
    np.testing.assert_allclose(Cb, Ca, atol=1e-13)
    for v in ("energy", "enstrophy", "heat", "angular_momentum", "energy_spectrum"):
        np.testing.assert_allclose(b[v].values, a[v].values, rtol=1e-11, atol=1e-14, err_msg=v)
    # H(0) of the field: ½ Σ weight |ω_lm|²/l(l+1)
    H0 = 0.5 * (0.5 ** 2 / 2 + 2 * 1 / 12 + 2 * 0.15 ** 2 / 30)
    assert a["energy"].values[0, 0] == pytest.approx(H0, rel=1e-13)
    sa, sb = (tomllib.loads(d.attrs["scene"])["initial"] for d in (a, b))
    assert sa["kind"] == "file" and len(sa["sha256"]) == 64 and sa["sha256"] != sb["sha256"]


def test_a_file_of_the_builtin_field_reproduces_the_builtin_run(tmp_path):
    """Coefficients taken from the built-in random fields, one per member, give
    the built-in run again (the file's field is the run's field)."""
    over = {**FLUID, "ensemble.members": 3}
    ref = liethermo.run("zeitlin_decay", over, compare=False)
    sc = load_scene("zeitlin_decay", over)
    from liethermo.zeitlin.run import initial_fields

    C = modes_to_triangle(zk.to_modes(initial_fields(sc), zk.basis(N)), N)
    for suffix in (".nc", ".npz"):
        path = write_initial(tmp_path / f"rand{suffix}", C)
        ds = liethermo.run("zeitlin_decay", {**over, "initial.kind": "file", "initial.file": str(path)},
                           compare=False)
        for v in ("energy", "enstrophy", "heat", "casimir"):
            np.testing.assert_allclose(ds[v].values, ref[v].values, rtol=1e-12, atol=1e-14, err_msg=v)


def _fluid_args(tmp_path, coef):
    return ["run", "zeitlin_decay", "-o", str(tmp_path / "x.nc"), "--no-progress",
            *sum((["--set", f"{k}={v}"] for k, v in
                  {"zeitlin.N": N, "initial.lmax": 4, "integrator.steps": 40, "output.every": 10,
                   "output.compare": "[]", "output.figures": "false", "ensemble.members": 6,
                   "output.member_chunk": 2, "initial.kind": "file", "initial.file": str(coef)}.items()), [])]


def test_resume_is_refused_when_the_coefficient_file_changed(tmp_path, monkeypatch, capsys):
    """An interrupted run from a file resumes only with the file it started
    from: after the file changes, --resume is refused in one line and nothing
    is touched; with the file as it was, the resumed run equals an uninterrupted one."""
    rng = np.random.default_rng(3)
    C = np.tril(rng.standard_normal((6, N, N)) + 1j * rng.standard_normal((6, N, N)))
    C[:, 0, 0] = 0.0
    C[:, :, 0] = C[:, :, 0].real
    coef = write_initial(tmp_path / "coef.npz", C)
    args = _fluid_args(tmp_path, coef)
    ref = tmp_path / "ref"
    ref.mkdir()
    assert main(_fluid_args(ref, coef)) == 0
    capsys.readouterr()
    interrupt_at_chunk(monkeypatch, 2)
    assert main(args) == 143
    assert "members 0-1 kept in" in _one_line(capsys.readouterr().err)
    monkeypatch.undo()
    original = coef.read_bytes()
    write_initial(coef, 2 * C)
    before = {p: p.stat().st_mtime_ns for p in tmp_path.iterdir()}
    assert main(args + ["--resume"]) == 2
    err = _one_line(capsys.readouterr().err)
    assert err.startswith(f"liethermo: error: cannot resume {tmp_path / 'x.nc'}: initial.file {coef} has "
                          "changed since the interrupted run (sha256 ")
    assert err.endswith("; rerun without --resume to start over")
    assert {p: p.stat().st_mtime_ns for p in tmp_path.iterdir()} == before
    coef.write_bytes(original)
    assert main(args + ["--resume"]) == 0
    assert "resumed: members 0-1" in capsys.readouterr().out
    assert_cf_clean(tmp_path / "x.nc")
    a, b = liethermo.open_dataset(tmp_path / "x.nc"), liethermo.open_dataset(ref / "x.nc")
    for v in ("energy", "heat", "initial_vorticity_real", "initial_vorticity_imag"):
        np.testing.assert_array_equal(a[v].values, b[v].values, err_msg=v)


def test_a_figure_reintegrates_member_0_from_the_stored_field(tmp_path):
    """The vorticity maps of a run that did not store W integrate member 0
    again: from the coefficients the file stores, even after the source file
    is gone."""
    from liethermo.zeitlin import model as zm

    coef = write_initial(tmp_path / "c.nc", _wave, N=N)
    over = {**FLUID, "ensemble.members": 2, "initial.kind": "file", "initial.file": str(coef)}
    kept = liethermo.run("zeitlin_decay", {**over, "output.vorticity": True}, compare=False)
    liethermo.run("zeitlin_decay", over, compare=False, output=tmp_path / "x.nc")
    coef.unlink()
    with liethermo.open_dataset(tmp_path / "x.nc") as ds:
        W = zm.Fluid().member0(ds)
    want = kept["vorticity_real"].values[0] + 1j * kept["vorticity_imag"].values[0]
    np.testing.assert_allclose(W, want, atol=1e-13)
    # the stored scene itself names a file that is gone: loading it says so
    with pytest.raises(SceneError, match="scene key 'initial.file': no such file"):
        load_scene(tomllib.loads(ds.attrs["scene"]))


def _bad_fluid_files(tmp_path):
    good = _wave_coefficients()
    nan = good.copy()
    nan[3, 1] = np.nan
    upper = good.copy()
    upper[2, 4] = 1.0
    mean = good.copy()
    mean[0, 0] = 0.3
    high = np.zeros((12, 12), complex)
    high[10, 3] = 1.0
    np.save(tmp_path / "nan.npy", nan)
    np.save(tmp_path / "shape.npy", good[:, :5])
    np.save(tmp_path / "upper.npy", upper)
    np.save(tmp_path / "mean.npy", mean)
    np.save(tmp_path / "high.npy", high)
    np.save(tmp_path / "three.npy", np.stack([good] * 3))
    np.savez(tmp_path / "units.npz", initial_vorticity=good, units="rad s-1")
    np.savez(tmp_path / "name.npz", omega=good)
    write_initial(tmp_path / "ms.nc", good)
    import netCDF4

    with netCDF4.Dataset(tmp_path / "ms.nc", "a") as nc:
        nc.variables["initial_vorticity_real"].units = "ms-1"
    (tmp_path / "text.npy").write_text("not an array")
    return {
        "nan.npy": ("initial.file", "the coefficients must be finite (C[3, 1] is (nan+0j))"),
        "shape.npy": ("initial.file", "must be a triangle C[l, m] of shape (L+1, L+1) or (members, L+1, L+1), "
                                      "not (7, 5)"),
        "upper.npy": ("initial.file", "C[l, m] with m > l must be 0"),
        "mean.npy": ("initial.file", "must be 0: a vorticity on the sphere has zero mean"),
        "high.npy": ("initial.file", "the field has degrees up to l = 11, but zeitlin.N = 8 holds l ≤ 7"),
        "three.npy": ("ensemble.members", "must equal the 3 fields of initial.file"),
        "units.npz": ("initial.file", "units 'rad s-1': the coefficients must be in s-1"),
        "name.npz": ("initial.file", "a .npz file must hold the array 'initial_vorticity' (it holds omega)"),
        "ms.nc": ("initial.file", "variable initial_vorticity_real has units 'ms-1'"),
        "text.npy": ("initial.file", "cannot be read as a .npy file"),
        "missing.nc": ("initial.file", "no such file"),
        "c.txt": ("initial.file", "must be a .npy, .npz, .nc file"),
    }


def test_bad_coefficient_files_are_refused_in_one_line(tmp_path, capsys):
    """Shape, finiteness, units, a real field of zero mean within su(N), the
    member count: each refused before any work with one line naming the key,
    exit 2 on the command line, no file written."""
    inputs = tmp_path / "in"
    inputs.mkdir()
    cases = _bad_fluid_files(inputs)
    out = tmp_path / "out"
    out.mkdir()
    for name, (key, text) in cases.items():
        over = {**FLUID, "ensemble.members": 2, "initial.kind": "file", "initial.file": str(inputs / name)}
        with pytest.raises(SceneError) as exc:
            load_scene("zeitlin_decay", over)
        assert str(exc.value).startswith(f"scene key '{key}': "), (name, str(exc.value))
        assert text in str(exc.value), (name, str(exc.value))
        args = ["run", "zeitlin_decay", "-o", str(out / "x.nc"), "--no-progress"]
        for k, v in over.items():
            args += ["--set", f"{k}={'[]' if v == [] else str(v).lower() if isinstance(v, bool) else v}"]
        assert main(args) == 2, name
        err = _one_line(capsys.readouterr().err)
        assert err.startswith(f"liethermo: error: scene key '{key}': ") and text in err, (name, err)
    assert _names(out) == []
    with pytest.raises(SceneError, match=r"initial.file.: kind = \"file\" needs|needs the path"):
        load_scene("zeitlin_decay", {**FLUID, "initial.kind": "file"})
    with pytest.raises(SceneError, match="is read only with initial.kind = \"file\""):
        load_scene("zeitlin_decay", {**FLUID, "initial.file": str(inputs / "three.npy")})


def test_a_scene_that_gives_the_sha256_refuses_a_changed_file(tmp_path):
    path = write_initial(tmp_path / "c.npy", _wave_coefficients())
    sc = load_scene("zeitlin_decay", {**FLUID, "initial.kind": "file", "initial.file": str(path)})
    digest = sc["initial"]["sha256"]
    assert load_scene(sc.to_dict())["initial"]["sha256"] == digest  # the stored scene loads again
    write_initial(path, 2 * _wave_coefficients())
    with pytest.raises(SceneError, match=r"^scene key 'initial.sha256': .*c.npy has changed: its sha256 is "):
        load_scene(sc.to_dict())


def test_project_is_exact_below_N_and_refuses_a_mean():
    C = project(_wave, N)
    np.testing.assert_allclose(C[:7, :7], _wave_coefficients(), atol=1e-14)
    assert np.abs(C[7]).max() < 1e-14
    with pytest.raises(SceneError, match="zero mean"):
        write_initial("unused.npy", lambda lon, lat: 1.0 + 0 * lon * lat, N=N)


# ------------------------------------------------------------------ the top
def _top_file(tmp_path, members=3, seed=5, name="top.npz"):
    rng = np.random.default_rng(seed)
    om = rng.uniform(-1.5, 1.5, (members, 3))
    q = rng.standard_normal((members, 4))
    R = quat_to_matrix(q / np.linalg.norm(q, axis=1, keepdims=True))
    np.savez(tmp_path / name, initial_omega=om, initial_attitude=R, units="rad s-1")
    return tmp_path / name, om, R


def test_a_top_run_from_a_file_of_omega_and_attitudes(tmp_path):
    """Member k of a run from a file is the single-member run with
    initial.omega and initial.R set to the file's row k; the output stores Ω₀
    and the attitudes, and is itself a valid input file."""
    path, om, R = _top_file(tmp_path)
    ds = liethermo.run("paper", {**TOP, "ensemble.members": 3, "initial.file": str(path)}, compare=False,
                       output=tmp_path / "x.nc")
    np.testing.assert_array_equal(ds["initial_omega"].values, om)
    np.testing.assert_array_equal(ds["initial_attitude"].values, R)
    for k in range(3):
        one = liethermo.run("paper", {**TOP, "initial.omega": om[k].tolist(), "initial.R": R[k].tolist()},
                            compare=False)
        for v in ("omega", "gamma", "entropy", "total_energy"):
            np.testing.assert_array_equal(ds.liethermo[v].values[k], one.liethermo[v].values[0], err_msg=v)
    again = liethermo.run("paper", {**TOP, "ensemble.members": 3, "initial.file": str(tmp_path / "x.nc")},
                          compare=False)
    np.testing.assert_array_equal(again["omega"].values, ds["omega"].values)
    # a .npy of Ω₀ alone: the scene's initial.R for every member
    np.save(tmp_path / "om.npy", om)
    only = liethermo.run("paper", {**TOP, "ensemble.members": 3, "initial.file": str(tmp_path / "om.npy")},
                         compare=False)
    np.testing.assert_array_equal(only["initial_attitude"].values,
                                  np.repeat(np.asarray(load_scene("paper")["initial"]["R"])[None], 3, 0))


def test_a_top_resume_is_refused_when_the_file_changed(tmp_path, monkeypatch, capsys):
    path, om, R = _top_file(tmp_path / ".", members=6)
    args = ["run", "paper", "-o", str(tmp_path / "x.nc"), "--no-progress", "--set", "ensemble.members=6",
            "--set", "output.member_chunk=2", "--set", "integrator.steps=20", "--set", "output.compare=[]",
            "--set", "output.figures=false", "--set", f"initial.file={path}"]
    interrupt_at_chunk(monkeypatch, 2)
    assert main(args) == 143
    capsys.readouterr()
    monkeypatch.undo()
    np.savez(path, initial_omega=2 * om, initial_attitude=R)
    assert main(args + ["--resume"]) == 2
    err = _one_line(capsys.readouterr().err)
    assert f"cannot resume {tmp_path / 'x.nc'}: initial.file {path} has changed since the interrupted run" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == [".x.nc.partial.json", "top.npz", "x.nc.partial"]


def test_bad_top_files_are_refused_in_one_line(tmp_path, capsys):
    inputs = tmp_path / "in"
    inputs.mkdir()
    _, om, R = _top_file(inputs)
    nan = om.copy()
    nan[1, 2] = np.inf
    np.save(inputs / "nan.npy", nan)
    np.save(inputs / "shape.npy", om[:, :2])
    np.save(inputs / "ints.npy", np.array([["a", "b", "c"]] * 3))
    skew = R.copy()
    skew[2] *= 1.01
    np.savez(inputs / "rot.npz", initial_omega=om, initial_attitude=skew)
    np.savez(inputs / "count.npz", initial_omega=om, initial_attitude=R[:2])
    np.savez(inputs / "deg.npz", initial_omega=om, units="deg/s")
    import xarray as xr

    xr.Dataset({"initial_omega": (("member", "axis"), om, {"units": "deg s-1"})}).to_netcdf(inputs / "deg.nc")
    np.save(inputs / "five.npy", np.ones((5, 3)))
    cases = {
        "nan.npy": ("initial.file", "Ω₀ must be finite (member 1 is not)"),
        "shape.npy": ("initial.file", "Ω₀ must have shape (members, 3), not (3, 2)"),
        "ints.npy": ("initial.file", "Ω₀ must be real numbers"),
        "rot.npz": ("initial.file", "attitude 2 is not a rotation matrix"),
        "count.npz": ("initial.file", "2 attitudes for 3 Ω₀"),
        "deg.npz": ("initial.file", "units 'deg/s': Ω₀ must be in rad s-1"),
        "deg.nc": ("initial.file", "variable initial_omega has units 'deg s-1'; give it in rad s-1"),
        "five.npy": ("ensemble.members", "must equal the 5 members of initial.file"),
        "none.npz": ("initial.file", "no such file"),
    }
    out = tmp_path / "out"
    out.mkdir()
    for name, (key, text) in cases.items():
        with pytest.raises(SceneError) as exc:
            load_scene("paper", {"ensemble.members": 3, "initial.file": str(inputs / name)})
        assert str(exc.value).startswith(f"scene key '{key}': ") and text in str(exc.value), (name, str(exc.value))
        assert main(["run", "paper", "-o", str(out / "x.nc"), "--set", "ensemble.members=3",
                     "--set", f"initial.file={inputs / name}"]) == 2
        err = _one_line(capsys.readouterr().err)
        assert err.startswith(f"liethermo: error: scene key '{key}': ") and text in err, (name, err)
    assert _names(out) == []
    with pytest.raises(SceneError, match="'initial.sha256': is read only with initial.file"):
        load_scene("paper", {"initial.sha256": "ab" * 32})
