"""The kernels' own exp and expm1 (liethermo.top.kernels.lanemath): accurate to the
last bit or so over the whole range, equal to the C library at the edges,
the same bits in their small-argument forms and in plain Python, and
vectorized by LLVM."""

from __future__ import annotations

import math
import os
import platform
import subprocess
import sys

import numpy as np
import pytest
from numba import njit

from liethermo.top.kernels._jit import ld, st
from liethermo.top.kernels.lanemath import SMALL, SMALL_M1, exp_lane, exp_small, expm1_lane, expm1_small


@njit
def _exp(x, out):
    for i in range(x.size):
        out[i] = exp_lane(x[i])


@njit
def _expm1(x, out):
    for i in range(x.size):
        out[i] = expm1_lane(x[i])


@njit
def _small(x, out, ok):
    for i in range(x.size):
        out[i, 0], ok[i, 0] = exp_small(x[i])
        out[i, 1], ok[i, 1] = expm1_small(x[i])


def _apply(f, x):
    out = np.empty_like(x)
    f(x, out)
    return out


def _ulp_distance(a, b):
    """Distance in units in the last place between float64 arrays (0 for
    equal values, ±0 included; through the ordered integer image of the bits)."""
    ia = a.view(np.int64).astype(object)
    ib = b.view(np.int64).astype(object)
    key = lambda i: i if i >= 0 else -(i & 0x7FFF_FFFF_FFFF_FFFF)  # noqa: E731
    return np.array([abs(key(p) - key(q)) for p, q in zip(ia, ib)], dtype=float)


def _libm(f, x):
    out = []
    for v in x:
        try:
            out.append(f(v))
        except OverflowError:
            out.append(math.inf)
    return np.array(out)


def _samples():
    rng = np.random.default_rng(20240611)
    n = 40_000
    return {
        "kernels' range |x| ≤ 0.2": rng.uniform(-0.2, 0.2, n),
        "reduced range |x| ≤ ln2/2": rng.uniform(-0.35, 0.35, n),
        "k = ±1, ±2": np.concatenate([rng.uniform(0.3, 1.5, n // 2), rng.uniform(-1.5, -0.3, n // 2)]),
        "moderate |x| ≤ 40": rng.uniform(-40.0, 40.0, n),
        "large": rng.uniform(-708.0, 709.7, n),
        "tiny, log-uniform": 10.0 ** rng.uniform(-320.0, -1.0, n) * rng.choice([-1.0, 1.0], n),
        "subnormal results": rng.uniform(-745.1, -708.4, n),
    }


EDGES = np.array([
    0.0, -0.0, 5e-324, -5e-324, 2.2250738585072014e-308, -2.2250738585072014e-308, 1e-300,
    2.0**-54, -2.0**-54, 2.0**-53, 1e-17, -1e-17, SMALL, -SMALL, 0.34657359027997264,
    -0.34657359027997264, 0.5, -0.5, 1.0, -1.0, 36.04365338911715, 37.42994775023705,
    -36.04365338911715, -37.42994775023705, -40.0, -50.0, 693.0, 708.0, 709.0,
    709.782712893384, 709.7827128933841, 709.79, 710.0, 711.0, 1e300, math.inf,
    -708.3964185322641, -708.4, -744.44, -745.1332191019411, -745.1332191019412, -745.2,
    -746.0, -800.0, -1e300, -math.inf,
])


@pytest.mark.parametrize("name,f,libf", [("exp", _exp, math.exp), ("expm1", _expm1, math.expm1)])
def test_at_most_one_ulp_from_the_c_library(name, f, libf):
    """Over every range (the kernels' small arguments, tiny, negative, large,
    subnormal results) the result is within 1 ulp of math.exp / math.expm1,
    and equal to it for most arguments."""
    for label, x in _samples().items():
        d = _ulp_distance(_apply(f, x), _libm(libf, x))
        assert d.max() <= 1.0, (name, label, x[np.argmax(d)])
        assert np.mean(d == 0.0) > 0.85, (name, label)


@pytest.mark.skipif(np.finfo(np.longdouble).nmant < 63, reason="needs x87 extended long double")
@pytest.mark.parametrize("name,f", [("exp", _exp), ("expm1", _expm1)])
def test_error_against_an_extended_precision_reference(name, f):
    """Against numpy's 64-bit-mantissa exp/expm1 the error is at most 0.57 ulp
    for normal results (one rounding plus a little), 0.76 ulp for subnormal
    ones (rounded twice), and exactly 0 near 0 for expm1 (x itself)."""
    for label, x in _samples().items():
        y = _apply(f, x)
        ref = (np.expm1 if name == "expm1" else np.exp)(x.astype(np.longdouble))
        ulp = np.spacing(np.abs(y)).astype(np.longdouble)
        err = (np.abs(y.astype(np.longdouble) - ref) / ulp).astype(float)
        bound = 0.76 if (name == "exp" and label == "subnormal results") else 0.57
        assert err.max() <= bound, (name, label, err.max(), x[np.argmax(err)])
    x = 10.0 ** np.linspace(-300, -17, 500)
    assert np.array_equal(_apply(_expm1, x), x) and np.array_equal(_apply(_expm1, -x), -x)


@pytest.mark.parametrize("name,f,libf", [("exp", _exp, math.exp), ("expm1", _expm1, math.expm1)])
def test_edge_cases_are_those_of_the_c_library(name, f, libf):
    """±0 (sign kept by expm1), subnormal arguments, ±inf, NaN, the overflow
    threshold (≈709.78: inf beyond) and underflow to 0 below ≈ −745.13:
    the C library's values, bit for bit except at most 1 ulp where finite."""
    y = _apply(f, EDGES)
    ref = _libm(libf, EDGES)
    for x, a, b in zip(EDGES, y, ref):
        if math.isfinite(b) and b != 0.0:
            assert _ulp_distance(np.array([a]), np.array([b]))[0] <= 1.0, (name, x, a, b)
        else:
            assert a == b and math.copysign(1.0, a) == math.copysign(1.0, b), (name, x, a, b)
    nan = _apply(f, np.array([math.nan, -math.nan]))
    assert np.isnan(nan).all()


def test_small_forms_give_the_same_bits_and_flag_their_range():
    """exp_small / expm1_small equal exp_lane / expm1_lane bit for bit where
    they say they are valid (|x| ≤ SMALL, resp. SMALL_M1), and say so
    exactly there."""
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.uniform(-SMALL, SMALL, 100_000), rng.uniform(-SMALL_M1, SMALL_M1, 100_000),
                        10.0 ** rng.uniform(-320, math.log10(SMALL), 20_000) * rng.choice([-1.0, 1.0], 20_000),
                        [0.0, -0.0, SMALL, -SMALL, np.nextafter(SMALL, 1.0), SMALL_M1, -SMALL_M1,
                         np.nextafter(SMALL_M1, 1.0), 0.5, -3.0, 800.0, math.inf, -math.inf, math.nan]])
    out = np.empty((x.size, 2))
    ok = np.empty((x.size, 2), dtype=np.bool_)
    _small(x, out, ok)
    for j, (f, bound) in enumerate(((_exp, SMALL), (_expm1, SMALL_M1))):
        inside = np.abs(x) <= bound
        assert np.array_equal(ok[:, j], inside)
        full = _apply(f, x[inside])
        assert np.array_equal(out[inside, j].view(np.int64), full.view(np.int64))


_PLAIN = r"""
import sys
import numpy as np
from liethermo.top.kernels.lanemath import exp_lane, expm1_lane, exp_small, expm1_small
x = np.load(sys.argv[1])
out = np.array([[exp_lane(v), expm1_lane(v), exp_small(v)[0], expm1_small(v)[0]] for v in x])
np.save(sys.argv[2], out)
"""


def test_plain_python_gives_the_jitted_bits(tmp_path):
    """With NUMBA_DISABLE_JIT=1 (bit casts through struct, fma in rational
    arithmetic) the functions give the jitted bits."""
    rng = np.random.default_rng(11)
    x = np.concatenate([EDGES, rng.uniform(-5, 5, 300), rng.uniform(-745, 709, 100),
                        rng.uniform(-SMALL, SMALL, 100), rng.uniform(-SMALL_M1, SMALL_M1, 100)])
    np.save(tmp_path / "x.npy", x)
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    subprocess.run([sys.executable, "-c", _PLAIN, str(tmp_path / "x.npy"), str(tmp_path / "y.npy")],
                   env=env, check=True, timeout=300)
    plain = np.load(tmp_path / "y.npy")
    out = np.empty((x.size, 2))
    ok = np.empty((x.size, 2), dtype=np.bool_)
    _small(x, out, ok)
    jitted = np.column_stack([_apply(_exp, x), _apply(_expm1, x), out])
    assert np.array_equal(plain.view(np.int64), jitted.view(np.int64))


def test_a_loop_of_them_is_vectorized():
    """A lane loop over exp_lane / expm1_lane compiles to packed arithmetic
    (no call into the C library, no masked memory access)."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        pytest.skip("packed-op check written for x86-64")
    from test_fast_kernels import _bench

    hot_loop_counts = _bench().hot_loop_counts

    def loop(f):
        @njit(fastmath=False, error_model="numpy")
        def g(x, y, n):
            for i in range(n):
                st(y, i, f(ld(x, i)))

        x = np.ones(64)
        g(x, np.empty(64), 64)
        return g.inspect_asm(g.signatures[0])

    for f in (exp_lane, expm1_lane):
        asm = loop(f)
        c = hot_loop_counts(asm)
        assert c and c["packed"] >= 25 and c["fma"] >= 12 and c["masked"] == 0, c
        assert "exp" not in " ".join(line for line in asm.splitlines() if "call" in line)
