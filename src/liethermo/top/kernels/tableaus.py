"""The Butcher tableaus of the explicit Runge–Kutta methods, as data.

Plain Python (no numba), so that the method table (:mod:`liethermo.top.methods`)
reads orders and stage counts without loading the kernels; the step they
define is :func:`liethermo.top.kernels.rk.explicit_step`.
"""

from __future__ import annotations

import functools
from collections import namedtuple


class Tableau(tuple):
    """Base of the tableau marker classes (a namedtuple with one unused field);
    the class attributes are the data."""

    __slots__ = ()
    A: tuple = ()
    b: tuple = ()
    c: tuple = ()
    order: int = 0
    stages: int = 0


def _set(cls, A, b, c, order: int):
    cls.A = tuple(tuple(float(x) for x in row) for row in A)
    cls.b = tuple(float(x) for x in b)
    cls.c = tuple(float(x) for x in c)
    cls.order = order
    cls.stages = len(cls.b)
    return cls


class Midpoint(namedtuple("Midpoint", "unused"), Tableau):
    __slots__ = ()


class ClassicalRK4(namedtuple("ClassicalRK4", "unused"), Tableau):
    __slots__ = ()


class DOP853(namedtuple("DOP853", "unused"), Tableau):
    """Filled from scipy on first use (:func:`dop853`)."""

    __slots__ = ()
    order = 8
    stages = 12


_set(Midpoint, [[], [0.5]], [0.0, 1.0], [0.0, 0.5], 2)
_set(ClassicalRK4, [[], [0.5], [0.0, 0.5], [0.0, 0.0, 1.0]],
     [1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0], [0.0, 0.5, 0.5, 1.0], 4)
MIDPOINT = Midpoint(0.0)
RK4 = ClassicalRK4(0.0)

#: the tableaus by name (:func:`tableau` gives the marker the kernels take)
TABLEAUS = {"midpoint": Midpoint, "rk4": ClassicalRK4, "dop853": DOP853}


@functools.cache
def dop853():
    """The DOP853 tableau (first 12 stages: the 8th-order solution); loads
    scipy.integrate (~0.3 s) on first use."""
    from scipy.integrate._ivp import dop853_coefficients as dop

    A = [[float(dop.A[i, j]) for j in range(i)] for i in range(12)]
    _set(DOP853, A, [float(x) for x in dop.B], [float(x) for x in dop.C[:12]], 8)
    return DOP853(0.0)


def tableau(name: str):
    """The marker instance of the tableau ``name`` (loading DOP853's from scipy)."""
    if name == "dop853":
        return dop853()
    return TABLEAUS[name](0.0)
