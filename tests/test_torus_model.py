"""The fluid on the torus through the one run layer: its scenes and keys, per-member
ensembles, chunks, resume after SIGKILL, CF-clean files, --check, figures."""

from __future__ import annotations

import re

import numpy as np
import pytest

from cfcheck import assert_cf_clean
from conftest import kill_and_resume
from liethermo.cf import open_dataset
from liethermo.cli import main
from liethermo.runner import run_scene
from liethermo.scene import SceneError, load_scene
from liethermo.torus.kernels import STATUS_MEANINGS
from ncsame import same_but_created

SMALL = ["torus.N=9", "ensemble.members=5", "output.member_chunk=2", "integrator.steps=20", "output.every=5",
         "output.compare=[]", "output.figures=false"]
SCENES = ("torus_euler", "torus_decay", "torus_convection")


def _sets(over):
    return [a for s in over for a in ("--set", s)]


def _over(over):
    return dict(s.split("=", 1) for s in over)


def test_torus_scenes_and_their_keys(capsys):
    for name in SCENES:
        sc = load_scene(name)
        assert type(sc).__name__ == "TorusScene" and sc["torus"]["N"] % 2 == 1
    with pytest.raises(SceneError, match="odd"):
        load_scene("torus_euler", {"torus.N": 12})
    # the top's heat capacity is refused on a torus scene, in one line naming the areal key
    with pytest.raises(SceneError, match="thermo.areal_heat_capacity"):
        load_scene("torus_decay", {"thermo.heat_capacity": 2.0})
    assert main(["run", "torus_decay", "--set", "thermo.heat_capacity=2", "--check"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'thermo.heat_capacity'" in err and "thermo.areal_heat_capacity" in err
    # and keeps the top's meaning on a top scene (J K-1)
    assert load_scene("paper", {"thermo.heat_capacity": 2.0})["thermo"]["heat_capacity"] == 2.0
    # the order-4 composition only at ν = κ = 0, in one line
    with pytest.raises(SceneError, match="ν = κ = 0 only"):
        load_scene("torus_decay", {"integrator.method": "cmp4"})
    assert load_scene("torus_euler", {"integrator.method": "cmp4"})["integrator"]["method"] == "cmp4"


def test_members_are_reproducible_and_chunks_give_the_same_bits(tmp_path):
    from liethermo.torus.run import initial_fields

    sc = load_scene("torus_decay", {"torus.N": 9, "ensemble.members": 6})
    W, S = initial_fields(sc, np.arange(6))
    W2, S2 = initial_fields(sc, np.array([4, 1]))
    assert np.array_equal(W2, W[[4, 1]]) and np.array_equal(S2, S[[4, 1]])
    assert not np.allclose(W[0], W[1])  # members differ
    from liethermo.torus import kernels as tk

    assert np.allclose(tk.kinetic_energy(W, tk.basis(9)), 1.0, rtol=1e-12)  # initial.energy = 1 J each
    # the same coefficients at every N
    f9 = tk.to_modes(W[0], tk.basis(9))
    W15, _ = initial_fields(load_scene("torus_decay", {"torus.N": 15}), np.arange(1))
    f15 = tk.to_modes(W15[0], tk.basis(15))
    k = np.arange(-4, 5)
    assert np.allclose(f9[np.ix_(k % 9, k % 9)], f15[np.ix_(k % 15, k % 15)], rtol=0, atol=1e-14)
    over = SMALL + ["output.vorticity=true", "output.entropy_field=true"]
    run_scene("torus_decay", tmp_path / "a.nc", overrides=over, progress=False)
    ds, summ = run_scene("torus_decay", None, overrides=over, progress=False)
    from liethermo.cf import open_dataset

    with open_dataset(tmp_path / "a.nc") as a:
        for name in ("total_energy", "entropy", "vorticity_real", "entropy_density_imag", "theta_min"):
            assert a[name].values.tobytes() == ds[name].values.tobytes(), name
        assert float(a["t"][1]) == 0.05
    assert summ.stats.members == 5 and summ.stats.failed == 0


@pytest.mark.parametrize("name", SCENES)
def test_a_torus_file_is_cf_clean_and_keeps_its_laws(tmp_path, name):
    out = tmp_path / f"{name}.nc"
    ds, summ = run_scene(name, out, overrides=SMALL + ["output.vorticity=true", "output.entropy_field=true"],
                         progress=False)
    assert_cf_clean(out)
    from liethermo.cf import open_dataset

    with open_dataset(out) as ds:
        for v in ("kinetic_energy", "internal_energy", "potential_energy", "total_energy", "entropy", "enstrophy",
                  "theta_min", "theta_max", "temperature_min", "temperature_max", "casimir"):
            assert v in ds and ds[v].attrs["units"], v
        H = ds["total_energy"].values
        assert np.abs(H - H[:, :1]).max() <= 1e-13 * np.abs(H).max()  # CMP: H to round-off
        assert (np.diff(ds["entropy"].values, axis=1) >= -1e-14 * 4 * np.pi**2).all()
    lines = "\n".join(summ.lines())
    assert "conduction:" in lines and "sub-step(s)" in lines
    assert f"  wall time {summ.wall_time:.3g} s (the run:" in lines and summ.wall_time > 0  # what --check estimates


def test_check_says_disk_memory_and_time(tmp_path, capsys):
    assert main(["run", "torus_convection", "-o", str(tmp_path / "c.nc"), "--check", *_sets(SMALL)]) == 0
    out = capsys.readouterr().out
    assert re.search(r"on disk", out) and re.search(r"of memory", out) and "ms per member-step" in out, out
    assert not (tmp_path / "c.nc").exists()


def test_check_warns_when_its_probe_member_stops_and_the_run_bears_it_out(tmp_path, capsys):
    """--check times the run's first steps of one member; where that member stops (a fixed point
    that does not converge, rk4 blowing up at a step far too large) it says the run's members
    will probably stop too, and they do; at the scene's own step it says nothing of the kind."""
    out = tmp_path / "d.nc"
    for method, h, why in (("isomp", 20, "fixed_point_not_converged"), ("rk4", 20, "non_finite"),
                           ("isomp", 0.01, None)):
        args = ["run", "torus_decay", "-o", str(out), "--no-progress", *_sets(
            [f'integrator.method="{method}"', f"integrator.h={h}", "integrator.steps=3", "output.every=1",
             "output.compare=[]", "output.figures=false"])]
        assert main([*args, "--check"]) == 0
        err = capsys.readouterr().err
        assert ("the timed probe's first member stopped with" in err) == (why is not None), err
        assert main(args) == 0
        summary = capsys.readouterr().out
        assert ("fixed-point iterations" in summary) == (method != "rk4"), summary  # rk4 solves none
        with open_dataset(out) as ds:
            got = {STATUS_MEANINGS[int(k)] for k in ds["status"].values}
        if why is None:
            assert got == {"ok"} and "stopped" not in err
        else:
            assert f"stopped with {why} at step" in err and got == {why}
        out.unlink()


def test_positivity_loss_stops_the_member_and_the_summary_says_why(tmp_path):
    over = ["torus.N=15", "initial.kind=random", "initial.kmax=3", "initial.energy=40", "thermo.buoyancy=0.9",
            "fluid.kinematic_viscosity=0", "thermo.conductivity=0", "initial.entropy_kind=random",
            "initial.entropy_amplitude=0.3", "ensemble.members=2", "integrator.steps=200", "output.every=10",
            "integrator.h=0.05", "output.figures=false"]
    ds, summ = run_scene("torus_convection", None, overrides=over, progress=False)
    lines = "\n".join(summ.lines())
    assert summ.stats.status.get("theta_not_positive", 0) >= 1, lines
    assert "theta_not_positive" in lines and "stopped" in lines


@pytest.mark.parametrize("name", SCENES)
def test_a_torus_run_killed_and_resumed_gives_the_same_file(tmp_path, name):
    over = ["torus.N=15", "ensemble.members=8", "output.member_chunk=1", "integrator.steps=60", "output.every=20",
            "output.compare=[]", "output.figures=false"]
    out, ref, stdout = kill_and_resume(tmp_path, ["run", name, "--no-progress", *_sets(over)], chunks=2)
    assert re.search(r"resumed: members 0-\d+ came from the interrupted run", stdout), stdout
    assert same_but_created(out, ref)


def test_torus_convection_writes_its_file_and_figures(tmp_path):
    from liethermo.cli import main as cli

    assert cli(["run", "torus_convection", "-o", str(tmp_path / "c.nc"), "--no-progress", "--set",
                "integrator.steps=40", "--set", "output.theta_map=true"]) == 0
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["c.nc", "c_budget.png", "c_maps.png"], names


def test_an_animation_on_request(tmp_path):
    from liethermo.cli import main as cli

    assert cli(["run", "torus_convection", "-o", str(tmp_path / "a.nc"), "--no-progress", "--set", "torus.N=9",
                "--set", "integrator.steps=8", "--set", "output.every=2", "--set", "output.animation=true"]) == 0
    anim = [p for p in tmp_path.iterdir() if p.stem == "a_animation"]
    assert len(anim) == 1 and anim[0].suffix in (".gif", ".mp4") and anim[0].stat().st_size > 1000
