"""The integrators liethermo offers, declared as data (cf. scipy's ``rk.py``).

Each method states its order (on the variables it is compared on), whether it
is implicit, how many right-hand-side evaluations a step costs, and which
discrete laws hold for its solutions to round-off.  Tests and studies read
these declarations instead of hard-coding them.
"""

from __future__ import annotations

from dataclasses import dataclass

from .kernels.ensemble import METHOD_REFERENCE, METHOD_RK2, METHOD_RK4, METHOD_VI

#: Laws a method may satisfy exactly (to round-off).
LAW_UNIT_GAMMA = "unit_gamma"  # | |Γ_k| − 1 | at round-off
LAW_ROTATION = "rotation"  # R_kᵀR_k = I at round-off (attitude)
LAW_ENTROPY_MONOTONE = "entropy_monotone"  # S_{k+1} ≥ S_k
LAW_KELVIN_NOETHER = "kelvin_noether"  # discrete Kelvin–Noether law of SPEC §4


@dataclass(frozen=True)
class Method:
    name: str
    kernel_id: int
    description: str
    #: order of convergence, by start ("node" / "staggered"; explicit methods
    #: ignore the start)
    order_node: int
    order_staggered: int
    implicit: bool
    rhs_evals_per_step: int
    laws: tuple[str, ...]

    #: order with endpoint friction f = cX (E3): the friction is then evaluated
    #: half a step off the centre of the momentum equation, so the VI is first
    #: order whatever the start (measured: slopes 1.13-1.3 falling towards 1)
    order_endpoint: int | None = None

    def order(self, start: str = "node", friction: str = "trapezoid") -> int:
        if friction == "endpoint" and self.order_endpoint is not None:
            return self.order_endpoint
        return self.order_staggered if start == "staggered" else self.order_node


METHODS: dict[str, Method] = {
    "vi": Method(
        "vi", METHOD_VI,
        "variational integrator (Cayley map, explicit entropy, Newton momentum solve)",
        order_node=1, order_staggered=2, implicit=True, rhs_evals_per_step=0, order_endpoint=1,
        laws=(LAW_UNIT_GAMMA, LAW_ROTATION, LAW_ENTROPY_MONOTONE, LAW_KELVIN_NOETHER),
    ),
    "rk2": Method(
        "rk2", METHOD_RK2, "explicit midpoint Runge-Kutta (order 2)",
        order_node=2, order_staggered=2, implicit=False, rhs_evals_per_step=2, laws=(),
    ),
    "rk4": Method(
        "rk4", METHOD_RK4, "classical Runge-Kutta (order 4)",
        order_node=4, order_staggered=4, implicit=False, rhs_evals_per_step=4, laws=(),
    ),
    "reference": Method(
        "reference", METHOD_REFERENCE,
        "fixed-step DOP853 (order 8) with substeps: high-accuracy reference",
        order_node=8, order_staggered=8, implicit=False, rhs_evals_per_step=12, laws=(),
    ),
}

FRICTION = {"trapezoid": (0.5, 0.5), "endpoint": (1.0, 0.0)}
STARTS = ("node", "staggered")


def get_method(name: str) -> Method:
    try:
        return METHODS[name]
    except KeyError:
        raise ValueError(
            f"unknown integrator.method {name!r}: expected one of {sorted(METHODS)}"
        ) from None
