"""The rules a study's verdicts rest on, checked on series and members whose answer is known: a drift under an
oscillation is found with its slope, an oscillation alone is not a drift, methods 2x apart on every member are
ranked while equal ones and values at round-off tie, too few members rank nothing, and a seeded bootstrap gives
the same interval on every run."""

from __future__ import annotations

import numpy as np
import pytest

from liethermo.analysis import MIN_MEMBERS, drift_test, least_over_members, paired_ratio


def _oscillations(t, members=16, seed=3, amplitude=1e-6):
    """Two incommensurate sines per member, random periods from 1/20 to 1/2 of the record and random phases."""
    rng, T = np.random.default_rng(seed), t[-1] - t[0]
    out = []
    for _ in range(members):
        p = rng.uniform(T / 20, T / 2)
        out.append(amplitude * (np.sin(2 * np.pi * t / p + rng.uniform(0, 2 * np.pi))
                                + 0.3 * np.sin(2 * np.pi * t / (p / 3.7) + rng.uniform(0, 2 * np.pi))))
    return np.array(out)


def test_a_drift_under_an_oscillation_is_found_with_its_slope():
    t = np.linspace(0.0, 200.0, 2001)
    y = _oscillations(t) + 5e-8 * t  # the trend over the record: 1e-5, the oscillation's range ~2.6e-6
    d = drift_test(t, y)
    assert d["measurable"].all()
    assert np.all(np.abs(d["slope"] - 5e-8) <= d["half_width"]), (d["slope"], d["half_width"])  # inside the interval
    np.testing.assert_allclose(d["slope"], 5e-8, rtol=0.2)


@pytest.mark.parametrize("periods", [1.0, 1.5, 2.0, 5.0, 37.0])
def test_an_oscillation_without_drift_is_not_a_drift(periods):
    """Any phase, one or more whole periods in the record: its least-squares slope is never reported as a drift,
    however narrow an interval that took the residuals as independent would be."""
    t = np.linspace(0.0, 10.0, 1001)
    y = np.array([np.sin(2 * np.pi * periods * t / 10.0 + ph) for ph in np.linspace(0, 2 * np.pi, 37)])
    d = drift_test(t, y)
    assert not d["measurable"].any()
    tc = t - t.mean()  # the ordinary least-squares interval, residuals taken as independent, calls most a drift
    ols = 1.96 * d["amplitude"] / np.sqrt(tc @ tc)
    assert periods > 2 or np.mean(np.abs(d["slope"]) > ols) > 0.5


def test_one_hump_is_not_a_drift():
    """An error that rises to 3.4e-7 at 4 s and falls back to 1.7e-8 at 10 s (the fluid's reduced run)."""
    t = np.linspace(0.0, 10.0, 101)
    y = np.array([1.7e-8 + 3.4e-7 * np.exp(-((t - 4.0) / w) ** 2) for w in (1.0, 2.0, 3.0)])
    assert not drift_test(t, y)["measurable"].any()


def test_failed_members_are_not_drifts():
    t = np.linspace(0.0, 1.0, 11)
    y = np.vstack([t, t])
    y[1, 5] = np.inf
    d = drift_test(t, y)
    assert d["measurable"].tolist() == [True, False] and np.isnan(d["slope"][1])


def test_methods_2x_apart_on_every_member_are_ranked_and_equal_ones_tie():
    rng = np.random.default_rng(7)
    a = rng.lognormal(0.0, 1.0, 48)
    assert paired_ratio(2 * a, a).verdict == "b smaller" and paired_ratio(a, 2 * a).verdict == "a smaller"
    assert paired_ratio(a, a).verdict == "tie"
    assert least_over_members({"p": a, "q": 2 * a, "r": a.copy()})[0] == ["p", "r"]


def test_noise_between_members_ties_and_a_failed_member_is_the_worst():
    """Medians 3 % apart with members scattered over a decade (vi6 lower on about half of them): a tie, whose
    interval contains 1; an infinite error counts against its method."""
    rng = np.random.default_rng(11)
    a = rng.lognormal(0.0, 1.0, 48)
    b = a * np.exp(rng.permutation(np.repeat([-0.5, 0.56], 24)))
    p = paired_ratio(a, b)
    assert p.verdict == "tie" and p.low < 1 < p.high
    c = a.copy()
    c[: 30] = np.inf
    assert paired_ratio(c, a).verdict == "b smaller"


def test_values_at_round_off_tie():
    """1.5e-15 against 4.9e-15 on every member: both below the floor, a tie; above it, 2x apart is ranked."""
    n = MIN_MEMBERS
    assert paired_ratio(np.full(n, 1.5e-15), np.full(n, 4.9e-15), floor=1e-13).verdict == "tie"
    assert paired_ratio(np.full(n, 2e-12), np.full(n, 4e-12), floor=1e-13).verdict == "a smaller"


def test_too_few_members_rank_nothing():
    a = np.arange(1.0, MIN_MEMBERS)
    p = paired_ratio(a, 2 * a)
    assert p.verdict == "too few members" and "too few" in p.text("a", "b")
    assert least_over_members({"a": a, "b": 2 * a})[0] == []


def test_the_bootstrap_is_seeded():
    rng = np.random.default_rng(5)
    a, b = rng.lognormal(0.0, 1.0, 32), rng.lognormal(0.2, 1.0, 32)
    assert paired_ratio(a, b) == paired_ratio(a, b)
    assert paired_ratio(a, b, seed=1) != paired_ratio(a, b, seed=2)


# ----------------------------------------------------------------------------- work_precision's ladder extension

def _ladder(p: float = 2.0, floor: float = 0.0):
    calls = []

    def error_at(h):
        calls.append(h)
        return h ** p + floor
    return error_at, calls


def test_an_unbracketed_time_extends_the_ladder_until_it_is_bracketed():
    from liethermo.studies.work_precision import extend_ladder, time_to_error

    hs = [0.1, 0.05, 0.025]
    f, calls = _ladder()
    es = [f(h) for h in hs]
    assert time_to_error(es, [1 / h for h in hs], 1e-4)[1] == "lower bound"  # 0.025² = 6.25e-4 > 1e-4
    calls.clear()
    got = extend_ladder(hs, es, [1e-4], 2, f)
    assert [h for h, _ in got] == [0.0125, 0.00625] == calls
    h2, e2 = hs + [h for h, _ in got], es + [e for _, e in got]
    assert time_to_error(e2, [1 / h for h in h2], 1e-4)[1] == "bracketed"
    # the upper side: the coarsest level is already below ε = 0.05, so h is doubled while it divides t_end = 0.4
    got = extend_ladder(hs, es, [0.05], 2, f, fits=lambda h: abs(0.4 / h - round(0.4 / h)) < 1e-9)
    assert [h for h, _ in got] == [0.4, 0.2]
    h2, e2 = [h for h, _ in got] + hs, [e for _, e in got] + es
    assert time_to_error(e2, [1 / h for h in h2], 0.05)[1] == "bracketed"


def test_a_time_out_of_the_caps_reach_keeps_its_bound_label():
    from liethermo.studies.work_precision import extend_ladder

    hs = [0.1, 0.05, 0.025]
    f, calls = _ladder()
    es = [f(h) for h in hs]
    calls.clear()
    assert extend_ladder(hs, es, [1e-6], 2, f) == [] and calls == []  # the h² line needs 4.6 halvings > 2
    assert extend_ladder(hs, es, [1e-4], 0, f) == [] and calls == []  # no extension allowed
    assert [h for h, _ in extend_ladder(hs, es, [1e-4, 1e-6], 2, f)] == [0.0125, 0.00625]  # the reachable ε still
    calls.clear()
    assert extend_ladder(hs, es, [1e-2, 1e-3], 2, f) == [] and calls == []  # bracketed already: nothing to add
    g, calls = _ladder(floor=5e-4)  # a round-off floor just below the finest level: the first added level stops it
    es = [g(h) for h in hs]
    calls.clear()
    assert len(extend_ladder(hs, es, [5.5e-4], 2, g)) == 1 and len(calls) == 1
