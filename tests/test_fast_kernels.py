"""The vectorized block kernel computes exactly what the straightforward kernel computes.

Every comparison is bitwise (states, outputs, status flags, failing steps,
Newton iteration counts and max |h|·|Ω|, signed zeros and NaN payloads
included): both kernels call the same lane functions.  The ensembles cover
every model variant (the paper's top, attitude, a diagonal friction, no
gravity, no friction, the coupled top, double-bracket friction), shared
parameters (registers) and per-member parameters (rows), partial blocks,
members that diverge (explicit RK2 at the paper's h), members whose Newton
iteration fails, and members whose entropy leaves the range of the inline
polynomials.
"""

from __future__ import annotations

import importlib.util
import math
import os
import platform
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from conftest import paper_physics, random_body, random_ensemble, stack
from liethermo.top.methods import MethodChoice
from liethermo.top.kernels import fast as F
from liethermo.top.kernels import layout as L
from liethermo.top.kernels import parallel, rk, simple, vi
from liethermo.top.kernels.steppers import Explicit
from liethermo.top.kernels.terms.thermo import EXPLICIT, EXP_SMALL, SYMMETRIC
from liethermo.top.physics import build_model
from liethermo.top.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]


#: the method variants a MethodChoice carries
_VARIANTS = ("friction", "start", "entropy", "composition")


def _bench():
    spec = importlib.util.spec_from_file_location("bench", ROOT / "benchmarks" / "bench.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def mixed(n_paper=2 * F.BLOCK + 10, n_random=40, seed=0, variant="paper"):
    """(physics, Ω₀, R₀): n_paper random members of a variant of the paper's
    top (shared parameters), then n_random random bodies (own parameters)."""
    phys = paper_physics(n_paper)
    if variant == "no_gravity":
        phys = replace(phys, gravity_torque=np.zeros((n_paper, 3)))
    elif variant == "no_friction":
        phys = replace(phys, stokes_resistance=np.zeros((n_paper, 3)))
    elif variant == "coupled":
        phys = replace(phys, heat_capacity=np.full(n_paper, 1e-3), thermal_expansion=np.full(n_paper, 1e-3))
    elif variant == "double_bracket":
        phys = replace(phys, internal_friction=np.full(n_paper, 5.0))
    elif variant == "diagonal":
        phys = replace(phys, stokes_resistance=phys.stokes_resistance * np.array([0.5, 1.0, 2.0]), isotropic_resistance=False)
    om, R = random_ensemble(n_paper, seed)
    if n_random == 0:
        return phys, om, R
    bodies = [random_body(seed * 1000 + k, diagonal=(variant == "diagonal")) for k in range(n_random)]
    extra = [replace(b[0], **{f: getattr(phys, f)[:1] for f in ("thermal_expansion", "internal_friction")})
             for b in bodies]
    if variant == "coupled":
        extra = [replace(e, heat_capacity=np.array([1e-3])) for e in extra]
    if variant == "no_gravity":
        extra = [replace(e, gravity_torque=np.zeros((1, 3))) for e in extra]
    if variant == "no_friction":
        extra = [replace(e, stokes_resistance=np.zeros((1, 3))) for e in extra]
    return (stack([phys] + extra), np.vstack([om] + [b[1] for b in bodies]),
            np.vstack([R] + [b[2] for b in bodies]))


def run(kernel, method, phys, om, R, h, steps, every, **kw):
    choice = MethodChoice.of(method, **{k: kw.pop(k) for k in _VARIANTS if k in kw})
    return simulate(phys, om, R, h, steps, choice, every=every, kernel=kernel, **kw)


FIELDS = ("states", "status", "fail_step", "newton_iterations", "newton_max", "steps_done",
          "max_h_omega")


def assert_same(a, b):
    """Bit-for-bit equality of two trajectories."""
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        np.testing.assert_array_equal(x, y, err_msg=name)
        if x.dtype == np.float64:
            np.testing.assert_array_equal(np.ascontiguousarray(x).view(np.uint64),
                                          np.ascontiguousarray(y).view(np.uint64), err_msg=name)


CASES = [  # (variant, method, extra simulate keywords, parameter layouts run by default)
    ("paper", "vi", dict(start="node", entropy="explicit"), (0, 12)),
    ("paper", "vi", dict(friction="endpoint"), (12,)),
    ("paper", "vi4", {}, (0,)),
    ("paper", "vi6", {}, (12,)),
    ("paper", "vi4", dict(composition="triple_jump"), (0,)),
    ("paper", "split", {}, (0, 12)),
    ("paper", "split4", {}, (12,)),
    ("paper", "split6", {}, (0,)),
    ("diagonal", "split4", {}, (0,)),
    ("no_friction", "split", {}, (12,)),
    ("no_gravity", "split6", {}, (12,)),
    ("paper", "rk2", {}, (0, 12)),
    ("paper", "rk4", {}, (12,)),
    ("diagonal", "vi", {}, (12,)),
    ("diagonal", "rk4", {}, (0,)),
    ("no_gravity", "vi", {}, (0,)),
    ("no_friction", "vi", {}, (12,)),
    ("no_friction", "rk2", {}, (0,)),
    ("coupled", "vi", {}, (0, 12)),
    ("coupled", "vi4", {}, (12,)),
    ("coupled", "rk4", {}, (0,)),
    ("double_bracket", "vi", {}, (12,)),
    ("double_bracket", "rk2", {}, (0,)),
]
#: every case runs with shared parameters (registers, n_random = 0) or per-member rows (12 random members)
#: where its last field says: each method, each variant and each family meets both layouts somewhere.
#: Each (case, layout) compiles a kernel pair of its own (10–20 s from an empty cache);
#: LIETHERMO_FAST_FULL=1 runs every case in both layouts.
FULL = os.environ.get("LIETHERMO_FAST_FULL") == "1"
RUNS = [(v, m, k, n) for v, m, k, layouts in CASES for n in ((0, 12) if FULL else layouts)]


@pytest.mark.slow
@pytest.mark.parametrize("variant,method,kw,n_random", RUNS,
                         ids=[f"{v}-{m}-{'-'.join(k.values())}-{n}" for v, m, k, n in RUNS])
def test_fast_equals_simple(variant, method, kw, n_random):
    phys, om, R = mixed(n_random=n_random, seed=1, variant=variant)
    assert (build_model(phys).shared is None) == (n_random > 0)
    attitude = method in ("vi", "rk2", "split", "split4") and variant == "paper"
    h = 0.05 if variant == "coupled" else 0.1
    fast = run("fast", method, phys, om, R, h, 100, 20, attitude=attitude, **kw)
    simple_ = run("simple", method, phys, om, R, h, 100, 20, attitude=attitude, **kw)
    assert_same(fast, simple_)
    if method == "rk2" and variant == "paper":  # the paper's h: many members blow up, at various steps
        failed = fast.status != L.STATUS_OK
        assert failed.sum() > 20 and len(set(fast.fail_step[failed])) > 5
    elif method != "rk2":
        assert np.all(fast.status == L.STATUS_OK)


def test_newton_failures_and_nan_members():
    """An iteration cap below what some steps need, a member with NaN data and
    a huge spin: the same members fail at the same steps with the same flags
    and Newton counts; the paper start (no solve before step 1) too."""
    phys, om, R = mixed(seed=3)
    om[7, 0] = np.nan
    om[F.BLOCK + 3] = [0.0, 300.0, 300.0]
    for start in ("legendre", "node"):
        for maxiter in (1, 2, 3, 30):
            kw = dict(start=start, newton_maxiter=maxiter)
            fast = run("fast", "vi", phys, om, R, 0.1, 60, 10, **kw)
            assert_same(fast, run("simple", "vi", phys, om, R, 0.1, 60, 10, **kw))
            assert fast.status[7] != L.STATUS_OK
            if maxiter < 30:
                assert (fast.status == L.STATUS_NEWTON).sum() > 10
    # tol = 0 never converges: every member fails with the cap
    fast = run("fast", "vi", phys, om, R, 0.1, 10, 10, start="node", newton_tol=0.0, newton_maxiter=5)
    assert_same(fast, run("simple", "vi", phys, om, R, 0.1, 10, 10, start="node", newton_tol=0.0,
                          newton_maxiter=5))
    assert np.all(fast.status == L.STATUS_NEWTON)
    # a loose tolerance: lanes converge in iteration 1 (inside the prepare sweep) or 2
    kw = dict(start="node", newton_tol=1e-4, newton_maxiter=2)
    fast = run("fast", "vi", phys, om, R, 0.1, 50, 10, **kw)
    assert_same(fast, run("simple", "vi", phys, om, R, 0.1, 50, 10, **kw))
    assert np.any(fast.newton_max == 1) and np.any(fast.newton_max == 2)


@pytest.mark.parametrize("method", ["vi", "vi4", "rk2", "rk4", "split4"])
def test_failing_member_does_not_corrupt_its_block(method):
    """One member of a full block fails at once; every other member is bitwise
    what it is in an ensemble without that member (in another lane) and what
    the straightforward kernel gives; for a composition the failing member's
    state is the start of its failing step."""
    phys, om, R = mixed(n_paper=F.BLOCK, n_random=0, seed=4)
    h = 0.02 if method == "rk2" else 0.1
    bad = 5
    om[bad] = [0.0, 3000.0, 3000.0] if method.startswith("rk") else [np.nan, 0.0, 0.0]
    fast = run("fast", method, phys, om, R, h, 60, 10)
    assert_same(fast, run("simple", method, phys, om, R, h, 60, 10))
    assert fast.status[bad] != L.STATUS_OK
    keep = np.arange(len(om)) != bad
    assert np.all(fast.status[keep] == L.STATUS_OK)
    without = run("fast", method, phys.take(keep), om[keep], R[keep], h, 60, 10)
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(fast, name)[keep], getattr(without, name))


def test_composition_failure_mid_step_restores_the_step_start():
    """A vi4 member whose second (negative) substep fails keeps the state at
    the start of the failing step — a node value, not a substep value — in
    both kernels (the triple jump, whose negative substep −1.70 h is large
    enough to fail here)."""
    phys, om, R = mixed(n_paper=40, n_random=0, seed=6)
    # the negative substep takes back more heat than a small heat capacity holds:
    # U(σ') − U(σ) = hP < −U(σ), no σ' exists (log1p of less than −1)
    hv = replace(phys, stokes_resistance=phys.stokes_resistance * 10.0, heat_capacity=np.full(len(om), 1e-7))
    fast = run("fast", "vi4", hv, om, R, 0.1, 20, 1, composition="triple_jump")
    simple_ = run("simple", "vi4", hv, om, R, 0.1, 20, 1, composition="triple_jump")
    assert_same(fast, simple_)
    failed = fast.status != L.STATUS_OK
    assert failed.any()
    m = int(np.argmax(failed))
    k = fast.steps_done[m]
    assert np.all(np.isfinite(fast.states[m, k])) and np.all(np.isnan(fast.states[m, k + 1:]))


@pytest.mark.parametrize("shared", [True, False])
@pytest.mark.parametrize("method", ["vi", "rk2", "rk4"])
def test_entropy_outside_the_inline_polynomials(method, shared):
    """Members whose σ/c_v leaves the range of the inline polynomials (a small
    heat capacity) at various steps, or from the first step, take the exact
    path, per lane, and still agree bitwise (explicit and symmetric entropy
    updates of the VI); shared and per-member parameters."""
    phys, om, R = mixed(n_paper=F.BLOCK + 5, n_random=0, seed=5)
    if shared:
        cv = np.full(len(om), 3e-4)
    else:
        cv = np.random.default_rng(5).choice([1306.9, 3e-2, 1e-3, 1e-5], len(om))
    phys = replace(phys, heat_capacity=cv)
    h = 0.02 if method == "rk2" else 0.1
    for kw in ([dict(entropy="explicit"), dict(entropy="symmetric")] if method == "vi" else [{}]):
        fast = run("fast", method, phys, om, R, h, 60, 10, **kw)
        assert_same(fast, run("simple", method, phys, om, R, h, 60, 10, **kw))
        ratio = np.abs(fast.sigma / cv[:, None])
        beyond = (ratio > EXP_SMALL).any(axis=1)
        assert beyond.any() and (shared or not beyond.all())


@pytest.mark.parametrize("method", ["vi", "rk2", "rk4"])
def test_inline_polynomial_range_is_exercised(method):
    """The lanes beyond the inline polynomials do exist in a run: σ/c_v large
    (a small heat capacity) puts every lane on the exact path, and the result
    still agrees bitwise."""
    phys, om, R = mixed(n_paper=F.BLOCK + 3, n_random=0, seed=8)
    phys = replace(phys, heat_capacity=np.full(len(om), 1e-6))
    h = 0.02 if method == "rk2" else 0.1
    fast = run("fast", method, phys, om, R, h, 30, 10)
    assert_same(fast, run("simple", method, phys, om, R, h, 30, 10))
    assert fast.sigma[:, -1].max() / 1e-6 > EXP_SMALL


def test_entry_states_and_partial_calls():
    """Members that already failed are skipped, members enter with their own
    step counters, a run in pieces equals one call; edge sizes."""
    phys, om, R = mixed(n_paper=F.BLOCK + 3, n_random=3, seed=7)
    for method in ("vi", "rk4"):
        one = run("fast", method, phys, om, R, 0.1, 40, 10)
        pieces = run("fast", method, phys, om, R, 0.1, 40, 10, chunk_steps=10)
        assert_same(one, pieces)
        assert_same(pieces, run("simple", method, phys, om, R, 0.1, 40, 10, chunk_steps=20))
    for N in (0, 1, F.BLOCK + 1):
        assert_same(run("fast", "vi", phys.take(slice(0, N)), om[:N], R[:N], 0.1, 10, 1),
                    run("simple", "vi", phys.take(slice(0, N)), om[:N], R[:N], 0.1, 10, 1))


def test_members_already_failed_are_skipped_by_both_kernels():
    phys, om, R = mixed(n_paper=F.BLOCK + 3, n_random=0, seed=9)
    km = build_model(phys)
    lay = km.layout("rk")
    Y0 = np.zeros((len(om), lay.size))
    Y0[:, 0:3] = om
    Y0[:, 3:6] = R[:, 2]
    res = []
    for kernel in ("fast", "simple"):
        Y = Y0.copy()
        OUT = np.full((len(om), 3, lay.size), np.nan)
        IS = np.zeros((len(om), L.NISTAT), np.int64)
        IS[::4, L.IS_STATUS] = L.STATUS_NONFINITE
        IS[1::4, L.IS_STEPS] = 17
        FS = np.zeros((len(om), L.NFSTAT))
        FS[2::5, 0] = 1e3
        stepper = Explicit(rk.RK4, 1)
        if kernel == "fast":
            parallel.run_ranges(F.advance_blocks, -(-len(om) // F.BLOCK),
                                (stepper, km.model, km.shared, Y, km.P), (0.1, 5, 3, OUT, 0, IS, FS))
        else:
            parallel.run_ranges(simple.advance_members, len(om), (stepper, km.model, km.shared, Y, km.P),
                                (0.1, 5, 3, OUT, 0, IS, FS))
        res.append((Y, OUT, IS, FS))
    for a, b in zip(*res):
        np.testing.assert_array_equal(a, b)
    Y, OUT, IS, FS = res[0]
    assert np.all(np.isnan(OUT[::4])) and np.all(IS[1::4, L.IS_STEPS] == 17 + 15)
    assert np.all(FS[2::5, 0] == 1e3)


def test_threads_do_not_change_numbers():
    phys, om, R = mixed(n_paper=3 * F.BLOCK, n_random=7, seed=11)
    for method in ("vi", "rk2"):
        assert_same(run("fast", method, phys, om, R, 0.1, 40, 10, threads=1),
                    run("fast", method, phys, om, R, 0.1, 40, 10, threads=2))


@pytest.mark.skipif(not hasattr(simple.advance_members, "signatures"), reason="plain Python: nothing is compiled")
def test_a_one_member_run_uses_the_kernels_compiled_for_many():
    """A run hands the kernels its whole output array and the first slot to fill, so
    their types do not depend on the member count: one member (whose output slice
    alone would be contiguous, another numba type) needs no kernel of its own."""
    phys, om, R = mixed(n_paper=3, n_random=0, seed=3)
    one = phys.take(slice(0, 1))
    for kernel, fn in (("simple", simple.advance_members), ("fast", F.advance_blocks)):
        many = run(kernel, "rk2", phys, om, R, 0.1, 6, 2)
        before = set(fn.signatures)
        alone = run(kernel, "rk2", one, om[:1], R[:1], 0.1, 6, 2)
        assert set(fn.signatures) == before, kernel
        assert_same(alone, many.take(slice(0, 1)))


def test_reference_runs_on_the_straightforward_kernel():
    phys, om, R = mixed(n_paper=20, n_random=4, seed=8)
    assert_same(run("fast", "reference", phys, om, R, 0.05, 4, 2),
                run("simple", "reference", phys, om, R, 0.05, 4, 2))
    with pytest.raises(ValueError, match="kernel"):
        run("vectorised", "vi", phys, om, R, 0.1, 10, 1)


def test_kernels_are_vectorized():
    """The hot loop of each sweep of the paper model is packed double-precision
    arithmetic with packed fused multiply-adds and no masked load or store."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        pytest.skip("packed-op check written for x86-64")
    counts = _bench().asm_report()
    for name in ("rk2 sweep", "rk4 sweep", "vi prepare", "vi newton"):
        c = counts[name]
        assert c and c["packed"] >= 40, (name, c)
        assert c["fma"] >= 20, (name, c)
        assert c["masked"] == 0, (name, c)


def test_import_compiles_nothing():
    code = ("import liethermo, liethermo.top.simulate, liethermo.top.kernels.fast as F, liethermo.top.kernels.simple as S;"
            "assert not F.advance_blocks.overloads and not S.advance_members.overloads")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_hot_loop_counts_reads_a_listing():
    """hot_loop_counts picks the loop with the most packed instructions and
    counts its arithmetic, memory operands, stack slots and stores."""
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
    hot_loop_counts = _bench().hot_loop_counts
    c = hot_loop_counts(asm)
    assert c["width"] == "ymm" and c["lanes"] == 4 and c["instructions"] == 9
    assert (c["packed"], c["fma"], c["mul"], c["addsub"], c["div"]) == (4, 1, 1, 1, 1)
    assert (c["mem"], c["stack"], c["stores"]) == (4, 2, 2)
    assert hot_loop_counts("retq\n") == {}


def test_row_map_has_no_overlap():
    """The block buffer's rows come from the part sizes: consecutive, disjoint,
    the parameters after all of them."""
    spans = sorted((start, start + size) for start, size in F.ROWS.values())
    for (a0, a1), (b0, b1) in zip(spans, spans[1:]):
        assert a1 == b0
    assert spans[0][0] == 0 and spans[-1][1] == F.NROWS_FIXED and F.O_P == F.NROWS_FIXED * F.ROW
    assert F.ROWS["Y"][1] >= max(L.state_layout(build_model(replace(
        paper_physics(), heat_capacity=np.array([1e-3]), thermal_expansion=np.array([1e-3])),
        attitude=True).model, "vi").size, 20)


def test_symmetric_update_and_explicit_differ_only_in_entropy():
    """(sanity of the entropy switch) the two entropy updates give the same
    mechanics for a constant inertia and different S."""
    phys, om, R = mixed(n_paper=8, n_random=0, seed=12)
    a = run("fast", "vi", phys, om, R, 0.1, 50, 10, entropy="explicit")
    b = run("fast", "vi", phys, om, R, 0.1, 50, 10, entropy="symmetric")
    np.testing.assert_array_equal(a.gamma, b.gamma)
    assert not np.array_equal(a.sigma, b.sigma)
    rel = np.abs(a.sigma[:, -1] - b.sigma[:, -1]) / np.abs(b.sigma[:, -1])
    assert rel.max() < 1e-6  # both approximate the same heat
    assert math.isfinite(rel.max()) and type(EXPLICIT) is not type(SYMMETRIC)


def test_auto_kernel_choice():
    """"auto" runs small runs (where compiling the vectorized loop would take
    longer than the run) on the one-member loop, large ones vectorized, the
    reference always one member at a time; an unknown kernel is refused."""
    from liethermo.top.simulate import SMALL_RUN_MEMBER_STEPS, kernel_for

    assert kernel_for("vi", 1, 300) == "simple"
    assert kernel_for("vi", 4096, 300) == "fast"
    assert kernel_for("rk2", SMALL_RUN_MEMBER_STEPS, 1) == "simple"
    assert kernel_for("rk2", SMALL_RUN_MEMBER_STEPS + 1, 1) == "fast"
    assert kernel_for("reference", 10**6, 10**3) == "simple"
    assert kernel_for("vi", 1, 300, "fast") == "fast"
    with pytest.raises(ValueError, match="unknown kernel 'gpu'"):
        kernel_for("vi", 1, 1, "gpu")
