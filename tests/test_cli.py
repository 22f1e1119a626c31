"""Scenes and their validation (docs/scenes.md), the command line and the written dataset (docs/netcdf.md)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import numpy as np
import pytest

from liethermo import cf
from liethermo.cli import main
from liethermo.runner import run_scene
from liethermo.scene import SceneError, load_scene

# (override, key named in the message) — one case per rule of docs/scenes.md
INVALID = [
    ("body.inertia=[1e-3, 1e-3, 0.0]", "body.inertia"),       # non-positive inertia
    ("body.inertia=[1e-3, -1e-3, 1e-3]", "body.inertia"),
    ("body.inertia=[1e-3, nan, 1e-3]", "body.inertia"),       # non-finite inertia
    ("body.inertia=[1e-3, 1e-3, inf]", "body.inertia"),
    ("body.inertia=[1e-3, 1e-3, 5e-3]", "body.inertia"),      # violates the triangle inequality
    ("integrator.h=0", "integrator.h"),                        # h ≤ 0
    ("integrator.h=-0.1", "integrator.h"),
    ("integrator.h=nan", "integrator.h"),
    ("fluid.viscosity=-0.1", "fluid.viscosity"),               # μ < 0
    ("thermo.T0=0", "thermo.T0"),                              # T0 ≤ 0
    ("thermo.T0=-5", "thermo.T0"),
    ("initial.R=[[1,0,0],[0,0,-1],[0,0,1]]", "initial.R"),     # the paper's printed (singular) R0, erratum E1
    ("initial.R=[[1,0,0],[0,1,0],[0,0,-1]]", "initial.R"),     # orthogonal but a reflection
    ("initial.omega=[0, nan, 1]", "initial.omega"),            # non-finite initial data
    ("initial.omega=[0, 1]", "initial.omega"),
    ("integrator.wobble=3", "integrator.wobble"),              # unknown key
    ("physics.g=3", "physics.g"),                              # unknown section
    ("integrator.method=rk5", "integrator.method"),
    ("integrator.friction=sideways", "integrator.friction"),
    ("integrator.start=late", "integrator.start"),
    ("integrator.steps=0", "integrator.steps"),
    ("integrator.steps=1.5", "integrator.steps"),
    ("output.every=7", "output.every"),                        # must divide steps (300)
    ("ensemble.members=0", "ensemble.members"),
    ("body.radius=0", "body.radius"),
    ("body.upper_mass_fraction=1.2", "body.upper_mass_fraction"),
    ("gravity.g=-9.81", "gravity.g"),
    ("output.compare=['rk9']", "output.compare"),
]


@pytest.mark.parametrize("override,key", INVALID)
def test_invalid_input_is_rejected_naming_the_key(override, key, tmp_path, capsys):
    """Every invalid input: exit status 2, one line naming the key, no output file, no traceback."""
    out = tmp_path / "x.nc"
    rc = main(["run", "paper", "-o", str(out), "--set", override])
    err = capsys.readouterr().err
    assert rc == 2
    assert f"'{key}'" in err, err
    assert "Traceback" not in err
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_invalid_input_subprocess_exit_code(tmp_path):
    """The console command itself: non-zero exit, the message, no file."""
    out = tmp_path / "bad.nc"
    p = subprocess.run([sys.executable, "-m", "liethermo.cli", "run", "paper", "-o", str(out),
                        "--set", "integrator.h=-1"], capture_output=True, text=True)
    assert p.returncode == 2
    assert "scene key 'integrator.h': must be > 0" in p.stderr
    assert "Traceback" not in p.stderr
    assert not out.exists()


def test_console_run_leaves_complete_files(tmp_path):
    """The console command (which leaves by os._exit after `run`) exits 0 with its
    summary printed and every file it wrote complete: both datasets with all
    their steps, and the four figures."""
    out = tmp_path / "p.nc"
    p = subprocess.run([sys.executable, "-m", "liethermo.cli", "run", "paper", "-o", str(out),
                        "--no-progress", "--set", "integrator.steps=40"],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert p.stdout.count("wrote ") == 2
    assert p.stdout.rstrip().endswith(f"{tmp_path / 'p_entropy.png'}")
    for path in (out, tmp_path / "p_rk2.nc"):
        with cf.open_dataset(path) as ds:
            assert ds.sizes["t"] == 41
            assert np.isfinite(ds["omega"].values[0, :20]).all()
    pngs = sorted(f.name for f in tmp_path.glob("*.png"))
    assert len(pngs) == 4
    for f in tmp_path.glob("*.png"):
        assert f.read_bytes().endswith(b"IEND\xaeB`\x82")  # PNG trailer: not truncated


def test_missing_scene_file_is_reported(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nope.toml")]) == 2
    err = capsys.readouterr().err
    assert f"scene file '{tmp_path / 'nope.toml'}': not found" in err and err.count("\n") == 1


def test_toml_scene_file_and_overrides(tmp_path):
    f = tmp_path / "spin.toml"
    f.write_text('[integrator]\nmethod = "rk4"\nh = 0.05\nsteps = 40\n[initial]\nomega = [2.0, -1.0, 0.5]\n')
    sc = load_scene(f, ["integrator.h=0.025", "integrator.friction=endpoint"])
    assert sc["scene"]["name"] == "spin"
    assert sc["integrator"]["method"] == "rk4"
    assert sc["integrator"]["h"] == 0.025            # --set wins over the file
    assert sc["integrator"]["friction"] == "endpoint"  # bare word taken as a string
    assert sc["initial"]["omega"] == (2.0, -1.0, 0.5)  # list values are tuples in the typed scene
    assert sc["fluid"]["viscosity"] == 0.1            # defaults are the paper's values


def test_unknown_key_in_file(tmp_path):
    f = tmp_path / "typo.toml"
    f.write_text("[fluid]\nviscosoty = 0.2\n")
    with pytest.raises(SceneError, match="'fluid.viscosoty'"):
        load_scene(f)


@pytest.mark.parametrize("value,message", [(0, "must be ≥ 1"), (201, "must be ≤ 200"), (10**6, "must be ≤ 200"),
                                           (2.5, "must be an integer"), (True, "must be an integer")])
def test_newton_maxiter_bounded(value, message):
    """A Newton limit in the millions would make one kernel call outlast a stop
    signal: it is refused, naming the key."""
    with pytest.raises(SceneError, match=f"integrator.newton_maxiter.*{message}"):
        load_scene("paper", [f"integrator.newton_maxiter={str(value).lower()}"])
    assert load_scene("paper", ["integrator.newton_maxiter=200"])["integrator"]["newton_maxiter"] == 200


def test_paper_scene_derived_values():
    """The derived values of docs/model.md, "The paper scene"."""
    from liethermo.top.physics import physics_of_scene

    b = physics_of_scene(load_scene("paper"))
    assert b.mass[0] == pytest.approx(1.4137166941154071, rel=1e-15)
    np.testing.assert_allclose(b.center_of_mass[0], [0.0, 0.0, 0.00125], rtol=1e-12)
    np.testing.assert_allclose(b.stokes_resistance[0], 3.1415926535897936e-4, rtol=1e-15)
    assert b.isotropic_resistance
    assert b.heat_capacity[0] == pytest.approx(1306.9263327416309, rel=1e-15)
    np.testing.assert_allclose(b.inertia[0], [6.6783e-4, 6.6783e-4, 1.31947e-3], rtol=1e-4)
    np.testing.assert_allclose(b.gravity_torque[0], b.mass[0] * 9.81 * b.center_of_mass[0], rtol=1e-15)


def _small(members=1, **kw):
    """A short paper run storing every variable (these tests read derived ones)."""
    over = {"integrator": {"steps": 40}, "ensemble": {"members": members}, "output": {"variables": "all"}}
    for k, v in kw.items():
        s, key = k.split("__")
        over.setdefault(s, {})[key] = v
    return load_scene("paper", over)


def test_members_1_uses_the_scene_initial_data_exactly():
    """One member starts from initial.omega exactly: the node velocity Ω(0) of
    RK and of the VI's Legendre start; the paper's node start takes it as
    the first step velocity Ω₀ instead."""
    w = [0.3, -0.2, 1.7]
    for method, start, var in (("vi", "legendre", "omega"), ("rk4", "legendre", "omega"),
                               ("vi", "node", "omega_step")):
        ds, _ = run_scene(_small(initial__omega=w, integrator__method=method, integrator__start=start),
                          progress=False)
        np.testing.assert_array_equal(ds["initial_omega"].values[0], w)
        np.testing.assert_array_equal(ds[var].values[0, 0], w)
        np.testing.assert_array_equal(ds["gamma"].values[0, 0], [0.0, 1.0, 0.0])  # Γ0 = R0ᵀe3 (E1)


def test_seed_reproducible_and_distribution():
    a, _ = run_scene(_small(members=64, ensemble__seed=7), progress=False)
    b, _ = run_scene(_small(members=64, ensemble__seed=7), progress=False)
    c, _ = run_scene(_small(members=64, ensemble__seed=8), progress=False)
    np.testing.assert_array_equal(a["omega"].values, b["omega"].values)
    assert not np.array_equal(a["initial_omega"].values, c["initial_omega"].values)
    w = np.linalg.norm(a["initial_omega"].values, axis=1)
    assert np.all((w >= 0.5 * np.sqrt(2)) & (w <= 1.5 * np.sqrt(2)))  # spin_range × |Ω0|
    R = a["initial_attitude"].values
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-14)


def test_member_chunking_does_not_change_results():
    """Chunked runs (bounded memory) give the same numbers as one chunk."""
    a, _ = run_scene(_small(members=50, output__member_chunk=7), progress=False)
    b, _ = run_scene(_small(members=50), progress=False)
    np.testing.assert_array_equal(a["omega"].values, b["omega"].values)
    np.testing.assert_array_equal(a["member"].values, np.arange(50))


def test_energy_error_without_cancellation():
    """E_k − E_0 computed from differences agrees with the naive difference of totals
    to the naive difference's own round-off, and is far more precise."""
    ds, _ = run_scene(_small(integrator__start="legendre"), progress=False)  # node 0 is Ω(0)
    naive = ds["total_energy"] - ds["total_energy"].isel(t=0)
    E = float(ds["total_energy"].values[0, 0])
    assert E == pytest.approx(3.9e5, rel=0.02)  # c_v T0 dominates (docs/model.md, "The paper scene")
    assert np.abs(ds["energy_error"] - naive).max() < 8 * np.finfo(float).eps * E
    assert ds["energy_error"].values[0, 0] == 0.0


def test_paper_command_writes_files_and_figures(tmp_path):
    """`liethermo run paper`: VI completes, RK2 at h = 0.1 is flagged non-finite, 4 figures."""
    out = tmp_path / "paper.nc"
    assert main(["run", "paper", "-o", str(out), "--no-progress"]) == 0
    vi = cf.open_dataset(out)
    rk2 = cf.open_dataset(tmp_path / "paper_rk2.nc")
    assert vi.attrs["method"] == "vi" and rk2.attrs["method"] == "rk2"
    assert int(vi["status"].values[0]) == 0
    assert rk2["status"].attrs["flag_meanings"].split()[int(rk2["status"].values[0])] == "non_finite"
    k = int(rk2["failed_at_step"].values[0])
    assert 0 < k <= 300
    assert np.all(np.isnan(rk2["omega"].values[0, k:]))            # stops advancing: NaN after
    assert np.all(np.isfinite(rk2["omega"].values[0, :k]))
    assert np.isfinite(vi["omega"].values).all()
    assert vi.sizes["t"] == 301 and float(vi["t"][-1]) == pytest.approx(30.0)
    for name in ("center_of_mass", "energies", "total_energy", "entropy"):
        png = tmp_path / f"paper_{name}.png"
        assert png.stat().st_size > 10_000
    vi.close()
    rk2.close()


def test_figures_are_named_as_the_primary_file(tmp_path, monkeypatch):
    """Without -o, a run of another method writes its own figures beside its
    own file and leaves the first run's figures alone."""
    monkeypatch.chdir(tmp_path)
    small = ["--no-progress", "--set", "ensemble.members=2", "--set", "integrator.steps=20"]
    assert main(["run", "paper", *small]) == 0
    runs = tmp_path / "data" / "runs"
    first = {p.name: p.read_bytes() for p in runs.glob("*.png")}
    assert "paper_vi_energies.png" in first and not any(n.startswith("paper_rk4") for n in first)
    assert main(["run", "paper", *small, "--set", "integrator.method=rk4", "--set", "output.compare=[]"]) == 0
    assert (runs / "paper_rk4.nc").exists() and (runs / "paper_rk4_energies.png").exists()
    assert {n: (runs / n).read_bytes() for n in first} == first


def test_dataset_contract_plain_xarray(tmp_path):
    """Opened by plain xarray without importing liethermo, as docs/netcdf.md shows:
    t as float seconds since the start of the run (no calendar, nothing to
    decode, no warning), the axis labels as a CF label variable that one line
    makes the index again;
    units and long_name on every variable; CF flags on status; provenance
    attributes, with the API call that made the file in 'history'."""
    out = tmp_path / "r.nc"
    # a file with every variable (the default holds the state: tests/test_output_variables.py)
    _, summ = run_scene(_small(members=3, integrator__method="rk4", output__variables="all"), out, progress=False)
    code = f"""
import sys, warnings, numpy as np, xarray as xr
warnings.simplefilter("error")
ds = xr.open_dataset({str(out)!r})
ds = ds.assign_coords({{v[:-6]: ds[v].values for v in ds.coords if v.endswith("_label")}})
assert 'liethermo' not in sys.modules
missing = [v for v in ds.variables if v not in ds.dims
           and ('units' not in ds[v].attrs or 'long_name' not in ds[v].attrs)]
assert not missing, missing
for v in ['omega','gamma','entropy','temperature','kinetic_energy','potential_energy','internal_energy',
          'total_energy','energy_error','status']:
    assert v in ds, v
assert ds['omega'].dims == ('member','t','axis') and list(ds['axis'].values) == ['x','y','z']
assert list(ds['axis_label'].values) == ['x','y','z'] and 'step' in ds.coords
assert float(ds['omega'].sel(axis='z').isel(member=0, t=0)) == float(ds['omega'][0, 0, 2])
assert ds['energy_error'].dims == ('member','t')
assert ds['t'].dtype == np.float64 and np.allclose(ds['t'].values, 0.1 * np.arange(ds.sizes['t']))
assert ds['t'].attrs['units'] == 's' and 'calendar' not in ds['t'].attrs and 'time' not in ds.variables
assert ds['omega'].attrs['units'] == 'rad s-1'
assert list(ds['status'].attrs['flag_values']) == [0, 1, 2]
assert ds['status'].attrs['flag_meanings'] == 'ok newton_not_converged non_finite'
for a in ['Conventions','history','method','h','friction','start','scene','software_version','created']:
    assert a in ds.attrs, a
assert ds.attrs['Conventions'] == 'CF-1.11'
assert ds.attrs['history'].startswith(ds.attrs['created'] + ': liethermo.runner.run_scene(')
assert {str(out)!r} in ds.attrs['history']
assert ds.attrs['method'] == 'rk4' and '[integrator]' in ds.attrs['scene']
print('OK')
"""
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0 and "OK" in p.stdout, p.stderr
    assert summ.path == out


def test_killed_run_leaves_no_file_at_the_output_path(tmp_path):
    """A run killed mid-way leaves no file at the output path (atomic write)."""
    out = tmp_path / "long.nc"
    p = subprocess.Popen([sys.executable, "-m", "liethermo.cli", "run", "paper", "-o", str(out),
                          "--no-progress", "--set", "ensemble.members=20000", "--set", "integrator.steps=100000",
                          "--set", "output.every=50000", "--set", "output.member_chunk=100",
                          "--set", "output.compare=[]", "--set", "output.figures=false",
                          "--set", "output.attitude=false"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while time.time() < deadline and not any(tmp_path.glob(".long.nc.*.tmp")):
        assert p.poll() is None, "the run ended before it was killed"
        time.sleep(0.2)
    assert any(tmp_path.glob(".long.nc.*.tmp")), "the run never started writing"
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    assert not out.exists()


def test_progress_summary_is_printed(tmp_path, capsys):
    out = tmp_path / "s.nc"
    assert main(["run", "paper", "-o", str(out), "--no-progress", "--set", "output.compare=[]",
                 "--set", "output.figures=false", "--set", "ensemble.members=4"]) == 0
    text = capsys.readouterr().out
    for needle in ("4 member(s) x 300 steps", "member-steps/s", "ok: 4", "max |E_k - E_0|",
                   "max ||Gamma| - 1|", "Newton iterations         mean",
                   "per solve (one per step)", "in one solve", "wrote"):
        assert needle in text, needle


def test_blow_up_ensemble_labels_without_warnings():
    """RK2 at the paper's h: members blow up through huge finite values; labelling them
    must not warn (pytest runs with warnings as errors) and must keep healthy members."""
    ds, summ = run_scene(_small(members=64, integrator__method="rk2", integrator__steps=300), progress=False)
    st = ds["status"].values
    assert 0 < np.sum(st == 2) < 64, "expected a mixed ensemble at h = 0.1"
    assert summ.status_counts["non_finite"] == int(np.sum(st == 2))
    ok = st == 0
    assert np.isfinite(ds["energy_error"].values[ok]).all()
    assert summ.first_fail_step == int(ds["failed_at_step"].values[~ok].min()) > 0
    text = "\n".join(summ.lines())
    assert f"first failure at step {summ.first_fail_step} " in text
    # completed members whose energy error passed E_mech,0 are counted beside "ok"
    rel = np.abs(ds["energy_error"].values[ok]) / np.abs(ds["mechanical_energy_initial"].values[ok])[:, None]
    diverged = int(np.sum(rel.max(axis=1) > 1.0))
    assert f"ok: {int(ok.sum())} (of which {diverged} diverged: max |E_k - E_0| > 1 x E_mech,0)" in text
    assert "newton_not_converged" not in text and "Newton" not in text  # RK2 has no Newton solve


def test_summary_reads_at_any_scale():
    """A blown-up ensemble's huge numbers print in exponent form, not in hundreds of
    digits; a temperature that did not change prints once, not as a range."""
    import re

    from liethermo.top.findings import finding_lines
    from liethermo.top.model import RunSummary

    s = RunSummary("paper", "rk2", 200000, 300, 0.1, wall_time=3.5, kernel_time=1e-4, compile_time=0.2,
                   status_counts={"ok": 82370, "newton_not_converged": 0, "non_finite": 117630},
                   max_abs_energy_error=1.4e240, max_rel_energy_error=7.7e241, max_gamma_defect=3.2e70,
                   max_h_omega=1.4395e71, diverged=1040,
                   findings={"heating": [1e-5, 2.7e240], "T_start": [300.0, 300.0],
                             "T_end": [300.0, 300.00001]})
    text = "\n".join(s.lines())
    assert not re.search(r"[0-9]{9,}", text.replace("200000", "").replace("117630", "")), text
    assert "max h|Omega|              1.44e+71 rad" in text
    assert "ok: 82370 (of which 1040 diverged" in text and "newton_not_converged" not in text
    heating = finding_lines(s.findings)[0]
    assert "T(0) = 300 K; T(end) = 300 K)" in heating and "2.7e+240 K over the members" in heating


def test_summary_of_a_run_where_every_member_failed():
    """No member completed: the summary says so and when the first one failed,
    instead of printing NaN accuracy figures."""
    _, summ = run_scene(_small(members=1, integrator__method="rk2", integrator__steps=300),
                        progress=False)
    assert summ.status_counts["ok"] == 0
    text = "\n".join(summ.lines())
    assert "no member completed" in text and "nan" not in text
    assert summ.first_fail_step == 142  # the paper's RK2 at h = 0.1 (t = 14.2 s)


@pytest.mark.parametrize("preset,expected", [(None, "2"), ("3", "3")])
def test_console_script_compiles_at_O2_unless_told(monkeypatch, preset, expected):
    """entry() sets NUMBA_OPT=2 for the process before numba is imported (same
    results, faster cold start), and leaves a user's own setting alone."""
    from liethermo.cli import entry

    if preset is None:
        monkeypatch.delenv("NUMBA_OPT", raising=False)
    else:
        monkeypatch.setenv("NUMBA_OPT", preset)
    monkeypatch.setattr(sys, "argv", ["liethermo", "study", "--help"])
    with pytest.raises(SystemExit):
        entry()
    assert os.environ["NUMBA_OPT"] == expected


def test_console_script_process_runs_at_O2(tmp_path):
    code = ("import sys; sys.argv = ['liethermo', 'study', '--help'];"
            "from liethermo.cli import entry\n"
            "try:\n    entry()\nexcept SystemExit:\n    pass\n"
            "import numba; print('OPT', int(numba.config.OPT))")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_OPT"}
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert "OPT 2" in p.stdout, p.stderr


def test_set_lists_take_bare_words_as_strings(tmp_path):
    """``--set output.compare=[rk4, rk2]`` needs no TOML quotes, like a bare word."""
    from liethermo.scene import load_scene, parse_override

    assert parse_override("output.compare=[rk4, rk2]") == ("output", "compare", ["rk4", "rk2"])
    assert parse_override('output.compare=[rk4, "rk2"]') == ("output", "compare", ["rk4", "rk2"])
    assert parse_override("initial.omega=[2, -1, 0.5]") == ("initial", "omega", [2, -1, 0.5])
    assert list(load_scene("paper", ["output.compare=[rk4, rk2]"])["output"]["compare"]) == ["rk4", "rk2"]
    out = tmp_path / "p.nc"
    assert main(["run", "paper", "-o", str(out), "--no-progress", "--set", "ensemble.members=2",
                 "--set", "integrator.steps=10", "--set", "output.figures=false",
                 "--set", "output.compare=[rk4]"]) == 0
    assert (tmp_path / "p_rk4.nc").exists() and not (tmp_path / "p_rk2.nc").exists()


def test_set_list_of_a_bad_bare_word_names_the_key(capsys):
    assert main(["run", "paper", "--check", "--set", "output.compare=[rk5]"]) == 2
    err = capsys.readouterr().err
    assert "output.compare" in err and "rk5" in err


def test_check_estimates_the_kernel_time_of_each_method(tmp_path, capsys):
    """--check times a probe of the scene's own members on the run's kernel and
    scales it: ten times the steps, about ten times the time."""
    import re

    base = ["run", "paper", "-o", str(tmp_path / "p.nc"), "--check", "--set", "ensemble.members=20000",
            "--set", "output.every=100"]
    est = {}
    for steps in (1000, 10000):
        assert main([*base, "--set", f"integrator.steps={steps}"]) == 0
        out = capsys.readouterr().out
        found = dict(re.findall(r"^  (\w+): about (\S+) s of kernel time on this machine", out, re.M))
        assert set(found) == {"vi", "rk2"}, out
        est[steps] = {m: float(v) for m, v in found.items()}
    for m in ("vi", "rk2"):
        assert 3 < est[10000][m] / est[1000][m] < 30, est
    assert not list(tmp_path.iterdir())  # a check writes nothing


def test_help_describes_both_models_and_lists_every_builtin_scene(capsys):
    """``liethermo --help`` names the Zeitlin fluid beside the top, and ``run --help``
    lists every built-in scene under its model."""
    from liethermo.scene import builtin_scenes

    with pytest.raises(SystemExit):
        main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "heavy top" in text and "Zeitlin fluid" in text
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    fluid = text[text.index("the Zeitlin fluid:"):text.index("the fluid on the torus:")]
    torus = text[text.index("the fluid on the torus:"):]
    for name in builtin_scenes():
        assert name in text and (name in fluid) == name.startswith("zeitlin"), name
        assert (name in torus) == name.startswith("torus"), name


def test_check_warns_of_an_output_conflict_and_still_estimates(tmp_path, capsys):
    """After a run, --check of another scene into the same output says the run would be
    refused (a warning on stderr, exit 0) and still prints its estimates; the file is kept."""
    out = tmp_path / "p.nc"
    small = ["--set", "output.compare=[]", "--set", "output.figures=false", "--no-progress"]
    assert main(["run", "paper", "-o", str(out), "--set", "ensemble.members=2", "--set",
                 "integrator.steps=20", *small]) == 0
    before = out.stat().st_mtime_ns
    capsys.readouterr()
    assert main(["run", "paper", "-o", str(out), "--check", "--set", "ensemble.members=1000",
                 "--set", "integrator.steps=20", *small]) == 0
    cap = capsys.readouterr()
    assert (f"liethermo: warning: the run would be refused: {out} exists and holds a run of another scene, "
            "differing in ensemble.members") in cap.err
    assert "on disk" in cap.out and "vi: about" in cap.out and "of kernel time on this machine" in cap.out
    assert out.stat().st_mtime_ns == before
    assert main(["run", "paper", "-o", str(out), "--set", "ensemble.members=1000", "--set",
                 "integrator.steps=20", *small]) == 2  # the run itself is refused
    assert "exists and holds a run of another scene" in capsys.readouterr().err


def test_check_of_a_fluid_scene_estimates_time_and_memory(tmp_path, capsys):
    """--check of a Zeitlin scene gives the basis's and each method's time and memory,
    and warns of N = 1024 (a set-up of minutes, 8.6 GB, a run of hours or more)."""
    import re

    base = ["run", "zeitlin_decay", "-o", str(tmp_path / "z.nc"), "--check"]
    assert main(base) == 0
    cap = capsys.readouterr()
    assert "split: about" in cap.out and "rk4: about" in cap.out and "in all: about" in cap.out
    assert "warning" not in cap.err
    assert main([*base, "--set", "zeitlin.N=1024"]) == 0
    cap = capsys.readouterr()
    assert re.search(r"basis of su\(1024\): about [0-9.]+ (s|min) and 8.6 GB to build \(timed at N = 128", cap.out)
    assert re.search(r"liethermo: warning: this run would take about [0-9.]+ (h|days) on this machine", cap.err)
    assert ("liethermo: warning: split's fixed point will probably not converge at N = 1024 and h = 0.01 s"
            in cap.err and "(h = 0.107 s) they did not" in cap.err and "At h = 0.005 s it converged" in cap.err)
    assert not list(tmp_path.iterdir())  # a check writes nothing


def test_check_foretells_a_fixed_point_that_will_not_converge_and_the_run_bears_it_out(tmp_path, capsys):
    """The splitting's fixed point contracts by a factor that depends on h·N: --check probes it at
    N = 96 with the run's h·N, warns where it fails and names a step that converges; the runs at
    N = 192 agree (h·N = 10.2: the member stops at its first step; 5.1: 40 iterations)."""
    from liethermo.cf import open_dataset

    out = tmp_path / "z.nc"
    base = ["run", "zeitlin_decay", "-o", str(out), "--no-progress", "--set", "zeitlin.N=192", "--set",
            "ensemble.members=1", "--set", "integrator.steps=1", "--set", "output.every=1", "--set",
            "output.compare=[]", "--set", "output.figures=false"]
    for h, fails in ((0.0533, True), (0.0267, False)):
        assert main([*base, "--set", f"integrator.h={h}", "--check"]) == 0
        err = capsys.readouterr().err
        warned = f"split's fixed point will probably not converge at N = 192 and h = {h} s" in err
        assert warned == fails, err
        if fails:
            assert "At h = 0.0267 s it converged" in err
        assert main([*base, "--set", f"integrator.h={h}"]) == 0
        with open_dataset(out) as ds:
            assert (int(ds["status"].values[0]) == 1) == fails  # fixed_point_not_converged
        out.unlink()
    # rk4 solves no fixed point: its members blowing up (non_finite at h = 5 s) is not called one
    rk4 = ["run", "zeitlin_decay", "-o", str(out), "--set", "zeitlin.N=32", "--set", "integrator.h=5", "--set",
           'integrator.method="rk4"', "--set", "output.compare=[]", "--set", "integrator.steps=5", "--set",
           "output.every=1"]
    assert main([*rk4, "--check"]) == 0
    assert "fixed point" not in capsys.readouterr().err
    # a run at N >= 256 estimates itself before it starts, and says so without --check
    assert main([*base, "--set", "zeitlin.N=256", "--set", "integrator.h=0.04"]) == 0
    assert "split's fixed point will probably not converge at N = 256 and h = 0.04 s" in capsys.readouterr().err


def test_fluid_estimates_memory_of_the_basis_it_builds():
    """The estimate's basis size is what kernels.basis holds (two copies of S numbers)."""
    from liethermo.zeitlin import kernels as zk
    from liethermo.zeitlin.estimate import basis_bytes, basis_numbers

    b = zk.basis(24)
    assert b.vecs.nbytes + b.vecs_t.nbytes == 16 * basis_numbers(24) == basis_bytes(24) * 2 // 3
    assert basis_numbers(24) == sum((24 - d) ** 2 for d in range(24))
    assert basis_bytes(24, cached=True) == b.vecs.nbytes + b.vecs_t.nbytes


def test_a_basis_in_the_disk_cache_is_counted_as_read_not_built(tmp_path, monkeypatch):
    """The run layer's memory for a fluid scene counts the build's peak (24·S) while the
    basis must be built, and the two copies a read leaves (16·S) once the cache holds it."""
    from liethermo import load_scene
    from liethermo.models import model_of
    from liethermo.zeitlin import kernels as zk
    from liethermo.zeitlin.estimate import basis_numbers

    monkeypatch.setenv("LIETHERMO_CACHE_DIR", str(tmp_path / "cache"))
    sc = load_scene("zeitlin_decay", {"zeitlin.N": 20, "ensemble.members": 2})
    built = model_of(sc).estimate(sc).memory
    zk.basis.cache_clear()
    zk.basis(20)  # built and stored
    assert zk.basis_on_disk(20)
    assert built - model_of(sc).estimate(sc).memory == 8 * basis_numbers(20)


def test_the_basis_build_time_is_this_machines_timed_probe_scaled_by_n_cubed(monkeypatch):
    """basis_seconds times a build of su(BASIS_PROBE_N) here (not a constant measured
    elsewhere) and scales it by N³."""
    import time

    from liethermo.zeitlin import estimate as ze
    from liethermo.zeitlin import kernels as zk

    calls = []

    def slow_build(N):
        calls.append(N)
        time.sleep(0.05)

    monkeypatch.setattr(zk, "compute_basis", slow_build)
    ze.basis_seconds_per_n3.cache_clear()
    try:
        s = ze.basis_seconds(1024)
        assert calls == [ze.BASIS_PROBE_N] * 2
        assert 0.05 * 8 ** 3 <= s < 0.08 * 8 ** 3, s
        ze.basis_seconds(512)
        assert len(calls) == 2  # timed once per process
    finally:
        ze.basis_seconds_per_n3.cache_clear()


def test_a_long_run_says_how_long_before_it_starts(tmp_path, monkeypatch, capsys):
    from liethermo import cli
    from liethermo.top import model as heavy_top

    monkeypatch.setattr(heavy_top, "LONG_RUN_MEMBER_STEPS", 100)
    monkeypatch.setattr(cli, "LONG_RUN_SECONDS", 0.0)
    out = tmp_path / "p.nc"
    assert main(["run", "paper", "-o", str(out), "--no-progress", "--set", "ensemble.members=4",
                 "--set", "integrator.steps=50", "--set", "output.figures=false",
                 "--set", "output.compare=[]"]) == 0
    err = capsys.readouterr().err
    assert f"liethermo: {out}:   vi: about" not in err and f"liethermo: {out}: vi: about" in err, err
    assert "of kernel time on this machine" in err


def test_python_m_liethermo_and_the_study_help_lists_kinds_and_files():
    """``python -m liethermo`` is the command line; ``liethermo study --help`` names
    the shipped study files and every study kind (and how to add one's own)."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "liethermo", "study", "--help"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    text = " ".join(r.stdout.split())
    from liethermo.studies import kinds, shipped_studies

    assert shipped_studies() and all(name in text for name in shipped_studies())
    assert all(kind in text for kind in kinds()) and "mypackage.mystudy" in text
    r = subprocess.run([sys.executable, "-m", "liethermo", "keys"], capture_output=True, text=True)
    assert r.returncode == 0 and "integrator.h [s]" in r.stdout


def test_a_basis_build_is_announced_when_this_machine_would_take_long(monkeypatch, capsys):
    """build_basis announces (and times) a build only when this machine's timed rate
    says it takes more than two seconds; a build that cannot take long is not probed."""
    from liethermo.zeitlin import estimate as ze
    from liethermo.zeitlin import kernels as zk

    built, rates = [], iter([3.0 / 512 ** 3, 1.0 / 512 ** 3])
    monkeypatch.setattr(zk, "basis", built.append)
    monkeypatch.setattr(zk, "basis_on_disk", lambda N: False)
    monkeypatch.setattr(ze, "basis_seconds_per_n3", lambda: next(rates))
    ze.build_basis(512)
    err = capsys.readouterr().err
    assert "liethermo: building the basis of su(512): about 3 s and 1.08 GB" in err and "built in" in err
    ze.build_basis(512)
    assert capsys.readouterr().err == ""
    ze.build_basis(64)  # 1.7e-7 s x 64³ = 0.04 s at most: not even probed
    assert capsys.readouterr().err == "" and built == [512, 512, 64]
    assert next(rates, None) is None
