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

from .kernels._jit import CACHE


def _warm(scene_toml: str, jobs: list[tuple[str, str]]) -> None:
    import signal
    import sys

    # Ctrl-C reaches the whole process group: the run decides, and terminates this process
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib

    from .initial import initial_conditions
    from .physics import physics_of_scene
    from .scene import load_scene
    from .simulate import simulate

    scene = load_scene(tomllib.loads(scene_toml))
    for method, part in jobs:
        sc = scene.with_overrides({"integrator.method": method})
        integ = sc.integrator
        om0, R0 = initial_conditions(sc, 0, 1)
        every = int(sc.output.every)
        simulate(physics_of_scene(sc, 1), om0, R0, float(integ.h), every, method,
                 friction=integ.friction, start=integ.start, entropy=integ.entropy,
                 attitude=bool(sc.output.attitude), every=every,
                 newton_tol=float(integ.newton_tol), newton_maxiter=int(integ.newton_maxiter),
                 compile_only="start" if part == "start" else True)


def start_warming(scene, methods: list[str]):
    """Start a process compiling what a run of ``methods`` on ``scene`` needs
    besides the first method's main kernel, which this process compiles
    first; returns it (join it before the second method), or None when
    there is nothing to share (one core, no cache, one explicit method)."""
    from .methods import get_method

    if not CACHE or (os.cpu_count() or 1) < 2 or not methods:
        return None
    jobs = []
    if get_method(methods[0]).family == "vi":
        jobs.append((methods[0], "start"))
    jobs += [(m, "all") for m in methods[1:]]
    if not jobs:
        return None
    proc = multiprocessing.get_context("spawn").Process(
        target=_warm, args=(scene.to_toml(), jobs), daemon=True, name="liethermo-warmup")
    proc.start()
    return proc
