"""Ensemble driver (liethermo.kernels.ensemble via simulate): members are
independent, threads do not change numbers, failures stay per member (SPEC §5)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numba
import numpy as np
import pytest

from liethermo.simulate import STATUS_NEWTON, STATUS_NONFINITE, STATUS_OK, simulate

from conftest import (  # tests/ is on sys.path
    H_PAPER, OMEGA0, R0, make_params, make_state, paper_numbers, random_body)

TESTS_DIR = Path(__file__).resolve().parent


def _ensemble(paper_y0_attitude, paper_params, n_random=5):
    """Paper scene + random non-symmetric bodies (attitude on); one member spins 20× faster."""
    Y = [paper_y0_attitude]
    P = [paper_params]
    for s in range(n_random):
        y, p = random_body(100 + s, attitude=True)
        Y.append(y)
        P.append(p)
    Y = np.array(Y)
    P = np.array(P)
    Y[3, 0:3] *= 20.0
    return Y, P


def _solo(Y, P, m, *args, **kw):
    return simulate(Y[m], P[m], *args, **kw)


# (method, start, friction, extra kwargs)
SOLO_CASES = [
    ("vi", "node", "trapezoid", {}),
    ("vi", "node", "endpoint", {}),
    ("rk2", "node", "trapezoid", {}),
    ("rk4", "node", "trapezoid", {}),
    # the reference's substep count is chosen from the whole ensemble: pin it
    ("reference", "node", "trapezoid", {"ref_substeps": 3}),
]


@pytest.mark.parametrize("method,start,friction,kw", SOLO_CASES,
                         ids=[f"{c[0]}-{c[1]}-{c[2]}" for c in SOLO_CASES])
def test_member_equals_solo_run(method, start, friction, kw, paper_y0_attitude, paper_params):
    """Members do not interact (no cross-member operation in the kernels), so
    each member of a 6-member ensemble is bitwise identical to the same initial
    condition and parameters run alone (stronger than the ≤ 1e-14 asked for)."""
    Y, P = _ensemble(paper_y0_attitude, paper_params)
    tr = simulate(Y, P, 0.01, 300, method, start=start, friction=friction, every=3, **kw)
    assert np.all(tr.status == STATUS_OK)
    for m in range(len(Y)):
        solo = _solo(Y, P, m, 0.01, 300, method, start=start, friction=friction, every=3, **kw)
        np.testing.assert_array_equal(solo.states[0], tr.states[m])
        assert solo.newton_iterations[0] == tr.newton_iterations[m]


@pytest.mark.parametrize("method,start", [("vi", "staggered"), ("reference", "node")])
def test_member_equals_solo_run_with_automatic_substeps(method, start, paper_y0_attitude,
                                                        paper_params):
    """Per member, never per ensemble (SPEC §5): with the staggered start (Ω₀ :=
    Ω(h/2) computed by the reference) and with the reference method at its
    automatic substep count, a member must be bitwise identical to its solo run,
    as it is for every method in test_member_equals_solo_run."""
    Y, P = _ensemble(paper_y0_attitude, paper_params)
    tr = simulate(Y, P, 0.01, 300, method, start=start)
    for m in range(len(Y)):
        solo = _solo(Y, P, m, 0.01, 300, method, start=start).states[0]
        np.testing.assert_array_equal(solo, tr.states[m])


@pytest.mark.parametrize("method", ["vi", "rk2", "rk4"])
def test_one_and_two_threads_identical(method, paper_y0_attitude, paper_params):
    """prange only distributes members over threads: threads=1 and threads=2
    (checked to be in effect during the kernel calls) give bitwise identical states, statuses and Newton counts, also with a
    failing member in the ensemble (huge spin)."""
    Y, P = _ensemble(paper_y0_attitude, paper_params)
    Y[2, 0:3] = [0.0, 2000.0, 2000.0]
    kw = dict(newton_maxiter=6, chunk_steps=100) if method == "vi" else dict(chunk_steps=100)
    seen = {1: set(), 2: set()}
    t1 = simulate(Y, P, 0.01, 200, method, threads=1,
                  progress=lambda n: seen[1].add(numba.get_num_threads()), **kw)
    t2 = simulate(Y, P, 0.01, 200, method, threads=2,
                  progress=lambda n: seen[2].add(numba.get_num_threads()), **kw)
    assert seen == {1: {1}, 2: {2}}  # the kernels really ran with 1 and with 2 threads
    np.testing.assert_array_equal(t1.states, t2.states)
    np.testing.assert_array_equal(t1.status, t2.status)
    np.testing.assert_array_equal(t1.newton_iterations, t2.newton_iterations)
    if method != "rk4":
        assert t1.status[2] != STATUS_OK  # the mixed case really is mixed


def test_rk2_blowup_is_per_member(paper_y0_attitude, paper_params):
    """A member with a huge spin (h|Ω| ≈ 28) makes explicit RK2 overflow: it is
    flagged STATUS_NONFINITE, stops (NaN after its failing step, finite
    before), and the healthy members are bitwise identical to their solo runs."""
    Y, P = _ensemble(paper_y0_attitude, paper_params)
    Y[2, 0:3] = [0.0, 2000.0, 2000.0]
    tr = simulate(Y, P, 0.01, 200, "rk2")
    assert tr.status[2] == STATUS_NONFINITE
    k = tr.fail_step[2]
    assert 1 <= k <= 200 and tr.steps_done[2] == k - 1
    assert np.all(np.isfinite(tr.states[2, :k])) and np.all(np.isnan(tr.states[2, k:]))
    for m in [0, 1, 3, 4, 5]:
        assert tr.status[m] == STATUS_OK
        np.testing.assert_array_equal(_solo(Y, P, m, 0.01, 200, "rk2").states[0], tr.states[m])


def test_vi_newton_failure_is_per_member(paper_y0_attitude, paper_params):
    """With newton_maxiter set to the largest count the healthy members need, a
    member with a huge spin (h|Ω| ≈ 21) fails its first Newton solve
    (STATUS_NEWTON, NaN afterwards) while the healthy members complete, bitwise
    identical to their solo runs with the default cap (the cap was never hit)."""
    Y, P = _ensemble(paper_y0_attitude, paper_params)
    healthy = simulate(Y, P, 0.05, 200, "vi")
    assert np.all(healthy.status == STATUS_OK)
    cap = int(healthy.newton_max.max())
    Yb = Y.copy()
    Yb[2, 0:3] = [0.0, 300.0, 300.0]
    tr = simulate(Yb, P, 0.05, 200, "vi", newton_maxiter=cap)
    assert tr.status[2] == STATUS_NEWTON and tr.fail_step[2] == 1
    assert np.all(np.isnan(tr.states[2, 1:]))
    for m in [0, 1, 3, 4, 5]:
        assert tr.status[m] == STATUS_OK
        np.testing.assert_array_equal(healthy.states[m], tr.states[m])
        np.testing.assert_array_equal(_solo(Y, P, m, 0.05, 200, "vi").states[0], tr.states[m])


def test_paper_h_rk2_blows_up_vi_does_not(paper_y0, paper_params):
    """At the paper's h = 0.1 over 300 steps (30 s) explicit RK2 is unstable on the
    paper scene (h|Ω| reaches ≈ 0.6 as the top falls): STATUS_NONFINITE with NaN
    from its failing step on; the VI completes with STATUS_OK and finite states."""
    rk2 = simulate(paper_y0, paper_params, H_PAPER, 300, "rk2")
    assert rk2.status[0] == STATUS_NONFINITE
    k = rk2.fail_step[0]
    assert 1 < k < 300
    assert np.all(np.isfinite(rk2.states[0, :k])) and np.all(np.isnan(rk2.states[0, k:]))
    v = simulate(paper_y0, paper_params, H_PAPER, 300, "vi")
    assert v.status[0] == STATUS_OK and v.steps_done[0] == 300
    assert np.all(np.isfinite(v.states))


@pytest.mark.parametrize("method", ["vi", "rk4"])
def test_chunking_does_not_change_results(method, paper_y0_attitude, paper_params):
    """simulate advances the kernels chunk by chunk, in place; splitting 240
    steps into chunks of 7·every or one chunk gives bitwise identical output."""
    a = simulate(paper_y0_attitude, paper_params, 0.02, 240, method, every=4, chunk_steps=28)
    b = simulate(paper_y0_attitude, paper_params, 0.02, 240, method, every=4, chunk_steps=240)
    np.testing.assert_array_equal(a.states, b.states)


_NOJIT_SCRIPT = r"""
import sys
import numpy as np
import numba
sys.path.insert(0, sys.argv[2])
assert numba.config.DISABLE_JIT
from conftest import make_state, paper_numbers, make_params, OMEGA0, R0
from liethermo.simulate import simulate
d = paper_numbers()
p = make_params(d["inertia"], d["c"], d["gvec"], d["cv"])
y0 = make_state(OMEGA0, R0, attitude=True)
tr = simulate(y0, p, 0.1, 30, "vi", start="staggered", friction="trapezoid")
np.save(sys.argv[1], tr.states)
"""


def test_plain_python_matches_jit(tmp_path):
    """NUMBA_DISABLE_JIT=1 runs the same kernels as plain Python: a 30-step VI
    trajectory (paper scene, attitude, staggered start, so the reference runs
    too) agrees with the jitted one to ≤ 1e-13 (in practice bitwise)."""
    out = tmp_path / "nojit.npy"
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    r = subprocess.run([sys.executable, "-c", _NOJIT_SCRIPT, str(out), str(TESTS_DIR)],
                       env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    plain = np.load(out)
    d = paper_numbers()
    p = make_params(d["inertia"], d["c"], d["gvec"], d["cv"])
    jitted = simulate(make_state(OMEGA0, R0, attitude=True), p, 0.1, 30, "vi",
                      start="staggered", friction="trapezoid").states
    assert plain.shape == jitted.shape and np.all(np.isfinite(jitted))
    assert np.abs(plain - jitted).max() <= 1e-13 * np.abs(jitted).max()
