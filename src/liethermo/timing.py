"""Costs that hold on a noisy machine: repeated, interleaved timings with their spread.

* :func:`pinned_threads` pins the BLAS/OpenMP pools and numba's threads while timing.
* :func:`measure` times candidates in interleaved, rotated rounds and returns a
  :class:`Cost` per candidate: the minimum over repeats with the spread beside it.
* :func:`rank` and :func:`compare` state an order only where the gap exceeds the
  measured spread (and :data:`NOISE_FLOOR`), else a tie within noise (between two candidates: ties do not
  chain); :func:`describe` words it for reports; :func:`loaded` names costs timed on a loaded machine.
* :func:`equalize_steps` sets time steps so that runs cost the same per simulated second;
  :func:`equal_cost_check` flags runs meant to cost the same that do not.

Plain Python: no arrays, no I/O.
"""

from __future__ import annotations

import itertools
import math
import numbers
import random
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
            threads: int | None = 1, max_rounds: int = 10_000, relayout: bool = True) -> dict[str, Cost]:
    """Time each candidate and return its :class:`Cost`.

    Each candidate is first called ``warm`` times untimed (compilation, caches).  Then
    rounds call every candidate once, round ``r`` starting at the ``r``-th candidate
    (rotated order: none is always first), for at least ``repeats`` rounds and until
    every candidate's samples add up to ``min_time`` s (at most ``max_rounds`` rounds).  A
    sample is what the call returns, if a number (its own measured time, e.g. a kernel
    time), else ``clock()`` after minus before.  With ``threads`` set, the whole
    measurement runs inside :func:`pinned_threads`; ``None`` leaves the pools alone.

    With ``relayout`` (the default) each call is preceded by a heap block of a random size (1–64 KiB), held
    during the call, so that what the call allocates can land at another offset in each repeat.  Repeated
    identical calls otherwise reuse the same addresses, and a placement that costs more slows every repeat
    alike.  Whether the block moves a call's arrays depends on the allocator's free blocks: in a fresh process
    a repeat's 50 kB array moved to 8 addresses in 16 calls, in a test worker's heap it stayed at one.  One
    comparison on a 2-core Zen 4 (a 64-member RK2 run, minimum of 3, 30 heap states each): 17.3–20.3 ms
    without, 17.1–18.2 ms with.  The sizes come from a generator seeded per measurement (the same each time)."""
    names = list(candidates)
    if not names:
        raise ValueError("candidates must name at least one callable")
    _integer("repeats", repeats, 1), _integer("warm", warm, 0), _integer("max_rounds", max_rounds, repeats)
    _number("min_time", min_time)
    if threads is not None:
        with pinned_threads(threads):
            return measure(candidates, repeats=repeats, min_time=min_time, warm=warm,
                           clock=clock, threads=None, max_rounds=max_rounds, relayout=relayout)
    for name in names:
        for _ in range(warm):
            candidates[name]()
    samples: dict[str, list[float]] = {name: [] for name in names}
    rounds, sizes = 0, random.Random(len(names))
    while rounds < max_rounds and (rounds < repeats or any(sum(s) < min_time for s in samples.values())):
        k = rounds % len(names)
        for name in names[k:] + names[:k]:
            pad = bytearray(sizes.randrange(1024, 65536)) if relayout else None  # noqa: F841 (held during the call)
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

    A tie is a relation between two candidates, not a chain: the cheapest candidate left leads a group, and the
    group holds it and every candidate left that ties with **it** (gap ``best_b / best_a − 1`` not above the
    larger of the two spreads, nor ``floor``).  A candidate that ties only with a member of the group, not with
    its leader, starts a later group (:func:`describe` names the ties across groups), so two candidates whose gap
    exceeds both their spreads never share a group."""
    left, groups = sorted(costs, key=lambda name: costs[name].best), []
    while left:
        lead = left[0]
        group = [name for name in left if name == lead or _ties(costs[lead], costs[name], floor)]
        groups.append(group)
        left = [name for name in left if name not in group]
    return groups


def compare(a: Cost, b: Cost, floor: float = NOISE_FLOOR) -> str:
    """``"a cheaper"``, ``"b cheaper"`` or ``"tie within noise"`` (the rule of :func:`rank`)."""
    if _ties(a, b, floor):
        return "tie within noise"
    return "a cheaper" if a.best < b.best else "b cheaper"


#: a spread above this (median more than twice the minimum) says the machine was loaded while it timed: a
#: ranking on such costs is not stated; the timings are to be repeated on a quieter machine
LOADED_SPREAD = 1.0


def loaded(costs: Mapping[str, Cost], limit: float = LOADED_SPREAD) -> list[str]:
    """The candidates whose spread exceeds ``limit`` (timed on a loaded machine), largest spread first."""
    return sorted((n for n, c in costs.items() if c.spread > limit), key=lambda n: -costs[n].spread)


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
    (1.5 ms, spread 3.1 %) and split4 (1.52 ms, spread 5.2 %) tie within noise < rk4 (…)"``.  A candidate of a
    later group that ties with one of an earlier group (not with its leader) says so: ``"< r (2 s, spread 0.0 %;
    ties q)"``."""
    parts, before = [], []
    for group in rank(costs, floor):
        words = []
        for name in group:
            w = format_cost(name, costs[name])
            also = [b for b in before if _ties(costs[b], costs[name], floor)]
            words.append(w[:-1] + f"; ties {', '.join(also)})" if also else w)
        before += group
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


def secant_step(tried: list[tuple[float, float]]) -> float:
    """The next log h from the (log h, f = log(cost / target)) tried: secant of the closest bracket, else x + f
    (exact where the cost per simulated second is a fixed cost per step over h)."""
    below, above = [t for t in tried if t[1] > 0], [t for t in tried if t[1] < 0]
    if below and above:
        (xa, fa), (xb, fb) = max(below), min(above)
        return xa - fa * (xb - xa) / (fb - fa)
    return tried[-1][0] + tried[-1][1]


def equalize_steps(cost_of: Callable[[dict], Mapping], steps: Mapping, targets: Mapping, *, rtol: float = 0.03,
                   rounds: int = 6) -> tuple[dict, int]:
    """Time steps at which each run ``k`` of ``targets`` costs what the run ``targets[k]`` costs per simulated second.

    ``cost_of({k: h})`` times every run at its step in one interleaved measurement (:func:`measure`) and returns
    ``{k: Cost}`` per simulated second; a run is compared with its target **timed in the same measurement** (a
    machine that changes speed between measurements moves both).  Runs that are not in ``targets`` keep their
    step.  Each round moves the steps still more than ``rtol`` off by :func:`secant_step` in log h, for at most
    ``rounds`` rounds.  Returns ``({k: (h, cost, the target's cost)}``, each run at its closest step tried), and the
    number of rounds."""
    _number("rtol", rtol, positive=True), _integer("rounds", rounds, 1)
    h, tried = dict(steps), {k: [] for k in targets}

    def gap(t):
        return math.log(t[1].best / t[2].best)

    for rnd in range(1, rounds + 1):
        c = cost_of(dict(h))
        for k in targets:
            tried[k].append((h[k], c[k], c[targets[k]]))
        todo = [k for k in targets if abs(math.expm1(gap(tried[k][-1]))) >= rtol]
        if not todo:
            break
        for k in todo:
            h[k] = math.exp(secant_step([(math.log(t[0]), gap(t)) for t in tried[k]]))
    best = {k: min(v, key=lambda t: abs(gap(t))) for k, v in tried.items()}
    return {k: best.get(k, (h[k], c[k], c[k])) for k in h}, rnd


__all__ = ["NOISE_FLOOR", "LOADED_SPREAD", "Cost", "loaded", "pinned_threads", "measure", "rank", "compare", "describe", "format_cost",
           "format_seconds", "equal_cost_check", "equalize_steps", "secant_step"]
