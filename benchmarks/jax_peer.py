"""The peer of the GPU check: RK4 of the paper's top written in JAX with ``vmap``.

The same equations as liethermo's ``rk4`` on the paper scene's terms (gravity,
isotropic or diagonal Stokes friction, an ideal solid's entropy):

    𝕀Ω̇ = 𝕀Ω × Ω + Γ × g⃗ − CΩ,   Γ̇ = Γ × Ω,   σ̇ = Ω·CΩ / (T₀ exp(σ/c_v)),

one member's right-hand side, ``jax.vmap`` over the members and
``lax.fori_loop`` over the steps, compiled by ``jax.jit`` in float64.
:func:`rk4_peer` returns the end state and the seconds of the timed call (the
first call, which compiles, is not timed).
"""

from __future__ import annotations

import time

import numpy as np


def rk4_peer(phys, omega0, gamma0, h: float, steps: int, repeat: int = 1):
    """(Ω, Γ, σ at the end as numpy arrays, best seconds over ``repeat`` timed calls)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    from jax import lax

    def rhs(y, p):
        w, G, s = y
        I, g, C, T0, cv = p
        Iw = I * w
        wd = (jnp.cross(Iw, w) + jnp.cross(G, g) - C * w) / I
        Gd = jnp.cross(G, w)
        sd = jnp.sum(C * w * w) / (T0 * jnp.exp(s / cv))
        return wd, Gd, sd

    def axpy(a, x, y):
        return tuple(yi + a * xi for xi, yi in zip(x, y))

    def step(y, p):
        k1 = rhs(y, p)
        k2 = rhs(axpy(0.5 * h, k1, y), p)
        k3 = rhs(axpy(0.5 * h, k2, y), p)
        k4 = rhs(axpy(h, k3, y), p)
        return tuple(yi + (h / 6.0) * (a + 2.0 * b + 2.0 * c + d)
                     for yi, a, b, c, d in zip(y, k1, k2, k3, k4))

    def member(y, p):
        return lax.fori_loop(0, steps, lambda _, z: step(z, p), y)

    run = jax.jit(jax.vmap(member))
    n = omega0.shape[0]
    y0 = (jnp.asarray(omega0), jnp.asarray(gamma0), jnp.zeros(n))
    p = (jnp.asarray(phys.inertia), jnp.asarray(phys.gravity_torque),
         jnp.asarray(np.broadcast_to(phys.stokes_resistance, (n, 3))), jnp.asarray(phys.T0),
         jnp.asarray(phys.heat_capacity))
    out = run(y0, p)
    jax.block_until_ready(out)
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = run(y0, p)
        jax.block_until_ready(out)
        best = min(best, time.perf_counter() - t0)
    return tuple(np.asarray(o) for o in out), best
