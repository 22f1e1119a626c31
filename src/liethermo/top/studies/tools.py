"""Helpers the study modules share: running a method spec, members set side by side, table columns named after
the quantities (ensemble numerics are :mod:`liethermo.analysis`, what a trajectory keeps :mod:`liethermo.top.laws`)."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from ...analysis import quantile_band
from ..physics import Physics, physics_of_scene
from ..resolve import resolve
from ..simulate import Trajectory
from ...studies.common import StudyError

#: the sentence every report uses to say what node values are
NODE_VALUES_NOTE = (
    "**Node values vs step velocities.** Every method gives the state at the instants t_k = k h — the "
    "*node values* Ω(t_k), Γ_k, S_k — and E_k is the energy of those values. The variational integrators "
    "also carry a *step velocity* Ω_k, the constant angular velocity of the step from t_k to t_k + h "
    "(≈ Ω(t_k + h/2)); the paper computes the energy from Ω_k with Γ_k and S_k, which mixes two instants "
    "and so adds an O(h) error of the diagnostic itself (\"paper convention\").")


def run_members(scene, method, omega0, R0, *, h: float, steps: int, every: int = 1, attitude: bool = False,
                physics: Physics | None = None, **kw) -> Trajectory:
    """Members with the initial conditions ``omega0`` (n, 3) and ``R0`` (n, 3, 3) run with ``method`` (a label or its
    :func:`method_choice`) at step ``h`` for ``steps`` steps, keeping every ``every``-th node, through the run layer:
    the scene with the method's keys and this step, resolved as every run of it is
    (:func:`liethermo.top.resolve.resolve`: physics, method choice, Newton settings, ensemble loop, device).
    ``physics``: the members' own parameters (one row per member) instead of the scene's.  The studies keep the
    exact 1/T beyond the cubic's range (no heat bound, ``heat_bound=None``) unless ``kw`` says otherwise; ``kw``:
    further keywords of :func:`liethermo.top.simulate.simulate` (``threads``, ``chunk_steps``, …)."""
    spec = method_choice(method) if isinstance(method, str) else method
    run = resolve(scene.with_overrides({**spec.overrides(), "integrator.h": float(h), "integrator.steps": int(steps),
                                        "output.every": int(every), "output.attitude": bool(attitude)}))
    if dataclasses.replace(run.choice, label=spec.label) != spec:
        raise StudyError(f"method {method!r}: the scene resolves it to {run.choice}")
    return run.simulate(omega0, R0, physics=physics, **{"heat_bound": None, **kw})


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


def status_units(not_run: bool = False) -> tuple[str, str]:
    """(units, long_name) of a member status variable of a study; ``not_run``:
    -1 marks a member the method did not run."""
    from ..simulate import STATUS_MEANINGS

    codes = ([(-1, "not run")] if not_run else []) + sorted(STATUS_MEANINGS.items())
    return "1", "member status (" + ", ".join(f"{k} {v}" for k, v in codes) + ")"


@functools.lru_cache(maxsize=256)
def method_choice(label: str):
    """The :class:`liethermo.top.methods.MethodChoice` of a method label of the top
    (``"vi"``, ``"vi:node:explicit"``, ``"vi4:triple_jump"``): its name,
    family, effective start, friction, entropy update and composition, and the
    scene overrides that run it; a bad label is a :class:`StudyError`."""
    from ..methods import MethodChoice

    try:
        return MethodChoice.parse(label)
    except ValueError as exc:
        raise StudyError(f"methods: {exc}") from None
