"""Numerics shared by the study modules: running a method spec, relative
energy errors on node values and in the paper's convention, the discrete
Kelvin–Noether residual, order fits and the continuous right-hand side for
scipy.

Node values and step velocities: every method reports the state at the
instants t_k = k h (the *node values*: Ω(t_k), Γ_k, S_k, and E_k computed from
them).  The variational integrators also produce a *step velocity* Ω_k, the
constant angular velocity of the step from t_k to t_k + h, which approximates
Ω(t_k + h/2); the paper evaluates the energy with Ω_k beside Γ_k and S_k,
mixing two instants, which adds an O(h) error of the diagnostic itself
(``energy_error_paper``).
"""

from __future__ import annotations

import math

import numpy as np

from ..dataset import node_energies
from ..physics import Physics, inertia_scale, kinetic_energy, mechanical_energy_scale, potential_energy
from ..simulate import Trajectory, simulate
from .common import method_choice

#: the sentence every report uses to say what node values are
NODE_VALUES_NOTE = (
    "**Node values vs step velocities.** Every method gives the state at the instants t_k = k h — the "
    "*node values* Ω(t_k), Γ_k, S_k — and E_k is the energy of those values. The variational integrators "
    "also carry a *step velocity* Ω_k, the constant angular velocity of the step from t_k to t_k + h "
    "(≈ Ω(t_k + h/2)); the paper computes the energy from Ω_k with Γ_k and S_k, which mixes two instants "
    "and so adds an O(h) error of the diagnostic itself (\"paper convention\").")


def run_spec(phys: Physics, omega0, R0, h: float, steps: int, spec: dict, **kw) -> Trajectory:
    """:func:`simulate` with the method choice of a parsed spec."""
    return simulate(phys, omega0, R0, h, steps, method_choice(spec), **kw)


def repeat_timing(fn, min_time: float, measure=None, max_repeats: int = 1000) -> np.ndarray:
    """Wall times (s) of repeated calls of ``fn``: at least one, and until
    ``min_time`` s have been spent (at most ``max_repeats``).  ``measure(out)``
    takes the time from what ``fn`` returns (e.g. a Trajectory's kernel
    ``wall_time``) instead of the wall clock around the call.  Compile before:
    every call is timed."""
    import time

    walls = []
    spent = 0.0
    while not walls or (spent < min_time and len(walls) < max_repeats):
        t0 = time.perf_counter()
        out = fn()
        dt = time.perf_counter() - t0
        spent += dt
        walls.append(float(measure(out)) if measure is not None else dt)
    return np.asarray(walls)


def energy_errors(traj: Trajectory, omega0: np.ndarray, R0: np.ndarray) -> dict:
    """E_k − E₀ (J) on node values (``node``) and, for the variational
    integrators, in the paper's convention (``paper``: step velocity Ω_k with
    Γ_k, S_k; None otherwise), and the scale E_mech,0 = K₀ + V₀ + |g⃗| (J) —
    the definitions of ``energy_error`` / ``energy_error_paper`` of
    :func:`liethermo.dataset.trajectory_dataset`."""
    phys = traj.physics
    with np.errstate(over="ignore", invalid="ignore"):
        e = node_energies(traj)
        K0 = kinetic_energy(phys, omega0, None)
        V0 = potential_energy(phys, R0[:, 2, :])
        dV = e["V"] - V0[:, None]
        node = (e["K"] - K0[:, None]) + dV + e["dU"]
        paper = None
        if traj.family == "vi":
            s = traj.sigma if traj.thermo else None
            paper = (kinetic_energy(phys, traj.omega_step, s) - K0[:, None]) + dV + e["dU"]
    return {"node": node, "paper": paper, "scale": mechanical_energy_scale(phys, omega0, R0[:, 2, :])}


def kelvin_noether_residual(traj: Trajectory) -> np.ndarray:
    """Per member, max over steps of the residual of the discrete Kelvin–Noether
    law of the variational integrator in node form (needs ``every = 1``):

        J_{k+1} − J_k + h (w_L Γ_k + w_R Γ_{k+1})·F(X_k) = 0,   J_k = Γ_k·μ_k,

    F(X) the sum of the terms' discrete frictions at the step velocity X_k
    (C X for a linear friction, D(X) for a nonlinear one, placed alike:
    :func:`liethermo.physics.discrete_friction`; conservative torques are ⟂ Γ
    and drop out), relative to max_k |μ_k| (1).  For a composition the law
    holds per substep; the stored steps are whole steps, so with friction it
    is checked only for ``vi`` (NaN for the others); without friction it
    reads J_{k+1} = J_k for every variational method.  NaN also where an
    acting friction does not give its discrete form (its law is not checked)."""
    phys = traj.physics
    frictionless = not phys.dissipative
    if traj.family != "vi" or traj.every != 1 or (traj.method != "vi" and not frictionless):
        return np.full(traj.states.shape[0], np.nan)
    from ..kernels.vi import FRICTION_WEIGHTS

    wl, wr = FRICTION_WEIGHTS[traj.friction]
    G = traj.gamma
    mu = traj.momentum
    X = traj.omega_step
    try:
        F = phys.discrete_friction(traj.h, X[:, :-1])
    except NotImplementedError:
        return np.full(traj.states.shape[0], np.nan)
    J = np.sum(G * mu, axis=-1)
    res = J[:, 1:] - J[:, :-1] + traj.h * np.sum((wl * G[:, :-1] + wr * G[:, 1:]) * F, axis=-1)
    scale = np.nanmax(np.linalg.norm(mu, axis=-1), axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.nanmax(np.abs(res), axis=1) / scale


def continuous_kelvin_noether_residual(traj: Trajectory) -> np.ndarray:
    """Per member, max over the stored steps of the defect of the continuous
    law d(Γ·μ)/dt = Γ·f(Ω, Γ) (f the sum of the terms' torques, whose
    conservative part is ⟂ Γ) integrated by the trapezoid rule between stored
    nodes, relative to max |μ| (1): what any method can be held to (its own
    quadrature error included)."""
    phys = traj.physics
    om = traj.omega
    G = traj.gamma
    sigma = traj.sigma if traj.thermo else None
    if traj.family != "vi":
        s = inertia_scale(phys, sigma)
        s = s[..., None] if isinstance(s, np.ndarray) else s
        mu = s * (phys.inertia[:, None, :] * om)
    else:
        mu = traj.momentum
    J = np.sum(G * mu, axis=-1)
    with np.errstate(invalid="ignore", over="ignore"):
        f = np.sum(G * phys.torque(om, G, sigma), axis=-1)
    dt = traj.h * traj.every
    res = J[:, 1:] - J[:, :-1] - 0.5 * dt * (f[:, 1:] + f[:, :-1])
    scale = np.nanmax(np.linalg.norm(mu, axis=-1), axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.nanmax(np.abs(res), axis=1) / scale


def drift_fit(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of y (N, T): (least-squares slope of y against t, standard
    deviation of the residual about that line).  Rows with a non-finite value
    give NaN."""
    t = np.asarray(t, float)
    tc = t - t.mean()
    with np.errstate(invalid="ignore", over="ignore"):
        ym = y.mean(axis=1, keepdims=True)
        slope = (y - ym) @ tc / (tc @ tc)
        resid = y - ym - slope[:, None] * tc[None, :]
        spread = np.sqrt(np.mean(resid * resid, axis=1))
    bad = ~np.all(np.isfinite(y), axis=1)
    slope[bad] = np.nan
    spread[bad] = np.nan
    return slope, spread


def fit_order(hs, errors, scale: float, floor_rel: float):
    """(order, constant, levels used): least squares of log(err) on log(h) from
    the coarsest level until the round-off floor (error < ``floor_rel`` ×
    ``scale``) or a stall (the error no longer falls by 1.2×)."""
    hs = np.asarray(hs, float)
    errors = np.asarray(errors, float)
    used = 0
    for i, e in enumerate(errors):
        if not np.isfinite(e) or e < floor_rel * scale:
            break
        if i > 0 and e > errors[i - 1] / 1.2:
            break
        used = i + 1
    if used < 3:
        return float("nan"), float("nan"), used
    slope, icept = np.polyfit(np.log(hs[:used]), np.log(errors[:used]), 1)
    return float(slope), float(np.exp(icept)), used


# ----------------------------------------------------------------------------- continuous rhs (scipy)

def continuous_rhs(phys: Physics, member: int = 0):
    """f(t, y) of the continuous equations of one member, y = (Ω, Γ, σ) (7,),
    for scipy's ``solve_ivp``: the kernels' own equations of every term the
    member's model has (compiled once per model type)."""
    from ..kernels.equations import rhs7_function
    from ..physics import build_model

    km = build_model(phys.take(slice(member, member + 1)))
    fn = rhs7_function(km.model)
    p = np.ascontiguousarray(km.P[0])

    def f(t, y):
        out = np.empty(7)
        fn(p, y, out)
        return out

    return f


# ----------------------------------------------------------------------------- settling and attitude

def settling_time(t: np.ndarray, ratio: np.ndarray, fraction: float) -> np.ndarray:
    """Per row of ``ratio`` (N, T) (a positive quantity relative to its initial
    value, e.g. E_mech,k / E_mech,0): the first time it falls to ``fraction``
    or below (s), log-linearly interpolated between the two nodes around the
    crossing; 0 if it starts there, NaN if it never gets there (or a value
    before the crossing is not finite)."""
    t = np.asarray(t, float)
    r = np.asarray(ratio, float)
    out = np.full(r.shape[0], np.nan)
    lf = math.log(fraction)
    with np.errstate(invalid="ignore", divide="ignore"):
        below = r <= fraction
    for i in range(r.shape[0]):
        k = np.flatnonzero(below[i])
        if k.size == 0:
            continue
        k = int(k[0])
        if k == 0:
            out[i] = 0.0
            continue
        if not np.all(np.isfinite(r[i, :k + 1])):
            continue
        a = math.log(r[i, k - 1])
        b = math.log(r[i, k]) if r[i, k] > 0.0 else -math.inf
        w = 1.0 if not math.isfinite(b) else (lf - a) / (b - a)
        out[i] = t[k - 1] + w * (t[k] - t[k - 1])
    return out


def direction_angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle (rad) between the directions of vectors u and v (..., 3), accurate
    for small and large angles (atan2 of |u×v| and u·v); |u|, |v| need not be 1."""
    return np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.sum(u * v, axis=-1))


def rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle (rad) of the rotation Ra Rbᵀ between attitudes (..., 3, 3), from the
    Frobenius distance ‖Ra − Rb‖ = 2√2 sin(θ/2) (accurate for small angles)."""
    d = np.linalg.norm(np.asarray(Ra) - np.asarray(Rb), axis=(-2, -1))
    return 2.0 * np.arcsin(np.clip(d / (2.0 * math.sqrt(2.0)), 0.0, 1.0))


def quantile_band(a: np.ndarray, q=(0.05, 0.5, 0.95)) -> np.ndarray:
    """Quantiles ``q`` of the finite values of a (NaN if none)."""
    a = np.asarray(a, float).ravel()
    a = a[np.isfinite(a)]
    if a.size == 0:
        return np.full(len(q), np.nan)
    return np.quantile(a, q)


def observed_orders(hs, errors) -> np.ndarray:
    """log(e_i / e_{i+1}) / log(h_i / h_{i+1}) between consecutive levels (NaN
    where an error is not finite and positive); one fewer than the levels."""
    hs = np.asarray(hs, float)
    e = np.asarray(errors, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        p = np.log(e[:-1] / e[1:]) / np.log(hs[:-1] / hs[1:])
    p[~(np.isfinite(e[:-1]) & np.isfinite(e[1:]) & (e[:-1] > 0) & (e[1:] > 0))] = np.nan
    return p


# ----------------------------------------------------------------------------- compact tables

def band_text(med: float, lo: float, hi: float) -> str:
    """A table cell "median [5 %, 95 %]" (each number as :func:`~.common.fmt` gives it)."""
    from .common import fmt

    if not np.isfinite(med):
        return "—"
    return f"{fmt(float(med))} [{fmt(float(lo))}, {fmt(float(hi))}]"


def display_table(df, title: str, csv_name: str) -> str:
    """A markdown table of the (already formatted) ``df`` with a ``### title``
    heading and a link to ``csv_name.csv``, which holds the same rows in
    numbers (written separately by :func:`~.common.write_table`)."""
    from .common import markdown_table

    return markdown_table(df, title, f"(numbers, with the 5 % and 95 % quantiles in columns of their own: "
                                     f"`{csv_name}.csv`)")
