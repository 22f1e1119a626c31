"""The fast (structure-of-arrays, vectorized) ensemble kernel computes exactly
what the straightforward one-member-per-iteration kernel computes.

Every comparison is bitwise (``assert_array_equal`` on states, outputs,
status flags, failing steps, Newton iteration counts and max h|Ω|): the fast
kernel performs the same floating-point operations in the same order.  The
ensembles are either all on the paper scene's parameters (which the fast
kernel then keeps in registers) or mix them with random bodies (each lane
then reads its coefficient rows), with partial blocks, members that diverge (explicit RK2 at the paper's
h), members whose Newton iteration fails (iteration cap, NaN data), and
members whose entropy leaves the range of the inline exp.
"""

from __future__ import annotations

import math
import platform
import subprocess
import sys

import numpy as np
import pytest
from conftest import random_body

from liethermo.kernels import ensemble as E
from liethermo.kernels import fast as F
from liethermo.kernels.model import P_CV
from liethermo.kernels.rk import DOP853_A, DOP853_B
from liethermo.simulate import simulate

METHODS = {"vi": E.METHOD_VI, "rk2": E.METHOD_RK2, "rk4": E.METHOD_RK4}


def _random_rotations(rng, N):
    q = rng.standard_normal((N, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], 1)


def mixed_ensemble(paper_params, n_paper=2 * F.BLOCK + 10, n_random=40, seed=0,
                   attitude=False):
    """n_paper random members on the paper scene (uniform attitude, spin
    direction uniform, |Ω| in [0.5, 1.5]·√2 rad/s), then n_random random
    bodies (each with its own parameters)."""
    rng = np.random.default_rng(seed)
    n = 16 if attitude else 7
    R = _random_rotations(rng, n_paper)
    d = rng.standard_normal((n_paper, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    Y = np.zeros((n_paper, n))
    Y[:, 0:3] = d * (rng.uniform(0.5, 1.5, n_paper) * math.sqrt(2.0))[:, None]
    Y[:, 3:6] = R[:, 2, :]
    if attitude:
        Y[:, 7:16] = R.reshape(-1, 9)
    P = np.tile(paper_params, (n_paper, 1))
    if n_random == 0:
        return Y, P
    ys, ps = zip(*(random_body(seed * 1000 + k, attitude=attitude) for k in range(n_random)))
    return np.vstack([Y, np.array(ys)]), np.vstack([P, np.array(ps)])


def run(kernel, method, Y0, P, h, steps, every, alpha=0.5, beta=0.5, tol=1e-14, maxiter=30,
        ISTAT=None):
    fn = F.advance_ensemble_fast if kernel == "fast" else E.advance_ensemble
    N, n = Y0.shape
    Y = Y0.copy()
    OUT = np.full((N, steps // every, n), np.nan)
    IS = np.zeros((N, E.NISTAT), np.int64) if ISTAT is None else ISTAT.copy()
    FS = np.zeros((N, E.NFSTAT))
    fn(METHODS.get(method, E.METHOD_REFERENCE), Y, np.ascontiguousarray(P), h, every,
       steps // every, alpha, beta, tol, maxiter, 2, DOP853_A, DOP853_B, OUT, IS, FS)
    return Y, OUT, IS, FS


def assert_same(a, b):
    """Bit-for-bit equality (signed zeros and NaN payloads included)."""
    for x, y, name in zip(a, b, ("Y", "OUT", "ISTAT", "FSTAT")):
        np.testing.assert_array_equal(x, y, err_msg=name)
        if x.dtype == np.float64:
            np.testing.assert_array_equal(np.ascontiguousarray(x).view(np.uint64),
                                          np.ascontiguousarray(y).view(np.uint64), err_msg=name)


@pytest.mark.parametrize("n_random", [0, 40])  # shared parameters (registers) / mixed (rows)
@pytest.mark.parametrize("attitude", [False, True])
@pytest.mark.parametrize("friction", [(0.5, 0.5), (1.0, 0.0)])
@pytest.mark.parametrize("method", ["vi", "rk2", "rk4"])
def test_fast_equals_simple_on_random_ensembles(method, friction, attitude, n_random,
                                                 paper_params):
    Y, P = mixed_ensemble(paper_params, n_random=n_random, attitude=attitude, seed=1 + attitude)
    assert (F.shared_params(P) is None) == (n_random > 0)
    args = (method, Y, P, 0.1, 200, 20, *friction)
    fast, simple = run("fast", *args), run("simple", *args)
    assert_same(fast, simple)
    status = simple[2][:, E.IS_STATUS]
    if method == "rk2":  # the paper's h: most paper members blow up, at various steps
        assert (status == E.STATUS_NONFINITE).sum() > 20
        assert len(set(simple[2][status != 0, E.IS_FAIL_STEP])) > 5
    else:
        assert np.all(status == E.STATUS_OK)


def test_newton_failures_and_nan_members(paper_params):
    """An iteration cap below what some steps need, a member with NaN data
    (singular Jacobian at once) and a huge spin: the same members fail at the
    same steps with the same flags and Newton counts."""
    Y, P = mixed_ensemble(paper_params, seed=3)
    Y[7, 0] = np.nan
    Y[F.BLOCK + 3, 0:3] = [0.0, 300.0, 300.0]
    for maxiter in (0, 1, 2, 3, 30):
        fast = run("fast", "vi", Y, P, 0.1, 100, 10, maxiter=maxiter)
        simple = run("simple", "vi", Y, P, 0.1, 100, 10, maxiter=maxiter)
        assert_same(fast, simple)
        status = simple[2][:, E.IS_STATUS]
        assert status[7] == E.STATUS_NEWTON and simple[2][7, E.IS_FAIL_STEP] == 1
        if maxiter < 30:
            assert (status == E.STATUS_NEWTON).sum() > 10
    # tol = 0 never converges: everybody fails its first step with the cap
    fast = run("fast", "vi", Y, P, 0.1, 10, 10, tol=0.0, maxiter=5)
    assert_same(fast, run("simple", "vi", Y, P, 0.1, 10, 10, tol=0.0, maxiter=5))
    assert np.all(fast[2][:, E.IS_STATUS] == E.STATUS_NEWTON)
    # a loose tolerance: lanes converge in iteration 1 (done inside _vi_prepare)
    # or 2, in mixed blocks
    fast = run("fast", "vi", Y, P, 0.1, 50, 10, tol=1e-4, maxiter=2)
    simple = run("simple", "vi", Y, P, 0.1, 50, 10, tol=1e-4, maxiter=2)
    assert_same(fast, simple)
    its = simple[2][:, E.IS_NEWTON_TOTAL] / np.maximum(simple[2][:, E.IS_STEPS], 1)
    assert np.any(simple[2][:, E.IS_NEWTON_MAX] == 1) and np.any(its > 1.0)


@pytest.mark.parametrize("method", ["vi", "rk2", "rk4"])
def test_failing_member_does_not_corrupt_its_block(method, paper_params):
    """One member of a full block fails at its first step; every other member
    of the block is bitwise what it is in an ensemble without that member
    (where it sits in another lane) and what the simple kernel gives."""
    Y, P = mixed_ensemble(paper_params, n_paper=F.BLOCK, n_random=0, seed=4)
    h = 0.02 if method == "rk2" else 0.1  # RK2 stable: only the bad member fails
    bad = 5
    Y[bad, 0:3] = [0.0, 3000.0, 3000.0] if method != "vi" else [np.nan, 0.0, 0.0]
    fast = run("fast", method, Y, P, h, 60, 10)
    assert_same(fast, run("simple", method, Y, P, h, 60, 10))
    assert fast[2][bad, E.IS_STATUS] != E.STATUS_OK
    keep = np.arange(len(Y)) != bad
    assert np.all(fast[2][keep, E.IS_STATUS] == E.STATUS_OK)
    without = run("fast", method, Y[keep], P[keep], h, 60, 10)
    for a, b in zip(fast, without):
        np.testing.assert_array_equal(a[keep], b)


@pytest.mark.parametrize("n_random", [0, 5])
@pytest.mark.parametrize("method", ["vi", "rk2", "rk4"])
def test_entropy_outside_inline_exp_range(method, n_random, paper_params):
    """Members whose σ/c_v is beyond EXP_SMALL (or straddles it) take the
    math.exp path, per lane, and still agree bitwise."""
    Y, P = mixed_ensemble(paper_params, n_paper=F.BLOCK + 5, n_random=n_random, seed=5)
    cv = P[:, P_CV]
    Y[::3, 6] = 0.3 * cv[::3]
    Y[1::7, 6] = F.EXP_SMALL * cv[1::7] * (1 - 1e-9)  # crosses the limit while stepping
    Y[2::11, 6] = -2.0 * F.EXP_SMALL * cv[2::11]
    h = 0.02 if method == "rk2" else 0.1
    fast = run("fast", method, Y, P, h, 60, 10)
    assert_same(fast, run("simple", method, Y, P, h, 60, 10))


def test_shared_params_compares_bits(paper_params):
    """The register (shared-parameter) kernel is chosen only when every row is
    bitwise the same: −0 against +0 or one differing last bit means rows."""
    P = np.tile(paper_params, (5, 1))
    np.testing.assert_array_equal(F.shared_params(P), paper_params)
    assert F.shared_params(P[:0]) is None
    P[3, 4] = np.nextafter(P[3, 4], np.inf)
    assert F.shared_params(P) is None
    P = np.tile(paper_params, (5, 1))
    P[:, 4] = 0.0
    assert F.shared_params(P) is not None
    P[2, 4] = -0.0
    assert F.shared_params(P) is None


def test_inline_entropy_rate_is_exact_to_round_off(paper_params):
    """model.sigma_rate_poly (cubic Taylor polynomial in σ, fused) gives the
    factor (c/T₀)·exp(mσ), m = −1/c_v, correctly rounded on its whole range
    |σ| ≤ σ_max = EXP_SMALL·c_v — checked against the exponential summed
    exactly in rational arithmetic, for the paper's c_v and two others — and
    flags exactly the σ beyond σ_max."""
    from fractions import Fraction

    from numba import njit

    from liethermo.kernels.model import Q_CT, Q_MICV, Q_SMAX, coefficients, sigma_rate_poly

    @njit
    def evaluate(ss, p):  # |Ω| = 1: σ̇ is the factor itself
        q = coefficients(p)
        out = np.empty_like(ss)
        small = np.empty(ss.size, np.bool_)
        for k in range(ss.size):
            out[k], small[k] = sigma_rate_poly(1.0, 0.0, 0.0, ss[k], q)
        return out, small, q

    def exact(s, cT, m):  # cT·Σ (ms)ⁿ/n! to n = 8 (|ms| ≤ 2⁻¹⁶: the rest is < 2⁻¹⁶⁰)
        X = Fraction(s) * Fraction(m)
        term = total = Fraction(1)
        for n in range(1, 9):
            term = term * X / n
            total += term
        return float(Fraction(cT) * total)

    rng = np.random.default_rng(6)
    for cv in (paper_params[P_CV], 1e2, 1e9):
        p = paper_params.copy()
        p[P_CV] = cv
        smax = evaluate(np.zeros(1), p)[2][Q_SMAX]
        for hi in (1e-12 * smax, 1e-6 * smax, smax):
            ss = np.concatenate([rng.uniform(-hi, hi, 2000), [smax, -smax, 0.0, -0.0, 5e-324]])
            got, small, q = evaluate(ss, p)
            assert small.all()
            np.testing.assert_array_equal(got, [exact(s, q[Q_CT], q[Q_MICV]) for s in ss])
        beyond = np.array([np.nextafter(smax, np.inf), -2.0 * smax, np.nan, np.inf])
        assert not evaluate(beyond, p)[1].any()


def test_entry_states_and_partial_calls(paper_params):
    """Members that already failed are skipped, members enter with their own
    step counters, a run in pieces equals one call; edge sizes."""
    Y, P = mixed_ensemble(paper_params, n_paper=F.BLOCK + 3, n_random=3, seed=7)
    IS = np.zeros((len(Y), E.NISTAT), np.int64)
    IS[::4, E.IS_STATUS] = E.STATUS_NONFINITE
    IS[1::4, E.IS_STEPS] = 17
    IS[1::4, E.IS_NEWTON_TOTAL] = 40
    for method in ("vi", "rk2", "rk4"):
        assert_same(run("fast", method, Y, P, 0.1, 30, 3, ISTAT=IS),
                    run("simple", method, Y, P, 0.1, 30, 3, ISTAT=IS))
        one = run("fast", method, Y, P, 0.1, 40, 10)
        a = run("fast", method, Y, P, 0.1, 20, 10)
        Yb, OUTb, ISb, FSb = a
        fn_out = np.full((len(Y), 2, Y.shape[1]), np.nan)
        F.advance_ensemble_fast(METHODS[method], Yb, P, 0.1, 10, 2, 0.5, 0.5, 1e-14, 30, 1,
                                DOP853_A, DOP853_B, fn_out, ISb, FSb)
        np.testing.assert_array_equal(np.concatenate([OUTb, fn_out], 1), one[1])
        np.testing.assert_array_equal(Yb, one[0])
        np.testing.assert_array_equal(ISb, one[2])
    for N in (0, 1, F.BLOCK + 1):
        assert_same(run("fast", "vi", Y[:N], P[:N], 0.1, 10, 1),
                    run("simple", "vi", Y[:N], P[:N], 0.1, 10, 1))
    assert_same(run("fast", "rk4", Y, P, 0.1, 0, 1), run("simple", "rk4", Y, P, 0.1, 0, 1))


@pytest.mark.parametrize("method", ["vi", "rk2", "rk4"])
def test_max_h_omega_entry_values_and_step_sign(method, paper_params):
    """max h|Ω| matches the simple kernel's per-step running max bitwise,
    whatever the entry values (larger than any step's, ±0, negative, NaN),
    for failing members, with no step, and for h ≤ 0."""
    Y, P = mixed_ensemble(paper_params, n_paper=F.BLOCK + 9, n_random=6, seed=10)
    N = len(Y)
    Y[4, 0] = np.nan
    FS0 = np.zeros((N, E.NFSTAT))
    FS0[1::5, 0] = 1e3
    FS0[2::5, 0] = -0.0
    FS0[3::5, 0] = -1.0
    FS0[4::5, 0] = np.nan
    FS0[::7, 0] = 0.1 * math.sqrt(2.0)  # likely ties with a step's h|Ω|
    for h, steps in ((0.1, 30), (0.05, 0), (-0.05, 10), (0.0, 5)):
        res = []
        for fn in (F.advance_ensemble_fast, E.advance_ensemble):
            Yc, FS = Y.copy(), FS0.copy()
            OUT = np.full((N, max(steps, 1), Y.shape[1]), np.nan)
            IS = np.zeros((N, E.NISTAT), np.int64)
            fn(METHODS[method], Yc, P, h, 1, steps, 0.5, 0.5, 1e-14, 30, 1,
               DOP853_A, DOP853_B, OUT, IS, FS)
            res.append((Yc, OUT, IS, FS))
        assert_same(*res)


def test_reference_method_falls_back(paper_params):
    Y, P = mixed_ensemble(paper_params, n_paper=20, n_random=4, seed=8)
    assert_same(run("fast", "reference", Y, P, 0.05, 4, 2),
                run("simple", "reference", Y, P, 0.05, 4, 2))


@pytest.mark.parametrize("method,start", [("vi", "staggered"), ("vi", "node"), ("rk2", "node"),
                                          ("rk4", "node")])
def test_simulate_kernel_switch(method, start, paper_params):
    Y, P = mixed_ensemble(paper_params, n_paper=150, n_random=10, seed=9, attitude=True)
    kw = dict(start=start, every=5, chunk_steps=15)
    fast = simulate(Y, P, 0.1, 60, method, kernel="fast", **kw)
    simple = simulate(Y, P, 0.1, 60, method, kernel="simple", **kw)
    auto = simulate(Y, P, 0.1, 60, method, threads=1, **kw)
    for t in (fast, auto):
        for name in ("states", "status", "fail_step", "newton_iterations", "newton_max",
                     "steps_done", "max_h_omega"):
            np.testing.assert_array_equal(getattr(t, name), getattr(simple, name), err_msg=name)
    with pytest.raises(ValueError, match="kernel"):
        simulate(Y, P, 0.1, 10, method, kernel="vectorised")


def test_kernels_are_vectorized():
    """The hot loop of each lane sweep is packed double-precision arithmetic with
    packed fused multiply-adds and no masked load or store, for a uniform block
    (coefficient tuples) and a mixed one (coefficient rows) (fresh, uncached
    compilations of four sweeps)."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        pytest.skip("packed-op check written for x86-64")
    from liethermo.bench import fresh_sweep_asm, hot_loop_counts
    from liethermo.kernels.model import coefficients
    from liethermo.kernels.vi import vi_coefficients

    S = np.ones(F.NROWS * F.ROW)
    pp = F._load_params(S, 0)
    qq = coefficients(pp)
    vv = vi_coefficients(pp, 0.1, 0.5, 0.5)
    for f, args in ((F._rk4_sweep, (S, 8, 0.1, qq, 0)),
                    (F._rk4_sweep, (S, 8, 0.1, None, 1)),
                    (F._rk2_sweep, (S, 8, 0.1, qq, 1)),
                    (F._rk2_sweep, (S, 8, 0.1, None, 0)),
                    (F._vi_prepare, (S, 8, 0.1, 1e-14, True, qq, vv)),
                    (F._vi_prepare, (S, 8, 0.1, 1e-14, True, None, None)),
                    (F._newton_sweep, (S, 8, 1e-14, 1, vv)),
                    (F._newton_sweep, (S, 8, 1e-14, 1, None))):
        c = hot_loop_counts(fresh_sweep_asm(f, args))
        assert c and c["packed"] >= 40, (f.__name__, c)
        assert c["fma"] >= 20, (f.__name__, c)
        assert c["masked"] == 0, (f.__name__, c)


def test_import_compiles_nothing():
    code = ("import liethermo.kernels.fast as F, liethermo.simulate;"
            "assert not F._advance_blocks_shared.overloads and not F._advance_blocks_rows.overloads"
            " and not F._block_steps.overloads")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_hot_loop_counts_reads_a_listing():
    """bench.hot_loop_counts picks the loop with the most packed instructions and
    counts its arithmetic, memory operands, stack slots and stores."""
    from liethermo.bench import hot_loop_counts

    asm = """
        movq %rdi, %rax
.LBB0_1:
        vaddsd %xmm0, %xmm1, %xmm1
        jne .LBB0_1
.LBB0_2:
        vmovupd (%rdi,%rax,8), %ymm0
        vfmadd213pd %ymm1, %ymm2, %ymm0
        vmulpd 32(%rsp), %ymm0, %ymm3
        vaddpd %ymm3, %ymm0, %ymm0
        vdivpd %ymm0, %ymm3, %ymm4
        vmovupd %ymm4, 64(%rsp)
        vmovupd %ymm0, (%rsi,%rax,8)
        addq $4, %rax
        jne .LBB0_2
        retq
"""
    c = hot_loop_counts(asm)
    assert c["width"] == "ymm" and c["lanes"] == 4
    assert c["instructions"] == 9
    assert (c["packed"], c["fma"], c["mul"], c["addsub"], c["div"]) == (4, 1, 1, 1, 1)
    assert (c["mem"], c["stack"], c["stores"]) == (4, 2, 2)
    assert hot_loop_counts("retq\n") == {}
