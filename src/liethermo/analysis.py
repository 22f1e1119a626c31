"""Numerics of ensembles of time series (plain arrays, no labels, no I/O):
drift fits, settling times, angles between directions and between attitudes,
quantile bands and observed orders between levels."""

from __future__ import annotations

import math

import numpy as np


def drift_fit(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of y (N, T): (least-squares slope of y against t, standard deviation of the residual about that
    line); NaN for rows with a non-finite value."""
    t = np.asarray(t, float)
    tc = t - t.mean()
    with np.errstate(invalid="ignore", over="ignore"):
        ym = y.mean(axis=1, keepdims=True)
        slope = (y - ym) @ tc / (tc @ tc)
        resid = y - ym - slope[:, None] * tc[None, :]
        spread = np.sqrt(np.mean(resid * resid, axis=1))
    bad = ~np.all(np.isfinite(y), axis=1)
    slope[bad], spread[bad] = np.nan, np.nan
    return slope, spread


def settling_time(t: np.ndarray, ratio: np.ndarray, fraction: float) -> np.ndarray:
    """Per row of ``ratio`` (N, T) (a positive quantity relative to its initial value, e.g. E_mech,k / E_mech,0):
    the first time it falls to ``fraction`` or below (s), log-linearly interpolated between the two nodes around
    the crossing; 0 if it starts there, NaN if it never gets there (or a value before it is not finite)."""
    t, r = np.asarray(t, float), np.asarray(ratio, float)
    out, lf = np.full(r.shape[0], np.nan), math.log(fraction)
    with np.errstate(invalid="ignore", divide="ignore"):
        below = r <= fraction
    for i in range(r.shape[0]):
        k = np.flatnonzero(below[i])
        if k.size == 0:
            continue
        k = int(k[0])
        if k == 0:
            out[i] = 0.0
            continue
        if not np.all(np.isfinite(r[i, :k + 1])):
            continue
        a = math.log(r[i, k - 1])
        b = math.log(r[i, k]) if r[i, k] > 0.0 else -math.inf
        w = 1.0 if not math.isfinite(b) else (lf - a) / (b - a)
        out[i] = t[k - 1] + w * (t[k] - t[k - 1])
    return out


def direction_angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle (rad) between the directions of u and v (..., 3), accurate for small and large angles (atan2 of |u×v|
    and u·v); |u|, |v| need not be 1."""
    return np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.sum(u * v, axis=-1))


def rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle (rad) of the rotation Ra Rbᵀ between attitudes (..., 3, 3), from the Frobenius distance
    ‖Ra − Rb‖ = 2√2 sin(θ/2) (accurate for small angles)."""
    d = np.linalg.norm(np.asarray(Ra) - np.asarray(Rb), axis=(-2, -1))
    return 2.0 * np.arcsin(np.clip(d / (2.0 * math.sqrt(2.0)), 0.0, 1.0))


def quantile_band(a: np.ndarray, q=(0.05, 0.5, 0.95)) -> np.ndarray:
    """Quantiles ``q`` of the finite values of a (NaN if none)."""
    a = np.asarray(a, float).ravel()
    a = a[np.isfinite(a)]
    if a.size == 0:
        return np.full(len(q), np.nan)
    return np.quantile(a, q)


def observed_orders(hs, errors) -> np.ndarray:
    """log(e_i / e_{i+1}) / log(h_i / h_{i+1}) between consecutive levels (NaN where an error is not finite and
    positive); one fewer than the levels."""
    hs, e = np.asarray(hs, float), np.asarray(errors, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        p = np.log(e[:-1] / e[1:]) / np.log(hs[:-1] / hs[1:])
    p[~(np.isfinite(e[:-1]) & np.isfinite(e[1:]) & (e[:-1] > 0) & (e[1:] > 0))] = np.nan
    return p


#: how far an observed order may fall below the declared one p and still count as it:
#: max(ORDER_TOLERANCE, ORDER_TOLERANCE_REL * p) (a slope fitted over a few halvings
#: of h carries the next term of the error, relatively more at high orders)
ORDER_TOLERANCE = 0.3
ORDER_TOLERANCE_REL = 0.1


def order_tolerance(declared: int) -> float:
    return max(ORDER_TOLERANCE, ORDER_TOLERANCE_REL * declared)


def judge_order(observed: float, declared: int, tolerance: float | None = None) -> str:
    """``"as declared"`` (within ``tolerance`` of the declared order, default
    :func:`order_tolerance`), ``"above declared"`` (more than ``tolerance``
    above it: the error falls faster than the method promises on this
    problem, which is no failure), or ``"below declared"`` (the failure);
    ``"not fitted"`` for a NaN order."""
    tol = order_tolerance(declared) if tolerance is None else tolerance
    if not np.isfinite(observed):
        return "not fitted"
    if observed < declared - tol:
        return "below declared"
    return "above declared" if observed > declared + tol else "as declared"
