"""Repeated, interleaved timings (liethermo.timing) with fake clocks and callables."""

from __future__ import annotations

import numba
import numpy as np  # noqa: F401  (loads the BLAS that threadpoolctl limits)
import pytest
import threadpoolctl

from liethermo import timing
from liethermo.timing import (Cost, compare, describe, equal_cost_check, format_cost,
                                      format_seconds, measure, pinned_threads, rank)


class FakeClock:
    """A clock that moves only when a fake candidate says it took time."""

    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def scripted(clock, calls, name, durations):
    """A candidate that logs its call and advances ``clock`` by the next duration."""
    it = iter(durations)

    def run():
        calls.append(name)
        clock.t += next(it)

    return run


def test_rounds_interleave_in_rotated_order_after_warming():
    clock, calls = FakeClock(), []
    cands = {n: scripted(clock, calls, n, [1.0] * 10) for n in "abc"}
    costs = measure(cands, repeats=4, warm=2, clock=clock, threads=None)
    assert calls == list("aabbcc") + list("abc" "bca" "cab" "abc")
    assert {n: c.repeats for n, c in costs.items()} == {"a": 4, "b": 4, "c": 4}


def test_best_is_the_minimum_over_repeats_and_spread_is_median_over_best():
    clock, calls = FakeClock(), []
    cands = {"x": scripted(clock, calls, "x", [100.0, 3.0, 1.0, 2.0, 5.0, 4.0])}
    c = measure(cands, repeats=5, warm=1, clock=clock, threads=None)["x"]
    assert c.samples == (3.0, 1.0, 2.0, 5.0, 4.0)  # the warm call's 100 s is not a sample
    assert (c.best, c.median, c.spread, c.repeats) == (1.0, 3.0, 2.0, 5)


def test_a_returned_time_replaces_the_wall_clock():
    clock, calls = FakeClock(), []
    wall = scripted(clock, calls, "k", [10.0] * 4)

    def kernel():
        wall()
        return 0.25

    c = measure({"k": kernel}, repeats=3, clock=clock, threads=None)["k"]
    assert c.samples == (0.25, 0.25, 0.25)


def test_rounds_go_on_until_every_candidate_spent_min_time():
    clock, calls = FakeClock(), []
    cands = {"fast": scripted(clock, calls, "fast", [0.25] * 20),
             "slow": scripted(clock, calls, "slow", [1.0] * 20)}
    costs = measure(cands, repeats=3, min_time=2.0, warm=0, clock=clock, threads=None)
    assert costs["fast"].repeats == costs["slow"].repeats == 8  # 8 × 0.25 s = 2 s


@pytest.mark.parametrize("kw, word", [({"repeats": 0}, "repeats"), ({"warm": -1}, "warm"),
                                      ({"min_time": float("nan")}, "min_time"),
                                      ({"threads": 0}, "threads"), ({"max_rounds": 2}, "max_rounds")])
def test_bad_settings_are_refused_by_name(kw, word):
    with pytest.raises(ValueError, match=word):
        measure({"a": lambda: 1.0}, **kw)


def test_a_bad_returned_time_names_the_candidate():
    with pytest.raises(ValueError, match="'neg'"):
        measure({"ok": lambda: 1.0, "neg": lambda: -1.0}, warm=0, threads=None)
    with pytest.raises(ValueError, match="at least one"):
        measure({})


def test_per_scales_times_and_keeps_the_spread():
    c = Cost.of([2.0, 4.0, 8.0]).per(4)
    assert (c.best, c.median, c.spread, c.samples) == (0.5, 1.0, 1.0, (0.5, 1.0, 2.0))
    with pytest.raises(ValueError, match="n must"):
        c.per(0)


def cost(best, median):
    return Cost.of([best, median, median])


def test_a_gap_equal_to_the_spread_ties_and_a_larger_one_ranks():
    a, b = cost(1.0, 1.25), cost(1.25, 1.25)  # gap 25 %, spreads 25 % and 0
    assert compare(a, b) == "tie within noise" and rank({"a": a, "b": b}) == [["a", "b"]]
    a = cost(1.0, 1.125)  # spread 12.5 % < gap 25 %
    assert compare(a, b) == "a cheaper" and compare(b, a) == "b cheaper"
    assert rank({"b": b, "a": a}) == [["a"], ["b"]]
    assert describe({"b": b, "a": a}) == "a (1 s, spread 12 %) < b (1.25 s, spread 0.0 %)"


def test_the_larger_spread_of_two_decides_and_ties_do_not_chain():
    costs = {"p": cost(1.0, 1.0), "q": cost(1.5, 2.25), "r": cost(2.0, 2.0), "s": cost(4.0, 4.5)}
    # p–q: gap 50 % ≤ q's 50 %; q–r: 33 % ≤ 50 %; but p–r: 100 % > both spreads (0): r is not absorbed
    assert rank(costs) == [["p", "q"], ["r"], ["s"]]
    assert compare(costs["p"], costs["r"]) == "a cheaper"
    assert describe(costs) == ("p (1 s, spread 0.0 %) and q (1.5 s, spread 50 %) tie within noise"
                               " < r (2 s, spread 0.0 %; ties q) < s (4 s, spread 12 %)")


def test_a_noisy_method_does_not_tie_two_tight_ones_4_8x_apart():
    """rk4 554 ns (9 %), split4 828 ns (306 %), split 2.64 µs (1.9 %): split4 ties both, rk4 and split do not tie;
    a spread over 100 % names a loaded machine."""
    from liethermo.timing import loaded

    c = {"rk4": cost(554e-9, 554e-9 * 1.09), "split4": cost(828e-9, 828e-9 * 4.06), "split": cost(2.64e-6, 2.64e-6 * 1.019)}
    assert rank(c) == [["rk4", "split4"], ["split"]] and compare(c["rk4"], c["split"]) == "a cheaper"
    assert "split (2.64 µs, spread 1.9 %; ties split4)" in describe(c)
    assert loaded(c) == ["split4"] and loaded({"rk4": c["rk4"]}) == []


def test_gaps_within_the_noise_floor_tie_even_with_no_spread():
    a, b = cost(1.0, 1.0), cost(1.015, 1.015)
    assert compare(a, b) == "tie within noise" and rank({"a": a, "b": b}) == [["a", "b"]]
    assert compare(a, b, floor=0.01) == "a cheaper" and rank({"a": a, "b": b}, floor=0) == [["a"], ["b"]]
    with pytest.raises(ValueError, match="floor"):
        rank({"a": a, "b": b}, floor=-0.1)


def test_format_seconds_picks_the_unit():
    assert [format_seconds(t) for t in (2.5, 1.2e-3, 0.9996, 3.4e-6, 5e-9)] == \
        ["2.5 s", "1.2 ms", "1 s", "3.4 µs", "5 ns"]
    assert format_cost("rk4", Cost.of([2e-3, 2.12e-3, 2.12e-3])) == "rk4 (2 ms, spread 6.0 %)"


def test_equal_cost_check_flags_16_percent_and_not_14():
    flagged = equal_cost_check({"vi": 1.0, "rk4": 1.16, "split": 1.14})
    assert [(a, b) for a, b, _ in flagged] == [("vi", "rk4")]
    assert flagged[0][2] == pytest.approx(1.16)
    assert equal_cost_check({"a": 2.0, "b": 1.0, "c": Cost.of([1.5])}, tolerance=0.5) == [("b", "a", 2.0)]
    with pytest.raises(ValueError, match="'b'"):
        equal_cost_check({"a": 1.0, "b": 0.0})


def test_equalize_steps_matches_targets_timed_in_the_same_measurement():
    """Costs per simulated second = (per-step cost + a run's fixed cost / n) / h on a machine whose speed changes
    by 30 % between measurements: each run reaches its target's cost within rtol, measured in the same round,
    the target keeps its step, and an unreachable rtol stops after ``rounds``."""
    speed, span = iter([1.0, 1.3, 0.9, 1.2, 1.1, 1.25, 0.95] * 3), 10.0
    per_step = {"split": 3e-3, "rk4": 1e-3, "vi": 2e-3}

    def cost_of(h):
        s = next(speed)
        return {k: Cost.of([s * (per_step[k] * span / v + 0.02) / span]) for k, v in h.items()}

    got, rounds = timing.equalize_steps(cost_of, dict.fromkeys(per_step, 0.02), {"rk4": "split", "vi": "split"})
    assert got["split"][0] == 0.02 and 1 < rounds < 6
    for k in ("rk4", "vi"):
        assert abs(got[k][1].best / got[k][2].best - 1) < 0.03, got[k]
    assert got["rk4"][0] == pytest.approx(0.02 / 3, rel=0.05)  # a third of the work per step: a third of the step
    fixed = lambda h: {"a": Cost.of([1.0]), "b": Cost.of([2.0])}  # noqa: E731 (b's cost does not follow its step)
    assert timing.equalize_steps(fixed, {"a": 1.0, "b": 1.0}, {"b": "a"}, rounds=2)[1] == 2
    with pytest.raises(ValueError, match="rtol"):
        timing.equalize_steps(cost_of, {"a": 1.0}, {}, rtol=0)


def test_relayout_holds_a_block_of_another_size_during_each_call():
    """With relayout every call runs with a heap block of a new size held (what the call allocates can land
    elsewhere); without it the heap is the same at every call."""
    import tracemalloc

    seen = {}
    tracemalloc.start()
    try:
        for relayout in (False, True):
            held = seen.setdefault(relayout, [])
            measure({"a": lambda held=held: held.append(tracemalloc.get_traced_memory()[0])}, repeats=8, warm=0,
                    threads=None, relayout=relayout)
    finally:
        tracemalloc.stop()
    spread = {k: max(v) - min(v) for k, v in seen.items()}  # bytes traced at the calls (the lists grow a little)
    assert spread[False] < 1024 < spread[True] and len(set(seen[True])) == 8, spread


def _blas_threads():
    return [p["num_threads"] for p in threadpoolctl.threadpool_info() if p["user_api"] == "blas"]


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two numba threads to see a change")
def test_pinned_threads_limits_blas_and_numba_and_restores_them():
    before_blas = _blas_threads()
    assert before_blas, "numpy's BLAS is not visible to threadpoolctl"
    old = numba.get_num_threads()
    numba.set_num_threads(2)
    try:
        with pytest.raises(RuntimeError):
            with pinned_threads(1) as n:
                assert n == 1 and numba.get_num_threads() == 1
                assert set(_blas_threads()) == {1}
                raise RuntimeError("left by an error")
        assert numba.get_num_threads() == 2 and _blas_threads() == before_blas
        seen = []
        measure({"a": lambda: seen.append(numba.get_num_threads())}, repeats=1, warm=0)
        assert seen == [1] and numba.get_num_threads() == 2
    finally:
        numba.set_num_threads(old)
