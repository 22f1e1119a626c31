"""Costs that hold on a noisy machine: repeated, interleaved timings with their spread.

* :func:`pinned_threads` pins the BLAS/OpenMP pools and numba's threads while timing.
* :func:`measure` times candidates in interleaved, rotated rounds and returns a
  :class:`Cost` per candidate: the minimum over repeats with the spread beside it.
* :func:`rank` and :func:`compare` state an order only where the gap exceeds the
  measured spread (and :data:`NOISE_FLOOR`), else a tie within noise; :func:`describe` words it for reports.
* :func:`equal_cost_check` flags runs meant to cost the same that do not.

Plain Python: no arrays, no I/O.
"""

from __future__ import annotations

import itertools
import math
import numbers
import statistics
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Iterator, Mapping

import numba
from threadpoolctl import threadpool_limits


def _integer(key: str, value, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < low:
        raise ValueError(f"{key} must be an integer >= {low}, got {value!r}")
    return value


def _number(key: str, value, positive: bool = False) -> float:
    if (isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value)
            or value < 0 or (positive and value == 0)):
        raise ValueError(f"{key} must be a finite number {'>' if positive else '>='} 0, got {value!r}")
    return float(value)


@contextmanager
def pinned_threads(n: int = 1) -> Iterator[int]:
    """Limit BLAS/OpenMP pools (threadpoolctl) and numba's threads to ``n`` inside the
    block; both are restored on leaving.  Numba's count is capped at
    ``NUMBA_NUM_THREADS``.  Code that picks its own thread count (an explicit
    ``threads=`` argument) must be given the yielded ``n`` as well."""
    _integer("threads", n, 1)
    old = numba.get_num_threads()
    numba.set_num_threads(min(n, int(numba.config.NUMBA_NUM_THREADS)))
    try:
        with threadpool_limits(limits=n):
            yield n
    finally:
        numba.set_num_threads(old)


@dataclass(frozen=True)
class Cost:
    """Repeated timings of one candidate, s.

    ``best`` is the minimum over the samples (noise only adds time), ``median`` the
    median, and ``spread = median / best − 1``: how far a typical repeat lies above
    the fastest.  One slow outlier (a context switch) does not move it while fewer
    than half the repeats are hit."""

    best: float
    median: float
    spread: float
    repeats: int
    samples: tuple[float, ...]

    @classmethod
    def of(cls, samples) -> "Cost":
        """The cost of a non-empty sequence of finite, non-negative times."""
        s = tuple(_number("a sample", x) for x in samples)
        if not s:
            raise ValueError("samples must hold at least one time, got none")
        best, median = min(s), statistics.median(s)
        return cls(best, median, median / best - 1.0 if best > 0 else 0.0, len(s), s)

    def per(self, n: float) -> "Cost":
        """The cost per one of ``n`` units (steps, members, member-steps); same spread."""
        n = _number("n", n, positive=True)
        return Cost(self.best / n, self.median / n, self.spread, self.repeats,
                    tuple(x / n for x in self.samples))


def measure(candidates: Mapping[str, Callable[[], float | None]], *, repeats: int = 5,
            min_time: float = 0.0, warm: int = 1, clock: Callable[[], float] = time.perf_counter,
            threads: int | None = 1, max_rounds: int = 10_000) -> dict[str, Cost]:
    """Time each candidate and return its :class:`Cost`.

    Each candidate is first called ``warm`` times untimed (compilation, caches).  Then
    rounds call every candidate once, round ``r`` starting at the ``r``-th candidate
    (rotated order: none is always first), for at least ``repeats`` rounds and until
    every candidate's samples add up to ``min_time`` s (at most ``max_rounds`` rounds).  A
    sample is what the call returns, if a number (its own measured time, e.g. a kernel
    time), else ``clock()`` after minus before.  With ``threads`` set, the whole
    measurement runs inside :func:`pinned_threads`; ``None`` leaves the pools alone."""
    names = list(candidates)
    if not names:
        raise ValueError("candidates must name at least one callable")
    _integer("repeats", repeats, 1), _integer("warm", warm, 0), _integer("max_rounds", max_rounds, repeats)
    _number("min_time", min_time)
    if threads is not None:
        with pinned_threads(threads):
            return measure(candidates, repeats=repeats, min_time=min_time, warm=warm,
                           clock=clock, threads=None, max_rounds=max_rounds)
    for name in names:
        for _ in range(warm):
            candidates[name]()
    samples: dict[str, list[float]] = {name: [] for name in names}
    rounds = 0
    while rounds < max_rounds and (rounds < repeats or any(sum(s) < min_time for s in samples.values())):
        k = rounds % len(names)
        for name in names[k:] + names[:k]:
            t0 = clock()
            got = candidates[name]()
            t1 = clock()
            samples[name].append(_number(f"the time of candidate {name!r}", t1 - t0 if got is None else got))
        rounds += 1
    return {name: Cost.of(samples[name]) for name in names}


#: the smallest relative gap ever ranked: the same code timed twice differs by about
#: a percent (memory placement, clock frequency), which one run's spread does not see
NOISE_FLOOR = 0.02


def _ties(a: Cost, b: Cost, floor: float) -> bool:
    lo, hi = sorted((a.best, b.best))
    gap = hi / lo - 1.0 if lo > 0 else (0.0 if hi == 0 else math.inf)
    return gap <= max(a.spread, b.spread, _number("floor", floor))


def rank(costs: Mapping[str, Cost], floor: float = NOISE_FLOOR) -> list[list[str]]:
    """Groups of candidates, cheapest group first, sorted by ``best`` within a group.

    Two neighbours in the order of ``best`` tie within noise when their gap
    ``best_b / best_a − 1`` does not exceed the larger of their two spreads (nor
    ``floor``); ties chain, so a group is a run of neighbours each tied to the next,
    and no order is claimed inside it.  Between groups the order holds beyond the
    measured spread."""
    order = sorted(costs, key=lambda name: costs[name].best)
    groups: list[list[str]] = []
    for name in order:
        if groups and _ties(costs[groups[-1][-1]], costs[name], floor):
            groups[-1].append(name)
        else:
            groups.append([name])
    return groups


def compare(a: Cost, b: Cost, floor: float = NOISE_FLOOR) -> str:
    """``"a cheaper"``, ``"b cheaper"`` or ``"tie within noise"`` (the rule of :func:`rank`)."""
    if _ties(a, b, floor):
        return "tie within noise"
    return "a cheaper" if a.best < b.best else "b cheaper"


def format_seconds(t: float) -> str:
    """``t`` s with three significant digits in s, ms, µs or ns."""
    for unit, scale in (("s", 1.0), ("ms", 1e-3), ("µs", 1e-6)):
        if abs(float(f"{t:.3g}")) >= scale:
            return f"{t / scale:.3g} {unit}"
    return f"{t / 1e-9:.3g} ns"


def format_cost(name: str, cost: Cost) -> str:
    """``"rk4 (2 ms, spread 6.0 %)"``: the best time and the spread (one decimal below 10 %)."""
    pct = 100 * cost.spread
    return f"{name} ({format_seconds(cost.best)}, spread {pct:.{1 if pct < 10 else 0}f} %)"


def describe(costs: Mapping[str, Cost], floor: float = NOISE_FLOOR) -> str:
    """The ranking as a sentence fragment, e.g. ``"split6 (1.2 ms, spread 4.0 %) < vi4
    (1.5 ms, spread 3.1 %) and split4 (1.52 ms, spread 5.2 %) tie within noise < rk4 (…)"``."""
    parts = []
    for group in rank(costs, floor):
        words = [format_cost(name, costs[name]) for name in group]
        if len(words) == 1:
            parts.append(words[0])
        else:
            parts.append(", ".join(words[:-1]) + " and " + words[-1] + " tie within noise")
    return " < ".join(parts)


def equal_cost_check(costs: Mapping[str, float | Cost], tolerance: float = 0.15
                     ) -> list[tuple[str, str, float]]:
    """Pairs of runs meant to cost the same that are more than ``tolerance`` apart:
    ``(cheaper, dearer, dearer / cheaper)`` for every pair whose ratio exceeds
    ``1 + tolerance``, largest ratio first.  A :class:`Cost` counts by its ``best``."""
    _number("tolerance", tolerance)
    values = {name: _number(f"the cost of {name!r}", getattr(c, "best", c), positive=True)
              for name, c in costs.items()}
    pairs = (sorted(pair, key=values.__getitem__) for pair in itertools.combinations(values, 2))
    flagged = [(lo, hi, values[hi] / values[lo]) for lo, hi in pairs]
    return sorted((f for f in flagged if f[2] > 1.0 + tolerance), key=lambda f: -f[2])


__all__ = ["NOISE_FLOOR", "Cost", "pinned_threads", "measure", "rank", "compare", "describe", "format_cost",
           "format_seconds", "equal_cost_check"]
