"""What a trajectory of the heavy top keeps: its energy error on node values
and in the paper's convention, the discrete and the continuous Kelvin–Noether
residuals, and the continuous right-hand side of one member for scipy.

Node values and step velocities: every method reports the state at the
instants t_k = k h (the *node values*: Ω(t_k), Γ_k, S_k, and E_k computed from
them).  The variational integrators also produce a *step velocity* Ω_k, the
constant angular velocity of the step from t_k to t_k + h, which approximates
Ω(t_k + h/2); the paper evaluates the energy with Ω_k beside Γ_k and S_k,
mixing two instants, which adds an O(h) error of the diagnostic itself
(``energy_error_paper``).
"""

from __future__ import annotations

import numpy as np

from .dataset import node_energies
from .physics import Physics, inertia_scale, kinetic_energy, mechanical_energy_scale, potential_energy
from .simulate import Trajectory


def energy_errors(traj: Trajectory, omega0: np.ndarray, R0: np.ndarray) -> dict:
    """E_k − E₀ (J) on node values (``node``) and, for the variational
    integrators, in the paper's convention (``paper``: step velocity Ω_k with
    Γ_k, S_k; None otherwise), and the scale E_mech,0 = K₀ + V₀ + |g⃗| (J) —
    the definitions of ``energy_error`` / ``energy_error_paper`` of
    :func:`liethermo.top.dataset.trajectory_dataset`."""
    phys = traj.physics
    with np.errstate(over="ignore", invalid="ignore"):
        e = node_energies(traj)
        K0 = kinetic_energy(phys, omega0, None)
        V0 = potential_energy(phys, R0[:, 2, :])
        dV = e["V"] - V0[:, None]
        node = (e["K"] - K0[:, None]) + dV + e["dU"]
        paper = None
        if traj.choice.method.node_form:
            s = traj.sigma if traj.thermo else None
            paper = (kinetic_energy(phys, traj.omega_step, s) - K0[:, None]) + dV + e["dU"]
    return {"node": node, "paper": paper, "scale": mechanical_energy_scale(phys, omega0, R0[:, 2, :])}


def kelvin_noether_residual(traj: Trajectory) -> np.ndarray:
    """Per member, max over steps of the residual of the discrete Kelvin–Noether
    law of the variational integrator in node form (needs ``every = 1``):

        J_{k+1} − J_k + h (w_L Γ_k + w_R Γ_{k+1})·F(X_k) = 0,   J_k = Γ_k·μ_k,

    F(X) the sum of the terms' discrete frictions at the step velocity X_k
    (C X for a linear friction, D(X) for a nonlinear one, placed alike:
    :func:`liethermo.top.physics.discrete_friction`; conservative torques are ⟂ Γ
    and drop out), relative to max_k |μ_k| (1).  For a composition the law
    holds per substep; the stored steps are whole steps, so with friction it
    is checked only for ``vi`` (NaN for the others); without friction it
    reads J_{k+1} = J_k for every variational method.  NaN also where an
    acting friction does not give its discrete form (its law is not checked)."""
    phys = traj.physics
    frictionless = not phys.dissipative
    if not traj.choice.method.node_form or traj.every != 1 or (traj.method != "vi" and not frictionless):
        return np.full(traj.states.shape[0], np.nan)
    from .kernels.vi import FRICTION_WEIGHTS

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
    if not traj.choice.method.node_form:
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


def continuous_rhs(phys: Physics, member: int = 0):
    """f(t, y) of the continuous equations of one member, y = (Ω, Γ, σ) (7,),
    for scipy's ``solve_ivp``: the kernels' own equations of every term the
    member's model has (compiled once per model type)."""
    from .kernels.equations import rhs7_function
    from .physics import build_model

    km = build_model(phys.take(slice(member, member + 1)))
    fn = rhs7_function(km.model)
    p = np.ascontiguousarray(km.P[0])

    def f(t, y):
        out = np.empty(7)
        fn(p, y, out)
        return out

    return f
