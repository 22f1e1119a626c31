"""Numerics shared by more than one model, with no model of their own: the
ideal solid's heat (:mod:`.heat`), the symmetric compositions of an order-2
step (:mod:`.compositions`), the names of the discrete laws a method keeps
(:mod:`.laws`) and the kernels' numba options (:mod:`.jit`)."""
