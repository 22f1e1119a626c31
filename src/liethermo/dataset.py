"""Label a :class:`~liethermo.simulate.Trajectory` as a CF-style xarray Dataset.

Names, dims and units follow SPEC §7.  Energies are computed without
cancellation: E_k − E₀ = (K_k − K₀) + (V_k − V₀) + c_v T₀ expm1(σ_k/c_v),
where E₀ is the energy of the scene's initial data at t = 0 (for the
staggered start the stored Ω₀ approximates Ω(h/2), so E₀ is computed from
the initial data, not from the stored first state).
"""

from __future__ import annotations

import platform

import numpy as np
import xarray as xr

from . import __version__, cf
from .kernels.model import P_C, P_CV, P_GX, P_GY, P_GZ, P_I1, P_I2, P_I3, P_T0
from .methods import METHODS
from .simulate import STATUS_MEANINGS, Trajectory

AXIS = ["x", "y", "z"]


def _var(data, dims, units, long_name, **extra):
    return xr.Variable(dims, data, attrs={"units": units, "long_name": long_name, **extra})


def energies(omega, gamma, sigma, params):
    """K, V, U−U₀ in J for arrays (..., 3), (..., 3), (...) and params (..., 9)."""
    I = params[..., [P_I1, P_I2, P_I3]]
    g = params[..., [P_GX, P_GY, P_GZ]]
    K = 0.5 * np.sum(I * omega * omega, axis=-1)
    V = np.sum(g * gamma, axis=-1)
    dU = params[..., P_CV] * params[..., P_T0] * np.expm1(sigma / params[..., P_CV])
    return K, V, dU


def trajectory_dataset(traj: Trajectory, *, S0: float, omega0: np.ndarray, R0: np.ndarray,
                       center_of_mass: np.ndarray | None = None, member_offset: int = 0) -> xr.Dataset:
    """The dataset of one member chunk (no global attributes; see :func:`global_attrs`).

    omega0, R0: the members' initial data at t = 0 (N, 3), (N, 3, 3);
    center_of_mass: G in the body frame (N, 3) in m, to store ℓRχ = R G.
    """
    # a member that blew up (explicit RK2) has huge-but-finite values before its NaNs:
    # the energies of those values overflow to inf, which is the truthful answer
    with np.errstate(over="ignore", invalid="ignore"):
        return _trajectory_dataset(traj, S0, omega0, R0, center_of_mass, member_offset)


def _trajectory_dataset(traj, S0, omega0, R0, center_of_mass, member_offset):
    N, n_t, _ = traj.states.shape
    p = traj.params[:, None, :]
    om, ga, sg = traj.omega, traj.gamma, traj.sigma
    K, V, dU = energies(om, ga, sg, p)
    K0, V0, _ = energies(omega0, R0[:, 2, :], np.zeros(N), traj.params)
    cv = traj.params[:, P_CV][:, None]
    T0 = traj.params[:, P_T0][:, None]
    T = T0 * np.exp(sg / cv)
    U = cv * T
    dE = (K - K0[:, None]) + (V - V0[:, None]) + dU
    # mechanical energy measured from the resting state (V_min = -|g|): the
    # energy the friction can turn into heat; the natural scale of E_k - E_0
    emech0 = K0 + V0 + np.linalg.norm(traj.params[:, [P_GX, P_GY, P_GZ]], axis=1)
    dims_t = ("member", "time")
    dims_v = ("member", "time", "axis")
    omega_note = ("step velocity Omega_k = cay^-1(R_k^T R_k+1)/h; approximates Omega(t_k + h/2)"
                  if traj.method == "vi" else "node value Omega(t_k)")
    data = {
        "omega": _var(om, dims_v, "rad s-1", "body angular velocity", comment=omega_note),
        "gamma": _var(ga, dims_v, "1", "direction of gravity in the body frame (R^T e3)"),
        "entropy": _var(S0 + sg, dims_t, "J K-1", "entropy S of body and fluid"),
        "temperature": _var(T, dims_t, "K", "temperature T(S) = T0 exp((S - S0)/c_v)",
                            units_metadata="temperature: on_scale"),
        "kinetic_energy": _var(K, dims_t, "J", "kinetic energy 1/2 Omega . I Omega"),
        "potential_energy": _var(V, dims_t, "J", "potential energy m g l Gamma . chi"),
        "internal_energy": _var(U, dims_t, "J", "internal energy U(S) = c_v T(S)"),
        "total_energy": _var(K + V + U, dims_t, "J", "total energy E = K + V + U"),
        "energy_error": _var(dE, dims_t, "J", "total energy error E_k - E_0 (computed without cancellation)",
                             comment="E_0 is the energy of the initial data at t = 0"),
        "mechanical_energy_initial": _var(emech0, ("member",), "J",
                                          "initial mechanical energy above the resting state K_0 + V_0 + m g l"),
        "status": _var(traj.status.astype(np.int8), ("member",), "1", "member status",
                       flag_values=np.array(sorted(STATUS_MEANINGS), dtype=np.int8),
                       flag_meanings=" ".join(STATUS_MEANINGS[k] for k in sorted(STATUS_MEANINGS))),
        "failed_at_step": _var(np.where(traj.status != 0, traj.fail_step, -1).astype(np.int64), ("member",), "1",
                               "step k+1 whose computation failed (-1: none); values from that step on are NaN"),
        "steps_done": _var(traj.steps_done.astype(np.int64), ("member",), "1", "steps accepted"),
        "max_h_omega": _var(traj.max_h_omega, ("member",), "rad", "max over steps of h |Omega_k|",
                            comment="the Cayley map turns by 2 atan(h|Omega|/2): phase error ~ (h|Omega|)^3/12 per step"),
        "initial_omega": _var(omega0, ("member", "axis"), "rad s-1", "initial body angular velocity Omega(0)"),
        "initial_attitude": _var(R0, ("member", "row", "col"), "1", "initial attitude R(0)"),
        "inertia": _var(traj.params[:, [P_I1, P_I2, P_I3]], ("member", "axis"), "kg m2", "principal moments of inertia"),
        "stokes_coefficient": _var(traj.params[:, P_C], ("member",), "N m s", "Stokes torque coefficient c = 8 pi mu a^3"),
        "gravity_torque": _var(traj.params[:, [P_GX, P_GY, P_GZ]], ("member", "axis"), "N m", "m g l chi"),
    }
    if METHODS[traj.method].implicit:
        steps = np.maximum(traj.steps_done, 1)
        data["newton_iterations_mean"] = _var(traj.newton_iterations / steps, ("member",), "1",
                                              "mean Newton iterations per step")
        data["newton_iterations_max"] = _var(traj.newton_max.astype(np.int64), ("member",), "1",
                                             "max Newton iterations in one step")
    R = traj.attitude
    if R is not None:
        data["attitude"] = _var(R, ("member", "time", "row", "col"), "1", "attitude R (body to space)")
        if center_of_mass is not None:
            data["center_of_mass"] = _var(np.einsum("mtij,mj->mti", R, center_of_mass), dims_v, "m",
                                          "centre of mass l R chi in space, relative to the fixed centre")
    coords = {
        "member": _var(np.arange(member_offset, member_offset + N, dtype=np.int64), ("member",), "1",
                       "ensemble member"),
        "time": _var(traj.times, ("time",), "s", "time t_k = k h", standard_name="time", axis="T"),
        "step": _var(traj.step_index.astype(np.int64), ("time",), "1", "step index k"),
        "axis": xr.Variable(("axis",), np.array(AXIS), attrs={"units": "1", "long_name": "body-frame axis"}),
    }
    return xr.Dataset(data, coords=coords)


def global_attrs(scene_toml: str, *, method: str, h: float, friction: str, start: str,
                 extra: dict | None = None, history: str | None = None) -> dict:
    """Global attributes of a run's dataset.  ``history``: the command line or
    API call that makes it (stored as a timestamped CF ``history`` line)."""
    created = cf.timestamp()
    attrs = {
        "Conventions": cf.CONVENTIONS,
        "title": "liethermo ensemble: heavy top in Stokes flow",
        "method": method,
        "method_description": METHODS[method].description,
        "method_order": METHODS[method].order(start, friction),
        "h": h,
        "h_units": "s",
        "friction": friction,
        "start": start,
        "scene": scene_toml,
        "software": f"liethermo {__version__}",
        "software_version": __version__,
        "python": platform.python_version(),
        "created": created,
        "history": cf.history_entry(history or f"liethermo {__version__}", created),
        "references": "Coueraud & Gay-Balmaz, Variational discretization of thermodynamical simple "
                      "systems on Lie groups; liethermo SPEC (errata E1-E5)",
    }
    if extra:
        attrs.update(extra)
    return attrs
