"""The continuous equations of a model (body frame), as lane functions.

With μ = 𝕀Ω, forces f (frictions and conservative torques) and the internal
energy U(S):

    d(𝕀Ω)/dt = 𝕀Ω×Ω + Σ f,      Γ̇ = Γ×Ω,      T Ṡ = −Σ⟨f_friction, Ω⟩,
    Ṙ = R Ω̂                        (only if the attitude is integrated)

For a constant inertia, Ω̇ takes Euler's form, Ω̇₁ = A₁Ω₂Ω₃ + (𝕀⁻¹Σf)₁
(and cyclically; A from :mod:`.terms.inertia`), T = U′(S) and
Ṡ = P/T(S).  For an entropy-dependent inertia 𝕀(S) = s(S)𝕀₀ (s = φ²,
φ(S) and φ′ = dφ/dS the inertia part's own, :func:`.terms.inertia_scale`
and :func:`.terms.inertia_scale_rate`; the coupled top's φ = 1 + α(θ − T₀),
θ = U′(S)), the temperature is T = −∂L/∂S = θ − ½Ω·𝕀′(S)Ω = θ − φφ′ Ω·𝕀₀Ω
(:func:`.terms.temperature_correction`), and

    Ω̇ = A(Ω) + 𝕀₀⁻¹Σf / s − 2(φ′/φ) Ṡ Ω,

so that E = ½Ω·𝕀(S)Ω + V(Γ) + U(S) is conserved.  Every kernel (explicit
steps, the reference, the variational integrator's Newton predictor) calls
these functions, so they all integrate the same model.
"""

from __future__ import annotations

from ._jit import fma, lane
from .dispatch import generic, has_capability, is_present
from .gen import madd, or_zero
from .so3 import attitude_rate_lane, cross_lane
from .terms import (NONE3, inertia_scale, inertia_scale_rate, sum_angular_acceleration, sum_dissipated_power,
                    temperature_correction)
from .terms.thermo import entropy_rate, temperature


#: the inertia's capability that brings the entropy into the motion
_COUPLED = "entropy_dependent_inertia"


def coupled_inertia(model) -> bool:
    """Key: whether a model's (or its numba type's) inertia part makes the
    inertia depend on the entropy (the coupled top)."""
    fields = getattr(model, "fields", None)
    inertia = model.types[fields.index("inertia")] if fields is not None else model.inertia
    return has_capability(inertia, _COUPLED)


@generic(coupled_inertia)
def omega_rate(model, w0, w1, w2, G0, G1, G2, s, exact):
    """Ω̇ (rad s⁻²) at (Ω, Γ, σ)."""
    I = model.inertia
    a0, a1, a2 = sum_angular_acceleration(model.forces, I, None, (w0, w1, w2), (G0, G1, G2), NONE3)
    return madd(I.A1 * w1, w2, a0), madd(I.A2 * w2, w0, a1), madd(I.A3 * w0, w1, a2)


@omega_rate.register(True)
def omega_rate_coupled(model, w0, w1, w2, G0, G1, G2, s, exact):
    wd, _ = _thermal_rates(model, w0, w1, w2, G0, G1, G2, s)
    return wd


@lane
def _thermal_rates(model, w0, w1, w2, G0, G1, G2, s):
    """((Ω̇), σ̇) of the coupled top (see module docstring)."""
    I = model.inertia
    th = model.thermo
    theta = temperature(th, s)
    # φ, Ω·𝕀₀Ω and T written as the variational integrator writes them, so that
    # where both run on the same (Ω, σ) (its predictor) LLVM computes them once
    phi = inertia_scale(I, th, theta)
    sc = phi * phi
    dphi = inertia_scale_rate(I, th, theta)
    K2 = fma(I.I1 * w0, w0, fma(I.I2 * w1, w1, (I.I3 * w2) * w2))
    T = theta - temperature_correction(I, th, theta, K2)
    P = sum_dissipated_power(model.forces, I, sc, (w0, w1, w2), None)
    sd = or_zero(P) / T
    a0, a1, a2 = sum_angular_acceleration(model.forces, I, sc, (w0, w1, w2), (G0, G1, G2), NONE3)
    k = (2.0 * dphi / phi) * sd
    isc = 1.0 / sc
    wd = (madd(I.A1 * w1, w2, or_zero(a0) * isc - k * w0),
          madd(I.A2 * w2, w0, or_zero(a1) * isc - k * w1),
          madd(I.A3 * w0, w1, or_zero(a2) * isc - k * w2))
    return wd, sd


@generic(coupled_inertia)
def entropy_and_omega_rates(model, w0, w1, w2, G0, G1, G2, s, exact):
    """((Ω̇), σ̇ or None, small)."""
    P = sum_dissipated_power(model.forces, model.inertia, None, (w0, w1, w2), None)
    sd, small = entropy_rate(model.thermo, P, s, exact)
    return omega_rate(model, w0, w1, w2, G0, G1, G2, s, exact), sd, small


@entropy_and_omega_rates.register(True)
def entropy_and_omega_rates_coupled(model, w0, w1, w2, G0, G1, G2, s, exact):
    wd, sd = _thermal_rates(model, w0, w1, w2, G0, G1, G2, s)
    return wd, sd, True


@generic(is_present)
def attitude_rate(R, w0, w1, w2):
    """Ṙ = RΩ̂ (9-tuple), or None without the attitude."""
    return None


@attitude_rate.register(True)
def attitude_rate_present(R, w0, w1, w2):
    return attitude_rate_lane(R, w0, w1, w2)


@lane
def rk_rhs(model, y, exact):
    """(f(y), small) for the part-wise state y = (Ω, Γ, σ, R) of the ``rk`` layout;
    ``small`` says whether the inline exp was valid (always with ``exact``)."""
    w, G, s, R = y
    wd, sd, small = entropy_and_omega_rates(model, w[0], w[1], w[2], G[0], G[1], G[2], s, exact)
    Gd = cross_lane(G[0], G[1], G[2], w[0], w[1], w[2])
    return (wd, Gd, sd, attitude_rate(R, w[0], w[1], w[2])), small


_RHS7: dict = {}


def rhs7_function(template):
    """A jitted ``f(p, y, out)``: the continuous equations of one member of a
    model of ``template``'s type, with its parameters ``p`` (the flat row of
    :func:`liethermo.top.physics.build_model`), on y = (Ω, Γ, σ) (7,), written to
    ``out``: Ω̇, Γ̇ = Γ×Ω and σ̇ (0 when nothing dissipates).  For callers
    that step one member from Python (scipy's ``solve_ivp``); compiled once
    per model type."""
    import numba

    from .gen import compile_source, unflatten

    key = str(numba.typeof(template))
    fn = _RHS7.get(key)
    if fn is None:
        ns = {"TEMPLATE": template, "unflatten": unflatten, "rates": entropy_and_omega_rates,
              "or_zero": or_zero}
        src = ("def rhs7(p, y, out):\n"
               "    model = unflatten(TEMPLATE, p, 0, 1)\n"
               "    wd, sd, small = rates(model, y[0], y[1], y[2], y[3], y[4], y[5], y[6], True)\n"
               "    out[0], out[1], out[2] = wd\n"
               "    out[3] = y[4] * y[2] - y[5] * y[1]\n"
               "    out[4] = y[5] * y[0] - y[3] * y[2]\n"
               "    out[5] = y[3] * y[1] - y[4] * y[0]\n"
               "    out[6] = or_zero(sd)\n")
        fn = numba.njit(cache=False, error_model="numpy")(
            compile_source(src, ns, "rhs7", f"rhs7 {key}"))
        _RHS7[key] = fn
    return fn
