"""Dask scale-out: a 2-worker LocalCluster run equals the in-process run.

One LocalCluster (2 worker processes with nannies, 1 thread each) serves the
whole module.  Faults are injected through ``run_scene_dask(task=...)`` with
module-level wrappers around :func:`liethermo.distributed.compute_part` (the
workers import this module by name: spawned workers inherit ``sys.path``),
using marker files to act only once.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

distributed = pytest.importorskip("distributed")

from liethermo import cf
from liethermo import distributed as ld  # noqa: E402
from liethermo.runner import run_scene  # noqa: E402

BASE = ["ensemble.members=600", "ensemble.seed=7", "output.every=10", "output.compare=[]",
        "output.figures=false"]
VI = BASE + ["integrator.steps=60"]
# RK2 at the paper's h blows up for part of the ensemble: non-trivial status flags
RK2 = BASE + ["integrator.steps=100", "integrator.method='rk2'"]
TASK = 128  # members per task: 5 tasks, the last one short
PROVENANCE = {"created", "history"}


@pytest.fixture(scope="module")
def client():
    from distributed import Client, LocalCluster

    # the scheduler's HTTP server on a port of its own: without a dashboard it still tries
    # :8787 first, and failed to start when another process on the machine took that port
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0",
                           env={"NUMBA_NUM_THREADS": "1"})
    c = Client(cluster)
    c.wait_for_workers(2)
    yield c
    c.close()
    cluster.close()


def _reference(path: Path, overrides) -> Path:
    # the RK2 blow-ups overflow in the energy diagnostics (values are then
    # flagged non_finite): the floating-point warnings are expected here
    with np.errstate(over="ignore", invalid="ignore"):
        run_scene("paper", path, overrides=overrides, progress=False)
    return path


@pytest.fixture(scope="module")
def ref_vi(tmp_path_factory) -> Path:
    return _reference(tmp_path_factory.mktemp("ref") / "vi.nc", VI)


@pytest.fixture(scope="module")
def ref_rk2(tmp_path_factory) -> Path:
    return _reference(tmp_path_factory.mktemp("ref") / "rk2.nc", RK2)


def assert_same_values(va: np.ndarray, vb: np.ndarray, name: str) -> None:
    """The same dtype; floats within 1e-14 relative with NaN and inf where the
    reference has them, everything else equal."""
    assert va.dtype == vb.dtype, name
    if va.dtype.kind == "f":
        fin = np.isfinite(vb)
        assert np.array_equal(va[~fin], vb[~fin], equal_nan=True), name
        scale = np.maximum(np.abs(vb[fin]), np.finfo(float).tiny)
        assert np.all(np.abs(va[fin] - vb[fin]) <= 1e-14 * scale), name
    else:
        np.testing.assert_array_equal(va, vb, err_msg=name)


def assert_same_run(path: Path, ref: Path) -> None:
    """Every variable within 1e-14 relative (NaN where the reference has NaN),
    integer variables and status flags equal, attributes equal but the provenance
    ('created', and 'history': the call that made each file)."""
    with cf.open_dataset(path) as a, cf.open_dataset(ref) as b:
        assert set(a.variables) == set(b.variables)
        assert a.sizes == b.sizes
        for name in b.variables:
            assert a[name].attrs.keys() == b[name].attrs.keys(), name
            assert_same_values(a[name].values, b[name].values, name)
        np.testing.assert_array_equal(a["status"].values, b["status"].values)
        assert a.attrs.keys() == b.attrs.keys()
        for k in b.attrs:
            if k not in PROVENANCE:
                np.testing.assert_array_equal(a.attrs[k], b.attrs[k], err_msg=k)


# ---------------------------------------------------------------- fault injection
def _marker(path: str, what: str, lo: int) -> Path:
    return Path(path).parent.parent / f"{what}-{lo}"  # next to <OUT>, outside <OUT>.parts


def die_once(scene, lo, hi, path, key, attrs, numba_threads=None):
    """Kill the worker process the first time chunk 128 runs."""
    m = _marker(path, "died", lo)
    if lo == TASK and not m.exists():
        m.touch()
        os._exit(13)
    return ld.compute_part(scene, lo, hi, path, key, attrs, numba_threads)


def raise_once(scene, lo, hi, path, key, attrs, numba_threads=None):
    m = _marker(path, "raised", lo)
    if lo == 2 * TASK and not m.exists():
        m.touch()
        raise RuntimeError("injected task failure")
    return ld.compute_part(scene, lo, hi, path, key, attrs, numba_threads)


def fail_256(scene, lo, hi, path, key, attrs, numba_threads=None):
    if lo == 2 * TASK:
        raise RuntimeError("injected interruption")
    return ld.compute_part(scene, lo, hi, path, key, attrs, numba_threads)


def stop_client(scene, lo, hi, path, key, attrs, numba_threads=None):
    """Chunk 256 sends the client a SIGTERM (a batch system's time limit), once,
    and is still running when the client stops."""
    m = _marker(path, "stopped", lo)
    if lo == 2 * TASK and not m.exists():
        m.touch()
        os.kill(int(_marker(path, "client", 0).read_text()), signal.SIGTERM)
        time.sleep(1.0)
    return ld.compute_part(scene, lo, hi, path, key, attrs, numba_threads)


def count_calls(scene, lo, hi, path, key, attrs, numba_threads=None):
    _marker(path, "called", lo).touch()
    return ld.compute_part(scene, lo, hi, path, key, attrs, numba_threads)


# ---------------------------------------------------------------- tests
@pytest.mark.parametrize("which", ["vi", "rk2"])
def test_two_workers_equal_in_process(client, tmp_path, which, ref_vi, ref_rk2):
    ref, ov = (ref_vi, VI) if which == "vi" else (ref_rk2, RK2)
    out = tmp_path / f"{which}.nc"
    _, summ = ld.run_scene_dask("paper", out, overrides=ov, address=client, task_members=TASK,
                                progress=False)
    assert summ.tasks == 5 and summ.tasks_skipped == 0
    assert not ld.parts_dir(out).exists()
    assert_same_run(out, ref)
    _, ref_summ = run_scene("paper", None, overrides=ov, progress=False) if which == "vi" else (None, None)
    if ref_summ is not None:
        assert summ.status_counts == ref_summ.status_counts
        assert summ.max_abs_energy_error == ref_summ.max_abs_energy_error
        assert summ.newton_mean == ref_summ.newton_mean
        assert summ.findings == ref_summ.findings and "exact_omega3" in summ.findings  # merged over the tasks
        assert summ.physics_notes == ref_summ.physics_notes
    else:
        with cf.open_dataset(ref) as b:
            assert summ.status_counts["non_finite"] == int((b["status"].values != 0).sum()) > 0
            failed = b["status"].values != 0
            assert summ.first_fail_step == int(b["failed_at_step"].values[failed].min())


def test_a_fluid_run_on_two_workers_equals_in_process(client, tmp_path):
    """The Zeitlin fluid through the same Dask path: its tasks are the scene's
    member chunks (3 members) and give the arrays of the in-process run bit for bit."""
    over = ["zeitlin.N=12", "initial.lmax=6", "ensemble.members=16", "output.member_chunk=3",
            "integrator.steps=40", "output.every=10", "output.compare=[]", "output.figures=false"]
    ref = tmp_path / "ref.nc"
    run_scene("zeitlin_decay", ref, overrides=over, progress=False)
    out = tmp_path / "z.nc"
    _, summ = ld.run_scene_dask("zeitlin_decay", out, overrides=over, address=client, progress=False)
    assert summ.tasks == 6 and summ.members == 16
    with cf.open_dataset(out) as a, cf.open_dataset(ref) as b:
        assert set(a.variables) == set(b.variables)
        for name in a.variables:
            va, vb = a[name].values, b[name].values
            assert va.dtype == vb.dtype and (va.tobytes() == vb.tobytes() if va.dtype.kind in "fiu"
                                             else np.array_equal(va, vb)), name


@pytest.mark.parametrize("name", ["torus_euler", "torus_decay", "torus_convection"])
def test_a_torus_run_on_two_workers_equals_in_process(client, tmp_path, name):
    """Each torus scene through the Dask path gives the in-process run's file bit for bit."""
    over = ["torus.N=9", "ensemble.members=5", "output.member_chunk=2", "integrator.steps=20", "output.every=10",
            "output.compare=[]", "output.figures=false", "output.vorticity=true"]
    ref = tmp_path / "ref.nc"
    run_scene(name, ref, overrides=over, progress=False)
    out = tmp_path / "t.nc"
    _, summ = ld.run_scene_dask(name, out, overrides=over, address=client, progress=False)
    assert summ.tasks == 3 and summ.members == 5
    with cf.open_dataset(out) as a, cf.open_dataset(ref) as b:
        assert set(a.variables) == set(b.variables)
        for v in a.variables:
            va, vb = a[v].values, b[v].values
            assert va.dtype == vb.dtype and (va.tobytes() == vb.tobytes() if va.dtype.kind in "fiu"
                                             else np.array_equal(va, vb)), v


def test_killed_worker_task_is_retried(client, tmp_path, ref_vi):
    out = tmp_path / "killed.nc"
    _, summ = ld.run_scene_dask("paper", out, overrides=VI, address=client, task_members=TASK,
                                progress=False, task=die_once)
    assert (tmp_path / f"died-{TASK}").exists()  # the worker really died once
    assert summ.tasks == 5
    assert_same_run(out, ref_vi)
    client.wait_for_workers(2)  # the nanny restarted it


def test_raising_task_is_retried(client, tmp_path, ref_vi):
    out = tmp_path / "raised.nc"
    ld.run_scene_dask("paper", out, overrides=VI, address=client, task_members=TASK, progress=False,
                      task=raise_once, retries=1)
    assert (tmp_path / f"raised-{2 * TASK}").exists()
    assert_same_run(out, ref_vi)


def test_resume_recomputes_nothing_finished(client, tmp_path, ref_vi):
    out = tmp_path / "resume.nc"
    parts = ld.parts_dir(out)
    with pytest.raises(RuntimeError, match="injected interruption"):
        ld.run_scene_dask("paper", out, overrides=VI, address=client, task_members=TASK, progress=False,
                          task=fail_256, retries=0)
    assert not out.exists()  # no partial output file
    idx = json.loads((parts / ld.INDEX_NAME).read_text())
    done = {f: (parts / f).stat().st_mtime_ns for f in idx["files"] if (parts / f).exists()}
    assert len(done) == 4 and not any(f"-{2 * TASK:012d}-" in f for f in done)

    # the rerun does not need task_members: the layout comes from index.json
    _, summ = ld.run_scene_dask("paper", out, overrides=VI, address=client, progress=False,
                                task=count_calls, keep_parts=True)
    assert sorted(p.name for p in tmp_path.glob("called-*")) == [f"called-{2 * TASK}"]
    assert summ.tasks == 5 and summ.tasks_skipped == 4
    assert {f: (parts / f).stat().st_mtime_ns for f in done} == done  # untouched
    assert_same_run(out, ref_vi)

    # the kept parts are an open_mfdataset-ready set, listed by index.json
    with xr.open_mfdataset([parts / f for f in idx["files"]], combine="nested", concat_dim="member",
                           decode_times=False, data_vars="minimal", coords="minimal", compat="override",
                           join="override") as mf, \
            cf.open_dataset(ref_vi) as b:
        np.testing.assert_array_equal(mf["omega"].values, b["omega"].values)
        np.testing.assert_array_equal(mf["member"].values, np.arange(600))

    # a different scene never reuses these chunk files; combine=False leaves
    # the result as the indexed set of chunk files (out is not touched)
    other = VI + ["ensemble.seed=8"]
    before = out.stat().st_mtime_ns
    _, summ2 = ld.run_scene_dask("paper", out, overrides=other, address=client, task_members=TASK,
                                 progress=False, combine=False)
    assert summ2.tasks_skipped == 0 and summ2.path == parts / ld.INDEX_NAME
    assert out.stat().st_mtime_ns == before
    idx2 = json.loads((parts / ld.INDEX_NAME).read_text())
    assert idx2["scene_key"] != idx["scene_key"] and all((parts / f).exists() for f in idx2["files"])


def test_stop_signal_cancels_the_tasks_and_keeps_the_parts(client, tmp_path, ref_vi):
    from liethermo.faults import Interrupted, stop_on_signals

    out = tmp_path / "stopped.nc"
    parts = ld.parts_dir(out)
    (tmp_path / "client-0").write_text(str(os.getpid()))
    with stop_on_signals(), pytest.raises(Interrupted) as exc:
        ld.run_scene_dask("paper", out, overrides=VI, address=client, task_members=TASK, progress=False,
                          task=stop_client)
    assert exc.value.exit_code == 143
    (msg,) = exc.value.kept
    m = re.fullmatch(rf"stopped with (\d)/5 member chunks of {re.escape(str(out))} done, kept in "
                     rf"{re.escape(str(parts))}/ \(rerun the same command to continue\)", msg)
    assert m and 0 < int(m[1]) < 5, msg
    assert not out.exists()
    # the rerun takes over the finished chunks and gives the in-process result
    _, summ = ld.run_scene_dask("paper", out, overrides=VI, address=client, progress=False)
    assert summ.tasks == 5 and summ.tasks_skipped >= int(m[1])
    assert_same_run(out, ref_vi)


@pytest.mark.slow
def test_ctrl_c_under_dask_local(tmp_path):
    """Ctrl-C at a terminal signals the whole process group, the local
    cluster's workers too: one line, exit status 130, no process left."""
    out = tmp_path / "x.nc"
    sets = ["ensemble.members=100000", "output.member_chunk=2000", "integrator.steps=3000", "output.every=300",
            "output.compare=[]", "output.figures=false", "output.attitude=false"]
    cmd = [sys.executable, "-m", "liethermo.cli", "run", "paper", "-o", str(out), "--no-progress", "--dask", "local"]
    p = subprocess.Popen(cmd + [a for x in sets for a in ("--set", x)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, start_new_session=True)
    parts = ld.parts_dir(out)
    deadline = time.time() + 120
    while time.time() < deadline and not (parts / ld.INDEX_NAME).exists():  # the tasks are submitted
        assert p.poll() is None, p.communicate()
        time.sleep(0.02)
    time.sleep(0.5)
    os.killpg(p.pid, signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert err.startswith("liethermo: interrupted by SIGINT: stopped "), err
    assert not out.exists() and not [f for f in os.listdir(parts) if f.startswith(".")]
    for _ in range(100):  # the workers are gone with the cluster
        try:
            os.killpg(p.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.05)
    else:
        raise AssertionError("processes of the stopped run are still alive")


def stop_on_item(item):
    """Item 2 sends the client a SIGTERM (noting when); every item takes a moment and leaves a marker."""
    client_pid, folder, i = item
    if i == 2:
        (Path(folder) / "signalled").write_text(repr(time.time()))
        os.kill(client_pid, signal.SIGTERM)
    time.sleep(0.3)
    (Path(folder) / f"ran-{i}").touch()
    return i


def test_stop_signal_cancels_mapped_tasks(client, tmp_path):
    """What `liethermo study --dask` relies on: a stop signal in the client
    cancels the remaining sweep-point tasks and goes on as Interrupted."""
    from liethermo.faults import Interrupted, stop_on_signals

    items = [(os.getpid(), str(tmp_path), i) for i in range(12)]
    with stop_on_signals(), pytest.raises(Interrupted) as exc:
        ld.map_tasks(stop_on_item, items, client, progress=False)
    stopped = time.time()
    assert exc.value.exit_code == 143
    # it did not wait for the other tasks (measured from the signal: the workers' start-up,
    # importing this module, is not the wait's)
    assert stopped - float((tmp_path / "signalled").read_text()) < 12 * 0.3 / 2
    time.sleep(3.0)  # long enough for every task to have run, had they not been cancelled
    assert len(list(tmp_path.glob("ran-*"))) < 8


def test_map_tasks_in_order(client):
    assert ld.map_tasks(abs, [-3, 2, -1, 0], client, progress=False) == [3, 2, 1, 0]
    assert ld.map_tasks(abs, [], client) == []


def small_point(h: float):
    return xr.Dataset({"h2": ((), h * h)})


def test_map_cached_points(client, tmp_path):
    pts = [(f"h{i}", small_point, (0.1 * i,)) for i in range(1, 4)]
    assert ld.map_cached_points(tmp_path, pts, client, progress=False) == ["h1", "h2", "h3"]
    assert ld.map_cached_points(tmp_path, pts, client, progress=False) == []  # resume: nothing to do
    with cf.open_dataset(tmp_path / "points" / "h2.nc") as ds:
        assert float(ds["h2"]) == 0.2 * 0.2


def test_cli_dask_address(client, tmp_path, ref_vi, capsys):
    from liethermo.cli import main

    out = tmp_path / "cli.nc"
    args = ["run", "paper", "-o", str(out), "--no-progress", "--dask", client.scheduler.address]
    for s in VI:
        args += ["--set", s]
    assert main(args) == 0
    assert "wrote" in capsys.readouterr().out
    assert_same_run(out, ref_vi)
    with cf.open_dataset(out) as ds:  # the command line that made the file
        shown = [a for a in args if a != "--no-progress"]  # a display flag, not part of what made the data
        assert ds.attrs["history"].endswith(": " + shlex.join(["liethermo", *shown]))


# ---------------------------------------------------------------- studies (--dask)
STUDIES = Path(__file__).resolve().parents[1] / "studies"
# timings, not results: they differ between any two runs
TIMING = {"wall_time", "kernel_time", "wall", "cost_per_simulated_s", "cost_spread"}


def _study(kind: str) -> dict:
    from liethermo.studies.runner import load_study

    study = load_study(STUDIES / f"{kind}.toml")
    if kind == "energy_drift":  # RK2 at the paper's h: part of the ensemble blows up (non-zero status)
        study["reduced"]["methods"] = ["vi:node:explicit", "rk2"]
    if kind == "long_drift":  # one method per family and a tenth of the horizon: the Dask path is what is tested
        study["reduced"]["methods"] = ["vi", "split4", "rk2"]
        study["reduced"]["options"].update(t_end=20.0, outputs=200, kn_steps=200, calibration_steps=200)
    return study


def assert_same_study(a_dir: Path, b_dir: Path, name: str) -> None:
    """The study netCDFs agree to 1e-14 relative (timings and provenance aside), status flags
    and integers exactly; the key-table CSVs agree on every non-timing column."""
    import pandas as pd

    with cf.open_dataset(a_dir / f"{name}.nc") as a, cf.open_dataset(b_dir / f"{name}.nc") as b:
        assert set(a.variables) == set(b.variables) and a.sizes == b.sizes
        for v in b.variables:
            if v in TIMING:
                continue
            assert a[v].dims == b[v].dims, v
            assert_same_values(a[v].values, b[v].values, v)
        np.testing.assert_array_equal(a["status"].values, b["status"].values)
        assert a.attrs.keys() == b.attrs.keys()
        assert {k: str(x) for k, x in a.attrs.items() if k not in TIMING | PROVENANCE} == \
            {k: str(x) for k, x in b.attrs.items() if k not in TIMING | PROVENANCE}
    csvs = sorted(p.name for p in b_dir.glob("*.csv"))
    assert csvs and csvs == sorted(p.name for p in a_dir.glob("*.csv"))
    for f in csvs:
        if f in ("closing.csv", "equal_cost.csv"):  # rank or compare the measured costs: timings
            continue
        ta, tb = pd.read_csv(a_dir / f), pd.read_csv(b_dir / f)
        cols = [c for c in tb.columns if "wall" not in c and "cost_per_simulated_s" not in c and "cost_spread" not in c]
        pd.testing.assert_frame_equal(ta[cols], tb[cols], check_exact=False, rtol=1e-14)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["energy_drift", "viscosity_sweep", "long_drift"])
def test_study_on_dask_equals_in_process(client, tmp_path, kind):
    from liethermo.studies import get_study

    mod = get_study(kind)
    mod = getattr(mod, "STUDY", mod)  # a declared study runs through its declaration
    study = _study(kind)
    mod.run(study, tmp_path / "inproc", reduced=True, progress=False)
    if kind == "long_drift":  # its steps come from a timed calibration: both runs share one measurement
        (tmp_path / "dask" / "points").mkdir(parents=True)
        for p in (tmp_path / "inproc" / "points").glob("*.nc"):
            with cf.open_dataset(p) as d:
                if "calibrated_cost" in d:
                    shutil.copy(p, tmp_path / "dask" / "points" / p.name)
    mod.run(study, tmp_path / "dask", reduced=True, progress=False, dask=client)
    assert_same_study(tmp_path / "dask", tmp_path / "inproc", kind)
    if kind == "energy_drift":
        with cf.open_dataset(tmp_path / "dask" / "energy_drift.nc") as ds:
            assert int((ds["status"].sel(scheme="rk2") != 0).sum()) > 0  # failure counts were compared
    points = sorted((tmp_path / "dask" / "points").glob("*.nc"))
    assert [p.name for p in points] == sorted(p.name for p in (tmp_path / "inproc" / "points").glob("*.nc"))
    # a rerun recomputes nothing: every point is in the cache (no task is even submitted)
    stamps = {p.name: p.stat().st_mtime_ns for p in points}
    mod.run(study, tmp_path / "dask", reduced=True, progress=False, dask=client)
    assert {p.name: p.stat().st_mtime_ns for p in (tmp_path / "dask" / "points").glob("*.nc")} == stamps
    assert_same_study(tmp_path / "dask", tmp_path / "inproc", kind)


@pytest.mark.slow
def test_cli_study_dask_address(client, tmp_path, capsys):
    """``liethermo study … --dask ADDRESS`` on a study with two rounds of tasks
    (convergence: references, then the errors against them)."""
    from liethermo.cli import main

    # three of its methods (one per family): the Dask path, not the methods, is what is tested
    text = (STUDIES / "convergence.toml").read_text()
    first = next(line for line in text.splitlines() if line.startswith("methods = "))
    study = tmp_path / "convergence.toml"
    reduced = "[reduced.options]\nh0 = 0.05\nlevels = 5\nt_end = 2.0\n"
    assert reduced in text
    study.write_text(text.replace(first, 'methods = ["vi", "split", "rk4"]', 1)
                     .replace(reduced, "[reduced.options]\nh0 = 0.05\nlevels = 3\nt_end = 0.5\n", 1))
    base = ["study", str(study), "--reduced", "--no-progress"]
    assert main(base + ["-o", str(tmp_path / "inproc")]) == 0
    assert main(base + ["-o", str(tmp_path / "dask"), "--dask", client.scheduler.address]) == 0
    assert "convergence" in capsys.readouterr().out
    assert_same_study(tmp_path / "dask", tmp_path / "inproc", "convergence")


def test_stack_points_single_key():
    """One sweep key (no MultiIndex to unstack): the key becomes the dimension,
    in the order of the study file."""
    from liethermo.studies.common import stack_points

    pts = [{"fluid.viscosity": v} for v in (1.0, 0.1, 10.0)]
    ds = stack_points([xr.Dataset({"x": ("member", [v, 2 * v])}) for v in (1.0, 0.1, 10.0)], pts)
    assert ds["x"].dims == ("fluid_viscosity", "member")
    np.testing.assert_array_equal(ds["fluid_viscosity"].values, [1.0, 0.1, 10.0])
    np.testing.assert_array_equal(ds["x"].values[:, 1], [2.0, 0.2, 20.0])
    assert ds["fluid_viscosity"].attrs["scene_key"] == "fluid.viscosity"
