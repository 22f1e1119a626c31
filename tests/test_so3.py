"""The SO(3) lane functions the kernels use (liethermo.top.kernels.so3) against
their definitions, through small array wrappers compiled here."""

from __future__ import annotations

import math

import numpy as np
from liethermo.top.kernels import so3
from liethermo.top.kernels._jit import jit


@jit
def _cross(a, b, out):
    out[0], out[1], out[2] = so3.cross_lane(a[0], a[1], a[2], b[0], b[1], b[2])


@jit
def _cayley_apply(w, v, out):
    """out = cay(ŵ) v (the vector form the kernels use); out may alias v."""
    out[0], out[1], out[2] = so3.cayley_lane(w[0], w[1], w[2], v[0], v[1], v[2])


@jit
def _cayley_matrix(w, out):
    C = so3.cayley_matrix_lane(w[0], w[1], w[2])
    for i in range(3):
        for j in range(3):
            out[i, j] = C[3 * i + j]


@jit
def _attitude_update(R, w, out):
    """out = attitude_lane(R, w): the kernels' R_{k+1} = R_k cay(hΩ̂_k)."""
    Rt = (R[0, 0], R[0, 1], R[0, 2], R[1, 0], R[1, 1], R[1, 2], R[2, 0], R[2, 1], R[2, 2])
    A = so3.attitude_lane(Rt, w[0], w[1], w[2])
    for i in range(3):
        for j in range(3):
            out[i, j] = A[3 * i + j]


@jit
def _attitude_rate(R, w, out):
    Rt = (R[0, 0], R[0, 1], R[0, 2], R[1, 0], R[1, 1], R[1, 2], R[2, 0], R[2, 1], R[2, 2])
    A = so3.attitude_rate_lane(Rt, w[0], w[1], w[2])
    for i in range(3):
        for j in range(3):
            out[i, j] = A[3 * i + j]


def _cayley_inverse(Q):
    """w with cay(ŵ) = Q (trace Q > −1): w = 2 vee(Q − Qᵀ)/(1 + tr Q)."""
    d = 1.0 + np.trace(Q)
    return 2.0 * np.array([Q[2, 1] - Q[1, 2], Q[0, 2] - Q[2, 0], Q[1, 0] - Q[0, 1]]) / d

# |w| from tiny to large (a Cayley step turning by almost π)
W_SCALES = [1e-9, 1e-3, 0.1, 1.0, 3.0, 20.0]


def _hat_np(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _cay_np(w):
    """cay(ŵ) = (I − ŵ/2)⁻¹(I + ŵ/2), straight from the definition."""
    W = _hat_np(w)
    return np.linalg.solve(np.eye(3) - W / 2.0, np.eye(3) + W / 2.0)


def _rotvec_matrix(axis, angle):
    """Rodrigues: rotation by ``angle`` about unit ``axis`` (right-hand rule)."""
    K = _hat_np(axis)
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * K @ K


def _samples(seed=0, per_scale=20):
    rng = np.random.default_rng(seed)
    for s in W_SCALES:
        for _ in range(per_scale):
            u = rng.normal(size=3)
            yield s * u / np.linalg.norm(u), rng.normal(size=3)


def test_cross_and_attitude_rate():
    """cross_lane is w × v, and attitude_rate_lane is Ṙ = R Ω̂ (row r of R times Ω̂)."""
    rng = np.random.default_rng(1)
    c, Rd = np.empty(3), np.empty((3, 3))
    for _ in range(50):
        w, v = rng.normal(size=3), rng.normal(size=3)
        _cross(w, v, c)
        np.testing.assert_allclose(c, np.cross(w, v), rtol=0, atol=1e-15 * 10)
        R = _rotvec_matrix(v / np.linalg.norm(v), rng.uniform(-3, 3))
        _attitude_rate(R, w, Rd)
        np.testing.assert_allclose(Rd, R @ _hat_np(w), rtol=0, atol=1e-15 * 10)


def test_cayley_vector_form_matches_matrix_definition():
    """cay(ŵ)v = v + 4/(4+|w|²)(w×v + ½w×(w×v)) equals (I − ŵ/2)⁻¹(I + ŵ/2)v
    (numpy solve of the definition) to round-off, for |w| from 1e-9 to 20; the
    matrix form cayley_matrix equals the same matrix."""
    out = np.empty(3)
    C = np.empty((3, 3))
    worst_v = worst_m = 0.0
    for w, v in _samples():
        ref = _cay_np(w)
        _cayley_apply(w, v, out)
        worst_v = max(worst_v, np.abs(out - ref @ v).max() / np.abs(v).max())
        _cayley_matrix(w, C)
        worst_m = max(worst_m, np.abs(C - ref).max())
    assert worst_v <= 1e-14, worst_v
    assert worst_m <= 1e-14, worst_m


def test_cayley_apply_may_alias():
    """The docstring allows out is v: the result must not change."""
    w = np.array([0.3, -1.2, 2.0])
    v = np.array([1.0, 2.0, -0.5])
    expected = np.empty(3)
    _cayley_apply(w, v, expected)
    _cayley_apply(w, v, v)
    np.testing.assert_array_equal(v, expected)


def test_cayley_is_a_rotation():
    """cay(ŵ) is orthogonal with determinant +1: |QᵀQ − I| and |det Q − 1| at
    round-off for every |w|."""
    C = np.empty((3, 3))
    worst_o = worst_d = 0.0
    for w, _ in _samples(seed=2):
        _cayley_matrix(w, C)
        worst_o = max(worst_o, np.abs(C.T @ C - np.eye(3)).max())
        worst_d = max(worst_d, abs(np.linalg.det(C) - 1.0))
    assert worst_o <= 1e-14, worst_o
    assert worst_d <= 1e-14, worst_d


def test_cayley_rotation_angle_is_two_atan_half_norm():
    """cay(ŵ) is the rotation about w (right-hand rule) by 2·atan(|w|/2), not |w|:
    it equals the Rodrigues matrix with that angle, and differs from the one with
    angle |w| (phase error |w|³/12 for small |w|)."""
    C = np.empty((3, 3))
    for w, _ in _samples(seed=3):
        n = np.linalg.norm(w)
        _cayley_matrix(w, C)
        np.testing.assert_allclose(C, _rotvec_matrix(w / n, 2.0 * math.atan(n / 2.0)),
                                   rtol=0, atol=1e-14)
        # angle recovered from the matrix itself
        ang = math.atan2(np.linalg.norm([C[2, 1] - C[1, 2], C[0, 2] - C[2, 0], C[1, 0] - C[0, 1]]) / 2,
                         (np.trace(C) - 1.0) / 2.0)
        assert abs(ang - 2.0 * math.atan(n / 2.0)) <= 1e-14 * max(1.0, ang)
    # the angle is genuinely not |w|
    w = np.array([0.0, 0.0, 1.0])
    _cayley_matrix(w, C)
    diff = np.abs(C - _rotvec_matrix(w, 1.0)).max()
    assert diff > 0.05  # angles 1 vs 2·atan(1/2) = 0.927: the matrices differ by ≈ 0.07


def test_cayley_inverse_inverts():
    """cayley_inverse(cay(ŵ)) = w (relative round-off, |w| up to 20), and
    cay(cayley_inverse(Q)) = Q for rotations Q with trace > −1."""
    C = np.empty((3, 3))
    worst = 0.0
    for w, _ in _samples(seed=4):
        _cayley_matrix(w, C)
        w_back = _cayley_inverse(C)
        worst = max(worst, np.abs(w_back - w).max() / np.abs(w).max())
    # round-off amplified by (4+|w|²)/16 near the angle π; |w| = 20 → ×25
    assert worst <= 1e-13, worst
    rng = np.random.default_rng(5)
    for _ in range(50):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        Q = _rotvec_matrix(axis, rng.uniform(-3.0, 3.0))
        w_back = _cayley_inverse(Q)
        _cayley_matrix(w_back, C)
        np.testing.assert_allclose(C, Q, rtol=0, atol=1e-13)


def test_attitude_update_is_right_multiplication():
    """attitude_update(R, w) = R·cay(ŵ) (body-frame update R_{k+1} = R_k cay(hΩ̂_k))."""
    rng = np.random.default_rng(6)
    out = np.empty((3, 3))
    for _ in range(20):
        R = _rotvec_matrix(np.array([0.6, 0.0, 0.8]), rng.uniform(-3, 3))
        w = rng.normal(size=3)
        _attitude_update(R, w, out)
        np.testing.assert_allclose(out, R @ _cay_np(w), rtol=0, atol=2e-15 * 10)
        assert np.abs(out - _cay_np(w) @ R).max() > 1e-3  # left multiplication differs


def test_cayley_of_zero_is_identity():
    """cay(0) = I exactly (and the inverse formula gives 0 exactly)."""
    C = np.empty((3, 3))
    _cayley_matrix(np.zeros(3), C)
    np.testing.assert_array_equal(C, np.eye(3))
    np.testing.assert_array_equal(_cayley_inverse(np.eye(3)), np.zeros(3))
