"""Numba kernels: plain floats and arrays only (no xarray, no I/O).

Every kernel writes into caller-allocated arrays.  Layouts of the flat state
and parameter vectors are documented in :mod:`liethermo.kernels.model`.
"""
