"""Faults: stop signals, resume, stale temporaries, write errors, and refusals
made before any work.  Every failure ends with one line on stderr, a known
exit status, and no file left behind but what the line says was kept."""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import netCDF4
import pytest

from conftest import interrupt_at_chunk
from liethermo.cli import main
from liethermo.faults import Interrupted, OutputLock
from liethermo.runner import run_scene
from ncsame import same_bytes_but_time, same_but_created
from liethermo.scene import load_scene

CLI = [sys.executable, "-m", "liethermo.cli"]
# a run of 8 member chunks, each ~0.1 s: long enough to be stopped in the middle
SLOW = ["--no-progress", "--set", "output.compare=[]", "--set", "output.figures=false",
        "--set", "output.attitude=false", "--set", "ensemble.members=4096", "--set", "output.member_chunk=512",
        "--set", "integrator.steps=6000", "--set", "output.every=600"]
# a tiny run
TINY = ["--no-progress", "--set", "output.compare=[]", "--set", "output.figures=false",
        "--set", "integrator.steps=20", "--set", "ensemble.members=3"]


def one_line(err: str) -> str:
    assert err.count("\n") == 1 and err.endswith("\n"), err
    assert "Traceback" not in err
    return err.strip()


def names(folder: Path) -> list[str]:
    return sorted(p.name for p in Path(folder).iterdir())


def start_and_signal(out: Path, sig: int, extra=()) -> subprocess.CompletedProcess:
    """Start ``liethermo run`` on a slow scene, send ``sig`` once its first
    member chunk is in the journal, and wait for it."""
    p = subprocess.Popen(CLI + ["run", "paper", "-o", str(out), *SLOW, *extra],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while time.time() < deadline and not list(out.parent.glob(f".{out.name}.*.tmp.json")):
        assert p.poll() is None, p.communicate()
        time.sleep(0.01)
    p.send_signal(sig)
    stdout, stderr = p.communicate(timeout=60)
    return subprocess.CompletedProcess(p.args, p.returncode, stdout, stderr)


# ---------------------------------------------------------------- signals and resume
def test_sigterm_keeps_the_partial_run_and_resume_is_bit_identical(tmp_path):
    out = tmp_path / "x.nc"
    r = subprocess.run(CLI + ["run", "paper", "-o", str(out), *SLOW], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    ref = tmp_path / "ref" / "x.nc"  # the uninterrupted run, written to the same path
    ref.parent.mkdir()
    out.rename(ref)
    p = start_and_signal(out, signal.SIGTERM)
    assert p.returncode == 143, p.stderr
    line = one_line(p.stderr)
    assert line.startswith("liethermo: interrupted by SIGTERM: stopped at member chunk ")
    assert f"kept in {out}.partial (rerun with --resume to continue)" in line
    assert names(tmp_path) == [".x.nc.partial.json", "ref", "x.nc.partial"]  # no temporary, no lock

    r = subprocess.run(CLI + ["run", "paper", "-o", str(out), *SLOW, "--resume"], capture_output=True, text=True)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert "resumed: members 0-" in r.stdout
    assert names(tmp_path) == ["ref", "x.nc"]
    assert same_but_created(out, ref)
    assert same_bytes_but_time(out, ref)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGHUP])
def test_sigint_and_sighup_stop_cleanly(tmp_path, sig):
    out = tmp_path / "x.nc"
    p = start_and_signal(out, sig)
    assert p.returncode == 128 + sig
    line = one_line(p.stderr)
    assert f"interrupted by {signal.Signals(sig).name}: stopped at member chunk " in line
    assert "KeyboardInterrupt" not in line
    assert names(tmp_path) == [".x.nc.partial.json", "x.nc.partial"]
    with netCDF4.Dataset(out.with_name("x.nc.partial")) as nc:  # the kept file is a closed, readable netCDF
        assert len(nc.dimensions["member"]) == 4096


def test_resume_in_process_equals_an_uninterrupted_run(tmp_path, monkeypatch):
    sc = load_scene("paper", ["ensemble.members=50", "output.member_chunk=8", "integrator.steps=40",
                              "output.compare=[]"])
    run_scene(sc, tmp_path / "ref.nc", progress=False)
    calls = interrupt_at_chunk(monkeypatch, 4)
    with pytest.raises(Interrupted) as exc:
        run_scene(sc, tmp_path / "x.nc", progress=False)
    assert exc.value.kept == [f"stopped at member chunk 4/7 of {tmp_path / 'x.nc'}: members 0-23 kept in "
                              f"{tmp_path / 'x.nc.partial'} (rerun with --resume to continue)"]
    assert names(tmp_path) == [".x.nc.partial.json", "ref.nc", "x.nc.partial"]
    monkeypatch.undo()
    _, summ = run_scene(sc, tmp_path / "x.nc", progress=False, resume=True)
    assert summ.resumed_members == 24 and summ.members == 50
    assert names(tmp_path) == ["ref.nc", "x.nc"]
    assert same_but_created(tmp_path / "x.nc", tmp_path / "ref.nc")
    assert calls[:3] == [0, 8, 16]


def test_the_journal_checksum_is_zlibs_crc32():
    """The CRC-32 a journal records is zlib's, whichever library computes it: a
    journal written by one install is read by another."""
    import zlib

    import numpy as np

    from liethermo.io import checksum

    x = np.arange(2 * 5 * 16, dtype=np.float64).reshape(2, 5, 16) / 7.0
    for a in (x[..., 3:6], x[:, :, 0].astype(np.int8), np.array([], dtype=np.int64)):
        assert checksum(a) == zlib.crc32(np.ascontiguousarray(a).tobytes())
    labels = np.array(["x", "y", "z"], dtype=object)
    assert checksum(labels) == zlib.crc32(b"x\0y\0z")


def test_resume_recomputes_a_chunk_whose_checksum_fails(tmp_path, monkeypatch):
    """A recorded chunk whose values do not match the journal (a damaged file)
    is computed again, and so is everything after it."""
    import json

    sc = load_scene("paper", ["ensemble.members=40", "output.member_chunk=8", "integrator.steps=40",
                              "output.compare=[]"])
    run_scene(sc, tmp_path / "ref.nc", progress=False)
    interrupt_at_chunk(monkeypatch, 5)
    with pytest.raises(Interrupted):
        run_scene(sc, tmp_path / "x.nc", progress=False)
    monkeypatch.undo()
    jf = tmp_path / ".x.nc.partial.json"
    j = json.loads(jf.read_text())
    assert [c["lo"] for c in j["chunks"]] == [0, 8, 16, 24]
    j["chunks"][2]["crc"]["omega"] ^= 1
    jf.write_text(json.dumps(j))
    calls = interrupt_at_chunk(monkeypatch, 99)
    _, summ = run_scene(sc, tmp_path / "x.nc", progress=False, resume=True)
    assert summ.resumed_members == 16
    assert calls == [16, 24, 32]  # chunks 3 to 5; the layout comes from the partial file
    assert same_but_created(tmp_path / "x.nc", tmp_path / "ref.nc")


def test_resume_with_a_changed_scene_is_refused(tmp_path, monkeypatch, capsys):
    args = ["run", "paper", "-o", str(tmp_path / "x.nc"), "--no-progress", "--set", "ensemble.members=30",
            "--set", "output.member_chunk=8", "--set", "integrator.steps=20", "--set", "output.compare=[]",
            "--set", "output.figures=false"]
    interrupt_at_chunk(monkeypatch, 3)
    assert main(args) == 143
    err = one_line(capsys.readouterr().err)
    assert "members 0-15 kept in" in err
    monkeypatch.undo()
    before = {p: p.stat().st_mtime_ns for p in tmp_path.iterdir()}
    assert main(args + ["--resume", "--set", "integrator.h=0.05"]) == 2
    err = one_line(capsys.readouterr().err)
    assert err == (f"liethermo: error: cannot resume {tmp_path / 'x.nc'}: the scene differs from the "
                   "interrupted run's in integrator.h (0.1 there, 0.05 here); rerun without --resume to start over")
    assert {p: p.stat().st_mtime_ns for p in tmp_path.iterdir()} == before
    # without --resume the leftovers go, with one line, and the run starts over
    assert main(args) == 0
    err = one_line(capsys.readouterr().err)
    assert err.startswith("liethermo: removed 2 files (") and err.endswith(f"left by interrupted or killed runs of {tmp_path / 'x.nc'}")
    assert names(tmp_path) == ["x.nc"]


def test_dead_temporaries_are_removed_live_ones_never(tmp_path, capsys):
    out = tmp_path / "x.nc"
    # a temporary (and journal) of a process that died, and one of a live writer
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(dead.stdout)
    (tmp_path / f".x.nc.{dead_pid}.tmp").write_bytes(b"\0" * 5000)
    (tmp_path / f".x.nc.{dead_pid}.tmp.json").write_text("{}")
    code = ("import sys, time; from liethermo.faults import create_temp; "
            f"t, fd = create_temp({str(out)!r}); print(t, flush=True); time.sleep(60)")
    with subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True) as live:
        try:
            live_tmp = Path(live.stdout.readline().strip())
            assert live_tmp.exists()
            assert main(["run", "paper", "-o", str(out), *TINY]) == 0
            err = one_line(capsys.readouterr().err)
            assert err == f"liethermo: removed 2 files (5 kB) left by interrupted or killed runs of {out}"
            assert names(tmp_path) == [live_tmp.name, "x.nc"]
        finally:
            live.kill()


def test_second_process_for_the_same_output_is_refused(tmp_path, capsys):
    out = tmp_path / "x.nc"
    code = ("import time; from liethermo.faults import OutputLock; "
            f"OutputLock({str(out)!r}).acquire(); print('locked', flush=True); time.sleep(60)")
    with subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True) as holder:
        try:
            assert holder.stdout.readline().strip() == "locked"
            assert main(["run", "paper", "-o", str(out), *TINY]) == 2
            err = one_line(capsys.readouterr().err)
            assert err == (f"liethermo: error: {out}: another liethermo process (pid {holder.pid} on "
                           f"{os.uname().nodename}) is writing it; wait for it to finish or write elsewhere")
            assert names(tmp_path) == [".x.nc.lock"]  # the holder's
        finally:
            holder.kill()
    # the holder died: its lock is free again
    assert main(["run", "paper", "-o", str(out), *TINY]) == 0
    assert names(tmp_path) == ["x.nc"]


def test_lock_is_released_and_its_file_removed(tmp_path, monkeypatch):
    lock = OutputLock(tmp_path / "a.nc").acquire()
    assert names(tmp_path) == [".a.nc.lock"]
    lock.release()
    assert names(tmp_path) == []
    # on a full disk the holder's name cannot be written: the lock holds all the same
    import liethermo.faults as lf

    def full(fd, data):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(lf.os, "write", full)
    lock = OutputLock(tmp_path / "a.nc").acquire()
    with pytest.raises(lf.Busy):
        OutputLock(tmp_path / "a.nc").acquire()
    lock.release()
    assert names(tmp_path) == []


# ---------------------------------------------------------------- write errors
def test_file_size_limit_while_writing(tmp_path):
    """EFBIG while writing (a file-size limit, as a full disk gives ENOSPC):
    one line naming the file and the cause, no file left, exit status 2."""
    out = tmp_path / "big.nc"
    limit = 2 * 2**20

    def small_files():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    r = subprocess.run(CLI + ["run", "paper", "-o", str(out), "--no-progress", "--set", "output.compare=[]",
                              "--set", "output.figures=false", "--set", "ensemble.members=200"],
                       capture_output=True, text=True, preexec_fn=small_files)
    assert r.returncode == 2
    assert one_line(r.stderr) == f"liethermo: error: cannot write {out}: File too large (EFBIG)"
    assert names(tmp_path) == []


def test_library_error_while_writing(tmp_path, monkeypatch, capsys):
    """Any netCDF/HDF error while writing: one line naming the file and the
    library's message, the partial file removed."""
    import liethermo.io as lio

    class FailingSync:  # the open netCDF file, whose flush fails
        def __init__(self, nc):
            self._nc = nc

        def __getattr__(self, name):
            return getattr(self._nc, name)

        def sync(self):
            raise RuntimeError("NetCDF: HDF error")

    real = lio.ChunkedWriter._define

    def define(self, ds):
        real(self, ds)
        self.nc = FailingSync(self.nc)

    monkeypatch.setattr(lio.ChunkedWriter, "_define", define)
    out = tmp_path / "x.nc"
    assert main(["run", "paper", "-o", str(out), *TINY]) == 2
    assert one_line(capsys.readouterr().err) == f"liethermo: error: cannot write {out}: NetCDF: HDF error"
    assert names(tmp_path) == []


def test_disk_full_while_drawing_the_figures(tmp_path, monkeypatch, capsys):
    """A figure is complete or absent: one half-written when the disk fills is removed."""
    import errno

    import liethermo.top.plotting as pl

    def full(outputs, folder, stem="run", member=0):
        (Path(folder) / f"{stem}_energies.png").write_bytes(b"\x89PNG half")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(pl, "scene_figures", full)
    out = tmp_path / "p.nc"
    assert main(["run", "paper", "-o", str(out), "--no-progress", "--set", "integrator.steps=20"]) == 2
    assert one_line(capsys.readouterr().err) == (f"liethermo: error: cannot write {tmp_path / 'p_*.png'}: "
                                                 "No space left on device (ENOSPC)")
    assert names(tmp_path) == ["p.nc", "p_rk2.nc"]  # the datasets are complete; no figure, no temporary


def test_figure_drafts_of_killed_runs_are_removed(tmp_path, monkeypatch, capsys):
    """A run killed while drawing leaves its hidden draft folder; the next run
    drawing there removes it (one line), and leaves a live process's draft alone."""
    import liethermo.top.plotting as pl

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    stale = tmp_path / f".p_figures.{dead}.x1y2"
    live = tmp_path / f".p_figures.{os.getppid()}.z3w4"
    for d in (stale, live):
        d.mkdir()
        (d / "p_energies.png").write_bytes(b"\x89PNG half")
    monkeypatch.setattr(pl, "scene_figures", lambda outputs, folder, stem="run", member=0: [])
    out = tmp_path / "p.nc"
    assert main(["run", "paper", "-o", str(out), "--no-progress", "--set", "integrator.steps=20"]) == 0
    assert one_line(capsys.readouterr().err) == (
        f"liethermo: removed 1 unfinished figure folder left by killed runs in {tmp_path}")
    assert names(tmp_path) == [live.name, "p.nc", "p_rk2.nc"]


# ---------------------------------------------------------------- refused before any work
@pytest.fixture
def no_simulation(monkeypatch):
    """Fail the test if a kernel is reached: refusals come before any work."""
    import liethermo.runner as lr

    def boom(*a, **k):
        raise AssertionError("a member chunk was simulated")

    monkeypatch.setattr(lr, "run_chunk", boom)


def test_output_in_a_folder_that_takes_no_files(capsys, no_simulation):
    assert main(["run", "paper", "-o", "/proc/x.nc", *TINY]) == 2
    assert one_line(capsys.readouterr().err) == ("liethermo: error: cannot write /proc/x.nc: the folder /proc "
                                                 "does not take new files (No such file or directory)")


def test_output_path_is_a_folder(tmp_path, capsys, no_simulation):
    (tmp_path / "d.nc").mkdir()
    assert main(["run", "paper", "-o", str(tmp_path / "d.nc"), *TINY]) == 2
    assert one_line(capsys.readouterr().err) == f"liethermo: error: cannot write {tmp_path / 'd.nc'}: it is a folder"
    (tmp_path / "f").write_text("")
    assert main(["run", "paper", "-o", str(tmp_path / "f" / "sub" / "x.nc"), *TINY]) == 2
    assert one_line(capsys.readouterr().err) == (f"liethermo: error: cannot write {tmp_path / 'f' / 'sub' / 'x.nc'}: "
                                                 f"{tmp_path / 'f'} is not a folder")
    assert names(tmp_path) == ["d.nc", "f"]


@pytest.fixture
def read_only_dir(tmp_path):
    d = tmp_path / "ro"
    d.mkdir()
    if os.geteuid() == 0:  # root writes through permissions: make the folder immutable instead
        if subprocess.run(["chattr", "+i", str(d)], capture_output=True).returncode != 0:
            pytest.skip("running as root without chattr: no read-only folder to test with")
        yield d
        subprocess.run(["chattr", "-i", str(d)], check=True)
    else:
        d.chmod(0o555)
        yield d
        d.chmod(0o755)


def test_output_in_a_read_only_folder(read_only_dir, capsys, no_simulation):
    out = read_only_dir / "sub" / "x.nc"
    assert main(["run", "paper", "-o", str(out), *TINY]) == 2
    err = one_line(capsys.readouterr().err)
    assert err.startswith(f"liethermo: error: cannot write {out}: cannot create the folder {out.parent} (")
    out = read_only_dir / "x.nc"
    assert main(["run", "paper", "-o", str(out), *TINY]) == 2
    err = one_line(capsys.readouterr().err)
    assert err.startswith(f"liethermo: error: cannot write {out}: the folder {read_only_dir} does not take new files (")
    assert names(read_only_dir) == []


def test_an_ensemble_too_large_for_the_disk(tmp_path, capsys, no_simulation):
    from liethermo.preflight import estimate

    per = estimate(load_scene("paper")).file_per_member
    out = tmp_path / "x.nc"
    assert main(["run", "paper", "-o", str(out), "--set", "ensemble.members=1000000000000"]) == 2
    err = one_line(capsys.readouterr().err)
    assert err.startswith(f"liethermo: error: {out} and {tmp_path / 'x_rk2.nc'} would need about ")
    assert f"(1000000000000 members x {per / 1e3:.3g} kB) but " in err
    assert " free; run fewer members (ensemble.members) or store less (output.every, output.attitude, output.variables)" in err
    assert names(tmp_path) == []


def test_a_member_chunk_too_large_for_the_memory(tmp_path, capsys, no_simulation):
    from liethermo.preflight import available_memory, estimate

    avail = available_memory()
    assert avail is not None and avail > 0
    e = estimate(load_scene("paper"))
    fixed = e.memory - e.chunk_memory  # the program and the writer's buffers (at most 2 disk chunks a variable)
    chunk = 2 * ((avail - fixed) // e.memory_per_member)  # twice what fits
    out = tmp_path / "x.nc"
    args = ["run", "paper", "-o", str(out), "--set", f"ensemble.members={chunk}", "--set", "output.compare=[]"]
    assert main(args + ["--set", f"output.member_chunk={chunk}"]) == 2
    err = one_line(capsys.readouterr().err)
    assert err.startswith("liethermo: error: a run would need about ")
    assert f"(a member chunk of {chunk} members x " in err
    fit = int(err.rsplit(" ", 1)[1])
    assert err.endswith(f"are available; lower output.member_chunk to at most {fit}")
    assert chunk // 4 < fit < chunk
    assert names(tmp_path) == []
    # the advice holds (with room for what other processes take meanwhile)
    assert main(args + ["--set", f"output.member_chunk={fit // 2}", "--check"]) == 0
    assert capsys.readouterr().out.startswith("scene 'paper' is valid: 1 output file(s), about ")


PEAK = """
import json, sys
from liethermo.cli import main

def status(key):
    for line in open("/proc/self/status"):
        if line.startswith(key):
            return int(line.split()[1]) * 1024

args = json.loads(sys.argv[1])
assert main(args + ["-o", sys.argv[2] + "/warm.nc", "--set", "ensemble.members=1"]) == 0  # the program loaded
# the kernels of the measured run (its vectorized loop: a one-member run takes the other), no big arrays
from liethermo import load_scene
from liethermo.top.initial import initial_conditions
from liethermo.top.physics import physics_of_scene
from liethermo.top.methods import MethodChoice
from liethermo.top.simulate import simulate
sc = load_scene("paper", [a for a in args if "=" in a])
om0, R0 = initial_conditions(sc, 0, 1)
i = sc.integrator
simulate(physics_of_scene(sc, 1), om0, R0, i.h, sc.output.every, MethodChoice.from_scene(sc),
         attitude=sc.output.attitude, every=sc.output.every, kernel="fast", compile_only=True)
base = status("VmRSS")
with open("/proc/self/clear_refs", "w") as f:  # the peak starts again from here
    f.write("5")
assert main(args + ["-o", sys.argv[2] + "/x.nc"]) == 0
print(status("VmHWM") - base)
"""


@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="needs Linux's peak-RSS reset")
def test_estimates_match_a_real_run(tmp_path):
    """The file size is estimated to within 1 %, and the memory of a member
    chunk and the writer is an upper bound of what they use, not more than twice it."""
    from liethermo.preflight import estimate

    sets = ["output.compare=[]", "output.figures=false", "output.every=10", "ensemble.members=12000",
            "output.member_chunk=12000"]
    e = estimate(load_scene("paper", sets))
    args = ["run", "paper", "--no-progress"] + [a for x in sets for a in ("--set", x)]
    r = subprocess.run([sys.executable, "-c", PEAK, json.dumps(args), str(tmp_path)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    used = int(r.stdout.split()[-1])
    size = (tmp_path / "x.nc").stat().st_size
    assert abs(e.file_bytes - size) < 0.01 * size, (e.file_bytes, size)
    need = e.chunk_memory + e.writer_memory
    assert used <= need <= 2 * used, (used, need)


# ---------------------------------------------------------------- output names and overwriting
def test_outputs_are_named_by_scene_and_method_and_never_silently_replaced(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    runs = tmp_path / "data" / "runs"
    small = ["--no-progress", "--set", "integrator.steps=20", "--set", "output.figures=false"]
    assert main(["run", "paper", *small, "--check"]) == 0
    assert capsys.readouterr().out.startswith("scene 'paper' is valid: 2 output file(s), about ")
    assert names(tmp_path) == []  # a check leaves nothing, not even the folders
    assert main(["run", "paper", *small]) == 0  # the VI, and RK2 (output.compare)
    assert names(runs) == ["paper_rk2.nc", "paper_vi.nc"]
    stamp = lambda: {p.name: p.stat().st_mtime_ns for p in runs.iterdir()}  # noqa: E731
    first = stamp()
    # another method: its own file; the RK2 comparison is the same scene again, so it is replaced
    assert main(["run", "paper", *small, "--set", "integrator.method=rk4"]) == 0
    assert capsys.readouterr().err == ""
    assert names(runs) == ["paper_rk2.nc", "paper_rk4.nc", "paper_vi.nc"]
    now = stamp()
    assert now["paper_vi.nc"] == first["paper_vi.nc"] and now["paper_rk2.nc"] != first["paper_rk2.nc"]
    # another scene under the same names: refused before any work, naming the first differing key
    assert main(["run", "paper", *small, "--set", "integrator.h=0.05"]) == 2
    assert one_line(capsys.readouterr().err) == (
        "liethermo: error: data/runs/paper_vi.nc exists and holds a run of another scene, differing in "
        "integrator.h (0.1 there, 0.05 here): pass --force to replace it, or -o to write elsewhere")
    assert stamp() == now
    assert main(["run", "paper", *small, "--set", "integrator.h=0.05", "--force"]) == 0
    with netCDF4.Dataset(runs / "paper_vi.nc") as nc:
        assert nc.getncattr("h") == 0.05
    # --resume: outputs complete for this scene are kept as they are
    now = stamp()
    assert main(["run", "paper", *small, "--set", "integrator.h=0.05", "--resume"]) == 0
    assert capsys.readouterr().err.splitlines() == [
        "liethermo: data/runs/paper_vi.nc is complete for this scene: kept",
        "liethermo: data/runs/paper_rk2.nc is complete for this scene: kept"]
    assert stamp() == now
    assert main(["run", "paper", *small, "--resume", "--force"]) == 2
    assert "give one of them" in one_line(capsys.readouterr().err)


def test_an_explicit_output_that_is_not_a_liethermo_file_is_kept(tmp_path, capsys):
    out = tmp_path / "notes.nc"
    out.write_text("my notes")
    assert main(["run", "paper", "-o", str(out), *TINY]) == 2
    assert one_line(capsys.readouterr().err) == (f"liethermo: error: {out} exists and is not a liethermo output: "
                                                 "pass --force to replace it, or -o to write elsewhere")
    assert out.read_text() == "my notes" and names(tmp_path) == ["notes.nc"]
    assert main(["run", "paper", "-o", str(out), *TINY, "--force"]) == 0
    with netCDF4.Dataset(out) as nc:
        assert len(nc.dimensions["member"]) == 3


def test_scene_file_syntax_error_names_the_file(tmp_path, capsys):
    f = tmp_path / "bad.toml"
    f.write_text("[integrator\nh = 0.1\n")
    assert main(["run", str(f), "-o", str(tmp_path / "x.nc")]) == 2
    err = one_line(capsys.readouterr().err)
    assert err.startswith(f"liethermo: error: scene file '{f}': not valid TOML: ") and "(at line 1" in err
    f.write_bytes(b"\xff\xfe[integrator]\n")
    assert main(["run", str(f), "-o", str(tmp_path / "x.nc")]) == 2
    assert one_line(capsys.readouterr().err).startswith(f"liethermo: error: scene file '{f}': not valid TOML: ")
    assert names(tmp_path) == ["bad.toml"]


# ---------------------------------------------------------------- studies
STUDY = """methods = ["vi"]
[study]
kind = "viscosity_sweep"
name = "sweep"
base_scene = "paper"
[scene.ensemble]
members = 256
[sweep]
"fluid.viscosity" = [0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0]
[options]
method = "vi"
h = 0.02
t_end_max = 100.0
outputs = 200
"""


def test_sigterm_stops_a_study_and_the_rerun_finishes_it(tmp_path):
    study = tmp_path / "sweep.toml"
    study.write_text(STUDY)
    outdir = tmp_path / "out"
    p = subprocess.Popen(CLI + ["study", str(study), "-o", str(outdir), "--no-progress"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while time.time() < deadline and len(list((outdir / "points").glob("*.nc"))) < 2:
        assert p.poll() is None, p.communicate()
        time.sleep(0.005)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 143
    line = one_line(err)
    n = len(list((outdir / "points").glob("*.nc")))
    assert 2 <= n < 8
    assert line == (f"liethermo: interrupted by SIGTERM: {n} finished sweep points kept in {outdir / 'points'} "
                    "(rerun the same command to continue)")
    assert not [f for f in names(outdir) + names(outdir / "points") if f.startswith(".")]  # no temporary, no lock
    r = subprocess.run(CLI + ["study", str(study), "-o", str(outdir), "--no-progress"], capture_output=True, text=True)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert len(list((outdir / "points").glob("*.nc"))) == 8


def test_study_folder_that_takes_no_files(tmp_path, capsys, read_only_dir):
    study = tmp_path / "sweep.toml"
    study.write_text(STUDY)
    assert main(["study", str(study), "-o", str(read_only_dir / "s")]) == 2
    err = one_line(capsys.readouterr().err)
    assert err.startswith(f"liethermo: error: cannot write the study to {read_only_dir / 's'}: ")
    (tmp_path / "file").write_text("")
    assert main(["study", str(study), "-o", str(tmp_path / "file")]) == 2
    assert one_line(capsys.readouterr().err) == (f"liethermo: error: cannot write the study to {tmp_path / 'file'}: "
                                                 "it is not a folder")


def test_a_stop_signal_is_recorded_and_raised_at_the_next_check():
    """The handler only records the signal: nothing is raised where it lands
    (in a garbage-collector callback or a library's compiled code the
    exception would be dropped).  check_stop raises it, not inside a critical
    section (which raises it as it ends), and again at every later check, so
    work that swallows the exception still stops at its next check."""
    from liethermo.faults import Interrupted, check_stop, critical, stop_on_signals, stop_received, stopping

    check_stop()  # outside a run: nothing to do
    with stop_on_signals():
        check_stop()  # no signal yet
        assert stop_received() is None
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.05)  # the handler has run by now, and raised nothing here
        assert stop_received() == signal.SIGTERM and not stopping()
        reached = False
        with pytest.raises(Interrupted) as err:
            with critical():
                check_stop()  # held while the section runs
                reached = True
        assert reached and stopping() and err.value.exit_code == 143
        try:
            check_stop()
        except BaseException:  # noqa: BLE001  what a careless library does
            pass
        with pytest.raises(Interrupted):
            check_stop()
    check_stop()  # the handlers are restored: the next run starts clean
    assert stop_received() is None


def test_a_forked_child_does_not_keep_a_killed_runs_output_locked(tmp_path):
    """The run forks a kernel-warming process; killed outright, the run must not
    leave that child holding its output lock (an flock is shared across fork):
    the rerun takes the output over at once."""
    target = tmp_path / "x.nc"
    code = f"""
import multiprocessing, os, signal, sys, time
from liethermo.faults import OutputLock
lock = OutputLock({str(target)!r}).acquire()
child = multiprocessing.get_context("fork").Process(target=time.sleep, args=(30,), daemon=True)
child.start()
print(child.pid, flush=True)
os.kill(os.getpid(), signal.SIGKILL)
"""
    with subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True) as p:
        child = int(p.stdout.readline())
        p.wait()
    try:
        os.kill(child, 0)  # the child outlives its parent
        OutputLock(target).acquire().release()  # and yet the output is free
    finally:
        os.kill(child, signal.SIGKILL)
