"""Fault injection: runs and studies killed with SIGKILL at random moments.

A killed process cleans nothing up, so what it leaves must be safe as it is:
the output path is absent or holds a complete, valid file; a rerun with
``--resume`` gives the file an uninterrupted run gives (the same data bit
for bit; only the creation time and the command in ``history`` differ) and removes what the killed process left; a study
rerun recomputes only the sweep points that were missing.

The trials run in a driver process that loads the kernels once and forks one
child per run (numba's workqueue threading layer, which is fork-safe), so
that 20 kills and 20 resumes take seconds, not the minute of 40 interpreter
starts; the children run :func:`liethermo.cli.main` exactly as the command
line does.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.slow  # 20 kills and resumes, 4 studies: about half a minute

DRIVER = r'''
import json, os, random, shutil, signal, sys, time, traceback
from pathlib import Path

import netCDF4

from liethermo.cli import main

cfg = json.loads(sys.argv[1])
root = Path(cfg["root"])
logs = root / "logs"
logs.mkdir()


sys.path.insert(0, cfg["tests"])
from ncsame import same_but_created  # noqa: E402


def child(argv, log):
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:
        fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        try:
            rc = main(argv)
        except BaseException:
            traceback.print_exc()
            rc = 99
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(rc)
    return pid


def wait(pid):
    return os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])


def timed(argv, log):
    t0 = time.perf_counter()
    rc = wait(child(argv, log))
    assert rc == 0, Path(log).read_text()
    return time.perf_counter() - t0


def listing(folder):
    return sorted(p.name for p in Path(folder).iterdir()) if Path(folder).exists() else []


rng = random.Random(cfg["seed"])
report = {"runs": [], "studies": []}

# ---- runs
sets = [a for s in cfg["sets"] for a in ("--set", s)] + ["--no-progress"]
work, ref = root / "run", root / "ref" / "x.nc"
out = work / "x.nc"
args = ["run", "paper", "-o", str(out)] + sets
main(["run", "paper", "-o", str(root / "warm" / "x.nc")] + sets + ["--set", "ensemble.members=2"])
T = timed(["run", "paper", "-o", str(ref)] + sets, logs / "ref.log")
report["run_time"] = T
for i in range(cfg["runs"]):
    pid = child(args, logs / f"kill{i}.log")
    time.sleep(rng.uniform(0, 1.1 * T))
    os.kill(pid, signal.SIGKILL)
    status = wait(pid)
    journals = [json.loads(p.read_text()) for p in work.glob(".x.nc.*.tmp.json")] if work.exists() else []
    at_kill = {
        "status": status,
        "left": listing(work),
        "chunks_journaled": max((len(j["chunks"]) for j in journals), default=0),
        "output": "absent" if not out.exists() else ("complete" if same_but_created(out, ref) else "different"),
    }
    rc = wait(child(args + ["--resume"], logs / f"resume{i}.log"))
    log = (logs / f"resume{i}.log").read_text()
    report["runs"].append({
        **at_kill, "resume_rc": rc, "resume_log": log, "resumed": "resumed: members 0-" in log,
        "identical": out.exists() and same_but_created(out, ref), "after": listing(work),
    })
    out.unlink(missing_ok=True)

# ---- studies
study = cfg["study"]
sref, sdir = root / "sref", root / "study"
Ts = timed(["study", study, "-o", str(sref), "--no-progress"], logs / "sref.log")
report["study_time"] = Ts
for i in range(cfg["studies"]):
    pid = child(["study", study, "-o", str(sdir), "--no-progress"], logs / f"skill{i}.log")
    # during the sweep: once a random number of points is done, and a moment later
    target, t0 = rng.randint(0, cfg["points"] - 1), time.perf_counter()
    while len(list((sdir / "points").glob("*.nc")) if (sdir / "points").exists() else []) < target:
        assert time.perf_counter() - t0 < 60
        time.sleep(0.002)
    time.sleep(rng.uniform(0, 0.02))
    os.kill(pid, signal.SIGKILL)
    wait(pid)
    pts = sdir / "points"
    kept = {p.name: p.stat().st_mtime_ns for p in pts.glob("*.nc")} if pts.exists() else {}
    rc = wait(child(["study", study, "-o", str(sdir), "--no-progress"], logs / f"srerun{i}.log"))
    after = {p.name: p.stat().st_mtime_ns for p in pts.glob("*.nc")}
    report["studies"].append({
        "kept": kept, "after": after, "rerun_rc": rc, "rerun_log": (logs / f"srerun{i}.log").read_text(),
        "all_points": sorted(p.name for p in (sref / "points").glob("*.nc")),
        "hidden_after": sorted(p.name for p in list(sdir.glob(".*")) + list(pts.glob(".*"))),
    })
    shutil.copyfile(sdir / "sweep.nc", logs / f"sweep{i}.nc")
    shutil.rmtree(sdir)
print(json.dumps(report))
'''

STUDY = """methods = ["vi"]
[study]
kind = "viscosity_sweep"
name = "sweep"
base_scene = "paper"
[scene.ensemble]
members = 128
[sweep]
"fluid.viscosity" = [0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0]
[options]
method = "vi"
h = 0.02
t_end_max = 100.0
outputs = 200
"""

RUNS = 20
STUDIES = 4


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    root = tmp_path_factory.mktemp("kills")
    (root / "sweep.toml").write_text(STUDY)
    cfg = {"root": str(root), "tests": os.path.dirname(os.path.abspath(__file__)), "seed": 20240611, "runs": RUNS, "studies": STUDIES, "points": 8,
           "study": str(root / "sweep.toml"),
           # 12 member chunks of about 40 ms each
           "sets": ["output.compare=[]", "output.figures=false", "output.attitude=false", "ensemble.members=3072",
                    "output.member_chunk=256", "integrator.steps=1500", "output.every=150"]}
    env = dict(os.environ, NUMBA_THREADING_LAYER="workqueue")
    p = subprocess.run([sys.executable, "-c", DRIVER, json.dumps(cfg)], capture_output=True, text=True,
                       env=env, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    rep = json.loads(p.stdout.strip().splitlines()[-1])
    rep["root"] = root
    return rep


def test_killed_runs_leave_nothing_wrong_and_resume_bit_identical(report):
    runs = report["runs"]
    assert len(runs) == RUNS
    for r in runs:
        # at the kill: no file at the output path, or the complete one
        assert r["output"] in ("absent", "complete"), r
        assert r["status"] in (-9, 0), r
        # the resume: exit 0, the file of an uninterrupted run, nothing else left
        assert r["resume_rc"] == 0, r["resume_log"]
        assert "Traceback" not in r["resume_log"]
        assert r["identical"], r
        assert r["after"] == ["x.nc"], r
    killed_mid_run = [r for r in runs if r["status"] == -9 and r["chunks_journaled"] > 0]
    # the kills hit before any chunk was done, and between chunks
    assert sum(r["status"] == -9 and r["chunks_journaled"] == 0 for r in runs) >= 1
    assert len(killed_mid_run) >= 5
    # a killed run's journaled chunks were taken over, not recomputed
    assert all(r["resumed"] for r in killed_mid_run if r["output"] == "absent")
    for r in runs:  # and its other leftovers (its lock file aside) were removed, with one line
        temps = [f for f in r["left"] if f not in ("x.nc", ".x.nc.lock")]
        if temps and not r["resumed"]:
            assert "left by interrupted or killed runs of" in r["resume_log"], r


def test_killed_studies_recompute_only_missing_points(report):
    import xarray as xr

    studies = report["studies"]
    assert len(studies) == STUDIES
    for i, s in enumerate(studies):
        assert s["rerun_rc"] == 0, s["rerun_log"]
        assert sorted(s["after"]) == s["all_points"]
        # the points the killed study had finished were loaded, not written again
        assert {k: s["after"][k] for k in s["kept"]} == s["kept"]
        assert not s["hidden_after"], s  # no temporary, no lock
        with xr.open_dataset(report["root"] / "logs" / f"sweep{i}.nc") as a, \
                xr.open_dataset(report["root"] / "sref" / "sweep.nc") as b:
            for v in b.data_vars:
                if "wall" not in v:
                    xr.testing.assert_equal(a[v], b[v])
    # some kills landed in the middle of the sweep
    assert any(0 < len(s["kept"]) < len(s["all_points"]) for s in studies)
