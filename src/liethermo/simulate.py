"""Array-level driver: run an ensemble with any method, in chunks.

This layer knows numpy and the kernels, not xarray or files.  It allocates
the outputs, applies the staggered start, advances the kernels chunk by chunk
(reporting progress) and returns a :class:`Trajectory`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numba
import numpy as np

from .kernels import ensemble as _ens
from .kernels.model import NPARAM, NSTATE_ATTITUDE, NSTATE_BASE, P_C, P_GX, P_GY, P_GZ, P_I1, P_I2, P_I3
from .kernels import rk as _rk
from .methods import FRICTION, STARTS, get_method

STATUS_OK = _ens.STATUS_OK
STATUS_NEWTON = _ens.STATUS_NEWTON
STATUS_NONFINITE = _ens.STATUS_NONFINITE
STATUS_MEANINGS = {
    STATUS_OK: "ok",
    STATUS_NEWTON: "newton_not_converged",
    STATUS_NONFINITE: "non_finite",
}

#: Reference substep: h_ref · ω_bound ≤ this (measured: ≤ 1e-15 on the paper scene).
REFERENCE_STEP_ANGLE = 0.05
DEFAULT_NEWTON_TOL = 1e-14
CHUNK_MEMBER_STEPS = 2_000_000
SMALL_ENSEMBLE = 64
DEFAULT_NEWTON_MAXITER = 30


@dataclass
class Trajectory:
    """Result of :func:`simulate`.

    ``states[m, j]`` is the flat state (model.py layout) of member m at step
    ``k = j * every`` (time ``k h``); ``j = 0`` is the initial state actually
    used (with the staggered start: Ω₀ ≈ Ω(h/2)).  Values after a member's
    failure are NaN.
    """

    method: str
    friction: str
    start: str
    h: float
    steps: int
    every: int
    params: np.ndarray
    states: np.ndarray
    status: np.ndarray
    fail_step: np.ndarray
    newton_iterations: np.ndarray  # total per member
    newton_max: np.ndarray  # max per step, per member
    steps_done: np.ndarray
    max_h_omega: np.ndarray
    wall_time: float = 0.0
    reference_substeps: int = 0
    extra: dict = field(default_factory=dict)

    @property
    def step_index(self) -> np.ndarray:
        return np.arange(self.states.shape[1]) * self.every

    @property
    def times(self) -> np.ndarray:
        return self.step_index * self.h

    @property
    def omega(self):
        return self.states[..., 0:3]

    @property
    def gamma(self):
        return self.states[..., 3:6]

    @property
    def sigma(self):
        return self.states[..., 6]

    @property
    def attitude(self):
        if self.states.shape[-1] < NSTATE_ATTITUDE:
            return None
        return self.states[..., 7:16].reshape(self.states.shape[:-1] + (3, 3))


def omega_bound(y0: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Per-member upper bound (rad s⁻¹) on |Ω(t)| of the continuous flow: the
    mechanical energy can only decrease, so K(t) ≤ K₀ + 2|g⃗|; plus the
    friction and pendulum rates."""
    I = params[:, [P_I1, P_I2, P_I3]]
    Imin = I.min(axis=1)
    K0 = 0.5 * np.sum(I * y0[:, 0:3] ** 2, axis=1)
    g = np.linalg.norm(params[:, [P_GX, P_GY, P_GZ]], axis=1)
    return np.sqrt(2.0 * (K0 + 2.0 * g) / Imin) + params[:, P_C] / Imin + np.sqrt(g / Imin)


def reference_substeps(h: float, y0: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Per-member DOP853 substep count for a step h, from each member's own data."""
    wb = omega_bound(y0, params)
    n = np.ceil(h * np.where(np.isfinite(wb), wb, 0.0) / REFERENCE_STEP_ANGLE)
    return np.maximum(1, n).astype(np.int64)


def staggered_omega(y0: np.ndarray, params: np.ndarray, h: float) -> np.ndarray:
    """Ω(h/2) from the initial data, by the high-accuracy reference (N, 3)."""
    Y = np.array(y0[:, :NSTATE_BASE], dtype=np.float64, order="C")
    N, n = Y.shape
    OUT = np.full((N, 1, n), np.nan)
    IS = np.zeros((N, _ens.NISTAT), np.int64)
    IS[:, _ens.IS_NSUB] = reference_substeps(0.5 * h, Y, params)
    FS = np.zeros((N, _ens.NFSTAT))
    _ens.advance_ensemble(_ens.METHOD_REFERENCE, Y, np.ascontiguousarray(params), 0.5 * h, 1, 1,
                          0.5, 0.5, DEFAULT_NEWTON_TOL, 1, 0, _rk.DOP853_A, _rk.DOP853_B, OUT, IS, FS)
    return OUT[:, 0, 0:3].copy()


def simulate(
    y0: np.ndarray,
    params: np.ndarray,
    h: float,
    steps: int,
    method: str = "vi",
    *,
    friction: str = "trapezoid",
    start: str = "node",
    every: int = 1,
    newton_tol: float = DEFAULT_NEWTON_TOL,
    newton_maxiter: int = DEFAULT_NEWTON_MAXITER,
    ref_substeps: int | None = None,
    chunk_steps: int | None = None,
    progress: Callable[[int], None] | None = None,
    threads: int | None = None,
    kernel: str = "auto",
) -> Trajectory:
    """Integrate an ensemble.

    y0: (N, 7) or (N, 16) initial states (model.py layout; 16 = with attitude);
    params: (N, NPARAM); h in s; ``steps`` steps, keeping every ``every``-th.
    ``progress(n)`` is called with the number of steps just advanced.
    ``kernel``: "fast" (vectorized blocks, :mod:`liethermo.kernels.fast`),
    "simple" (one member per prange iteration) or "auto" (= "fast"); both
    give bitwise the same results.
    """
    m = get_method(method)
    if kernel not in ("auto", "fast", "simple"):
        raise ValueError(f"unknown kernel {kernel!r}: expected 'auto', 'fast' or 'simple'")
    if kernel == "simple":
        advance = _ens.advance_ensemble
    else:
        from .kernels.fast import advance_ensemble_fast as advance
    if friction not in FRICTION:
        raise ValueError(f"unknown integrator.friction {friction!r}: expected one of {sorted(FRICTION)}")
    if start not in STARTS:
        raise ValueError(f"unknown integrator.start {start!r}: expected one of {list(STARTS)}")
    y0 = np.array(y0, dtype=np.float64, order="C", ndmin=2)
    params = np.array(params, dtype=np.float64, order="C", ndmin=2)
    N, n = y0.shape
    if n not in (NSTATE_BASE, NSTATE_ATTITUDE):
        raise ValueError(f"state width must be {NSTATE_BASE} or {NSTATE_ATTITUDE}, got {n}")
    if params.shape != (N, NPARAM):
        raise ValueError(f"params must have shape ({N}, {NPARAM}), got {params.shape}")
    if steps % every:
        raise ValueError(f"steps ({steps}) must be a multiple of every ({every})")
    eff_start = start if m.name == "vi" else "node"
    alpha, beta = FRICTION[friction]
    Y = y0.copy()
    if eff_start == "staggered" and N:
        Y[:, 0:3] = staggered_omega(y0, params, h)
    # reference: per-member substeps (ISTAT[:, IS_NSUB], nsub argument 0) unless fixed
    nsub = int(ref_substeps) if ref_substeps else 0
    n_out = steps // every
    states = np.full((N, n_out + 1, n), np.nan)
    states[:, 0] = Y
    IS = np.zeros((N, _ens.NISTAT), np.int64)
    IS[:, _ens.IS_NSUB] = reference_substeps(h, y0, params) if m.name == "reference" else 1
    if m.name == "reference":
        tab_a, tab_b = _rk.DOP853_A, _rk.DOP853_B
    else:  # never read: spares the scipy import on the common path
        tab_a, tab_b = _rk.NO_TABLEAU_A, _rk.NO_TABLEAU_B
    FS = np.zeros((N, _ens.NFSTAT))
    if chunk_steps is None:
        # one kernel call per ~2e6 member-steps (≈0.1 s): frequent enough for a progress
        # bar, rare enough that the thread-pool launch per call does not show
        chunk_steps = max(every, min(steps, CHUNK_MEMBER_STEPS // max(N, 1)))
    out_per_chunk = max(1, chunk_steps // every)
    old_threads = numba.get_num_threads()
    if threads is None and N < SMALL_ENSEMBLE:
        threads = 1  # a few members: waking threads costs more than it gains
    if threads is not None:
        numba.set_num_threads(min(threads, old_threads))
    import time

    t0 = time.perf_counter()
    try:
        j = 0
        while j < n_out:
            nj = min(out_per_chunk, n_out - j)
            OUT = states[:, 1 + j: 1 + j + nj]  # strided view, written in place
            advance(m.kernel_id, Y, params, float(h), int(every), int(nj),
                                  alpha, beta, float(newton_tol), int(newton_maxiter), int(nsub),
                                  tab_a, tab_b, OUT, IS, FS)
            j += nj
            if progress is not None:
                progress(nj * every)
    finally:
        if threads is not None:
            numba.set_num_threads(old_threads)
    wall = time.perf_counter() - t0
    return Trajectory(
        method=m.name, friction=friction, start=eff_start, h=float(h), steps=int(steps),
        every=int(every), params=params, states=states,
        status=IS[:, _ens.IS_STATUS].astype(np.int8), fail_step=IS[:, _ens.IS_FAIL_STEP].copy(),
        newton_iterations=IS[:, _ens.IS_NEWTON_TOTAL].copy(), newton_max=IS[:, _ens.IS_NEWTON_MAX].copy(),
        steps_done=IS[:, _ens.IS_STEPS].copy(), max_h_omega=FS[:, _ens.FS_MAX_H_OMEGA].copy(),
        wall_time=wall,
        reference_substeps=(int(nsub) if nsub else int(IS[:, _ens.IS_NSUB].max(initial=0)))
        if m.name == "reference" else 0,
    )
