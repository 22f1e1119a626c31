"""Ensembles of the torus fluid: initial fields, a member chunk's run and its
labelled dataset.  Runs with an output go through the common runner
(:mod:`liethermo.torus.model`); :func:`simulate` is the in-memory run."""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field

import numpy as np
import xarray as xr

from .. import cf
from ..faults import check_stop
from ..numerics.fluid_outputs import provenance, run_variables
from . import kernels as tk
from . import step as ts
from .kernels import STATUS_MEANINGS

METHOD_ORDER = {"cmp": 2, "magmp": 2, "isomp": 2, "cmp4": 4, "magmp4": 4, "isomp4": 4, "rk4": 4, "reference": 8}
METHOD_DESCRIPTION = {
    "cmp": "Strang V(h/2) C(h/2) I(h) C(h/2) V(h/2), I the Cayley midpoint (energy- and Casimir-exact)",
    "magmp": "Strang V C I C V, I the Lie-Poisson (MagMP) midpoint",
    "isomp": "Strang V C I C V, I the isospectral midpoint (alpha = 0)",
    "cmp4": "the Cayley midpoint composed to order 4 (nu = kappa = 0)",
    "magmp4": "the MagMP midpoint composed to order 4 (nu = kappa = 0)",
    "isomp4": "the isospectral midpoint composed to order 4 (nu = kappa = 0)",
    "rk4": "classical Runge-Kutta 4 on the continuous matrix right-hand side",
    "reference": "DOP853 (scipy) at rtol 1e-12 on the continuous matrix right-hand side, restarted every step",
}
LAW_ENERGY = "energy"
LAW_ISOSPECTRAL = "isospectral"
LAW_ENTROPY = "entropy_monotone"
METHOD_LAWS = {
    "cmp": (LAW_ENERGY, LAW_ISOSPECTRAL, LAW_ENTROPY),
    "magmp": (LAW_ISOSPECTRAL, LAW_ENTROPY),
    "isomp": (LAW_ISOSPECTRAL, LAW_ENTROPY),
    "cmp4": (LAW_ENERGY, LAW_ISOSPECTRAL),
    "magmp4": (LAW_ISOSPECTRAL,),
    "isomp4": (LAW_ISOSPECTRAL,),
    "rk4": (),
    "reference": (),
}


def thermo_of(scene) -> tk.Thermo:
    th = scene["thermo"]
    return tk.Thermo(c=float(th["areal_heat_capacity"]), T0=float(th["T0"]), alpha=float(th["buoyancy"]),
                     nu=float(scene["fluid"]["kinematic_viscosity"]), kappa=float(th["conductivity"]))


# ----------------------------------------------------------------------------- initial fields


def _real(f: np.ndarray) -> np.ndarray:
    """The modes of a real field: ½(f_m + conj f_{−m}), mean 0."""
    g = 0.5 * (f + np.conj(np.roll(np.flip(f, (-2, -1)), 1, axis=(-2, -1))))
    g[..., 0, 0] = 0.0
    return g


def _random_modes(rng, N: int, kmax: int) -> np.ndarray:
    """Modes |m_i| ≤ kmax drawn in an order that does not depend on N."""
    n = 2 * kmax + 1
    c = rng.standard_normal((n, n)) + 1j * rng.standard_normal((n, n))
    f = np.zeros((N, N), complex)
    ks = np.arange(-kmax, kmax + 1)
    f[np.ix_(ks % N, ks % N)] = c
    return _real(f)


def _energy(f: np.ndarray, b: tk.Basis) -> float:
    return float(2 * math.pi**2 * (np.abs(f) ** 2 * b.inv_k2).sum())


def _rng(scene, member: int, stream: int):
    return np.random.default_rng([int(scene["ensemble"]["seed"]), int(member), stream])


def vorticity_modes0(scene, member: int) -> np.ndarray:
    ini = scene["initial"]
    N = int(scene["torus"]["N"])
    b = tk.basis(N)
    kind = ini["kind"]
    f = np.zeros((N, N), complex)
    if kind == "rest":
        return f
    if kind == "random":
        f = _random_modes(_rng(scene, member, 0), N, int(ini["kmax"]))
    elif kind == "kolmogorov":
        k = int(ini["k"])
        if k > b.M:
            raise ValueError(f"initial.k = {k} is above the largest mode (torus.N − 1)/2 = {b.M}")
        f[0, k % N] = f[0, -k % N] = -k / 2
    elif kind == "taylor_green":
        f[1, 1] = f[-1, -1] = -0.5
        f[1, -1] = f[-1, 1] = 0.5
    elif kind == "shell":
        lam = int(ini["k"])
        m = tk.wave_numbers(N)
        on = (m[:, None] ** 2 + m[None, :] ** 2) == lam
        if not on.any():
            raise ValueError(f"initial.k = {lam}: no mode of |m|² = {lam} with |m_i| ≤ {b.M}")
        rng = _rng(scene, member, 0)
        f = np.where(on, rng.standard_normal((N, N)) + 1j * rng.standard_normal((N, N)), 0)
        f = _real(f)
    return f * math.sqrt(float(ini["energy"]) / _energy(f, b))


def _patch_modes(N: int, a: float, r: float) -> np.ndarray:
    """a e^{−d²/2r²} (d the periodic distance to (π, π)) projected onto |m_i| ≤ M, from a fine grid."""
    n = max(256, 4 * N)
    x = 2 * math.pi * np.arange(n) / n
    d1 = np.minimum(np.abs(x - math.pi), 2 * math.pi - np.abs(x - math.pi))
    g = a * np.exp(-(d1[:, None] ** 2 + d1[None, :] ** 2) / (2 * r * r))
    F = np.fft.fft2(g) / (n * n)
    M = (N - 1) // 2
    ks = np.arange(-M, M + 1)
    f = np.zeros((N, N), complex)
    f[np.ix_(ks % N, ks % N)] = F[np.ix_(ks % n, ks % n)]
    return 0.5 * (f + np.conj(np.roll(np.flip(f, (-2, -1)), 1, axis=(-2, -1))))


def entropy0(scene, member: int, th: tk.Thermo, b: tk.Basis) -> np.ndarray:
    ini = scene["initial"]
    ek = ini["entropy_kind"]
    if ek == "uniform":
        if ini["kind"] == "rest":
            return tk.rest_state(float(ini["theta0"]), th, b)[1][0]
        return np.zeros((b.N, b.N), complex)
    if ek == "patch":
        f = _patch_modes(b.N, float(ini["entropy_amplitude"]), float(ini["entropy_radius"]))
    else:
        f = _random_modes(_rng(scene, member, 1), b.N, min(int(ini["kmax"]), b.M))
        sd = math.sqrt(float((np.abs(f) ** 2).sum()))
        f = f * (float(ini["entropy_amplitude"]) / sd if sd > 0 else 0.0)
    return tk.herm(tk.from_modes(f, b))


def initial_fields(scene, members) -> tuple[np.ndarray, np.ndarray]:
    """(W, S) of the given members, (members, N, N) each; member k's fields depend on
    (scene, k) only, and a random field's coefficients are the same at every N."""
    b = tk.basis(int(scene["torus"]["N"]))
    th = thermo_of(scene)
    members = np.asarray(members)
    W = np.empty((members.size, b.N, b.N), complex)
    S = np.empty_like(W)
    for j, k in enumerate(members):
        W[j] = tk.herm(tk.from_modes(vorticity_modes0(scene, int(k)), b))
        S[j] = entropy0(scene, int(k), th, b)
    return W, S


# ----------------------------------------------------------------------------- a run


class Recorder:
    """The diagnostics of every member at the kept times (the fields only where kept)."""

    NAMES = ("kinetic", "internal", "potential", "enstrophy", "entropy", "theta_min", "theta_max",
             "temperature_min", "temperature_max")

    def __init__(self, M: int, n_out: int, b: tk.Basis, th: tk.Thermo, keep_W: bool, keep_S: bool):
        self.b, self.th = b, th
        for name in self.NAMES:
            setattr(self, name, np.full((M, n_out), np.nan))
        self.cas = np.full((M, n_out, 3), np.nan)
        shape = (M, n_out, b.N, b.N)
        self.W = np.full(shape, np.nan + 0j) if keep_W else None
        self.S = np.full(shape, np.nan + 0j) if keep_S else None
        self.W_first = np.full((n_out, b.N, b.N), np.nan + 0j)
        self.S_first = np.full((n_out, b.N, b.N), np.nan + 0j)

    def record(self, j: int, members: np.ndarray, state) -> None:
        if members.size == 0:
            return
        W, S = state
        b, th = self.b, self.th
        lam = np.linalg.eigvalsh(S)
        self.kinetic[members, j] = tk.kinetic_energy(W, b)
        self.internal[members, j] = tk.internal(S, th, b, lam)
        self.potential[members, j] = tk.potential(S, th, b)
        self.enstrophy[members, j] = tk.enstrophy(W, b)
        self.entropy[members, j] = b.area * lam.sum(axis=-1)
        self.temperature_min[members, j] = th.T0 * np.exp(lam[:, 0] / th.c)
        self.temperature_max[members, j] = th.T0 * np.exp(lam[:, -1] / th.c)
        if th.alpha:
            lo, hi = tk.theta_range(S, th, b)
        else:
            lo, hi = self.temperature_min[members, j], self.temperature_max[members, j]
        self.theta_min[members, j], self.theta_max[members, j] = lo, hi
        self.cas[members, j] = tk.casimirs(W, b)
        if self.W is not None:
            self.W[members, j] = W
        if self.S is not None:
            self.S[members, j] = S
        first = np.flatnonzero(members == 0)
        if first.size:
            self.W_first[j], self.S_first[j] = W[first[0]], S[first[0]]


@dataclass
class Trajectory:
    times: np.ndarray
    out: Recorder
    iterations: np.ndarray
    status: np.ndarray
    failed_step: np.ndarray
    kernel_seconds: float
    conduction: tk.ConductionCount = field(default_factory=tk.ConductionCount)
    conduction_seconds: float = 0.0


def integrate(scene, W0, S0, *, method: str | None = None, progress=None, keep=None,
              budget_members: int | None = None, threads: int | None = None, xp=None) -> Trajectory:
    """Integrate the members (W0, S0) with the scene's method (or ``method``).  The
    matrices are small and each member's own: BLAS and LAPACK run on ``threads``
    threads (default 1; their thread pools cost more than they give at these sizes).
    ``xp``: the array module the steps run on (None: numpy, the CPU; see
    :func:`integrate_xp`)."""
    from threadpoolctl import threadpool_limits
    from tqdm.auto import tqdm

    from ..gpu import synchronize

    itg, out = scene["integrator"], scene["output"]
    method = method or itg["method"]
    N = int(scene["torus"]["N"])
    b = tk.basis(N)  # the diagnostics of the kept outputs run on the host
    bx = b if xp is None else tk.basis(N, xp)
    th = thermo_of(scene)
    h, steps, every = float(itg["h"]), int(itg["steps"]), int(out["every"])
    M = W0.shape[0]
    n_out = steps // every + 1
    keep_W, keep_S = (bool(out["vorticity"]), bool(out["entropy_field"])) if keep is None else keep
    rec = Recorder(M, n_out, b, th, keep_W, keep_S)
    rec.record(0, np.arange(M), (W0, S0))
    count = tk.ConductionCount()
    bar = tqdm(total=steps, desc=f"{scene.name} {method}", unit="step", leave=False,
               disable=None if progress is None else not progress)
    t0 = _time.perf_counter()
    with threadpool_limits(limits=threads or 1):
        its, status, failed = ts.drive(W0, S0, rec.record, th=th, b=bx, method=method,
                                       composition=itg["composition"], h=h, steps=steps, every=every,
                                       tol=float(itg["tol"]), max_iter=int(itg["max_iter"]),
                                       budget_members=budget_members, bar=bar,
                                       check_stop=check_stop, count=count)
        synchronize(bx.xp)
    bar.close()
    times = np.arange(n_out) * every * h
    return Trajectory(times, rec, its, status, failed, _time.perf_counter() - t0, count, count.seconds)


def integrate_xp(xp, scene, W0, S0, *, method: str | None = None, **kw) -> Trajectory:
    """:func:`integrate` with the steps on the array module ``xp`` (CuPy on a GPU:
    ``ensemble.device = "gpu"``; numpy runs the same steps on the host).  The
    members' states stay on ``xp``; the kept outputs and the per-member flags come
    back to the host, where the diagnostics are taken.  Methods:
    :data:`.step.XP_METHODS` (the reference, scipy's DOP853, is refused)."""
    ts.check_xp_method(method or scene["integrator"]["method"])
    return integrate(scene, W0, S0, method=method, xp=xp, **kw)


# ----------------------------------------------------------------------------- dataset


def _var(data, dims, units, long_name, **extra):
    return xr.Variable(dims, data, {"units": units, "long_name": long_name, **extra})


def trajectory_dataset(scene, traj: Trajectory, method: str, member_offset: int = 0,
                       attrs: dict | None = None) -> xr.Dataset:
    r = traj.out
    M, T = r.kinetic.shape
    total = r.kinetic + r.internal + r.potential
    dims_t = ("member", "t")
    on = "on the 2π-periodic square (area 4π² m², unit surface density)"
    data = {
        "kinetic_energy": _var(r.kinetic, dims_t, "J", "kinetic energy K", comment=f"K = ½∫|u|² dA {on}"),
        "internal_energy": _var(r.internal, dims_t, "J", "internal energy",
                                comment="(4π²/N) tr E(S), E(s) = c T0 exp(s/c)"),
        "potential_energy": _var(r.potential, dims_t, "J", "buoyancy potential energy",
                                 comment="−α⟨Φ, S⟩ = −α (4π²/N) tr(ΦS), Φ = cos y"),
        "total_energy": _var(total, dims_t, "J", "total energy H", comment="H = K + U: conserved by the model"),
        "energy_error": _var((total - total[:, :1]) / total[:, :1], dims_t, "1", "relative energy error",
                             comment="(H − H(0)) / H(0)"),
        "entropy": _var(r.entropy, dims_t, "J K-1", "total entropy S_tot", comment="S_tot = (4π²/N) tr S"),
        "enstrophy": _var(r.enstrophy, dims_t, "m2 s-2", "enstrophy Z", comment=f"Z = ½∫ω² dA {on}"),
        "theta_min": _var(r.theta_min, dims_t, "K", "least eigenvalue of Θ",
                          comment="Θ = T0 exp(S/c) − αΦ, the temperature of the second law; must stay > 0"),
        "theta_max": _var(r.theta_max, dims_t, "K", "largest eigenvalue of Θ"),
        "temperature_min": _var(r.temperature_min, dims_t, "K", "least temperature T",
                                comment="T = T0 exp(S/c), the solid's temperature (least eigenvalue)"),
        "temperature_max": _var(r.temperature_max, dims_t, "K", "largest temperature T"),
        "casimir": _var(r.cas, dims_t + ("k",), "1", "Casimir C_k",
                        comment="C_k = (4π²/N) tr W^k ≈ ∫ω^k dA (unit m2 s-k); conserved at ν = 0 and α = 0"),
        **run_variables(traj.iterations, traj.status, traj.failed_step, STATUS_MEANINGS, dims_t),
    }
    how = ("W = Σ ω_m T_m (clock-and-shift basis T_m); liethermo.torus.vorticity_modes(ds) gives ω_m in s-1")
    dims_w = dims_t + ("row", "col")
    if r.W is not None:
        data["vorticity_real"] = _var(r.W.real, dims_w, "s-1", "vorticity W, real part", comment=how)
        data["vorticity_imag"] = _var(r.W.imag, dims_w, "s-1", "vorticity W, imag. part", comment=how)
    if r.S is not None:
        how_s = "S = Σ s_m T_m: the entropy density matrix"
        data["entropy_density_real"] = _var(r.S.real, dims_w, "J K-1 m-2", "entropy density S, real part",
                                            comment=how_s)
        data["entropy_density_imag"] = _var(r.S.imag, dims_w, "J K-1 m-2", "entropy density S, imag. part",
                                            comment=how_s)
    steps = np.arange(T) * int(scene["output"]["every"])
    coords = {
        "member": _var(np.arange(member_offset, member_offset + M), ("member",), "1", "ensemble member"),
        "t": _var(cf.decimal_times(steps, scene["integrator"]["h"]), ("t",), "s", "time t",
                  comment="time since the start of the run (the decimal value of k h)"),
        "k": _var(np.array([2, 3, 4]), ("k",), "1", "power k of the Casimir"),
    }
    return xr.Dataset(data, coords=coords, attrs=attrs if attrs is not None else run_attrs(scene, method))


def run_attrs(scene, method: str, history: str | None = None) -> dict:
    N = int(scene["torus"]["N"])
    itg = scene["integrator"]
    return {
        "Conventions": cf.CONVENTIONS,
        "title": "liethermo ensemble: Zeitlin's sine-bracket fluid on the torus with heat",
        "model": "torus",
        "method": method,
        "method_description": METHOD_DESCRIPTION[method],
        "method_order": METHOD_ORDER[method],
        "N": N,
        "hbar": 4 * math.pi / N,
        "h": float(itg["h"]),
        "h_units": "s",
        **provenance(scene, history),
        "references": "Zeitlin (1991); Fairlie, Fletcher & Zachos (1989); McLachlan (1993); Modin & Roop (2023); "
                      "liethermo docs/model.md, the fluid on the torus",
    }


def vorticity_modes(ds: xr.Dataset) -> xr.DataArray:
    """The Fourier modes ω_m (s⁻¹, complex) of a run's stored vorticity, ω = Σ ω_m e^{i m·x},
    dims (member, t, m1, m2) with the wave numbers as coordinates."""
    if "vorticity_real" not in ds:
        raise ValueError("the dataset holds no vorticity: run the scene with output.vorticity = true")
    W = ds["vorticity_real"].values + 1j * ds["vorticity_imag"].values
    N = W.shape[-1]
    f = tk.to_modes(W, tk.basis(N))
    m = tk.wave_numbers(N)
    return xr.DataArray(f, dims=("member", "t", "m1", "m2"),
                        coords={"member": ds["member"].values, "t": ds["t"].values, "m1": m, "m2": m},
                        name="vorticity_modes", attrs={"units": "s-1", "long_name": "vorticity mode ω_m"})


def simulate(scene, *, method: str | None = None, progress=None) -> xr.Dataset:
    """The scene's ensemble in memory."""
    M = int(scene["ensemble"]["members"])
    W0, S0 = initial_fields(scene, np.arange(M))
    method = method or scene["integrator"]["method"]
    traj = integrate(scene, W0, S0, method=method, progress=progress)
    ds = trajectory_dataset(scene, traj, method)
    ds.attrs["kernel_seconds"] = traj.kernel_seconds
    return ds
