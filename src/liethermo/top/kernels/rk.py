"""Explicit Runge–Kutta methods from their Butcher tableaus.

A method is data (cf. scipy's ``integrate/_ivp/rk.py``): the tableau
(``A``, ``b``, ``c``) and its order, held as class attributes of a marker
namedtuple whose *type* the kernels are compiled for.  :func:`explicit_step`
turns a tableau into straight-line code at compile time: the stage values
stay in registers as part-wise states (:mod:`.layout`), zero coefficients
are skipped, every product h·a_ij is one multiplication, every stage sum a
chain of fused multiply-adds onto y.  Both ensemble kernels call it, so they
compute the same bits; the vectorized kernel calls it on a lane of its rows.

* :data:`MIDPOINT` — explicit midpoint (the paper's "standard Runge–Kutta of
  order 2"), 2 evaluations;
* :data:`RK4` — classical Runge–Kutta, order 4, 4 evaluations;
* :func:`dop853` — the 8th-order solution of Dormand–Prince 8(5,3), 12
  stages (scipy's ``dop853_coefficients``), at fixed step with substeps: the
  high-accuracy reference.

None of these preserves |Γ| = 1, RᵀR = I or the discrete Kelvin–Noether law.
"""

from __future__ import annotations

from numba.extending import overload

from ._jit import LANE_OPTIONS
from .equations import rk_rhs
from .gen import compile_source, tree_fma
from .split import Splitting, register, split_step
from .tableaus import (DOP853, MIDPOINT, RK4, TABLEAUS, ClassicalRK4, Midpoint, Tableau,  # noqa: F401
                       dop853, tableau)


def explicit_step(tab, model, y, h, exact):
    """(y', small): one step of size h of the tableau ``tab`` from the
    ``rk``-layout state y; ``small`` says whether every stage's inline exp was
    valid (always with ``exact``).  A splitting marker (:mod:`.split`) takes
    its own step, on the ``split``-layout state."""
    cls = type(tab)
    if isinstance(tab, Splitting):
        return split_step(tab, model, y, h, exact)
    k, small = [], True
    for i in range(cls.stages):
        z = y
        for j, a in enumerate(cls.A[i]):
            if a != 0.0:
                z = tree_fma(h * a, k[j], z)
        ki, si = rk_rhs(model, z, exact)
        k.append(ki)
        small = small & si
    z = y
    for j, bj in enumerate(cls.b):
        if bj != 0.0:
            z = tree_fma(h * bj, k[j], z)
    return z, small


@overload(explicit_step, jit_options=LANE_OPTIONS)
def _explicit_step(tab, model, y, h, exact):
    cls = getattr(tab, "instance_class", None)
    if not (isinstance(cls, type) and issubclass(cls, Tableau)) or not cls.stages:
        return None
    lines = ["def impl(tab, model, y, h, exact):"]
    small = []
    for i in range(cls.stages):
        z = "y"
        for j, a in enumerate(cls.A[i]):
            if a != 0.0:
                lines.append(f"    z{i} = tree_fma(h * {a!r}, k{j}, {z})")
                z = f"z{i}"
        lines.append(f"    k{i}, s{i} = rk_rhs(model, {z}, exact)")
        small.append(f"s{i}")
    z = "y"
    for j, bj in enumerate(cls.b):
        if bj != 0.0:
            lines.append(f"    yn{j} = tree_fma(h * {bj!r}, k{j}, {z})")
            z = f"yn{j}"
    lines.append(f"    return {z}, {' & '.join(small)}")
    return compile_source("\n".join(lines) + "\n", {"tree_fma": tree_fma, "rk_rhs": rk_rhs},
                          label=f"explicit_step {cls.__name__}")


register(explicit_step)
