"""Helpers the study modules share: running a method spec, settling times, angles, members set side by side,
table columns named after the quantities (what a trajectory keeps is :mod:`liethermo.laws`)."""

from __future__ import annotations

import math

import numpy as np

from ..physics import Physics, physics_of_scene
from ..simulate import Trajectory, simulate
from .common import method_choice

#: the sentence every report uses to say what node values are
NODE_VALUES_NOTE = (
    "**Node values vs step velocities.** Every method gives the state at the instants t_k = k h — the "
    "*node values* Ω(t_k), Γ_k, S_k — and E_k is the energy of those values. The variational integrators "
    "also carry a *step velocity* Ω_k, the constant angular velocity of the step from t_k to t_k + h "
    "(≈ Ω(t_k + h/2)); the paper computes the energy from Ω_k with Γ_k and S_k, which mixes two instants "
    "and so adds an O(h) error of the diagnostic itself (\"paper convention\").")


def run_spec(phys: Physics, omega0, R0, h: float, steps: int, spec, **kw) -> Trajectory:
    """:func:`simulate` with a method label or its :func:`~.common.method_choice`."""
    return simulate(phys, omega0, R0, h, steps, method_choice(spec) if isinstance(spec, str) else spec, **kw)


def drift_fit(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of y (N, T): (least-squares slope of y against t, standard deviation of the residual about that
    line); NaN for rows with a non-finite value."""
    t = np.asarray(t, float)
    tc = t - t.mean()
    with np.errstate(invalid="ignore", over="ignore"):
        ym = y.mean(axis=1, keepdims=True)
        slope = (y - ym) @ tc / (tc @ tc)
        resid = y - ym - slope[:, None] * tc[None, :]
        spread = np.sqrt(np.mean(resid * resid, axis=1))
    bad = ~np.all(np.isfinite(y), axis=1)
    slope[bad], spread[bad] = np.nan, np.nan
    return slope, spread


def settling_time(t: np.ndarray, ratio: np.ndarray, fraction: float) -> np.ndarray:
    """Per row of ``ratio`` (N, T) (a positive quantity relative to its initial value, e.g. E_mech,k / E_mech,0):
    the first time it falls to ``fraction`` or below (s), log-linearly interpolated between the two nodes around
    the crossing; 0 if it starts there, NaN if it never gets there (or a value before it is not finite)."""
    t, r = np.asarray(t, float), np.asarray(ratio, float)
    out, lf = np.full(r.shape[0], np.nan), math.log(fraction)
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
    """Angle (rad) between the directions of u and v (..., 3), accurate for small and large angles (atan2 of |u×v|
    and u·v); |u|, |v| need not be 1."""
    return np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.sum(u * v, axis=-1))


def rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle (rad) of the rotation Ra Rbᵀ between attitudes (..., 3, 3), from the Frobenius distance
    ‖Ra − Rb‖ = 2√2 sin(θ/2) (accurate for small angles)."""
    d = np.linalg.norm(np.asarray(Ra) - np.asarray(Rb), axis=(-2, -1))
    return 2.0 * np.arcsin(np.clip(d / (2.0 * math.sqrt(2.0)), 0.0, 1.0))


def quantile_band(a: np.ndarray, q=(0.05, 0.5, 0.95)) -> np.ndarray:
    """Quantiles ``q`` of the finite values of a (NaN if none)."""
    a = np.asarray(a, float).ravel()
    a = a[np.isfinite(a)]
    if a.size == 0:
        return np.full(len(q), np.nan)
    return np.quantile(a, q)


def column(ds, name: str, stat: str = "") -> str:
    """A table column for the quantity ``name`` of the study dataset, its netCDF name and units
    (``"median settling_time (s)"``): a CSV or report column is the quantity the netCDF defines."""
    return f"{stat} {name} ({ds[name].attrs.get('units', '1')})".strip()


def ensemble(ctx, point: dict, method: str, limit: int | None = None):
    """``(scene, parsed method, physics, Ω₀, R₀, N)``: the first ``limit`` (all: None) of the N members of a
    study's sweep point run with ``method``."""
    from ..initial import initial_conditions
    spec = method_choice(method)
    scene = ctx.scene({**point, **spec.overrides()})
    N = int(scene["ensemble"]["members"])
    n = min(N, limit) if limit else N
    om, R = initial_conditions(scene, 0, n)
    return scene, spec, physics_of_scene(scene, N).take(slice(0, n)), om, R, N


def pad_members(a: np.ndarray, n: int, fill=np.nan) -> np.ndarray:
    """``a`` (m, …) padded to n members with ``fill`` (members a method did not run)."""
    out = np.full((n,) + a.shape[1:], fill, dtype=np.result_type(a.dtype, type(fill)))
    out[:a.shape[0]] = a
    return out


def reference_label(methods) -> str | None:
    """The study's reference method among ``methods``, if any."""
    return next((m for m in methods if method_choice(m).name == "reference"), None)


def same_members(ds, methods) -> np.ndarray:
    """(member,) bool: the members every method ran — the reference's (status ≥ 0 at every point), all without one."""
    ref = reference_label(methods)
    if ref is None:
        return np.ones(ds.sizes["member"], bool)
    st = ds["status"].sel(scheme=ref) >= 0
    return st.all([d for d in st.dims if d != "member"]).values


def quantile_columns(ds, d, names, members, stats=("5%", "median", "95%")) -> dict:
    """{column: value}: the quantiles ``stats`` over ``members`` of each quantity in ``names`` of ``d``."""
    q = [{"5%": 0.05, "median": 0.5, "95%": 0.95}[s] for s in stats]
    return {column(ds, v, s): float(x) for v in names for s, x in zip(stats, quantile_band(d[v].values[members], q))}


def observed_orders(hs, errors) -> np.ndarray:
    """log(e_i / e_{i+1}) / log(h_i / h_{i+1}) between consecutive levels (NaN where an error is not finite and
    positive); one fewer than the levels."""
    hs, e = np.asarray(hs, float), np.asarray(errors, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        p = np.log(e[:-1] / e[1:]) / np.log(hs[:-1] / hs[1:])
    p[~(np.isfinite(e[:-1]) & np.isfinite(e[1:]) & (e[:-1] > 0) & (e[1:] > 0))] = np.nan
    return p
