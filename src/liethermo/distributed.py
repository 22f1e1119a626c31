"""Scale out on a Dask cluster: ensembles split into member-chunk tasks.

``liethermo run SCENE --dask local|ADDRESS`` calls :func:`run_scene_dask`.
The ensemble is cut into member ranges ``[lo, hi)``; each range is one Dask
task (:func:`compute_part`) that runs the *same* code as an in-process run
(:func:`liethermo.runner.run_chunk`) and writes its own chunk file
``<OUT>.parts/part-<lo>-<hi>.nc`` atomically (temporary name, then
``os.replace``).  Member i's initial condition depends only on (seed, i)
(:mod:`liethermo.top.initial`) and members never interact in the kernels, so the
numbers do not depend on the split nor on the number of workers or threads:
the combined file is identical to the in-process one.

Failure containment, all provided by Dask and by the file layout — there is
no scheduler here:

* a task that raises is retried by Dask (``retries``); a task whose worker
  dies (killed, out of memory, lost node) is rescheduled on another worker
  (Dask's ``distributed.scheduler.allowed-failures``, default 3);
* a chunk file is either absent or complete (atomic rename), is named by its
  member range and tagged with a hash of the resolved scene, so a task that
  runs twice (worker lost after writing) rewrites the same content and never
  duplicates members; the combine step reads exactly one file per range;
* a rerun after an interruption finds ``<OUT>.parts/index.json`` (the layout
  and scene hash) and submits only the ranges without a valid chunk file.

At the end the chunk files are streamed, one at a time (bounded memory),
into the single output file through :class:`liethermo.io.ChunkedWriter`
(atomic as well), and the ``.parts`` folder is removed unless
``keep_parts=True`` — the kept folder, with its ``index.json``, is also an
``xarray.open_mfdataset``-ready set.

The client, the workers and the output path must share a filesystem (the
tasks write where the client reads).  See docs/distributed.md.

:func:`map_tasks` is the generic helper for other fan-outs (study sweep
points): ``Client.map`` with pure keys and retries, results in input order.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import math
import os
import shutil
import threading
import time
import uuid
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

from . import cf
from .faults import POLL_SECONDS, Interrupted, check_stop, folder_leftovers, remove_files
from .io import ChunkedWriter, parts_dir, write_atomic
from .version import __version__
from .models import model_of
from .runner import _progress_bar, run_chunk, scene_setup
from .scene import scene_to_toml

INDEX_NAME = "index.json"
PARTS_FORMAT = "liethermo-parts-1"
#: Tasks per worker thread the default split aims at (load balance vs per-task overhead).
TASKS_PER_THREAD = 4

# one kernel at a time per worker process: a worker with several threads runs
# its chunks one after the other, each with that many numba threads (numba's
# default threading layer does not allow concurrent parallel launches)
_KERNEL_LOCK = threading.Lock()


# ---------------------------------------------------------------- clients
def make_client(address: Any = "local"):
    """A dask.distributed Client.

    ``"local"``: a LocalCluster owned by the client (closed with it), one
    worker process per core, one thread per worker, numba limited to one
    thread in each worker.  Otherwise ``address`` is a scheduler address
    (``tcp://host:8786``) or a scheduler file path (``*.json``).
    """
    from distributed import Client, LocalCluster

    if address in (None, "local"):
        n = os.cpu_count() or 1
        with _workers_ignore_sigint():
            # dashboard on a free local port: no warning when another cluster holds 8787;
            # the workers' logs silenced: a task's error reaches the client as its exception,
            # and a stopped run's shutdown (workers losing the scheduler) is not an error
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                   dashboard_address="127.0.0.1:0", silence_logs=logging.CRITICAL,
                                   env={"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"})
        client = Client(cluster)
        client._liethermo_cluster = cluster  # closed by close_client
        # its scheduler runs in this process: a run stopped by Ctrl-C cancels tasks while the comms close, which
        # it logs as CRITICAL ("Closed comm ... while trying to write"); silenced until close_client
        log = logging.getLogger("distributed.scheduler")
        client._liethermo_log_level = log.level
        log.setLevel(logging.CRITICAL + 1)
        return client
    if str(address).endswith(".json"):
        return Client(scheduler_file=str(address))
    return Client(address)


@contextlib.contextmanager
def _workers_ignore_sigint():
    """Worker processes started within inherit an ignored SIGINT: a Ctrl-C at
    the terminal (sent to the whole process group) stops the client, which
    cancels the tasks and closes the cluster, instead of printing a traceback
    from every worker."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    import signal

    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def close_client(client) -> None:
    """Close a client made by :func:`make_client` (and its LocalCluster)."""
    cluster = getattr(client, "_liethermo_cluster", None)
    client.close()
    if cluster is not None:
        cluster.close()
        logging.getLogger("distributed.scheduler").setLevel(client._liethermo_log_level)


@contextlib.contextmanager
def client_for(address: Any = "local"):
    """Yield a Client: ``address`` may already be a Client (left open) or what
    :func:`make_client` accepts (closed on exit)."""
    from distributed import Client

    if isinstance(address, Client):
        yield address
        return
    client = make_client(address)
    try:
        yield client
    finally:
        close_client(client)


def map_tasks(func: Callable, items: Iterable, address: Any = "local", *, retries: int = 2,
              progress: bool | None = None, desc: str = "tasks") -> list:
    """``[func(x) for x in items]`` as Dask tasks, results in input order.

    Keys are pure (``tokenize(func, item)``), so resubmitting the same items on
    the same cluster reuses the results; a task that raises is retried up to
    ``retries`` times, one whose worker dies is rescheduled by Dask.  ``func``
    and the items must be picklable and importable on the workers.  The first
    task that still fails raises here, after the others have finished (so
    their side effects, e.g. files, are complete).
    """
    items = list(items)
    if not items:
        return []
    with client_for(address) as client:
        futures = client.map(func, items, pure=True, retries=retries)
        bar = _progress_bar(len(items), progress, desc)
        _wait_all(client, futures, bar, lambda fut: 1, error_step=1)
        return client.gather(futures)


def _cached_point_task(item) -> str:
    from .io import cached_point

    outdir, key, func, args = item
    cached_point(outdir, key, lambda: func(*args))  # writes outdir/points/<key>.nc atomically
    return key


def map_cached_points(outdir: str | os.PathLike, points: Iterable[tuple[str, Callable, tuple]],
                      address: Any = "local", *, retries: int = 2, progress: bool | None = None) -> list[str]:
    """Compute study sweep points as Dask tasks into the studies' resume cache.

    ``points``: ``(key, func, args)`` with ``func(*args) -> xr.Dataset``.  Each
    point not yet in ``outdir/points/<key>.nc`` becomes a task that runs
    :func:`liethermo.io.cached_point` on a worker (``outdir`` must
    be on the shared filesystem); only keys travel back.  Afterwards the
    study's usual ``cached_point`` loop loads every point without recomputing.
    Returns the keys that were computed.
    """
    from .io import point_is_cached

    outdir = str(Path(outdir).resolve())
    todo = [(outdir, k, f, tuple(a)) for k, f, a in points if not point_is_cached(outdir, k)]
    return map_tasks(_cached_point_task, todo, address, retries=retries, progress=progress,
                     desc="sweep points")


# ---------------------------------------------------------------- chunk files
def scene_key(scene: dict) -> str:
    """Hash of the resolved scene and software version: chunk files of another
    scene (or version) are never reused."""
    text = f"{__version__}\n{scene_to_toml(scene)}"
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def part_path(parts: Path, lo: int, hi: int) -> Path:
    return parts / f"part-{lo:012d}-{hi:012d}.nc"


def plan_chunks(members: int, task_members: int) -> list[tuple[int, int]]:
    return [(lo, min(lo + task_members, members)) for lo in range(0, members, task_members)]


def default_task_members(scene: dict, nthreads: int) -> int:
    """Members per task: at most ``output.member_chunk`` (the memory bound),
    else about TASKS_PER_THREAD equal tasks per worker thread (load balance).
    Any split gives the same numbers (member i depends only on (seed, i)), but
    for a model whose last bits depend on the batch
    (:attr:`liethermo.models.Model.chunk_sets_bits`): its tasks are the member chunks."""
    members = int(scene["ensemble"]["members"])
    cap = int(scene["output"]["member_chunk"])
    if model_of(scene).chunk_sets_bits:  # the in-process run's chunks, for the same bits
        return cap
    want = math.ceil(members / max(1, TASKS_PER_THREAD * max(1, nthreads)))
    return max(1, min(cap, want))


def read_part_stats(path: Path, key: str, lo: int, hi: int, scene=None):
    """The stats stored in a finished chunk file, or None if it is missing,
    unreadable, or belongs to another scene/range."""
    import netCDF4

    try:
        with netCDF4.Dataset(path, "r") as nc:
            if (nc.getncattr("liethermo_part_key") != key
                    or int(nc.getncattr("liethermo_part_lo")) != lo
                    or int(nc.getncattr("liethermo_part_hi")) != hi
                    or len(nc.dimensions["member"]) != hi - lo):
                return None
            d = json.loads(nc.getncattr("liethermo_part_stats"))
    except (OSError, KeyError, AttributeError, ValueError, RuntimeError):
        return None
    return model_of(scene if scene is not None else {}).stats_from_dict(d)


def compute_part(scene: dict, lo: int, hi: int, path: str, key: str, attrs: dict,
                 numba_threads: int | None = None) -> dict:
    """The Dask task: members ``lo:hi`` → chunk file ``path`` (atomic).

    Returns ``{"stats": ChunkStats dict, "task_time": s, "skipped": bool}``.
    If a valid chunk file is already there (the task ran before, e.g. on a
    worker that was lost before reporting), it is not recomputed.
    """
    t0 = time.perf_counter()
    path = Path(path)
    st = read_part_stats(path, key, lo, hi, scene)
    if st is not None:
        return {"stats": st.to_dict(), "task_time": time.perf_counter() - t0, "skipped": True}
    if numba_threads is None:
        try:
            from distributed import get_worker

            import numba

            numba_threads = min(int(get_worker().state.nthreads), numba.config.NUMBA_NUM_THREADS)
        except (ImportError, ValueError, AttributeError):
            numba_threads = None
    with _KERNEL_LOCK:
        t1 = time.perf_counter()
        ds, st = run_chunk(scene, lo, hi, threads=numba_threads)
        t_run = time.perf_counter() - t1
    part_attrs = dict(attrs)
    part_attrs.update({
        "liethermo_part_key": key, "liethermo_part_lo": int(lo), "liethermo_part_hi": int(hi),
        "liethermo_part_stats": json.dumps(st.to_dict()),
    })
    # the writer's temporary is created exclusively and locked: two copies of one
    # task (a worker presumed lost that is still running) never write the same
    # temporary file, and a rerun tells a live task's temporary from a dead one's
    w = ChunkedWriter(path, hi - lo, part_attrs)
    t2 = time.perf_counter()
    with w:
        w.write(ds, 0)
    t_write = time.perf_counter() - t2
    return {"stats": st.to_dict(), "task_time": time.perf_counter() - t0, "skipped": False,
            "run_time": t_run, "write_time": t_write}


def _load_index(parts: Path, key: str, members: int) -> list[tuple[int, int]] | None:
    try:
        idx = json.loads((parts / INDEX_NAME).read_text())
    except (OSError, ValueError):
        return None
    if idx.get("format") != PARTS_FORMAT or idx.get("scene_key") != key or idx.get("members") != members:
        return None
    return [tuple(b) for b in idx["chunks"]]


def _write_index(parts: Path, key: str, members: int, chunks, out: Path) -> None:
    parts.mkdir(parents=True, exist_ok=True)
    idx = {
        "format": PARTS_FORMAT, "scene_key": key, "members": members, "output": out.name,
        "chunks": [list(c) for c in chunks],
        "files": [part_path(parts, lo, hi).name for lo, hi in chunks],
        "concat_dim": "member",
    }
    text = json.dumps(idx, indent=1)
    write_atomic(parts / INDEX_NAME, lambda tmp: tmp.write_text(text),
                 temp=parts / f".{INDEX_NAME}.{uuid.uuid4().hex}.tmp")


def _read_part(path: Path):
    """A chunk file as an in-memory dataset with the raw stored values."""
    import xarray as xr

    with xr.open_dataset(path, engine="netcdf4", decode_cf=False) as ds:
        ds = ds.load()
    for name in list(ds.variables):
        v = ds.variables[name]
        if v.dtype.kind == "O":  # netCDF vlen strings come back as objects
            new = xr.Variable(v.dims, np.asarray(v.values).astype(str), v.attrs)
            if name in ds.coords:
                ds = ds.assign_coords({name: new})
            else:
                ds[name] = new
    return ds


def combine_parts(parts: Path, chunks, out: Path, members: int, attrs: dict, member_chunk: int | None = None) -> Path:
    """Stream the chunk files, one at a time, into the single output file (its disk
    chunks bounded by ``member_chunk`` as an in-process run's)."""
    w = ChunkedWriter(out, members, attrs, member_chunk=member_chunk)
    with w:
        for lo, hi in chunks:
            check_stop()
            w.write(_read_part(part_path(parts, lo, hi)), lo)
    return out


# ---------------------------------------------------------------- ensembles
def run_scene_dask(scene: dict | str, out: str | os.PathLike, *, address: Any = "local",
                   progress: bool | None = None, overrides=None, task_members: int | None = None,
                   keep_parts: bool = False, combine: bool = True, retries: int = 2,
                   numba_threads: int | None = None, task: Callable = compute_part,
                   history: str | None = None) -> tuple:
    """Run a scene's ensemble as Dask tasks; same output file as :func:`liethermo.runner.run_scene`.

    ``address``: ``"local"``, a scheduler address, or an existing Client.
    ``task_members``: members per task (default: :func:`default_task_members`;
    on a rerun, the layout recorded in ``<OUT>.parts/index.json``).
    ``combine=False``: leave the result as the chunk files plus
    ``<OUT>.parts/index.json`` (an ``open_mfdataset``-ready set; for
    ensembles too large to funnel through one writer) instead of one file.
    ``task``: the task function (same signature as :func:`compute_part`; tests
    inject faults with it).  Returns ``(None, summary)``; the summary also
    carries ``tasks``, ``tasks_skipped`` (finished before this call) and
    ``task_overhead`` (mean task wall time minus kernel time, s) and
    ``task_timings`` (per computed task: task, kernel, run_chunk and write times, s).
    ``history``: the command line or API call recorded in the files' ``history``
    attribute (default: this call).

    On a stop signal (:class:`liethermo.faults.Interrupted`) the tasks are
    cancelled, the finished chunk files kept for a rerun, and the exception
    goes on with a phrase saying so in its ``kept`` list.
    """
    if history is None:
        history = cf.api_call("liethermo.distributed.run_scene_dask", scene, out, overrides=overrides,
                              combine=None if combine else False)
    scene, attrs, summ = scene_setup(scene, overrides, history)
    out = Path(out)
    key = scene_key(scene)
    parts = parts_dir(out)
    t_wall = time.perf_counter()
    chunks: list = []
    try:
        return _run_scene_dask(scene, attrs, summ, out, key, parts, t_wall, chunks, address, progress,
                               task_members, keep_parts, combine, retries, numba_threads, task)
    except Interrupted as exc:
        # the tasks are cancelled and a local cluster is closed by now: the
        # temporaries its workers were writing are stale, the finished parts stay
        remove_files(folder_leftovers(parts))
        n = sum(1 for lo, hi in chunks if part_path(parts, lo, hi).exists())
        if chunks and n == len(chunks):
            exc.kept.append(f"stopped while combining {out}: all {n} member chunks are kept in {parts}/ "
                            "(rerun the same command to combine them)")
        elif n:
            exc.kept.append(f"stopped with {n}/{len(chunks)} member chunks of {out} done, kept in {parts}/ "
                            "(rerun the same command to continue)")
        else:
            exc.kept.append(f"stopped before any member chunk of {out} was done: nothing kept")
        raise


def _wait_all(client, futures, bar, done: Callable, error_step: int = 0) -> None:
    """Wait for every task; a failure does not stop the others (their side
    effects, e.g. chunk files, are what a rerun resumes from).  ``done(fut)``
    takes each successful task and returns how far it moves ``bar`` (a failed
    one moves it by ``error_step``).  A stop
    signal cancels the tasks; afterwards the first failed task's error is
    raised here.  The wait polls the tasks, checking for a stop signal
    between polls (:func:`liethermo.faults.check_stop`)."""
    from distributed import wait

    first_error = None
    pending = list(futures)
    try:
        while pending:
            check_stop()
            try:
                wait(pending, timeout=POLL_SECONDS, return_when="FIRST_COMPLETED")
            except TimeoutError:  # none finished within the poll
                pass
            is_done = [f.done() for f in pending]
            finished = [f for f, d in zip(pending, is_done) if d]
            pending = [f for f, d in zip(pending, is_done) if not d]
            for fut in finished:
                if fut.status == "error":
                    first_error = first_error or fut
                    step = error_step
                else:
                    step = done(fut)
                if bar:
                    bar.update(step)
    except Interrupted:
        _cancel(client, futures)
        raise
    finally:
        if bar:
            bar.close()
    if first_error is not None:
        first_error.result()  # raises the task's exception


def _cancel(client, futures) -> None:
    try:
        client.cancel(list(futures))
    except Exception:  # pragma: no cover - the cluster may be going away already
        pass


def _run_scene_dask(scene, attrs, summ, out, key, parts, t_wall, chunks_out, address, progress, task_members,
                    keep_parts, combine, retries, numba_threads, task):
    from dask.base import tokenize

    members, steps = summ.members, summ.steps
    with client_for(address) as client:
        chunks = _load_index(parts, key, members)
        if chunks is None or (task_members is not None and chunks != plan_chunks(members, task_members)):
            if task_members is None:
                nthreads = sum(client.nthreads().values()) or 1
                task_members = default_task_members(scene, nthreads)
            chunks = plan_chunks(members, task_members)
            _write_index(parts, key, members, chunks, out)
        chunks_out[:] = chunks
        total = model_of(scene).new_stats()
        todo = []
        for lo, hi in chunks:
            st = read_part_stats(part_path(parts, lo, hi), key, lo, hi, scene)
            if st is None:
                todo.append((lo, hi))
            else:
                total.merge(st)
        bar = _progress_bar(members * steps, progress, f"{summ.scene_name} [{summ.method}, dask]")
        if bar:
            bar.update(sum(hi - lo for lo, hi in chunks if (lo, hi) not in todo) * steps)
        futures = {}
        for lo, hi in todo:
            ppath = str(part_path(parts, lo, hi).resolve())
            # deterministic key per (task function, scene, range, file): resubmitting
            # the same work dedupes on the scheduler, other work never collides
            tkey = f"liethermo-part-{lo}-{hi}-{tokenize(task, key, ppath)}"
            f = client.submit(task, scene, lo, hi, ppath, key, attrs, numba_threads,
                              key=tkey, pure=True, retries=retries)
            futures[f] = (lo, hi)
        overhead = []
        timings = []

        def done(fut) -> int:
            lo, hi = futures[fut]
            res = fut.result()
            st = model_of(scene).stats_from_dict(res["stats"])
            total.merge(st)
            if not res["skipped"]:
                overhead.append(res["task_time"] - st.kernel_time)
                timings.append({"lo": lo, "hi": hi, "task": res["task_time"], "kernel": st.kernel_time,
                                "run": res.get("run_time"), "write": res.get("write_time")})
            return (hi - lo) * steps

        # finished chunk files stay for a rerun when a task fails
        _wait_all(client, list(futures), bar, done)
    t_comb = time.perf_counter()
    if combine:
        combine_parts(parts, chunks, out, members, attrs, int(scene["output"]["member_chunk"]))
        if not keep_parts:
            shutil.rmtree(parts, ignore_errors=True)
    summ.combine_time = time.perf_counter() - t_comb
    summ.wall_time = time.perf_counter() - t_wall
    if hasattr(summ, "wall_what"):  # the workers compile inside their tasks
        summ.wall_what = "the Dask run: its tasks, with the workers' compiling, and the combining"
    summ.finish(total)
    summ.path = out if combine else parts / INDEX_NAME
    summ.tasks = len(chunks)
    summ.tasks_skipped = len(chunks) - len(todo)
    summ.task_overhead = float(np.mean(overhead)) if overhead else float("nan")
    summ.task_timings = timings
    return None, summ
