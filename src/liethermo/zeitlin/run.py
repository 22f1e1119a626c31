"""Ensembles of the thermodynamic Zeitlin fluid: initial fields, the methods'
steps over a batch of members, and the dataset of a member chunk.  Runs with
an output go through the common runner (:mod:`liethermo.zeitlin.model`);
:func:`simulate` is the in-memory run the studies and tests use."""

from __future__ import annotations

import time as _time
from dataclasses import dataclass

import numpy as np
import xarray as xr

from .. import cf
from ..numerics import matrix_flow as mf
from ..numerics.matrix_flow import Predictor, factors  # noqa: F401  (the fluid's names)
from ..numerics.laws import LAW_ENTROPY_MONOTONE
from . import kernels as zk
from ..numerics import heat as _heat
from ..numerics.fluid_outputs import provenance, run_variables
from ..faults import check_stop
from .field import read_field, triangle_to_modes
from .scene import ZeitlinScene

#: per-member status (dataset variable ``status``)
STATUS_MEANINGS = {0: "ok", 1: "fixed_point_not_converged", 2: "non_finite"}
METHOD_ORDER = {"split": 2, "split4": 4, "split6": 6, "rk4": 4, "reference": 8}
METHOD_DESCRIPTION = {
    "split": "Strang splitting: exact viscous-and-heat flow (h/2), isospectral midpoint (h), exact flow (h/2)",
    "split4": "the Strang splitting composed to order 4",
    "split6": "the Strang splitting composed to order 6",
    "rk4": "classical Runge-Kutta 4 on the vorticity equation, with the heat integrated alongside",
    "reference": "DOP853 (scipy) at rtol 1e-13 on the vorticity equation and the heat",
}
REFERENCE_RTOL = 1e-13

#: what each method keeps to round-off, for every field and step (the laws of
#: docs/model.md, "What each method keeps"): ``isospectral`` — W's spectrum
#: (every Casimir) at ν = 0; ``angular_momentum`` — the l = 1 modes;
#: ``entropy_monotone`` — the heat never falls in a step.  The compositions'
#: merged viscous flows of negative duration return heat inside a step, so a
#: monotone entropy is measured for them, not declared.
LAW_ISOSPECTRAL = "isospectral"
LAW_ANGULAR_MOMENTUM = "angular_momentum"
METHOD_LAWS = {
    "split": (LAW_ISOSPECTRAL, LAW_ANGULAR_MOMENTUM, LAW_ENTROPY_MONOTONE),
    "split4": (LAW_ISOSPECTRAL, LAW_ANGULAR_MOMENTUM),
    "split6": (LAW_ISOSPECTRAL, LAW_ANGULAR_MOMENTUM),
    "rk4": (LAW_ANGULAR_MOMENTUM,),
    "reference": (),
}


# ----------------------------------------------------------------------------- initial fields


def _random_modes(b: zk.Basis, rng, lmax: int) -> np.ndarray:
    """Random ω_lm for 1 ≤ l ≤ lmax, drawn in the order (m, l), which does not
    depend on N: the same seed gives the same coefficients at every N."""
    C = np.zeros(b.modes, dtype=np.complex128)
    sel = (b.ell >= 1) & (b.ell <= lmax)
    n = int(sel.sum())
    re, im = rng.standard_normal(n), rng.standard_normal(n)
    C[sel] = re + 1j * im
    C[: b.N] = C[: b.N].real  # m = 0: ω_l0 is real
    return C


def _shape_spectrum(C: np.ndarray, b: zk.Basis, target: np.ndarray) -> np.ndarray:
    """Rescale each degree l of C so that its energy is target[l - 1]."""
    E = zk.spectrum_of_modes(C[None], b)[0]
    scale = np.zeros(b.N)
    scale[1:] = np.sqrt(np.divide(target, E, out=np.zeros_like(E), where=E > 0))
    return C * scale[b.ell.astype(int)]


def initial_fields(scene: ZeitlinScene, members: np.ndarray | None = None) -> np.ndarray:
    """W(0) of the given members (default: all), (members, N, N).  Member k's
    field ω = Σ ω_lm Y_lm depends on (ensemble.seed, k) only, not on N: its
    coefficients for l ≤ initial.lmax are the same at every N, so runs at
    different N are the same physical flow, and any subset of members is
    reproducible."""
    z, ini, ens = scene["zeitlin"], scene["initial"], scene["ensemble"]
    b = zk.basis(z["N"])
    members = np.arange(ens["members"]) if members is None else np.asarray(members)
    if ini["kind"] == "file":
        return zk.from_modes(triangle_to_modes(file_fields(scene, members), b.N), b)
    lmax, energy = ini["lmax"], ini["energy"]
    ls = np.arange(1, b.N, dtype=float)
    out = np.empty((len(members), b.N, b.N), dtype=np.complex128)
    for j, k in enumerate(members):
        rng = np.random.default_rng([ens["seed"], int(k)])
        C = _random_modes(b, rng, lmax)
        if ini["kind"] == "random":
            prof = np.where(ls <= lmax, ls ** (-ini["slope"]), 0.0)
            C = _shape_spectrum(C, b, energy * prof / prof.sum())
        else:  # rossby_haurwitz: solid-body rotation and the (lmax, m) wave, equal energy, plus noise,
            # the sum scaled to initial.energy (the noise shares modes with the wave and the rotation,
            # so the energies of the parts do not add up to that of the sum)
            noise = ini["noise"]
            prof = np.where(ls <= lmax, 1.0, 0.0)
            C = _shape_spectrum(C, b, noise * energy * prof / prof.sum()) if noise > 0 else 0 * C
            wave = np.zeros(b.modes, dtype=np.complex128)
            m = ini["m"]
            wave[b.offset[m] + (lmax - m)] = 1.0  # ω ∝ Re Y_lm: a crest at φ = 0
            rot = np.zeros(b.modes, dtype=np.complex128)
            rot[1] = 1.0  # (l, m) = (1, 0): ω = 2Ω_b cos θ, solid-body rotation about z (Ω_b > 0)
            modes = [rot] if (lmax, m) == (1, 0) else [rot, wave]
            for mode in modes:
                share = (1.0 - noise) * energy / len(modes)
                C = C + mode * np.sqrt(share / zk.energy_of_modes(mode[None], b)[0])
            if noise > 0:
                C = C * np.sqrt(energy / zk.energy_of_modes(C[None], b)[0])
        out[j] = zk.from_modes(C[None], b)[0]
    return out


def file_fields(scene: ZeitlinScene, members: np.ndarray) -> np.ndarray:
    """The coefficient triangles C[l, m] (members, N, N), s⁻¹, of the given
    members of a scene with ``initial.kind = "file"`` (the file must still
    have the scene's sha256)."""
    ini = scene["initial"]
    C, _ = read_field("initial.file", ini["file"], scene["zeitlin"]["N"], ini["sha256"])
    members = np.asarray(members)
    return C[members] if C.shape[0] > 1 else np.repeat(C, members.size, axis=0)


# ----------------------------------------------------------------------------- steps


class SphereOps:
    """The sphere's operations for :mod:`liethermo.numerics.matrix_flow` on numpy
    (the numba kernels of :mod:`.kernels`)."""

    xp = np

    def __init__(self, b: zk.Basis):
        self.b = b

    def viscous_flow(self, W, t, nu):
        return zk.viscous_flow(W, t, nu, self.b)

    def isomp(self, W, h, tol, max_iter, guess):
        return zk.isomp(W, h, self.b, tol, max_iter, guess)

    def rhs(self, W, nu):
        return zk.rhs(W, nu, self.b)

    @staticmethod
    def asarray(a):
        return np.array(a, copy=True)

    @staticmethod
    def to_host(a):
        return np.asarray(a)

    @staticmethod
    def synchronize():
        pass


def split_step(W, q, h, nu, b, fac, tol, max_iter, guess=None, predictor: Predictor | None = None,
               active: np.ndarray | None = None):
    """One step of the split family on a batch of the sphere's members
    (:func:`liethermo.numerics.matrix_flow.split_step`)."""
    return mf.split_step(SphereOps(b), W, q, h, nu, fac, tol, max_iter, guess, predictor, active)


def rk4_step(W, q, h, nu, b):
    return mf.rk4_step(SphereOps(b), W, q, h, nu)


# ----------------------------------------------------------------------------- a run


class Recorder:
    """The outputs of a run, gathered as the run goes: the diagnostics of every
    member at every output time (a few numbers each), W itself only where it
    is kept (``keep_all``: every member; always member 0, for the figures).
    A run's memory is then O(members × times × N), not × N²."""

    def __init__(self, M: int, n_out: int, b: zk.Basis, keep_all: bool):
        self.b = b
        nan = np.nan
        # the fields of kernels.diagnostics, per member and output time
        self.H = np.full((M, n_out), nan)
        self.spec = np.full((M, n_out, b.N - 1), nan)
        self.cas = np.full((M, n_out, 3), nan)
        self.L = np.full((M, n_out, 3), nan)
        self.Z = np.full((M, n_out), nan)
        self.q = np.full((M, n_out), nan)
        self.W = np.full((M, n_out, b.N, b.N), nan + 0j) if keep_all else None
        self.W_first = np.full((n_out, b.N, b.N), nan + 0j)

    def record(self, j: int, members: np.ndarray, W: np.ndarray, q: np.ndarray) -> None:
        if members.size == 0:
            return
        for name, values in zk.diagnostics(W, self.b).items():
            getattr(self, name)[members, j] = values
        self.q[members, j] = q
        if self.W is not None:
            self.W[members, j] = W
        first = np.flatnonzero(members == 0)
        if first.size:
            self.W_first[j] = W[first[0]]


@dataclass
class Trajectory:
    """A run's outputs: the diagnostics (:class:`Recorder`) at the output times."""

    times: np.ndarray
    out: Recorder
    iterations: np.ndarray   # (members, times): fixed-point iterations per step over the interval before
    status: np.ndarray       # (members,)
    failed_step: np.ndarray  # (members,), −1 if none
    kernel_seconds: float

    @property
    def W(self) -> np.ndarray | None:
        """W of every member at every output time (None unless kept)."""
        return self.out.W

    @property
    def q(self) -> np.ndarray:
        return self.out.q


def integrate(scene: ZeitlinScene, W0: np.ndarray, *, method: str | None = None, progress=None,
              keep_vorticity: bool | None = None, budget_members: int | None = None) -> Trajectory:
    """Integrate the members W0 with the scene's method; outputs every
    output.every steps.  ``keep_vorticity``: keep W of every member at every
    output (default: the scene's output.vorticity).  ``budget_members``: the
    batch size that sets the fixed point predictor's order (default: W0's;
    see :class:`Predictor`).  The same steps over an array namespace (CuPy on
    a GPU): :func:`.xpstep.integrate_xp`."""
    z, itg, out = scene["zeitlin"], scene["integrator"], scene["output"]
    method = method or itg["method"]
    b = zk.basis(z["N"])
    nu = float(scene["fluid"]["kinematic_viscosity"])
    h, steps, every = float(itg["h"]), int(itg["steps"]), int(out["every"])
    M = W0.shape[0]
    n_out = steps // every + 1
    times = np.arange(n_out) * every * h
    rec = Recorder(M, n_out, b, bool(out["vorticity"] if keep_vorticity is None else keep_vorticity))
    its = np.zeros((M, n_out))
    status = np.zeros(M, dtype=np.int8)
    failed_step = np.full(M, -1, dtype=np.int64)
    rec.record(0, np.arange(M), W0, np.zeros(M))
    t0 = _time.perf_counter()
    if method == "reference":
        from tqdm.auto import tqdm

        for k in tqdm(range(M), desc="reference", unit="member", leave=False,
                      disable=None if progress is None else not progress):
            Wk = np.full((1, n_out, b.N, b.N), np.nan + 0j)
            qk = np.full((1, n_out), np.nan)
            reference_run(W0[k:k + 1], times, nu, b, Wk, qk, status[k:k + 1], False)
            if status[k] == 0:
                for j in range(1, n_out):
                    rec.record(j, np.array([k]), Wk[:, j], qk[:, j])
        return Trajectory(times, rec, its, status, failed_step, _time.perf_counter() - t0)
    return run_steps(SphereOps(b), scene, W0, rec, method=method, progress=progress,
                     budget_members=budget_members, t0=t0)


def run_steps(ops, scene, W0, rec, *, method, progress, budget_members, t0) -> Trajectory:
    """The scene's steps of every member of W0 on ``ops`` (the numba kernels, or
    an array namespace: :func:`.xpstep.integrate_xp`), recorded into ``rec``."""
    from tqdm.auto import tqdm

    itg, every = scene["integrator"], int(scene["output"]["every"])
    steps = int(itg["steps"])
    bar = tqdm(total=steps, desc=f"{scene.name} {method}", unit="step", leave=False,
               disable=None if progress is None else not progress)
    its, status, failed_step = mf.drive(
        ops, W0, rec.record, method=method, composition=itg["composition"], h=float(itg["h"]), steps=steps,
        every=every, nu=float(scene["fluid"]["kinematic_viscosity"]), tol=itg["tol"], max_iter=itg["max_iter"],
        budget_members=budget_members, bar=bar, check_stop=check_stop)
    bar.close()
    times = np.arange(steps // every + 1) * every * float(itg["h"])
    return Trajectory(times, rec, its, status, failed_step, _time.perf_counter() - t0)


def reference_run(W0, times, nu, b, Ws, qs, status, progress):
    """DOP853 per member at rtol REFERENCE_RTOL into Ws, qs at ``times`` (status 2 where it fails)."""
    from scipy.integrate import solve_ivp
    from tqdm.auto import tqdm

    N = b.N

    def f(t, y):
        W = y[:-1].view(np.complex128).reshape(1, N, N)
        dW, qd = zk.rhs(W, nu, b)
        return np.concatenate([dW.ravel().view(np.float64), qd])

    for k in tqdm(range(W0.shape[0]), desc="reference", unit="member", leave=False,
                  disable=None if progress is None else not progress):
        check_stop()
        y0 = np.concatenate([np.ascontiguousarray(W0[k]).ravel().view(np.float64), [0.0]])
        atol = REFERENCE_RTOL * np.abs(W0[k]).max()
        sol = solve_ivp(f, (0.0, times[-1]), y0, method="DOP853", t_eval=times, rtol=REFERENCE_RTOL, atol=atol)
        if not sol.success:
            status[k] = 2
            continue
        y = sol.y.T.copy()
        Ws[k] = y[:, :-1].copy().view(np.complex128).reshape(len(times), N, N)
        qs[k] = y[:, -1]


# ----------------------------------------------------------------------------- dataset


def _var(data, dims, units, long_name, **extra):
    return xr.Variable(dims, data, {"units": units, "long_name": long_name, **extra})


def trajectory_dataset(scene: ZeitlinScene, traj: Trajectory, method: str, history: str | None = None,
                       member_offset: int = 0, attrs: dict | None = None) -> xr.Dataset:
    """The labelled dataset of members ``member_offset + (0 … M−1)``; ``attrs``:
    its global attributes (default: :func:`run_attrs` and the kernel time)."""
    b = zk.basis(scene["zeitlin"]["N"])
    cv, T0 = scene["thermo"]["heat_capacity"], scene["thermo"]["T0"]
    r = traj.out
    M, T = r.q.shape
    H, spec, cas, L, ens, q = r.H, r.spec, r.cas, r.L, r.Z, r.q
    E0 = H[:, :1]
    dims_t = ("member", "t")
    field = "of the vorticity field ω on the unit sphere (radius 1 m, unit surface density)"
    data = {
        "energy": _var(H, dims_t, "J", "kinetic energy H",
                       comment=f"H = ½∫|u|² dA = −½∫ψω dA {field}"),
        "heat": _var(q, dims_t, "J", "heat absorbed q = U - U0",
                     comment="the energy that viscosity dissipated since t = 0"),
        "total_energy": _var(H + q, dims_t, "J", "H + q", comment="conserved by the model"),
        "energy_error": _var((H + q - E0) / E0, dims_t, "1", "relative energy error",
                             comment="(H + q - H(0)) / H(0)"),
        "entropy": _var(_heat.entropy_of_heat(q, cv, T0), dims_t, "J K-1", "entropy produced",
                        comment="S - S0 = c_v log(T/T0) since t = 0"),
        "temperature": _var(_heat.temperature_of_heat(q, cv, T0), dims_t, "K", "temperature",
                            comment="T = T0 + q/c_v"),
        "enstrophy": _var(ens, dims_t, "m2 s-2", "enstrophy Z", comment=f"Z = ½∫ω² dA {field}"),
        "casimir": _var(cas, dims_t + ("k",), "1", "Casimir C_k",
                        comment="C_k = (4π/N) tr((−iW)^k), which approximates ∫ω^k dA (C_2 = ∫ω² dA exactly); "
                                "its unit depends on k (m2 s-k), so units is 1"),
        "casimir_drift": _var(zk.casimir_change(cas, cas[:, :1], b), dims_t + ("k",), "1", "relative Casimir change",
                              comment="(tr((−iW)^k) − its value at t = 0) / tr((−iW)²)(0)^(k/2)"),
        "angular_momentum": _var(L, dims_t + ("axis",), "kg m2 s-1", "angular momentum L",
                                 comment="L = σ∫x × u dA = ∫x ω dA (σ = 1 kg m-2, radius 1 m): the degree-1 "
                                         "part of ω; a solid-body rotation Ω has L = (8π/3)Ω"),
        "energy_spectrum": _var(spec, dims_t + ("l",), "J", "energy of degree l",
                                comment="E_l = ½ Σ_m |ω_lm|²/(l(l+1)); Σ_l E_l = H"),
        **run_variables(traj.iterations, traj.status, traj.failed_step, STATUS_MEANINGS, dims_t),
    }
    if scene["output"]["vorticity"] and r.W is not None:
        dims_w = dims_t + ("row", "col")
        how = ("W = i√(N/4π) Σ ω_lm T_lm (T_lm orthonormal quantized harmonics); "
               "liethermo.zeitlin.vorticity_coefficients(ds) gives ω_lm in s-1")
        data["vorticity_real"] = _var(r.W.real, dims_w, "s-1", "vorticity W, real part", comment=how)
        data["vorticity_imag"] = _var(r.W.imag, dims_w, "s-1", "vorticity W, imag. part", comment=how)
    if scene["initial"]["kind"] == "file":
        C = file_fields(scene, np.arange(member_offset, member_offset + M))
        dims_c = ("member", "degree", "order")
        how = (f"C[l, m] = ω_lm of ω(t = 0) = Σ ω_lm Y_lm, m ≥ 0 (zero for m > l), read from initial.file "
               f"(sha256 {scene['initial']['sha256']})")
        data["initial_vorticity_real"] = _var(C.real, dims_c, "s-1", "initial vorticity coefficient, real part",
                                              comment=how)
        data["initial_vorticity_imag"] = _var(C.imag, dims_c, "s-1", "initial vorticity coefficient, imag. part",
                                              comment=how)
    steps = np.arange(traj.times.size) * int(scene["output"]["every"])  # t_j = j every h
    coords = {
        "member": _var(np.arange(member_offset, member_offset + M), ("member",), "1", "ensemble member"),
        "t": _var(cf.decimal_times(steps, scene["integrator"]["h"]), ("t",), "s", "time t",
                  comment="time since the start of the run (the decimal value of k h)"),
        "k": _var(np.array([2, 3, 4]), ("k",), "1", "power k of the Casimir"),
        "axis": xr.Variable(("axis",), np.array(["x", "y", "z"]), {"long_name": "space axis"}),
        "l": _var(np.arange(1, b.N), ("l",), "1", "degree l",
                  comment="degree l of the spherical harmonics"),
    }
    if scene["initial"]["kind"] == "file":
        coords["degree"] = _var(np.arange(b.N), ("degree",), "1", "degree l of the initial coefficients")
        coords["order"] = _var(np.arange(b.N), ("order",), "1", "order m of the initial coefficients")
    if attrs is None:
        attrs = run_attrs(scene, method, history)
        attrs["kernel_seconds"] = traj.kernel_seconds
    return xr.Dataset(data, coords=coords, attrs=attrs)


def run_attrs(scene: ZeitlinScene, method: str, history: str | None = None) -> dict:
    """The global attributes of a run's dataset (without its kernel time)."""
    N = scene["zeitlin"]["N"]
    itg = scene["integrator"]
    attrs = {
        "Conventions": cf.CONVENTIONS,
        "title": "liethermo ensemble: thermodynamic Zeitlin fluid on the sphere",
        "model": "zeitlin",
        "method": method,
        "method_description": METHOD_DESCRIPTION[method],
        "method_order": METHOD_ORDER[method],
        "composition": itg["composition"] if method in ("split4", "split6") else "none",
        "N": scene["zeitlin"]["N"],
        "hbar": zk.hbar(N),
        "h": float(itg["h"]),
        "h_units": "s",
        **provenance(scene, history),
        "references": "Zeitlin (1991, 2004); Modin & Viviani (2020), the isospectral midpoint; "
                      "liethermo docs/model.md, the thermodynamic Zeitlin fluid",
    }
    return attrs


def vorticity_coefficients(ds: xr.Dataset) -> xr.DataArray:
    """The coefficients ω_lm (s⁻¹, complex, m ≥ 0) of the vorticity
    ω = Σ ω_lm Y_lm of a run that stored it (``output.vorticity = true``),
    with dims (member, t, mode) and coordinates ``l`` and ``m`` on ``mode``
    (orthonormal complex spherical harmonics with the Condon–Shortley phase,
    scipy's ``sph_harm_y``; ω_l,−m = (−1)^m conj(ω_lm))."""
    if "vorticity_real" not in ds:
        raise ValueError("the dataset holds no vorticity: run the scene with output.vorticity = true")
    W = ds["vorticity_real"].values + 1j * ds["vorticity_imag"].values
    N = W.shape[-1]
    b = zk.basis(N)
    C = zk.to_modes(W.reshape(-1, N, N), b).reshape(W.shape[:-2] + (b.modes,))
    return xr.DataArray(C, dims=("member", "t", "mode"),
                        coords={"member": ds["member"].values, "t": ds["t"].values,
                                "l": ("mode", b.ell.astype(int)), "m": ("mode", b.order)},
                        name="vorticity_coefficients",
                        attrs={"units": "s-1", "long_name": "vorticity coefficient ω_lm"})


def stepping_line(seconds: float) -> str:
    """The summary's line on what the time stepping took (what ``kernel_seconds`` measures)."""
    return (f"  stepping {seconds:.3g} s (the members' steps and diagnostics, compiling or loading the step "
            "kernels on first use included; not the basis, the writing or figures)")


def status_line(counts: dict, method: str) -> str:
    """The members per status flag (a flag the method cannot raise left out)."""
    shown = {k: v for k, v in counts.items()
             if not (k == "fixed_point_not_converged" and method in ("rk4", "reference"))}
    return "  status   " + ", ".join(f"{k}: {v}" for k, v in shown.items())


def summary(ds: xr.Dataset) -> str:
    import warnings

    with warnings.catch_warnings():  # members that failed are NaN; all of them may have
        warnings.simplefilter("ignore", RuntimeWarning)
        return _summary(ds)


def _summary(ds: xr.Dataset) -> str:
    n_bad = int((ds["status"] != 0).sum())
    M = ds.sizes["member"]
    err = float(np.nanmax(np.abs(ds["energy_error"].values)))
    cas = float(np.nanmax(np.abs(ds["casimir_drift"].sel(k=2).values)))
    L = ds["angular_momentum"].values
    dL = float(np.nanmax(np.abs(L - L[:, :1]))) / max(float(np.nanmax(np.abs(L[:, :1]))), 1e-300)
    heat = float(np.nanmean(ds["heat"].values[:, -1] / ds["energy"].values[:, 0]))
    its = ds["fixed_point_iterations"].values[:, 1:]
    import tomllib

    viscous = tomllib.loads(ds.attrs["scene"])["fluid"]["kinematic_viscosity"] > 0
    casimir_words = ("tr W² (∫ω² dA) changed by {:.2e} (viscosity dissipates it)" if viscous
                     else "tr W² drift ≤ {:.2e} (∫ω² dA)")
    flags = ds["status"].values
    counts = {name: int((flags == flag).sum()) for flag, name in STATUS_MEANINGS.items()}
    lines = [f"{ds.attrs['method']}: {M} member(s), N = {ds.attrs['N']}, h = {ds.attrs['h']:g} s, "
             f"t = {float(ds['t'][-1]):g} s",
             stepping_line(ds.attrs["kernel_seconds"]),
             status_line(counts, ds.attrs["method"]),
             f"  |H + q − H(0)|/H(0) ≤ {err:.2e}; {casimir_words.format(cas)}; angular momentum drift ≤ "
             f"{dL:.2e} (relative); heat {100 * heat:.1f} % of H(0)"]
    if its.size and np.nanmax(its) > 0:
        lines.append(f"  fixed-point iterations per step: mean {np.nanmean(its):.2f}, max {np.nanmax(its):.2f}")
    if n_bad:
        lines.append(f"  {n_bad} member(s) failed: see status and failed_step")
    return "\n".join(lines)


def check_memory(scene: ZeitlinScene) -> None:
    """An in-memory run keeps W of every member at every output only with
    output.vorticity: refuse one whose W would not fit in half of the memory
    available (:func:`liethermo.preflight.available_memory`, cgroup limits included)."""
    from ..preflight import available_memory
    from ..scene import SceneError

    if not scene["output"]["vorticity"]:
        return
    M, N = scene["ensemble"]["members"], scene["zeitlin"]["N"]
    T = scene["integrator"]["steps"] // scene["output"]["every"] + 1
    need = 16 * M * T * N * N
    have = available_memory()
    if have is None:
        return
    if need > have / 2:
        raise SceneError("output.vorticity", f"W of {M} members at {T} output times, N = {N}, needs "
                         f"{need / 2**30:.1f} GiB, more than half of the {have / 2**30:.1f} GiB available: "
                         f"store fewer outputs (output.every) or members, or leave the vorticity out", True)


def simulate(scene: ZeitlinScene, *, method: str | None = None, progress=None, history=None) -> xr.Dataset:
    """Run the scene's ensemble with its method (or ``method``) into an in-memory
    dataset."""
    check_memory(scene)
    W0 = initial_fields(scene)
    method = method or scene["integrator"]["method"]
    traj = integrate(scene, W0, method=method, progress=progress)
    ds = trajectory_dataset(scene, traj, method, history)
    ds.attrs["summary"] = summary(ds)
    return ds
