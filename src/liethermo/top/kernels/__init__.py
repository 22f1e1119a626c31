"""Numba kernels: plain floats and arrays only (no xarray, no I/O).

Every kernel writes into caller-allocated arrays.  The pieces:

- :mod:`.terms`: the model's terms (inertia, internal energy, Stokes and
  double-bracket friction, gravity), each a named tuple of its parameters
  with the functions the integrators call on it; a run's model holds only
  the terms some member needs, so a term a scene switches off costs nothing.
- :mod:`.equations`: the continuous equations of a model (the right-hand side
  of the Runge-Kutta methods).
- :mod:`.rk`, :mod:`.vi`: one step of the explicit Runge-Kutta tableaus and of
  the variational integrator in node form (with its compositions).
- :mod:`.layout`: the columns of the flat state of each method family and the
  status codes; :mod:`.gen`: helpers that make code generic over a model.
- :mod:`.simple` (one member per loop iteration) and :mod:`.fast`
  (structure-of-arrays blocks of members, vectorized): the ensemble loops;
  :mod:`.parallel` runs them on threads.
"""
