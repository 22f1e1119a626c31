"""The write pipeline of a run with an output file: chunk k is written on a
thread of its own while chunk k+1 computes, at most two chunks are in memory,
and the file is the one a run that writes each chunk before the next would
write (values, layout, journal); write errors and stop signals end the run
as before."""

from __future__ import annotations

import signal
import threading

import netCDF4
import numpy as np
import pytest

import liethermo.io as lio
import liethermo.runner as lr
from liethermo.faults import Interrupted
from liethermo.runner import run_scene

WAIT = 30  # s: a run that writes before computing on waits this long, then fails
SMALL = ["output.compare=[]", "output.figures=false", "integrator.steps=20", "output.every=5",
         "ensemble.members=40", "output.member_chunk=8", "integrator.method=\"rk2\""]


def _values(path) -> dict:
    with netCDF4.Dataset(path) as nc:
        nc.set_auto_mask(False)
        return {k: v[...] for k, v in nc.variables.items()}


def _serial(monkeypatch):
    """Make the pipeline write each chunk in the caller's thread at once (the
    order of a run without a writer thread)."""
    def put(self, ds, lo, hi, stats):
        self.wait()
        self._write(ds, lo, hi, stats.to_dict())

    monkeypatch.setattr(lr._WritePipeline, "put", put)


def test_the_file_equals_a_serial_runs_and_the_in_memory_dataset(tmp_path, monkeypatch):
    run_scene("paper", tmp_path / "piped.nc", overrides=SMALL, progress=False)
    with monkeypatch.context() as m:
        _serial(m)
        run_scene("paper", tmp_path / "serial.nc", overrides=SMALL, progress=False)
    ds, _ = run_scene("paper", None, overrides=SMALL, progress=False)
    a, b = _values(tmp_path / "piped.nc"), _values(tmp_path / "serial.nc")
    assert list(a) == list(b)
    for k in a:
        assert a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f"), k
    for k in ("omega", "gamma", "entropy_change", "status"):
        assert np.array_equal(a[k], ds[k].values, equal_nan=True), k


def test_no_disk_chunk_spans_two_member_chunks(tmp_path):
    """Each disk chunk is filled by one member chunk and written once: none is
    larger than a member chunk (a narrow variable's 4 MiB chunk would be flushed
    part-filled after every member chunk and rewritten by the next)."""
    run_scene("paper", tmp_path / "x.nc", overrides=SMALL, progress=False)
    with netCDF4.Dataset(tmp_path / "x.nc") as nc:
        sizes = {k: v.chunking()[0] for k, v in nc.variables.items()
                 if "member" in v.dimensions and v.chunking() != "contiguous"}
    assert {"omega", "gamma", "entropy_change"} <= set(sizes)
    assert set(sizes.values()) == {8}, sizes  # output.member_chunk = 8 of 40 members
    assert lio.disk_chunk_members(40, 16) == 40 and lio.disk_chunk_members(40, 16, 8) == 8
    assert lio.disk_chunk_members(2**20, 144, 65536) == 16384  # 4 MiB bounds it first


def test_chunk_k_is_written_while_chunk_k_plus_1_computes(tmp_path, monkeypatch):
    """The write of chunk 0 waits for chunk 1 to start computing: a run that
    wrote before computing on would wait forever (here: time out and fail)."""
    started = {}
    events = []
    real_chunk, real_write = lr.run_chunk, lio.ChunkedWriter.write

    def chunk(scene, lo, hi, **kw):
        events.append(("compute", lo))
        started.setdefault(lo, threading.Event()).set()
        return real_chunk(scene, lo, hi, **kw)

    def write(self, ds, offset, pause=None):
        events.append(("write", offset, threading.current_thread().name))
        if offset == 0:
            assert started.setdefault(8, threading.Event()).wait(timeout=WAIT), "chunk 1 did not start"
        out = real_write(self, ds, offset, pause)
        events.append(("written", offset))
        return out

    monkeypatch.setattr(lr, "run_chunk", chunk)
    monkeypatch.setattr(lio.ChunkedWriter, "write", write)
    run_scene("paper", tmp_path / "x.nc", overrides=SMALL, progress=False)
    writes = [e for e in events if e[0] == "write"]
    assert [e[1] for e in writes] == [0, 8, 16, 24, 32]  # in the plan's order
    assert all(e[2].startswith("liethermo-writer") for e in writes)
    # memory: chunk k+2 starts computing only once chunk k is written
    for k in range(0, 24, 8):
        assert events.index(("written", k)) < events.index(("compute", k + 16))


def test_a_write_error_on_the_writer_thread_ends_the_run_and_leaves_nothing(tmp_path, monkeypatch):
    real = lio.ChunkedWriter.write_arrays

    def write_arrays(self, arrays, offset, pause=None):
        if offset == 16:
            self._fail(OSError(28, "No space left on device"))
        return real(self, arrays, offset, pause)

    monkeypatch.setattr(lio.ChunkedWriter, "write_arrays", write_arrays)
    with pytest.raises(lio.WriteError, match="No space left on device"):
        run_scene("paper", tmp_path / "x.nc", overrides=SMALL, progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_stop_while_a_chunk_is_written_keeps_every_chunk_written(tmp_path, monkeypatch):
    """Stopped while chunk 2 computes and chunk 1 is being written: the kept
    file and its journal hold chunks 0 and 1, and a resume equals a whole run."""
    from liethermo.faults import stop_on_signals

    real_chunk, real_write = lr.run_chunk, lio.ChunkedWriter.write
    writing = threading.Event()
    release = threading.Event()

    def write(self, ds, offset, pause=None):
        if offset == 8:
            writing.set()
            release.wait(timeout=30)
        return real_write(self, ds, offset, pause)

    def chunk(scene, lo, hi, **kw):
        if lo == 16:
            assert writing.wait(timeout=30)
            threading.Timer(0.2, release.set).start()  # the write finishes after the stop
            raise Interrupted(signal.SIGTERM)
        return real_chunk(scene, lo, hi, **kw)

    monkeypatch.setattr(lr, "run_chunk", chunk)
    monkeypatch.setattr(lio.ChunkedWriter, "write", write)
    out = tmp_path / "x.nc"
    with stop_on_signals(), pytest.raises(Interrupted) as exc:
        run_scene("paper", out, overrides=SMALL, progress=False)
    assert "members 0-15 kept in" in exc.value.kept[0]
    monkeypatch.undo()
    run_scene("paper", out, overrides=SMALL, progress=False, resume=True)
    run_scene("paper", tmp_path / "whole.nc", overrides=SMALL, progress=False)
    a, b = _values(out), _values(tmp_path / "whole.nc")
    assert all(np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f") for k in a)


def test_the_write_probe_measures_a_disk_once_per_process(tmp_path, monkeypatch):
    """``--check`` measures the writer's rate; a sweep of checks in one process probes
    each file system once, and a folder that does not exist yet is probed where it will be."""
    from liethermo import io

    calls = []
    real = io._measure_write_rate
    monkeypatch.setattr(io, "_WRITE_RATES", {})
    monkeypatch.setattr(io, "_measure_write_rate", lambda f, n: calls.append(f) or real(f, n))
    rate = io.write_rate(tmp_path / "not" / "yet", nbytes=2**20)
    assert 0 < rate < float("inf") and calls == [tmp_path]
    assert io.write_rate(tmp_path, nbytes=2**20) == rate and len(calls) == 1
    assert not list(tmp_path.iterdir())  # the probe file is gone


def test_the_write_probe_is_no_larger_than_the_file(tmp_path, monkeypatch):
    """A run's estimate probes as many bytes as its file, within 1 MiB … 64 MiB: a small
    file is not outweighed by its probe (the fluid's runs at N ≥ 256 estimate their time
    before they start)."""
    from liethermo import io
    from liethermo.preflight import estimate
    from liethermo.runner import estimate_time
    from liethermo.scene import load_scene

    sizes = []
    real = io._measure_write_rate

    def measure(folder, nbytes):
        sizes.append(nbytes)
        seen = set(folder.iterdir())
        rate = real(folder, nbytes)
        assert set(folder.iterdir()) == seen
        return rate

    monkeypatch.setattr(io, "_WRITE_RATES", {})
    monkeypatch.setattr(io, "_measure_write_rate", measure)
    written = []
    real_write = io.ChunkedWriter.write_arrays
    monkeypatch.setattr(io.ChunkedWriter, "write_arrays",
                        lambda self, arrays, offset, pause=None: written.append(
                            sum(a.nbytes for a in arrays.values())) or real_write(self, arrays, offset, pause))
    for members, want in ((4, io.WRITE_PROBE_MIN_BYTES), (2**20, io.WRITE_PROBE_BYTES)):
        sc = load_scene("paper", {"ensemble.members": members, "integrator.steps": 10, "output.every": 5})
        written.clear()
        est = estimate_time(sc, tmp_path / "run.nc")
        fb = estimate(sc).file_bytes
        assert sizes[-1] == min(io.WRITE_PROBE_BYTES, max(io.WRITE_PROBE_MIN_BYTES, fb)) == want
        assert sum(written) == want and est.rate > 0  # the probe wrote what it was asked, no more


def test_the_kernel_probe_grows_until_its_calls_outweigh_their_fixed_cost(monkeypatch):
    """A probe call of a few milliseconds is mostly its fixed cost (waking the threads,
    a core back from idle): the probe grows, steps first and then members, until a call
    takes PROBE_MIN_SECONDS, and the estimate is then the kernels' per member-step time.
    A kernel modelled as 2 ms a call plus 3 ns a member-step: the first call
    (8192 x 200) alone would say 4.2 ns, 41 % high."""
    from types import SimpleNamespace

    from liethermo.scene import load_scene
    from liethermo.top import model as tm
    from liethermo.top import resolve as tr

    per_step, fixed = 3e-9, 2e-3
    calls = []

    def simulate(om0, R0, steps, every):
        calls.append((om0.shape[0], steps))
        return SimpleNamespace(wall_time=fixed + per_step * om0.shape[0] * steps,
                               compile_time=0.5 if len(calls) == 1 else 0.0)

    real = tr.resolve
    monkeypatch.setattr(tr, "resolve", lambda sc: SimpleNamespace(
        members=real(sc).members, steps=real(sc).steps, choice=real(sc).choice, simulate=simulate))
    monkeypatch.setattr(tm, "label_chunk", lambda *a, **k: None)
    for members, steps in ((10**6, 1000), (10**6, 300), (5000, 100)):
        calls.clear()
        sc = load_scene("paper", {"ensemble.members": members, "integrator.steps": steps, "output.every": steps,
                                  "integrator.method": "rk2"})
        est = tm.estimate_time(sc)
        assert calls[0] == (min(members, tm.PROBE_MEMBERS), min(steps, tm.PROBE_STEPS))  # compiles or loads
        timed = calls[-tm.PROBE_REPEATS:]  # the fastest of these counts; the calls before grew the probe
        assert len(set(timed)) == 1 and len(calls) <= 1 + tm.PROBE_GROWTHS + tm.PROBE_REPEATS
        assert all(a[0] <= b[0] and a[1] <= b[1] for a, b in zip(calls, calls[1:]))  # it only grows
        pm, ps = timed[0]
        assert (est.probe_members, est.probe_steps) == (pm, ps) and ps <= steps and est.compile_seconds == 0.5
        assert pm <= max(min(members, tm.PROBE_MEMBERS), int(sc["output"]["member_chunk"]))
        most = min(members, max(tm.PROBE_MEMBERS, int(sc["output"]["member_chunk"])))
        assert ps == steps or pm == min(members, tm.PROBE_MEMBERS)  # steps first
        if most * steps * per_step >= tm.PROBE_MIN_SECONDS:  # room to grow: the fixed cost is outweighed
            assert est.probe_seconds >= tm.PROBE_MIN_SECONDS
            assert est.seconds == pytest.approx(per_step * members * steps, rel=0.03)
        else:  # a member chunk of the run's steps is shorter: the probe is that
            assert (pm, ps) == (most, steps)


class _Stats:
    def __init__(self, kernel_time):
        self.kernel_time = kernel_time

    def to_dict(self):
        return {"kernel_time": self.kernel_time}


class _Journal:
    chunks: list = []

    def save(self, path):
        pass


def test_the_writer_gives_way_to_the_kernels_while_it_keeps_up(tmp_path):
    """While the kernels run (they take every core) the writer waits, and writes once
    they end; once the main thread has had to wait for a write longer than a tenth of
    a chunk's kernel time, it writes beside the kernels."""
    from liethermo.threads import kernels_running

    events = []

    class Writer:
        delay = 0.0

        def write(self, ds, offset, pause=None):
            if pause is not None:
                pause()
            threading.Event().wait(self.delay)
            events.append(offset)
            return {}

        def sync(self):
            pass

    w = Writer()
    pipe = lr._WritePipeline(w, _Journal(), tmp_path / "journal")
    try:
        with kernels_running():
            pipe.put(None, 0, 1, _Stats(kernel_time=1.0))
            threading.Event().wait(0.3)
            assert events == []  # waiting for the kernels
        pipe.wait()
        assert events == [0] and pipe.give_way
        w.delay = 0.3  # a write now takes longer than the kernels it could hide behind
        pipe.put(None, 1, 2, _Stats(kernel_time=0.01))
        pipe.put(None, 2, 3, _Stats(kernel_time=0.01))  # waits 0.3 s for chunk 1: > 0.001 s
        assert not pipe.give_way
        w.delay = 0.0
        pipe.wait()
        with kernels_running():
            pipe.put(None, 3, 4, _Stats(kernel_time=1.0))
            pipe._pending.result(timeout=10)  # written while the kernels run (a writer giving way would time out)
            assert events == [0, 1, 2, 3]
    finally:
        pipe.close()
