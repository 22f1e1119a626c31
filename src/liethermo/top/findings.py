"""What a run shows: the lines of its summary that state the point of its physics.

Each finding is chosen by what the run's physics contains, never by the
scene's name, so a scene of one's own with the same physics gets the same
lines:

* **exact solution** — a spherical top (𝕀₀ = I₀·Id) whose every term keeps
  the law ``LAW_SPHERICAL_DECAY`` (its torque is −cΩ with one c, or 0 when
  μ ∥ Ω): μ ∥ Ω, so (docs/model.md, "Exact solutions used in the tests")

      Ω(t) = Ω₀ e^{−ct/I₀},   Γ(t) = Rot(Ω₀/|Ω₀|, −φ(t)) Γ₀,   φ(t) = (I₀|Ω₀|/c)(1 − e^{−ct/I₀}),
      S(t) = S₀ + c_v log(1 + I₀|Ω₀|²(1 − e^{−2ct/I₀}) / (2 c_v T₀)),

  and the summary gives the run's largest error against it;
* **Ω₃ exactly** — a Lagrange top (I₁ = I₂) whose terms keep
  ``LAW_LAGRANGE_OMEGA3`` (nothing acts on the third axis but −C₃Ω₃; the
  paper's top): Ω₃(t) = Ω₃(0) e^{−C₃t/I₃} (docs/model.md), and the summary
  gives its largest error;
* **|μ|** — every term keeps ``LAW_MOMENTUM_NORM`` (no torque, or one ⟂ μ):
  |μ| is conserved by the continuous system, and the summary gives its drift;
* **spin axis** — a friction at constant |μ|: the body ends spinning about
  its major axis (largest moment, when it is unique); the summary gives the
  angle between Ω and that axis at the start and at the end;
* **heating** — any friction: the temperature change T(end) − T(0) (K), from the
  temperature at t = 0 (not the key thermo.T0 when the inertia depends on S);
* **inertia** — a term that makes the inertia depend on S: the change of the
  inertia over the run (%);
* **what the terms' parameters set** — each term's own lines
  (``Term.summary_lines``), e.g. a friction tensor and its decay times.

The terms say which members keep each law (``Term.keeps``); c and C₃ are
read off the sum of the terms' torques, so nothing here names a term.

:func:`chunk_findings` measures one member chunk (from its dataset and
:class:`~liethermo.top.physics.Physics`) as ``{name: [min, max]}`` over its
members that completed; :func:`merge_findings` combines chunks (also chunks
computed elsewhere: the values are plain JSON); :func:`finding_lines`
phrases them.
"""

from __future__ import annotations

import numpy as np

from . import physics as ph
from .kernels.reductions import decay_error_span
from .kernels.terms import norm3

#: relative spread under which per-member values count as equal (isotropy tests)
_RTOL = 1e-12
AXIS = "xyz"


def exact_spherical_top(I0, c, cv, T0, omega0, gamma0, t):
    """The spherical top's exact solution (Ω, Γ, σ = S − S₀) at times t (T,),
    for members with moments I0 (N,) kg m², friction c (N,) N m s, heat
    capacity cv (N,) J/K, temperature T0 (N,) K, and Ω₀, Γ₀ (N, 3).
    Returns arrays (N, T, 3), (N, T, 3), (N, T); c = 0 gives the free
    rotation (Ω constant, Γ turning by |Ω₀|t)."""
    I0, c, cv, T0 = (np.asarray(x, dtype=float)[:, None] for x in (I0, c, cv, T0))
    t = np.asarray(t, dtype=float)[None, :]
    x = c * t / I0
    w = np.linalg.norm(omega0, axis=-1)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(x > 0, -np.expm1(-x) / np.where(x > 0, x, 1.0), 1.0)  # (1 − e^{−x})/x
    omega = np.exp(-x)[..., None] * omega0[:, None, :]
    ang = -(w * t * frac)[..., None]  # Γ turns by −φ about Ω₀ (Γ̇ = −Ω × Γ)
    k = omega0 / np.where(w > 0, w, 1.0)
    k, v = k[:, None, :], gamma0[:, None, :]
    gamma = (v * np.cos(ang) + np.cross(k, v) * np.sin(ang)
             + k * np.sum(k * v, axis=-1, keepdims=True) * (1.0 - np.cos(ang)))
    with np.errstate(invalid="ignore", divide="ignore"):
        sigma = np.where(cv > 0, cv * np.log1p(I0 * w * w * (-np.expm1(-2.0 * x)) / (2.0 * cv * T0)), 0.0)
    return omega, gamma, sigma


def _equal(a: np.ndarray) -> np.ndarray:
    """Rows of a (N, 3) whose three entries are equal (to _RTOL)."""
    return np.ptp(a, axis=-1) <= _RTOL * np.max(np.abs(a), axis=-1)


def _linear_friction(phys: ph.Physics, axis: int) -> np.ndarray:
    """(N,) C_axis = −f_axis(Ω = e_axis, Γ = e₃): the linear friction on one
    body axis, from every term's torque (exact for the members that keep
    the law being checked: there the torque is −CΩ, or 0 on that axis)."""
    e = np.zeros((phys.n, 3))
    e[:, axis] = 1.0
    g = np.zeros((phys.n, 3))
    g[:, 2] = 1.0
    return -ph.torque(phys, e, g)[:, axis]


def _span(values) -> list[float] | None:
    """[min, max] of the finite values (None if there are none)."""
    v = np.asarray(values, dtype=float)
    if v.size:
        lo, hi = float(np.min(v)), float(np.max(v))  # both finite and not 0: no NaN, no inf, one sign of zero
        if lo != 0.0 and hi != 0.0 and np.isfinite(lo) and np.isfinite(hi):
            return [lo, hi]
    finite = np.isfinite(v)
    lo = float(np.min(v, where=finite, initial=np.inf))
    return [lo, float(np.max(v, where=finite, initial=-np.inf))] if lo != np.inf else None


def _decay(c: np.ndarray, inertia: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``np.exp(-(c / inertia)[:, None] * t[None, :])`` (M, T): computed on one row and
    broadcast where every member shares c and the inertia (views of one row), with
    the same bits (numpy's exp gives a value the same bits wherever it stands in a
    contiguous array)."""
    if len(c) > 1 and c.strides[0] == 0 and inertia.strides[0] == 0:
        return np.broadcast_to(np.exp(-(c[:1] / inertia[:1])[:, None] * t[None, :]), (len(c), len(t)))
    return np.exp(-(c / inertia)[:, None] * t[None, :])


def _max_over_t(x: np.ndarray) -> np.ndarray:
    """``np.max(x, axis=1)`` of values (M, T) that are ≥ 0 or NaN, in T − 1 passes of
    ``np.maximum`` where T is short (numpy reduces a short inner axis slowly): the same
    values, NaN where a row has one."""
    if x.ndim != 2 or not 1 <= x.shape[1] <= 8:
        return np.max(x, axis=1)
    out = x[:, 0].copy()
    for k in range(1, x.shape[1]):
        np.maximum(out, x[:, k], out=out)
    return out


def _parameter_facts(phys: ph.Physics) -> dict:
    """Per member, what its parameters alone decide: which exact laws apply, the
    linear friction on axes 1 and 3, the major axis.  For members that share one
    row of parameters (:attr:`~liethermo.top.physics.Physics.uniform`) they are
    worked out once per row of values (every chunk of a run has the same row)
    and broadcast."""
    return phys.per_row(_row_facts)


def _row_facts(phys: ph.Physics) -> dict:
    """:func:`_facts` of ``phys``; of one member, kept by its values (:data:`_ROW_FACTS`)."""
    if phys.n != 1:
        return _facts(phys)
    key = _row_key(phys)
    facts = _ROW_FACTS.get(key)
    if facts is None:
        if len(_ROW_FACTS) >= 8:
            _ROW_FACTS.clear()
        facts = _ROW_FACTS[key] = _facts(phys)
        for v in facts.values():
            if isinstance(v, np.ndarray):
                v.flags.writeable = False  # shared by every chunk with these values
    return dict(facts)


#: the facts of one row of parameters, by the row's values (:func:`_row_key`)
_ROW_FACTS: dict = {}


def _row_key(one: ph.Physics) -> tuple:
    """The values of a one-member Physics, as a key: every field, arrays by their type, shape and bytes."""
    import dataclasses

    out = []
    for f in dataclasses.fields(one):
        v = getattr(one, f.name)
        out.append((f.name, v.dtype.str, v.shape, v.tobytes()) if isinstance(v, np.ndarray) else (f.name, repr(v)))
    return tuple(out)


def _facts(phys: ph.Physics) -> dict:
    """:func:`_parameter_facts` of every member of ``phys``, one by one."""
    from .kernels.terms import LAW_LAGRANGE_OMEGA3, LAW_MOMENTUM_NORM, LAW_SPHERICAL_DECAY, registry

    acting = phys.acting()
    srt = np.sort(phys.inertia, axis=-1)
    frictions = np.any([acting[t.name] for t in registry() if t.friction], axis=0)
    return {
        "no_torque": phys.keeps(LAW_MOMENTUM_NORM),  # forces ⟂ μ only: |μ| is kept
        "spherical": _equal(phys.inertia) & phys.keeps(LAW_SPHERICAL_DECAY),
        "c1": _linear_friction(phys, 0),  # the same on every axis for the spherical members
        "lagrange": ((np.abs(phys.inertia[:, 0] - phys.inertia[:, 1]) <= _RTOL * phys.inertia[:, 2])
                     & phys.keeps(LAW_LAGRANGE_OMEGA3)),
        "c3": _linear_friction(phys, 2),
        "unique_major": srt[:, 2] > srt[:, 1] * (1.0 + 1e-9),
        "major": np.argmax(phys.inertia, axis=-1),
        "frictions": frictions,
        "sets_inertia": np.any([acting[t.name] for t in registry() if t.sets_inertia], axis=0),
    }


def chunk_findings(ds, phys: ph.Physics) -> dict:
    """``{name: [min, max]}`` over the chunk's members that completed (and to
    which the finding applies); ``ds`` is the chunk's dataset (or any mapping of
    its labelled variables, read only where a finding applies), ``phys`` its
    physics (one row per member)."""
    ok = ds["status"].values == 0
    tdim = ds["omega"].dims[1]  # the time dimension, whatever its name
    t = np.asarray(ds[tdim].values, dtype=float)
    om = ds["omega"].values
    # each exact law below holds on the members whose every term keeps it
    facts = _parameter_facts(phys)
    out: dict = {}

    def put(name, sel, values):
        if isinstance(sel, np.ndarray) and sel.all():
            sel = slice(None)  # every member: no copy
        s = _span(np.asarray(values)[sel])
        if s is not None:
            out[name] = s

    # the spherical top's exact solution
    sph = ok & facts["spherical"]
    if sph.any():
        gamma, S = ds["gamma"].values[sph], ds["entropy"].values[sph]
        om0 = ds["initial_omega"].values[sph]  # Ω(0), Γ(0) = R(0)ᵀe₃ of the initial data
        g0 = ds["initial_attitude"].values[sph, 2, :]
        T0 = ds["temperature"].values[sph, 0]  # θ(S₀) = T₀ for a constant inertia
        e_om, e_g, e_s = exact_spherical_top(phys.inertia[sph, 0], facts["c1"][sph],
                                             phys.heat_capacity[sph], T0, om0, g0, t)
        w0 = np.linalg.norm(om0, axis=-1)
        sig = S - S[:, :1]
        with np.errstate(invalid="ignore", divide="ignore"):
            put("exact_omega", slice(None), _max_over_t(np.linalg.norm(om[sph] - e_om, axis=-1)) / w0)
            put("exact_gamma", slice(None), _max_over_t(np.linalg.norm(gamma - e_g, axis=-1)))
            d_s = _max_over_t(np.abs(sig - e_s))
            put("exact_entropy", slice(None), d_s)
            produced = e_s[:, -1]
            put("exact_entropy_rel", produced > 0, d_s / np.where(produced > 0, produced, 1.0))

    # the Lagrange top's Ω₃ (I₁ = I₂, no torque on the third axis but −C₃Ω₃)
    lag = ok & ~sph & facts["lagrange"]
    if lag.all():
        lag = slice(None)  # every member: views, not copies
    if isinstance(lag, slice) or lag.any():
        om0 = ds["initial_omega"].values[lag]
        decay = _decay(facts["c3"][lag], phys.inertia[lag, 2], t)  # e^{−C₃t/I₃} (M, T)
        with np.errstate(invalid="ignore", divide="ignore"):
            if hasattr(decay_error_span, "overloads"):  # one compiled pass, numpy's values
                span = np.empty(3)
                decay_error_span(om[lag, :, 2], om0[:, 2], decay, norm3(om0), span)
                if span[2] > 0:
                    out["exact_omega3"] = [float(span[0]), float(span[1])]
            else:  # NUMBA_DISABLE_JIT
                put("exact_omega3", slice(None),
                    _max_over_t(np.abs(om[lag, :, 2] - om0[:, 2:3] * decay)) / norm3(om0))

    # |μ| without external torque
    free = ok & facts["no_torque"]
    if free.any():
        mu = ds["angular_momentum_norm"].values
        with np.errstate(invalid="ignore", divide="ignore"):
            put("mu_drift", free, _max_over_t(np.abs(mu - mu[:, :1])) / mu[:, 0])

    # the flat spin: a friction that keeps |μ|, a unique major axis
    flat = free & facts["frictions"] & facts["unique_major"]  # dissipation at constant |μ| ends at the major axis
    if flat.any():
        major = facts["major"]
        rows = np.arange(om.shape[0])
        with np.errstate(invalid="ignore", divide="ignore"):
            cos = np.abs(om[rows, :, major]) / np.linalg.norm(om, axis=-1)
        ang = np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))  # (N, T)
        put("spin_axis_start", flat, ang[:, 0])
        put("spin_axis_end", flat, ang[:, -1])
        put("major_axis", flat, major)
        put("t_end", flat, np.full(om.shape[0], t[-1]))

    # heating and the inertia's change
    warm = ok & facts["frictions"]
    if warm.any():
        T = ds["temperature"].values
        put("heating", warm, T[:, -1] - T[:, 0])
        put("T_start", warm, T[:, 0])
        put("T_end", warm, T[:, -1])
    grow = warm & facts["sets_inertia"]
    if grow.any():
        sigma = ds["entropy"].values - ds["entropy"].values[:, :1]
        s = np.broadcast_to(ph.inertia_scale(phys, sigma), sigma.shape)
        put("inertia_change", grow, 100.0 * (s[:, -1] / s[:, 0] - 1.0))
    return out


def merge_findings(a: dict, b: dict) -> dict:
    """The findings of two chunks together (``a`` is updated and returned)."""
    for k, (lo, hi) in b.items():
        if k in a:
            a[k] = [min(a[k][0], lo), max(a[k][1], hi)]
        else:
            a[k] = [lo, hi]
    return a


def _range(span, fmt: str, unit: str = "") -> str:
    """``x unit``, or ``lo to hi unit over the members`` when they differ as printed."""
    lo, hi = span
    u = f" {unit}" if unit else ""
    a, b = f"{lo:{fmt}}", f"{hi:{fmt}}"
    if a == b:
        return f"{b}{u}"
    return f"{a} to {b}{u} over the members"


def _round_off(x: float) -> str:
    return "kept to round-off" if x < 1e-12 else "not kept to round-off by this method"


def physics_lines(phys: ph.Physics) -> list[str]:
    """The lines that the parameters alone give (member 0's, or their range)."""
    from .kernels.terms import registry

    return [line for t in registry() for line in t.summary_lines(phys)]


def finding_lines(found: dict) -> list[str]:
    """The summary lines of the merged findings."""
    out = []
    if "exact_omega" in found:
        s_rel = (f" ({found['exact_entropy_rel'][1]:.2e} of the entropy produced)"
                 if "exact_entropy_rel" in found else "")
        out += ["  exact solution            spherical top (isotropic inertia, torque -c Omega only);",
                f"                            max over the run: |Omega - exact|/|Omega_0| {found['exact_omega'][1]:.2e}, "
                f"|Gamma - exact| {found['exact_gamma'][1]:.2e},",
                f"                            |S - exact| {found['exact_entropy'][1]:.2e} J/K{s_rel}"]
    if "exact_omega3" in found:
        out += ["  exact Omega_3             Lagrange top (I_1 = I_2, no torque on z but -C_3 Omega_3): "
                "Omega_3(0) exp(-C_3 t/I_3);",
                f"                            max over the run |Omega_3 - exact|/|Omega_0| {found['exact_omega3'][1]:.2e}"]
    if "mu_drift" in found:
        x = found["mu_drift"][1]
        out.append(f"  |mu| (no external torque) max ||mu_k| - |mu_0||/|mu_0| {x:.2e}: {_round_off(x)}")
    if "spin_axis_end" in found:
        lo, hi = found["major_axis"]
        axis = f"{AXIS[int(lo)]}, " if lo == hi else ""
        out += [f"  spin axis                 angle of Omega to the major axis ({axis}largest moment): "
                f"{_range(found['spin_axis_start'], '.3g', 'deg')} at t = 0,",
                f"                            {_range(found['spin_axis_end'], '.3g', 'deg')} at t = "
                f"{found['t_end'][1]:g} s (internal friction turns it to the major axis)"]
    if "heating" in found:
        out.append(f"  heating                   T(end) - T(0) = {_range(found['heating'], '.4g', 'K')} "
                   f"(T(0) = {_range(found['T_start'], '.5g', 'K')}; T(end) = {_range(found['T_end'], '.5g', 'K')})")
    if "inertia_change" in found:
        out.append(f"  inertia I(S)              I(S_end) - I(S_0) = "
                   f"{_range(found['inertia_change'], '+.3g', '%')} of I(S_0)")
    return out
