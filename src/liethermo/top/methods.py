"""The integrators liethermo offers, declared as data (cf. scipy's ``rk.py``).

A method is data plus the one step of its family: an explicit Runge–Kutta
method is its Butcher tableau (:mod:`liethermo.top.kernels.rk`), a composition
of the variational integrator or of the splitting its substep factors
(:data:`COMPOSITION_FACTORS`: by default Suzuki's and Kahan and Li's,
"small_error"; Yoshida's triple jump as "triple_jump").
Each method states here, and only here, its family, its order on node
values (by start and friction; an RK method's is its tableau's), whether it
is implicit, how much a step costs, and which discrete laws hold for its
solutions to round-off.  Tests, studies and the run driver read these
declarations instead of hard-coding them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..numerics.compositions import COMPOSITION_FACTORS, COMPOSITION_KINDS  # noqa: F401
from ..analysis import ORDER_TOLERANCE, judge_order, order_tolerance  # noqa: F401
from ..numerics.laws import (LAW_CASIMIR, LAW_ENTROPY_MONOTONE, LAW_KELVIN_NOETHER,  # noqa: F401
                             LAW_ROTATION, LAW_UNIT_GAMMA, LAW_VERTICAL_MOMENTUM)

FRICTION = ("trapezoid", "endpoint")
STARTS = ("node", "staggered", "legendre")
ENTROPY_UPDATES = ("explicit", "symmetric")


@dataclass(frozen=True)
class Method:
    """What every method declares; its family's class (:class:`RungeKuttaMethod`,
    :class:`SplittingMethod`, :class:`VariationalMethod`) says how it runs:
    its state layout, its kernel data (:meth:`stepper`), its initial state
    (:meth:`initial_state`) and which scene variants it takes."""

    name: str
    family: str  # "vi", "rk" or "split": a label for tables and files
    description: str
    order_base: int  # on node values, with its best start and trapezoid friction
    implicit: bool
    #: right-hand-side evaluations (rk), Newton solves (vi) or Strang steps (split)
    #: per step, with the default composition
    evaluations_per_step: int
    laws: tuple[str, ...]
    #: the start and entropy update the method always uses (None: the scene's)
    fixed_start: str | None = None
    fixed_entropy: str | None = None
    #: rk: the name of its tableau in :mod:`liethermo.top.kernels.rk` (``TABLEAUS``)
    tableau: str | None = None
    #: vi, split: the order of the composition of the order-2 step (None: the step itself)
    composed: int | None = None

    #: the state layout its kernels keep: "rk" (the explicit methods' node
    #: values (Ω, Γ, σ, R)), "split" (μ, Γ, the heat q, R) or "vi" (node values
    #: and the step velocity)
    layout: ClassVar[str] = "rk"
    #: each step solves the momentum equation by Newton's method (Newton
    #: statistics, the status newton_not_converged, a start and friction and
    #: entropy variants)
    solves_newton: ClassVar[bool] = False
    #: the state holds the step velocity X_k and the node momentum μ_k (node
    #: form), from which the node velocity is derived
    node_form: ClassVar[bool] = False
    #: the step is built of the exact flows of every term (a term without one refuses it)
    needs_exact_flows: ClassVar[bool] = False

    def substeps(self, composition: str = "small_error") -> tuple[float, ...]:
        """vi, split: the factors f_i of the substeps h_i = f_i h of one step
        (``composition``: a kind of :data:`COMPOSITION_FACTORS`); () for the others."""
        return ()

    def _composed_substeps(self, composition: str) -> tuple[float, ...]:
        if self.composed is None:
            return (1.0,)
        if composition not in COMPOSITION_KINDS:
            raise ValueError(f"unknown composition {composition!r}: expected one of {list(COMPOSITION_KINDS)}")
        return COMPOSITION_FACTORS[(composition, self.composed)]

    def order(self, start: str = "legendre", friction: str = "trapezoid") -> int:
        """Observed order on node values (Ω(t_k), Γ_k, S_k, E_k)."""
        return self.order_base

    def effective_start(self, start: str) -> str:
        return "node"

    def effective_entropy(self, entropy: str) -> str | None:
        return None

    def effective_friction(self, friction: str) -> str | None:
        return None

    def effective_composition(self, composition: str) -> str | None:
        """The composition a composed method runs (None for the others)."""
        return composition if self.composed else None

    def refusal(self, model) -> str | None:
        """Why this method cannot run the kernel model ``model`` (None: it can)."""
        return None

    def stepper(self, choice: "MethodChoice", nsub: int = 1):
        """The kernel data that selects and parametrises this method's step
        (:mod:`liethermo.top.kernels.steppers`)."""
        raise NotImplementedError

    def initial_state(self, layout, physics, omega0: np.ndarray, R0: np.ndarray,
                      step_velocity: np.ndarray | None = None) -> np.ndarray:
        """The (N, layout.size) state rows at t = 0 from Ω(0) and R(0): Ω (the
        ``rk`` layout) or μ = 𝕀Ω with no heat yet (``split``), Γ and R."""
        N = omega0.shape[0]
        Y = np.zeros((N, layout.size))
        if layout.has("omega"):
            Y[:, layout.slice("omega")] = omega0
        else:
            Y[:, layout.slice("momentum")] = physics.inertia * omega0
        Y[:, layout.slice("gamma")] = R0[:, 2, :]  # Γ = Rᵀe₃ = third row of R
        if layout.has("attitude"):
            Y[:, layout.slice("attitude")] = R0.reshape(N, 9)
        return Y


@dataclass(frozen=True)
class RungeKuttaMethod(Method):
    """An explicit Runge–Kutta method: its Butcher tableau."""

    def kernel_tableau(self, composition: str = "small_error"):
        """The marker the kernels are compiled for: the Butcher tableau."""
        from .kernels import rk

        return rk.tableau(self.tableau)

    def stepper(self, choice: "MethodChoice", nsub: int = 1):
        from .kernels.steppers import Explicit

        return Explicit(self.kernel_tableau(), int(nsub))


@dataclass(frozen=True)
class SplittingMethod(Method):
    """The explicit thermodynamic splitting or a composition of it."""

    layout: ClassVar[str] = "split"
    needs_exact_flows: ClassVar[bool] = True

    def substeps(self, composition: str = "small_error") -> tuple[float, ...]:
        return self._composed_substeps(composition)

    def kernel_tableau(self, composition: str = "small_error"):
        """The marker the kernels are compiled for: the factors of the splitting."""
        from .kernels.split import splitting

        return splitting(self.substeps(composition), self.order_base)

    def refusal(self, model) -> str | None:
        from .kernels.split import can_split

        part = can_split(model)
        if part is None:
            return None
        return (f"method {self.name!r} needs the exact flow of every term; {part} has none "
                f"(the vi and rk methods run it)")

    def stepper(self, choice: "MethodChoice", nsub: int = 1):
        from .kernels.steppers import Split

        tab = self.kernel_tableau(choice.composition or "small_error")
        return Split(tab, int(nsub), type(tab).factors)


@dataclass(frozen=True)
class VariationalMethod(Method):
    """The variational integrator in node form or a composition of it: one
    Newton solve per substep."""

    layout: ClassVar[str] = "vi"
    solves_newton: ClassVar[bool] = True
    node_form: ClassVar[bool] = True

    def substeps(self, composition: str = "small_error") -> tuple[float, ...]:
        return self._composed_substeps(composition)

    def order(self, start: str = "legendre", friction: str = "trapezoid") -> int:
        """The plain VI is first order when started with the paper's
        Ω₀ := Ω(0) ("node": the initial node momentum is then off by O(h)) or
        with endpoint friction (evaluated half a step off the centre of the
        momentum equation); second order with the "legendre" or "staggered"
        start."""
        if self.composed is None and (friction == "endpoint" or start == "node"):
            return 1
        return self.order_base

    def effective_start(self, start: str) -> str:
        return self.fixed_start or start

    def effective_entropy(self, entropy: str) -> str | None:
        return self.fixed_entropy or entropy

    def effective_friction(self, friction: str) -> str | None:
        return "trapezoid" if self.fixed_start else friction

    def stepper(self, choice: "MethodChoice", nsub: int = 1, newton_tol: float = 1e-12,
                newton_maxiter: int = 50):
        from .kernels import vi as _vi
        from .kernels.steppers import Variational
        from .kernels.terms.thermo import EXPLICIT, SYMMETRIC

        factors = tuple(float(f) for f in self.substeps(choice.composition or "small_error"))
        wl, wr = _vi.FRICTION_WEIGHTS[choice.friction]
        mode = EXPLICIT if choice.entropy == "explicit" else SYMMETRIC
        return Variational(factors, float(wl), float(wr), mode, float(newton_tol), int(newton_maxiter))

    def initial_state(self, layout, physics, omega0: np.ndarray, R0: np.ndarray,
                      step_velocity: np.ndarray | None = None) -> np.ndarray:
        """The step velocity to start from (``step_velocity``, e.g. the
        staggered start's Ω(h/2), or Ω(0)), Γ, 𝕀(S₀)Ω(0) as the momentum and
        R: the start kernel then solves the first step velocity or the node
        momentum from these."""
        N = omega0.shape[0]
        Y = np.zeros((N, layout.size))
        Y[:, layout.slice("omega_step")] = omega0 if step_velocity is None else step_velocity
        Y[:, layout.slice("gamma")] = R0[:, 2, :]
        Y[:, layout.slice("momentum")] = physics.inertia * omega0  # 𝕀(S₀)Ω(0)
        if layout.has("attitude"):
            Y[:, layout.slice("attitude")] = R0.reshape(N, 9)
        return Y


def _rk_method(name: str, tableau: str, description: str) -> Method:
    """An explicit Runge–Kutta method: its order and stages are its tableau's."""
    from .kernels.tableaus import TABLEAUS

    cls = TABLEAUS[tableau]
    return RungeKuttaMethod(name, "rk", description, cls.order, False, cls.stages, (), tableau=tableau)


#: vi: a step of positive size adds hP/T or c_v log1p(hP/(c_v T)) ≥ 0 to σ, P ≥ 0 being
#: the power of the discrete friction: S_{k+1} ≥ S_k in floating point too
_VI_LAWS = (LAW_UNIT_GAMMA, LAW_ROTATION, LAW_ENTROPY_MONOTONE, LAW_KELVIN_NOETHER, LAW_CASIMIR,
            LAW_VERTICAL_MOMENTUM)
#: the compositions take negative substeps, on which friction gives heat back:
#: their entropy can decrease over a whole step (a last-digit change even at small
#: friction per step κ; docs/model.md "Negative substeps")
_COMPOSED_LAWS = tuple(x for x in _VI_LAWS if x != LAW_ENTROPY_MONOTONE)
#: the splittings keep |Γ| and RᵀR = I (every flow is a rotation or leaves Γ) and
#: Γ·μ without friction (the rotations turn Γ and μ together, the kick is ⟂ Γ)
_SPLIT_LAWS = (LAW_UNIT_GAMMA, LAW_ROTATION, LAW_VERTICAL_MOMENTUM)
#: split: its two friction flows run forward (h/2 each) and the step adds the kinetic
#: energy they take, a sum of non-negative terms, to the heat once: S_{k+1} ≥ S_k.
#: split4 and split6 merge adjacent half-flows into friction flows of negative
#: duration (Suzuki: −0.12 h twice; Kahan–Li: −0.19 h and −0.31 h twice each), which
#: give heat back inside the step: their monotone entropy is measured up to a friction
#: per step κ (benchmarks/split_entropy.py, docs/model.md), not a law
_STRANG_LAWS = _SPLIT_LAWS + (LAW_ENTROPY_MONOTONE,)


def _vi_method(name: str, description: str, order: int, laws, composed: bool = False) -> Method:
    """The variational integrator or a composition of it: one Newton solve per
    substep; compositions always start from μ₀ = 𝕀Ω(0) and use the symmetric
    entropy update (they need the symmetric map)."""
    n = len(COMPOSITION_FACTORS[("small_error", order)]) if composed else 1
    return VariationalMethod(name, "vi", description, order, True, n, laws,
                  fixed_start="legendre" if composed else None,
                  fixed_entropy="symmetric" if composed else None,
                  composed=order if composed else None)


def _split_method(name: str, description: str, order: int) -> Method:
    """The explicit thermodynamic splitting (Strang step of the exact flows of
    friction and gravity and Cayley free rotations) or a composition of it."""
    n = len(COMPOSITION_FACTORS[("small_error", order)]) if order > 2 else 1
    return SplittingMethod(name, "split", description, order, False, n, _SPLIT_LAWS if order > 2 else _STRANG_LAWS,
                  composed=order if order > 2 else None)


METHODS: dict[str, Method] = {
    "vi": _vi_method("vi", "variational integrator in node form (Cayley map, discrete Legendre "
                     "transforms, Newton momentum solve)", 2, _VI_LAWS),
    "vi4": _vi_method("vi4", "variational integrator composed to order 4 (Suzuki's 5 substeps; "
                      "integrator.composition = \"triple_jump\": Yoshida's 3)", 4, _COMPOSED_LAWS,
                      composed=True),
    "vi6": _vi_method("vi6", "variational integrator composed to order 6 (Kahan and Li's 9 substeps; "
                      "\"triple_jump\": two triple jumps, 9)", 6, _COMPOSED_LAWS, composed=True),
    "split": _split_method("split", "explicit thermodynamic splitting: Strang step of the terms' "
                           "flows (exact friction and heat, gravity kick; Cayley free rotations)", 2),
    "split4": _split_method("split4", "the splitting composed to order 4 (Suzuki's 5 Strang steps)", 4),
    "split6": _split_method("split6", "the splitting composed to order 6 (Kahan and Li's 9 Strang steps)", 6),
    "rk2": _rk_method("rk2", "midpoint", "explicit midpoint Runge-Kutta (order 2)"),
    "rk4": _rk_method("rk4", "rk4", "classical Runge-Kutta (order 4)"),
    "reference": _rk_method("reference", "dop853",
                            "fixed-step DOP853 (order 8) with substeps: high-accuracy reference"),
}


def friction_amplification(method: str, kappa, friction: str = "trapezoid", composition: str = "small_error"):
    """R(κ) = Π_i r(f_i κ): one step of a VI-family method on a purely frictional linear mode (κ = c h / I),
    r(z) = (1 − w_R z)/(1 + w_L z) with the friction's weights (trapezoid: (1 − z/2)/(1 + z/2))."""
    from .kernels.vi import FRICTION_WEIGHTS

    wl, wr = FRICTION_WEIGHTS[friction]
    kappa = np.asarray(kappa, float)
    out = np.ones_like(kappa)
    with np.errstate(divide="ignore", invalid="ignore"):
        for f in METHODS[method].substeps(composition):
            out = out * (1.0 - wr * f * kappa) / (1.0 + wl * f * kappa)
    return out


def negative_substep_limits(method: str, friction: str = "trapezoid", composition: str = "small_error") -> dict:
    """For a VI-family method: the most negative substep factor f, the κ at which a negative substep's Newton
    matrix factor 1 + w_L f κ vanishes, and the band of κ where |R(κ)| > 1 (a friction mode grows), from a
    fine grid of κ up to 50."""
    from .kernels.vi import FRICTION_WEIGHTS

    f = np.asarray(METHODS[method].substeps(composition), float)
    neg = f[f < 0]
    k = np.linspace(1e-3, 50.0, 200_000)
    bad = np.abs(friction_amplification(method, k, friction, composition)) > 1.0 + 1e-9
    return {"min_factor": float(f.min()),
            "kappa_singular": sorted(set(np.round(-1.0 / (FRICTION_WEIGHTS[friction][0] * neg), 4))) if neg.size else [],
            "growth_band": (float(k[bad].min()), float(k[bad].max())) if bad.any() else None}


def get_method(name: str) -> Method:
    try:
        return METHODS[name]
    except KeyError:
        raise ValueError(
            f"unknown integrator.method {name!r}: expected one of {sorted(METHODS)}"
        ) from None


# ----------------------------------------------------------------------------- a method choice


@dataclass(frozen=True)
class MethodChoice:
    """A method with the variants it really runs, worked out once: from a
    scene (:meth:`from_scene`), a study's label such as ``"vi:node:explicit"``
    (:meth:`parse`) or keywords (:meth:`of`).  Everything that runs or
    describes a run (:func:`liethermo.top.simulate.simulate`, the dataset's
    attributes, preflight, the studies) reads these fields.

    ``start``: the first step of the variational integrators ("node" for
    the others, whose state starts at the nodes); ``friction``, ``entropy``:
    the variational integrators' (None for the others); ``composition``: the
    composed methods' (None for the others).  ``label``: how it was asked for
    (a study's label, or the method's name)."""

    name: str
    start: str
    friction: str | None
    entropy: str | None
    composition: str | None
    label: str = ""

    @property
    def method(self) -> Method:
        return METHODS[self.name]

    @property
    def family(self) -> str:
        return self.method.family

    @classmethod
    def of(cls, method: str, *, start: str = "legendre", friction: str = "trapezoid",
           entropy: str = "symmetric", composition: str = "small_error", label: str | None = None
           ) -> "MethodChoice":
        """The choice that ``method`` with these asked-for variants runs; an
        unknown name or variant raises ValueError naming it."""
        m = get_method(method)
        for what, value, allowed in (("friction", friction, FRICTION), ("start", start, STARTS),
                                     ("entropy", entropy, ENTROPY_UPDATES),
                                     ("composition", composition, COMPOSITION_KINDS)):
            if value not in allowed:
                raise ValueError(f"unknown integrator.{what} {value!r}: expected one of {list(allowed)}")
        return cls(m.name, m.effective_start(start), m.effective_friction(friction),
                   m.effective_entropy(entropy), m.effective_composition(composition),
                   m.name if label is None else label)

    @classmethod
    def from_scene(cls, scene) -> "MethodChoice":
        """The choice of a scene's ``[integrator]`` table."""
        integ = scene["integrator"]
        return cls.of(integ["method"], start=integ["start"], friction=integ["friction"],
                      entropy=integ["entropy"], composition=integ["composition"])

    @classmethod
    def parse(cls, label: str) -> "MethodChoice":
        """A study's method label: a method's name, then variants after colons,
        in any order, each changing one choice — starts ``legendre``, ``node``
        (the paper's Ω₀ := Ω(0)), ``staggered``; friction ``trapezoid``,
        ``endpoint``; entropy ``symmetric``, ``explicit`` (e.g.
        ``"vi:node:explicit"``, the paper's choices); a composed method's
        ``small_error`` or ``triple_jump`` (``"vi4:triple_jump"``).  ``vi4`` and
        ``vi6`` accept and ignore the variational integrator's variants;
        explicit methods take none.  ValueError names what is wrong."""
        parts = label.split(":") if isinstance(label, str) else [label]
        name = parts[0]
        if name not in METHODS:
            raise ValueError(f"unknown method {label!r}; known methods: {', '.join(sorted(METHODS))}")
        m = METHODS[name]
        chosen = {"start": "legendre", "friction": "trapezoid", "entropy": "symmetric",
                  "composition": "small_error"}
        seen: set[str] = set()
        for p in parts[1:]:
            what = ("start" if p in STARTS else "friction" if p in FRICTION
                    else "entropy" if p in ENTROPY_UPDATES else "composition" if p in COMPOSITION_KINDS
                    else None)
            if what is None:
                raise ValueError(f"{label!r}: unknown variant {p!r} (starts: {', '.join(STARTS)}; "
                                 f"friction: {', '.join(FRICTION)}; entropy: {', '.join(ENTROPY_UPDATES)}; "
                                 f"composition: {', '.join(COMPOSITION_KINDS)})")
            if what == "composition" and not m.composed:
                raise ValueError(f"{label!r}: {name} is not composed and takes no composition")
            if what != "composition" and not m.solves_newton:
                raise ValueError(f"{label!r}: {name} is explicit and takes no variant")
            if what in seen:
                raise ValueError(f"{label!r}: more than one {what} variant")
            seen.add(what)
            chosen[what] = p
        return cls.of(name, label=label, **chosen)

    def asked(self) -> dict:
        """Values for every variant key, the effective one where it applies
        and the scene default elsewhere: what a scene must say to run this
        choice (:meth:`overrides`), or ``simulate``'s keywords."""
        return {"start": self.start if self.method.solves_newton else "legendre",
                "friction": self.friction or "trapezoid", "entropy": self.entropy or "symmetric",
                "composition": self.composition or "small_error"}

    def overrides(self) -> dict:
        """Scene overrides that make a scene run this choice."""
        a = self.asked()
        return {"integrator.method": self.name, "integrator.start": a["start"],
                "integrator.friction": a["friction"], "integrator.entropy": a["entropy"],
                "integrator.composition": a["composition"]}

    def order(self) -> int:
        """The observed order on node values this choice declares (:meth:`Method.order`)."""
        return self.method.order(self.start, self.friction or "trapezoid")


def kept_laws(label: str) -> str:
    """The laws among |Γ| = 1, Kelvin–Noether and entropy monotone that the method of ``label``
    declares, e.g. "|Γ| = 1, Kelvin–Noether"; a method from outside liethermo (scipy's) declares none."""
    name = str(label).split(":")[0]
    laws = METHODS[name].laws if name in METHODS else ()
    kept = [text for law, text in ((LAW_UNIT_GAMMA, "|Γ| = 1"), (LAW_KELVIN_NOETHER, "Kelvin–Noether"),
                                   (LAW_ENTROPY_MONOTONE, "entropy monotone")) if law in laws]
    return ", ".join(kept) if kept else "none of these"


def keeps_geometry(label: str) -> bool:
    """Whether the method of ``label`` declares both |Γ| = 1 and the discrete
    Kelvin–Noether law (the variational family)."""
    name = str(label).split(":")[0]
    return name in METHODS and {LAW_UNIT_GAMMA, LAW_KELVIN_NOETHER} <= set(METHODS[name].laws)
