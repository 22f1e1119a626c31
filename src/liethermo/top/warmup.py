"""Compile a run's kernels on the second core while the first compiles its own.

A cold ``liethermo run`` compiles one kernel per method it runs (and, for the
variational integrators, a start kernel); numba compiles one function at a
time per process.  :func:`start_warming` hands the kernels the run needs
after its first one to a second process, which compiles them into numba's
on-disk cache while this process compiles the first; when this process gets
to them, it loads them from the cache.  On a warm cache the second process
finds everything there and exits at once.
"""

from __future__ import annotations

import multiprocessing
import os
import sys

from .kernels._jit import CACHE


def _warm(scene_toml: str, jobs: list[tuple[str, str]]) -> None:
    import signal
    import sys

    # Ctrl-C reaches the whole process group: the run decides, and terminates
    # this process (SIGTERM, its default action: nothing here needs cleaning up,
    # numba writes each cache file whole); the run's own handlers, inherited by
    # a fork, are not for this process
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for name in ("SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_DFL)

    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib

    from .initial import initial_conditions
    from .resolve import resolve
    from ..scene import load_scene

    scene = load_scene(tomllib.loads(scene_toml))
    for method, part in jobs:
        sc = scene.with_overrides({"integrator.method": method})
        om0, R0 = initial_conditions(sc, 0, 1)
        run = resolve(sc)
        # the kernels the run's member chunks use, compiled on one member
        run.simulate(om0, R0, steps=run.every, compile_only="start" if part == "start" else True)


def start_warming(scene, methods: list[str]):
    """Start a process compiling what a run of ``methods`` on ``scene`` needs
    besides the first method's main kernel, which this process compiles
    first; returns it (join it before the second method), or None when
    there is nothing to share (one core, no cache, one explicit method)."""
    from .methods import get_method

    if not CACHE or (os.cpu_count() or 1) < 2 or not methods:
        return None
    jobs = []
    if get_method(methods[0]).solves_newton:
        jobs.append((methods[0], "start"))
    jobs += [(m, "all") for m in methods[1:]]
    if not jobs:
        return None
    # fork where it is safe (Linux: no threads run yet in this process): the
    # child starts with everything imported, which on a warm cache is most of its work
    method = "fork" if sys.platform.startswith("linux") else "spawn"
    proc = multiprocessing.get_context(method).Process(
        target=_warm, args=(scene.to_toml(), jobs), daemon=True, name="liethermo-warmup")
    proc.start()
    return proc
