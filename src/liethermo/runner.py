"""Run a scene of any model: member chunks → labelled datasets → netCDF.

:func:`run_scene` is what ``liethermo run`` calls.  Members are simulated in
chunks of ``output.member_chunk``; with an output path, a writer thread
writes chunk k while chunk k+1 computes (:class:`_WritePipeline`), so memory
is bounded by two chunks whatever the ensemble size, and the file is the one
a run writing each chunk before computing the next would write.  What a chunk is (initial conditions,
kernels, variables, stats) is the scene's model's
(:func:`liethermo.models.model_of`); this module only orders, writes,
journals and resumes the chunks.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import xarray as xr

from . import cf
from .faults import check_stop
from .models import model_of
from .scene import load_scene, scene_to_toml


def scene_setup(scene, overrides=None, history: str | None = None) -> tuple:
    """Resolve a scene: ``(scene, global attributes, empty summary)``;
    ``history`` is the command line or API call stored in the attributes."""
    if overrides or not hasattr(scene, "with_overrides"):
        scene = load_scene(scene, overrides)
    attrs, summ = model_of(scene).setup(scene, history)
    return scene, attrs, summ


def run_chunk(scene, lo: int, hi: int, *, progress_cb=None, kernel: str | None = None,
              threads: int | None = None) -> tuple:
    """Members ``lo:hi`` of a resolved scene: ``(labelled chunk, its stats)``.

    The one code path shared by :func:`run_scene` and the Dask tasks of
    :mod:`liethermo.distributed`; member i's result depends only on (scene, i).
    ``progress_cb(n)`` gets the number of member-steps just done.
    """
    from .threads import pools, usable_cores

    check_stop()  # a stop signal whose exception a library swallowed still stops the run
    model = model_of(scene)
    # the pools fit the cores this process may use (or the threads it was given); inside a
    # run's chunk loop, which set the same, nothing is set again
    with pools(model.thread_counts(scene, threads or usable_cores())):
        return model.run_chunk(scene, lo, hi, progress_cb=progress_cb, kernel=kernel, threads=threads)


def estimate_time(scene, out: str | Path | None = None):
    """The run's time on this machine (``.seconds``, ``.line()``, ``.warnings()``):
    the model's probe (kernel time, and what else the model times), run with the
    thread pools the run will use, plus writing the file at the rate a probe
    write measures in ``out``'s folder (the current folder without ``out``): as
    many bytes as the file, from :data:`liethermo.io.WRITE_PROBE_MIN_BYTES` to
    :data:`liethermo.io.WRITE_PROBE_BYTES`.
    A model without :class:`liethermo.models.Estimates` says it has none."""
    from .models import Estimates
    from .threads import pools, usable_cores

    model = model_of(scene)
    if not isinstance(model, Estimates):
        return _NoTimeEstimate(model.title or model.name)
    with pools(model.thread_counts(scene, usable_cores())):  # the probe runs as the run will
        inner = model.estimate_time(scene)
    from .io import WRITE_PROBE_BYTES, WRITE_PROBE_MIN_BYTES, write_rate
    from .preflight import estimate

    folder = Path(out).parent if out is not None else Path.cwd()
    file_bytes = estimate(scene).file_bytes
    probe = min(WRITE_PROBE_BYTES, max(WRITE_PROBE_MIN_BYTES, file_bytes))
    return _WithWriting(inner, file_bytes, write_rate(folder, probe), folder)


class _WithWriting:
    """A model's time estimate with the time to write the file added."""

    def __init__(self, inner, file_bytes: int, rate: float, folder: Path):
        self.inner, self.file_bytes, self.rate, self.folder = inner, int(file_bytes), float(rate), folder

    @property
    def write_seconds(self) -> float:
        return self.file_bytes / self.rate if self.rate > 0 else float("inf")

    @property
    def seconds(self) -> float:
        """The whole run: the model's figure (kernels, and labelling where it says so) and writing."""
        return getattr(self.inner, "total_seconds", self.inner.seconds) + self.write_seconds

    def line(self) -> str:
        from .faults import human_bytes

        return (self.inner.line() + "\n"
                f"  writing: about {human_bytes(self.file_bytes)} at {self.rate / 1e6:.3g} MB/s (a probe write "
                f"in {self.folder}): about {human_seconds(self.write_seconds)}; the run in all about "
                f"{human_seconds(self.seconds)} (not compiling, start-up or figures; a writer thread "
                "overlaps writing with computing where cores are free)")

    def warnings(self) -> list[str]:
        return self.inner.warnings()

    def cautions(self) -> list[str]:
        """The warnings a run gives before it starts, however long it takes (the model's
        ``cautions()``, where it has any)."""
        return list(getattr(self.inner, "cautions", lambda: [])())


class _NoTimeEstimate:
    """The time estimate of a model that offers none."""

    seconds = 0.0

    def __init__(self, title: str):
        self.title = title

    def line(self) -> str:
        return f"  time: {self.title} gives no estimate before a run"

    def warnings(self) -> list[str]:
        return []

    def cautions(self) -> list[str]:
        return []


def human_seconds(s: float) -> str:
    """``0.42 s``, ``3.1 min``, ``2.5 h``, ``1.3 days``."""
    if not np.isfinite(s):
        return "unknown"
    if s < 60:
        return f"{s:.2g} s" if s < 10 else f"{s:.0f} s"
    if s < 3600:
        return f"{s / 60:.1f} min"
    if s < 86400:
        return f"{s / 3600:.1f} h"
    return f"{s / 86400:.1f} days"


def run_scene(scene, out: str | Path | None = None, *, overrides=None,
              progress: bool | None = None, kernel: str | None = None,
              history: str | None = None, resume=False) -> tuple:
    """Run one scene with its own method.

    With ``out``: streams member chunks into the netCDF file (atomically) and
    returns ``(None, summary)``; without: returns the in-memory dataset.
    ``history``: the command line or API call recorded in the ``history``
    attribute (default: this call, ``liethermo.runner.run_scene(...)``).

    ``resume``: go on from what an interrupted or killed run of the same
    scene left for ``out`` (``True``: the best of
    :func:`liethermo.io.resume_sources`, or a given :class:`liethermo.io.ResumeSource`); the scene must be
    the same (the caller checks it: :func:`liethermo.preflight.prepare_run`).
    On a stop signal (:class:`liethermo.faults.Interrupted`) the chunks done
    are kept in ``<out>.partial`` for a resume, and the exception goes on
    with a phrase saying so in its ``kept`` list.
    """
    if history is None:
        history = cf.api_call("liethermo.runner.run_scene", scene, out, overrides=overrides)
    scene, attrs, summ = scene_setup(scene, overrides, history)
    members, steps = summ.members, summ.steps
    chunk = int(scene["output"]["member_chunk"])
    t_wall = time.perf_counter()
    _warm_labelling()
    bar = _progress_bar(members * steps, progress, f"{scene['scene']['name']} [{summ.method}]")
    model = model_of(scene)
    total = model.new_stats()
    from .threads import pools, usable_cores

    try:  # the pools fit the cores this process may use, set once for the run: each chunk keeps them
        with pools(model.thread_counts(scene, usable_cores())):
            if out is None:
                pieces = []
                for lo in range(0, members, chunk):
                    hi = min(lo + chunk, members)
                    ds, st = run_chunk(scene, lo, hi, progress_cb=bar.update if bar else None, kernel=kernel)
                    total.merge(st)
                    pieces.append(ds)
            else:
                _run_to_file(scene, attrs, Path(out), summ, total, bar, kernel, resume, model)
    finally:
        if bar:
            bar.close()
    # compiling (or loading) the kernels happens inside the first chunk: the wall
    # time the summary reports is the simulating and writing around it
    summ.wall_time = max(time.perf_counter() - t_wall - getattr(total, "compile_time", 0.0), 0.0)
    summ.finish(total)
    if out is not None:
        summ.path = Path(out)
        return None, summ
    ds = xr.concat(pieces, dim="member", data_vars="minimal", coords="minimal", compat="override",
                   join="override") if len(pieces) > 1 else pieces[0]
    ds.attrs.update(attrs)
    return ds, summ


_WARMED = False


def _warm_labelling() -> None:
    """Start, on a thread of its own, what labelling the first chunk would otherwise
    wait for: xarray's first variable imports dask where it is installed (0.3-0.9 s
    measured), once per process; it then overlaps the first chunk's kernels, which
    release the GIL.  A failure here only means the first chunk pays it."""
    global _WARMED
    if _WARMED:
        return
    _WARMED = True

    def warm():
        try:
            xr.Variable(("member",), np.zeros(1))
        except Exception:  # pragma: no cover - the chunk's own labelling reports any problem
            pass

    import threading

    threading.Thread(target=warm, name="liethermo-warm", daemon=True).start()


def _run_to_file(scene, attrs, out: Path, summ, total, bar, kernel, resume, model) -> None:
    """The chunk loop of a run with an output file: write, flush and journal
    each chunk; resume; keep the partial file on a stop signal."""
    from .faults import Interrupted, critical
    from .io import ChunkedWriter, Journal, journal_path, resume_sources

    members, steps = summ.members, summ.steps
    chunk = int(scene["output"]["member_chunk"])
    plan = [(lo, min(lo + chunk, members)) for lo in range(0, members, chunk)]
    source = None
    if resume is True:
        found = resume_sources(out)
        source = found[0] if found else None
    elif resume:
        source = resume
    writer = ChunkedWriter(out, members, attrs, member_chunk=chunk)
    journal = Journal(out, scene_to_toml(scene), members, chunk)
    jpath = journal_path(writer.tmp)
    i = 0
    copying = finished = False
    try:
        if source is not None and source.journal.chunks:
            copying = True
            recs = source.journal.chunks[:len(plan)]
            if all([r["lo"], r["hi"]] == list(plan[k]) for k, r in enumerate(recs)):
                writer.define_like(source.data)  # the layout the earlier run wrote
                for rec, arrays in source.read_chunks(writer.member_vars):
                    check_stop()
                    with critical():
                        crc = writer.write_arrays(arrays, rec["lo"])
                        writer.sync()  # flushed chunk by chunk as the run did: HDF5 places them alike
                        journal.chunks.append({"lo": rec["lo"], "hi": rec["hi"], "crc": crc, "stats": rec["stats"]})
                    st = model.stats_from_dict(rec["stats"])
                    st.kernel_time = 0.0  # spent by the earlier run: not this run's throughput
                    total.merge(st)
                    if bar:
                        bar.update((rec["hi"] - rec["lo"]) * steps)
                    i += 1
                    del arrays
                with critical():
                    writer.sync()
                    journal.save(jpath)
            copying = False
            summ.resumed_members = journal.members_done
            source.remove()  # superseded by this run's file and journal
            source = None
        pipe = _WritePipeline(writer, journal, jpath)
        try:
            for k in range(i, len(plan)):
                lo, hi = plan[k]
                ds, st = run_chunk(scene, lo, hi, progress_cb=bar.update if bar else None, kernel=kernel)
                pipe.put(ds, lo, hi, st)  # waits for the previous chunk's write, then writes this one
                del ds
                total.merge(st)
            pipe.wait()
        finally:
            pipe.close()  # a chunk being written is complete (or failed) before the file is kept
        with critical():
            writer.close()
            _unlink(jpath)
            finished = True
    except Interrupted as exc:
        if finished:  # the signal came while the file was being completed
            exc.kept.append(f"{out} written")
            raise
        what = _interrupted(exc, writer, journal, jpath, out, plan, copying, source)
        exc.kept.append(what)
        raise
    except BaseException:
        writer.abort()
        _unlink(jpath)
        raise


class _WritePipeline:
    """Write member chunks on a thread of their own while the next chunk computes.

    ``put(ds, lo, hi, stats)`` waits until the chunk before is written (so at
    most two chunks are in memory: the one being written and the one being
    computed), then hands this one to the writer thread: encode, write, flush,
    journal, in the order of the plan, so the file and journal are those of a
    run that writes each chunk before computing the next.  The kernels release
    the GIL, so the write (netCDF, CRC-32, the page cache) overlaps them.  A
    write error is raised from the next ``put`` or ``wait``; a stop signal in
    the main thread lets the chunk being written finish first (``close``), so
    a kept partial file holds every chunk its journal lists.

    The writer gives way to the kernels: while they run (they use every core it
    could take) it waits between variables (:func:`liethermo.threads.wait_for_kernels`),
    and it writes in the host's share of each chunk instead (labelling it, setting
    up the next).  That holds while it keeps up: once the main thread has waited
    for a write longer than GIVE_WAY_WAIT of the chunk's kernel time, the writer
    writes beside the kernels for the rest of the run (a run that writes much).
    Either way the file is the same.
    """

    #: the main thread's wait for a write, as a share of the chunk's kernel time, beyond which
    #: the writer stops giving way to the kernels
    GIVE_WAY_WAIT = 0.1

    def __init__(self, writer, journal, jpath: Path):
        from concurrent.futures import ThreadPoolExecutor

        self.writer, self.journal, self.jpath = writer, journal, jpath
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="liethermo-writer")
        self._pending = None
        self.give_way = True

    def _write(self, ds, lo: int, hi: int, stats: dict) -> None:
        from .threads import wait_for_kernels

        pause = wait_for_kernels if self.give_way else None
        crc = self.writer.write(ds, lo, pause)
        if pause is not None:
            pause()
        self.writer.sync()
        self.journal.chunks.append({"lo": lo, "hi": hi, "crc": crc, "stats": stats})
        self.journal.save(self.jpath)

    def wait(self) -> None:
        """Until the chunk handed over last is written (its error raised here);
        checks for a stop signal while waiting."""
        from concurrent.futures import wait

        from .faults import wait_checking

        fut, self._pending = self._pending, None
        if fut is not None:
            try:
                wait_checking(lambda t: bool(wait([fut], timeout=t).done))
            except BaseException:
                self._pending = fut  # close() still waits for it
                raise
            fut.result()

    def put(self, ds, lo: int, hi: int, stats) -> None:
        t0 = time.perf_counter()
        self.wait()
        if time.perf_counter() - t0 > self.GIVE_WAY_WAIT * getattr(stats, "kernel_time", 0.0):
            self.give_way = False
        self._pending = self._pool.submit(self._write, ds, lo, hi, stats.to_dict())

    def close(self) -> None:
        """Let a write in progress finish (its error is dropped: an exception is on its way)."""
        fut, self._pending = self._pending, None
        if fut is not None:
            try:
                fut.result()
            except BaseException:
                pass
        self._pool.shutdown(wait=True)


def _unlink(p: Path) -> None:
    try:
        p.unlink()
    except FileNotFoundError:
        pass


def _interrupted(exc, writer, journal, jpath, out, plan, copying, source) -> str:
    """Keep what a stopped run completed; the phrase for the one line."""
    from .io import journal_path, partial_path

    done = len(journal.chunks)
    where = f"member chunk {min(done + 1, len(plan))}/{len(plan)} of {out}"
    if copying or not done:
        writer.abort()
        _unlink(jpath)
        if source is not None:
            return (f"stopped at {where} while resuming: {source.data} kept as it was "
                    "(rerun with --resume to continue)")
        return f"stopped at {where}: no member chunk was complete, nothing kept"
    part = partial_path(out)
    try:
        writer.keep(part)
        journal.save(journal_path(part))
    except Exception:  # the file could not be closed or kept: do not leave a broken one
        writer.abort()
        _unlink(part)
        _unlink(journal_path(part))
        return f"stopped at {where}: the partial file could not be kept"
    finally:
        _unlink(jpath)
    hi = journal.members_done
    return (f"stopped at {where}: members 0-{hi - 1} kept in {part} "
            "(rerun with --resume to continue)")


def _progress_bar(total: int, progress: bool | None, desc: str):
    """A tqdm bar over member-steps (auto: only on a terminal and for long runs)."""
    if progress is False:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="member-step", unit_scale=True, leave=False,
                disable=None if progress is None else False, mininterval=0.5)
