"""What the three Zeitlin studies share: scenes, methods, steps, warm timing."""

from __future__ import annotations

import time

import numpy as np

from ..zeitlin import run as zr
from ..zeitlin.scene import DEFAULTS, METHODS
from .common import StudyError, study_scene

#: what a Zeitlin study compares (the reference is what they measure against)
ZEITLIN_METHODS = tuple(m for m in METHODS if m != "reference")


def zeitlin_scene(s: dict, overrides: dict | None = None):
    sc = study_scene(s, overrides)
    if getattr(sc, "model", None) != "zeitlin":
        raise StudyError("study.base_scene: a Zeitlin study needs a Zeitlin scene (with a [zeitlin] table), "
                         f"e.g. zeitlin_decay; got {s['study'].get('base_scene')!r}")
    return sc


def check_methods(s: dict) -> list[str]:
    methods = s.get("methods", [])
    for m in methods:
        if m not in ZEITLIN_METHODS:
            raise StudyError(f"methods: {m!r} is not a method of the Zeitlin fluid ({', '.join(ZEITLIN_METHODS)})")
    return list(methods)


def advance(method: str, W, q, h: float, steps: int, nu: float, b, composition="small_error",
            tol=DEFAULTS["integrator"]["tol"], max_iter=100, state: dict | None = None):
    """``steps`` steps of ``method`` on a batch; returns W, q and the fixed-point
    iterations per step (mean over members), raising if a member fails.
    ``state``: a dict carried from one call to the next (the fixed point's
    predictor), so that a run cut into calls costs what one call would."""
    fac = zr.factors(method, composition) if method != "rk4" else ()
    state = {} if state is None else state
    if method != "rk4" and "predictor" not in state:
        state["predictor"] = zr.Predictor(len(fac), W.shape[0], W.shape[-1])
        state["D"] = None
    members = np.arange(W.shape[0])
    its = 0.0
    for _ in range(steps):
        if method == "rk4":
            W, q = zr.rk4_step(W, q, h, nu, b)
        else:
            W, q, it, failed, state["D"] = zr.split_step(W, q, h, nu, b, fac, tol, max_iter, state["D"],
                                                         state["predictor"], members)
            if failed.any():
                raise ArithmeticError(f"{method} at h = {h:g} s: the fixed point did not converge")
            its += float(it.mean())
    return W, q, its / max(steps, 1)


def step_seconds(method: str, W, h: float, nu: float, b, min_time: float = 0.2) -> float:
    """Warm wall time of one step of ``method`` on the batch W (seconds per step):
    a few steps compile and warm (and fill the predictor), then runs of doubling
    length are timed until one takes at least ``min_time``."""
    q = np.zeros(W.shape[0])
    state: dict = {}
    W, q, _ = advance(method, W, q, h, 5, nu, b, state=state)
    n = 4
    while True:
        t0 = time.perf_counter()
        W, q, _ = advance(method, W, q, h, n, nu, b, state=state)
        t = time.perf_counter() - t0
        if t >= min_time:
            return t / n
        n *= 2
