"""Numerics of ensembles of time series (plain arrays, no labels, no I/O):
drift fits and the test whether a drift stands out of the oscillation, paired comparisons of methods over
members, settling times, angles between directions and between attitudes, quantile bands and observed orders
between levels."""

from __future__ import annotations

import math
from dataclasses import dataclass

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


#: z of a two-sided 95 % interval
Z95 = 1.959963984540054


def newey_west_lag(n: int) -> int:
    """The Bartlett lag of :func:`drift_test` for ``n`` nodes: a tenth of the record.  The residual of an energy
    error about its line is an oscillation whose autocorrelation lasts many nodes; the usual ``4 (n/100)^(2/9)``
    lags (5 at n = 1000) would see it as independent noise and give far too narrow an interval."""
    return max(1, int(n) // 10)


#: a drift's trend over the record must exceed this many times the residual's peak-to-peak range
TREND_OVER_RANGE = 2.0


def drift_test(t: np.ndarray, y: np.ndarray, lag: int | None = None) -> dict[str, np.ndarray]:
    """Whether each row of y (N, T) drifts over the record, beyond its oscillation.

    Per row: ``slope`` (least squares against t), ``amplitude`` (RMS of the residual about that line),
    ``range`` (peak-to-peak of the residual), ``half_width`` (half the 95 % Newey–West interval of the slope,
    Bartlett weights up to ``lag`` nodes, default :func:`newey_west_lag`) and ``measurable``: a drift is reported
    only where both the interval excludes 0 and the trend over the record, |slope| × (t_end − t_0), exceeds
    :data:`TREND_OVER_RANGE` (2) times the residual's peak-to-peak range.  The second rule is what an oscillation
    cannot pass once the record holds a whole period: a sine's least-squares slope × T is at most 1.0 times its
    residual's range over one period and 0.5 times it over two or more (any phase); an oscillation slower than the
    record is indistinguishable from a drift over it.  NaN (and not measurable) for rows with a non-finite value."""
    t, y = np.asarray(t, float), np.asarray(y, float)
    slope, amp = drift_fit(t, y)
    n, span = t.size, float(t[-1] - t[0]) if t.size else 0.0
    tc = t - t.mean()
    with np.errstate(invalid="ignore", over="ignore"):
        resid = y - y.mean(axis=1, keepdims=True) - slope[:, None] * tc[None, :]
        u = resid * tc[None, :]
        L = min(newey_west_lag(n) if lag is None else int(lag), n - 1)
        s = np.sum(u * u, axis=1)
        for k in range(1, L + 1):
            s = s + 2.0 * (1.0 - k / (L + 1.0)) * np.sum(u[:, k:] * u[:, :-k], axis=1)
        half = Z95 * np.sqrt(np.maximum(s, 0.0)) / (tc @ tc)
        rng = np.ptp(resid, axis=1) if n else np.full(y.shape[0], np.nan)
        measurable = (np.abs(slope) > half) & (np.abs(slope) * span > TREND_OVER_RANGE * rng)
    bad = ~np.all(np.isfinite(y), axis=1)
    half[bad], rng[bad], measurable[bad] = np.nan, np.nan, False
    return {"slope": slope, "amplitude": amp, "range": rng, "half_width": half, "measurable": measurable}


#: relative values (energy errors, law defects, entropy errors) at or below this are round-off: two of them are equal
ROUND_OFF = 1e-13
#: fewer members than this give no paired interval worth stating: the report says so instead of ranking
MIN_MEMBERS = 10
#: the seed of every paired bootstrap (a rerun, or a resumed study, states the same verdicts)
BOOTSTRAP_SEED = 20240611
BOOTSTRAP_RESAMPLES = 4000
FAILED = 1e300  # a failed member's value (inf, NaN) in a paired comparison: worse than any finite one


@dataclass(frozen=True)
class Paired:
    """Method a against method b over the same members: the ratio of their medians with its 95 % paired
    bootstrap interval, how many members a is below b on, and the verdict: ``"a smaller"``, ``"b smaller"``,
    ``"tie"`` (the interval contains 1, or both medians at the round-off floor) or ``"too few members"``."""

    ratio: float
    low: float
    high: float
    members: int
    a_below: int
    verdict: str

    def text(self, a: str, b: str) -> str:
        """``"vi6 / split6 1.06 (95 % 0.84–2.5, 48 members, vi6 lower on 26)"``."""
        if self.verdict == "too few members":
            return f"{a} / {b} {self.ratio:.3g} ({self.members} members: too few for an interval)"
        return (f"{a} / {b} {self.ratio:.3g} (95 % {self.low:.2g}–{self.high:.2g}, {self.members} members, {a} "
                f"lower on {self.a_below})")


def _clean(x, floor: float) -> np.ndarray:
    x = np.asarray(x, float).ravel()
    return np.maximum(np.where(np.isfinite(x), np.abs(x), FAILED), floor) if floor > 0 else \
        np.where(np.isfinite(x), np.abs(x), FAILED)


def paired_ratio(a, b, *, floor: float = 0.0, seed: int = BOOTSTRAP_SEED, min_members: int = MIN_MEMBERS,
                 n_resamples: int = BOOTSTRAP_RESAMPLES) -> Paired:
    """Compare two methods' non-negative values on the same members (errors, |drift rates|): the ratio of
    median(a) to median(b), with a 95 % percentile interval from a seeded paired bootstrap over members
    (``scipy.stats.bootstrap``, ``paired=True``).  Values are taken as |x|, raised to ``floor`` (the round-off
    floor: two values at it are equal), and a non-finite value counts as a failure, worse than any finite one."""
    from scipy.stats import bootstrap

    a, b = _clean(a, floor), _clean(b, floor)
    if a.shape != b.shape:
        raise ValueError(f"paired values need the same members, got {a.size} and {b.size}")
    n = a.size
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = float(np.median(a) / np.median(b)) if n else math.nan
    below = int(np.sum(a < b))
    if n < min_members or not math.isfinite(ratio) or ratio == 0:
        return Paired(ratio, math.nan, math.nan, n, below, "too few members" if n < min_members else "tie")
    if np.array_equal(a, b):
        return Paired(1.0, 1.0, 1.0, n, 0, "tie")

    def stat(x, y, axis=-1):
        return np.log(np.median(x, axis=axis)) - np.log(np.median(y, axis=axis))

    res = bootstrap((a, b), stat, paired=True, vectorized=True, n_resamples=n_resamples, method="percentile",
                    confidence_level=0.95, rng=np.random.default_rng(seed))
    lo, hi = (math.exp(float(v)) for v in (res.confidence_interval.low, res.confidence_interval.high))
    return Paired(ratio, lo, hi, n, below, "a smaller" if hi < 1 else "b smaller" if lo > 1 else "tie")


def least_over_members(values: dict, *, floor: float = 0.0, seed: int = BOOTSTRAP_SEED,
                       min_members: int = MIN_MEMBERS) -> tuple[list[str], dict[str, Paired]]:
    """(the methods with the least median value that the data can tell apart from no other: the least median and
    every method whose paired interval against it contains 1, {method: its comparison with the least}).  With
    fewer than ``min_members`` members the list is empty: no ranking is stated."""
    med = {m: float(np.median(_clean(v, floor))) for m, v in values.items()}
    if not med:
        return [], {}
    best = min(med, key=med.get)
    cmp = {m: paired_ratio(v, values[best], floor=floor, seed=seed, min_members=min_members)
           for m, v in values.items() if m != best}
    if any(c.verdict == "too few members" for c in cmp.values()):
        return [], cmp
    return [best] + [m for m, c in cmp.items() if c.verdict == "tie"], cmp


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
