"""The fluid's steps over an array namespace (zeitlin/xpstep.py), run with
numpy against the numba kernels: round-off agreement, the same fixed-point
iterations, the same status of every member."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from liethermo.scene import load_scene
from liethermo.zeitlin import kernels as zk
from liethermo.zeitlin import run as zr
from liethermo.zeitlin import xpstep as xs


def _rel(a, c):
    """max|a − c| / max|c| (max|a − c| where c is 0: N = 2 has no heat)."""
    scale = np.abs(c).max()
    return np.abs(a - c).max() / (scale if scale > 0 else 1.0)


def _fields(N, M, seed):
    return xs._members(N, M, seed)


@pytest.mark.parametrize("N", [2, 5, 12])
def test_operators_agree_with_the_kernels(N):
    b, xb = zk.basis(N), xs.xp_basis(np, N)
    W = _fields(N, 3, N)
    assert _rel(xs.laplacian_inverse(W, xb, 0.7), zk.laplacian_inverse(W, b, 0.7)) < 1e-14
    assert _rel(xs.laplacian(W, xb), zk.laplacian(W, b)) < 1e-15
    W1, q1 = zk.viscous_flow(W, 0.3, 0.02, b)
    for batched in (True, False):  # padded blocks in one product, or one product per diagonal
        W2, q2 = xs.viscous_flow(W, 0.3, 0.02, xs.XpBasis(np, N, batched=batched))
        assert _rel(W2, W1) < 1e-14 and _rel(q2, q1) < 1e-14
    r1, r2 = zk.isomp(W, 0.05, b, 1e-15, 100), xs.isomp(W, 0.05, xb, 1e-15, 100)
    assert _rel(r2[0], r1[0]) < 1e-14 and _rel(r2[3], r1[3]) < 1e-14
    assert np.array_equal(r2[1], r1[1]) and np.array_equal(r2[2], r1[2])
    (d1, s1), (d2, s2) = zk.rhs(W, 0.02, b), xs.rhs(W, 0.02, xb)
    assert _rel(d2, d1) < 1e-14 and _rel(s2, s1) < 1e-14


def test_a_nan_anywhere_in_the_fixed_point_change_is_the_change():
    """A NaN in any part of any entry makes the member's change NaN (so it
    never counts as converged), on both backends; an infinity is the change."""
    rng = np.random.default_rng(1)
    M, N = 5, 4
    D = rng.normal(size=(M, N, N)) + 1j * rng.normal(size=(M, N, N))
    Dn = D + 1e-3 * (rng.normal(size=(M, N, N)) + 1j * rng.normal(size=(M, N, N)))
    Dn[1, 1, 2] = complex(np.nan, 0.0)   # in the middle
    Dn[2, N - 1, N - 1] = complex(np.nan, 1.0)  # last
    Dn[3, 0, 1] = complex(0.0, np.nan)   # imaginary part only: max(a, nan) = a
    Dn[4, 2, 2] = complex(np.inf, 0.0)
    # the kernel forms D_new = X − X† + XA: X = Dn/2 on a skew-Hermitian part is awkward, so feed
    # X = 0 and XA = Dn, which gives D_new = Dn exactly
    X = np.zeros_like(Dn)
    change = np.empty(M)
    Dk, Wt = D.copy(), np.empty_like(D)
    zk._fixed_point_update(np.zeros_like(D), X, Dn, Dk, Wt, change)
    ours = xs._change(np, Dn, D)
    assert np.isnan(change).tolist() == [0, 1, 1, 1, 0] and change[4] == np.inf
    assert np.array_equal(np.isnan(ours), np.isnan(change))
    assert np.array_equal(ours[~np.isnan(ours)], change[~np.isnan(change)])


def _scene(method, nu, **more):
    over = {"zeitlin.N": 8, "initial.lmax": 4, "ensemble.members": 3, "integrator.steps": 50,
            "output.every": 10, "integrator.method": method, "fluid.kinematic_viscosity": nu, **more}
    return load_scene("zeitlin_decay", over)


def _both(sc, W0):
    cpu = zr.integrate(sc, W0, progress=False, keep_vorticity=True)
    xp = xs.integrate_xp(np, sc, W0, progress=False, keep_vorticity=True)
    return cpu, xp


@pytest.mark.parametrize("nu", [1e-3, 0.0])
@pytest.mark.parametrize("method", xs.METHODS)
def test_fifty_steps_agree_with_the_kernels_to_round_off(method, nu):
    sc = _scene(method, nu)
    cpu, xp = _both(sc, zr.initial_fields(sc))
    assert (cpu.status == 0).all() and np.array_equal(xp.status, cpu.status)
    assert np.array_equal(xp.failed_step, cpu.failed_step)
    assert _rel(xp.W, cpu.W) < 1e-12
    assert np.array_equal(xp.iterations, cpu.iterations)  # the same fixed-point iterations, step by step
    if nu > 0:
        assert (cpu.q[:, -1] > 0).all() and _rel(xp.q, cpu.q) < 1e-12
    else:
        assert (xp.q == 0).all() and (cpu.q == 0).all()
    for name in ("H", "cas", "L", "Z"):
        assert _rel(getattr(xp.out, name), getattr(cpu.out, name)) < 1e-12


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("method, status, step", [("rk4", 2, 3), ("split", 1, 1), ("split4", 1, 1)])
def test_a_member_that_blows_up_is_retired_as_on_the_cpu(method, status, step):
    sc = _scene(method, 1e-3)
    W0 = zr.initial_fields(sc)
    W0[1] *= 1000.0  # rk4 overflows; the fixed point of the midpoint diverges
    cpu, xp = _both(sc, W0)
    assert cpu.status.tolist() == [0, status, 0] and cpu.failed_step.tolist() == [-1, step, -1]
    assert np.array_equal(xp.status, cpu.status) and np.array_equal(xp.failed_step, cpu.failed_step)
    assert np.isnan(xp.W[1, 1:]).all() and np.isnan(xp.q[1, 1:]).all()
    keep = [0, 2]
    assert _rel(xp.W[keep], cpu.W[keep]) < 1e-12 and np.array_equal(xp.iterations, cpu.iterations)


def test_a_fixed_point_out_of_iterations_is_flagged_as_on_the_cpu():
    sc = _scene("split", 0.0, **{"integrator.max_iter": 2})
    cpu, xp = _both(sc, zr.initial_fields(sc))
    assert (cpu.status == 1).all() and (cpu.failed_step == 1).all()
    assert np.array_equal(xp.status, cpu.status) and np.array_equal(xp.failed_step, cpu.failed_step)


def test_a_dataset_through_the_xp_backend_matches_the_cpu():
    sc = _scene("split4", 1e-3)
    a = zr.simulate(sc, progress=False)
    m = sc["integrator"]["method"]
    c = zr.trajectory_dataset(sc, xs.integrate_xp(np, sc, zr.initial_fields(sc), progress=False), m)
    for v in ("energy", "heat", "entropy", "casimir", "angular_momentum", "energy_spectrum"):
        assert np.allclose(c[v].values, a[v].values, rtol=1e-12, atol=1e-14 * np.abs(a[v].values).max()), v
    assert (c["status"].values == a["status"].values).all()
    assert (c["fixed_point_iterations"].values == a["fixed_point_iterations"].values).all()


def test_backends_refuse_what_they_cannot_run(monkeypatch):
    sc = _scene("reference", 1e-3)
    with pytest.raises(ValueError, match="'reference' does not run on the array-namespace"):
        xs.integrate_xp(np, sc, zr.initial_fields(sc), progress=False)
    with pytest.raises(ValueError, match="'tpu'"):
        xs.namespace("tpu")
    monkeypatch.setitem(sys.modules, "cupy", None)  # as where CuPy is not installed
    with pytest.raises(RuntimeError, match="backend 'gpu' needs CuPy"):
        xs.namespace("gpu")


def test_timing_returns_seconds_per_member_step():
    t = xs.time_fluid_xp(np, 6, 2, 2, "split")
    assert 0 < t < 10


@pytest.mark.parametrize("timer", ["xp", "cpu"])
def test_timing_refuses_steps_whose_fixed_point_did_not_converge(timer):
    """One iteration cannot reach the tolerance: there is no step to time, and the
    timing says so instead of returning the time of iterations that reach nothing."""
    time_it = (lambda **k: xs.time_fluid_xp(np, 8, 2, 1, "split", **k)) if timer == "xp" else \
        (lambda **k: xs.time_fluid_cpu(8, 2, 1, "split", **k))
    with pytest.raises(ArithmeticError, match=r"split at N = 8, h = 0.01 s: the fixed point of 2 of 2 member\(s\) "
                                              r"did not converge within 1 iterations"):
        time_it(max_iter=1, warmup=0)
    assert 0 < time_it(warmup=0) < 10  # converged: timed


def test_a_thomas_kernel_that_fails_falls_back_to_the_vector_sweeps():
    """Where the namespace offers RawKernel (CuPy) but the kernel does not
    compile or disagrees, the sweeps run as vector operations, and say why."""
    import types

    def broken(*a, **k):
        raise OSError("no compiler")

    ns = types.SimpleNamespace(**{k: getattr(np, k) for k in dir(np) if not k.startswith("__")}, RawKernel=broken)
    xb = xs.XpBasis(ns, 6)
    assert xb.thomas_backend == "xp (OSError: no compiler)"
    W = _fields(6, 2, 0)
    assert _rel(xs.laplacian_inverse(W, xb), zk.laplacian_inverse(W, zk.basis(6))) < 1e-14
    assert xs.xp_basis(np, 6).thomas_backend == "xp"


@pytest.mark.parametrize("method", xs.METHODS)
def test_the_memory_estimate_bounds_what_numpy_allocates(method):
    import tracemalloc

    N, M = 24, 8
    fac = zr.factors(method, "small_error") if method != "rk4" else ()
    tracemalloc.start()
    try:
        xb = xs.XpBasis(np, N)
        W = np.array(_fields(N, M, 2))
        q, act, D = np.zeros(M), np.arange(M), None
        pred = xs.Predictor(np, len(fac), M, N) if fac else None
        guess = np.zeros_like(W)  # the run's own arrays besides W: the guess and the active members' copies
        for _ in range(6):
            Wa = W[act]
            if fac:
                Wa, q, _, _, D = xs.split_step(Wa, q, 0.01, 1e-3, xb, fac, 1e-15, 100, D, pred, act)
                guess[act] = D
            else:
                Wa, q = xs.rk4_step(Wa, q, 0.01, 1e-3, xb)
            W[act] = Wa
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    est = xs.memory_bytes(N, M, method)
    assert peak <= est <= 1.6 * peak, (peak, est)


def test_the_thomas_kernel_source_does_what_the_vector_sweeps_do(tmp_path):
    """The CUDA source of the Thomas sweeps, compiled here as C++ with one
    loop over the threads, gives the vector sweeps' bits."""
    import ctypes
    import shutil
    import subprocess

    cxx = shutil.which("g++") or shutil.which("c++")
    if cxx is None:
        pytest.skip("no C++ compiler to run the CUDA source on the host")
    (tmp_path / "k.cu").write_text(xs._THOMAS_CUDA)
    (tmp_path / "h.cpp").write_text(
        "struct D3 { long x; };\nstatic D3 blockIdx, blockDim, threadIdx;\n#define __global__\n#include \"k.cu\"\n"
        "extern \"C\" void run(const double* r, const double* a, const double* b, const double* c, double s,\n"
        "                      double* y, int N, int rows) {\n"
        "  long cols = (long)rows * N; blockDim.x = 32;\n"
        "  for (long i = 0; i < (cols + 31) / 32; i++) for (long t = 0; t < 32; t++) {\n"
        "    blockIdx.x = i; threadIdx.x = t; thomas_sweeps(r, a, b, c, s, y, N, rows); } }\n")
    lib = tmp_path / "k.so"
    subprocess.run([cxx, "-O1", "-ffp-contract=off", "-shared", "-fPIC", "-o", str(lib), str(tmp_path / "h.cpp")],
                   check=True, capture_output=True)
    run = ctypes.CDLL(str(lib)).run
    ptr = ctypes.POINTER(ctypes.c_double)
    for N in (2, 7, 20):
        xb = xs.XpBasis(np, N)
        r = np.random.default_rng(N).standard_normal((N, 6, N))
        r[(N - 2) // 2, 2, 1] = np.inf  # a non-finite entry stays in its own column, as in the kernels
        y = np.empty_like(r)
        run(*(a.ctypes.data_as(ptr) for a in (r, xb.tinv, xb.offp, xb.tc)), ctypes.c_double(-0.3),
            y.ctypes.data_as(ptr), N, 6)
        with np.errstate(invalid="ignore"):
            want = xb.thomas_xp(r, -0.3)
        assert np.array_equal(y, want, equal_nan=True)
