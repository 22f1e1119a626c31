"""The one owner of the kernels' layouts: state parts, status codes, statistics.

State of a member, by method family (parts absent from a model are not stored):

* ``rk`` (explicit Runge–Kutta and the reference):
  ``omega`` Ω (3, rad s⁻¹), ``gamma`` Γ (3), ``sigma`` σ = S − S₀ (1, J K⁻¹;
  only with thermodynamics), ``attitude`` R row-major (9; only if integrated);
* ``split`` (the splitting integrators): ``momentum`` μ = 𝕀Ω, the body
  angular momentum (3, kg m² s⁻¹), ``gamma`` Γ (3), ``heat`` q = U − U₀, the
  heat absorbed since the start (1, J; only with thermodynamics),
  ``attitude`` (9; only if integrated) — what its flows move, so that a step
  neither divides by 𝕀 nor converts heat into entropy (Ω = 𝕀⁻¹μ and
  S = S(U₀ + q) at output);
* ``vi`` (the variational integrator in node form):
  ``omega_step`` X = Ω_k, the step velocity of the step that starts at the
  node (3), ``gamma`` Γ_k (3), ``sigma`` σ_k (1), ``momentum`` μ_k, the body
  angular momentum at the node (3, kg m² s⁻¹), ``sigma_next`` σ_{k+1}
  (1; only for the coupled top, whose Newton solve gives X and σ_{k+1}
  together), ``attitude`` (9).

In the kernels a state is a tuple of parts, ``None`` for an absent one:
``(Ω, Γ, σ, R)``, ``(μ, Γ, q, R)`` or ``(X, Γ, σ, μ, σₙ, R)``.  :func:`state_layout` gives the
columns of the flat arrays the Python layer holds; the generic functions
:func:`load_rk_state` / :func:`store_rk_state` (and the ``vi`` pair) move a
state between those columns, strided by ``stride`` from ``base`` in a flat
buffer (the member's row: stride 1; a lane of the block kernel's rows:
stride = row length), with the column numbers compiled in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba.extending import overload

from ._jit import LANE_OPTIONS, jit, ld, st
from .gen import compile_source, is_none

STATUS_OK, STATUS_NEWTON, STATUS_NONFINITE = 0, 1, 2
STATUS_MEANINGS = {STATUS_OK: "ok", STATUS_NEWTON: "newton_not_converged",
                   STATUS_NONFINITE: "non_finite"}

# per-member integer statistics (ISTAT columns) and float statistics (FSTAT)
IS_STATUS, IS_FAIL_STEP, IS_NEWTON_TOTAL, IS_NEWTON_MAX, IS_STEPS, IS_NSUB = range(6)
NISTAT = 6
FS_MAX_H_OMEGA = 0
NFSTAT = 1

#: on a GPU, a kernel call's kept outputs take at most this many bytes of device memory
#: (:mod:`.cuda`); more outputs make more calls
OUT_BYTES = 256 * 2**20

# Newton outcome codes
NEWTON_OK, NEWTON_MAXITER, NEWTON_SINGULAR = 0, 1, 2

@dataclass(frozen=True)
class Traits:
    """What of the state a model needs."""

    thermo: bool  # σ is integrated (something dissipates)
    attitude: bool  # R is integrated
    coupled: bool  # 𝕀 depends on S: the VI solves for σ_{k+1} with X


def traits(model) -> Traits:
    """Traits of a model instance or of its numba type."""
    from .dispatch import has_capability

    if hasattr(model, "fields") and hasattr(model, "types"):  # numba NamedTuple type
        get = dict(zip(model.fields, model.types)).__getitem__
        present = lambda name: not is_none(get(name))  # noqa: E731
        inertia = get("inertia")
    else:
        present = lambda name: getattr(model, name) is not None  # noqa: E731
        inertia = model.inertia
    return Traits(thermo=present("thermo"), attitude=present("attitude"),
                  coupled=has_capability(inertia, "entropy_dependent_inertia"))


#: the parts of each state layout: (name, size) in tuple order, absent parts of size 0
_STATE_PARTS = {
    "rk": lambda tr: [("omega", 3), ("gamma", 3), ("sigma", 1 if tr.thermo else 0),
                      ("attitude", 9 if tr.attitude else 0)],
    "split": lambda tr: [("momentum", 3), ("gamma", 3), ("heat", 1 if tr.thermo else 0),
                         ("attitude", 9 if tr.attitude else 0)],
    "vi": lambda tr: [("omega_step", 3), ("gamma", 3), ("sigma", 1 if tr.thermo else 0),
                      ("momentum", 3), ("sigma_next", 1 if tr.coupled else 0),
                      ("attitude", 9 if tr.attitude else 0)],
}


def state_parts(tr: Traits, family: str) -> list[tuple[str, int]]:
    """(name, size) of the parts of the state layout ``family`` ("rk", "split"
    or "vi"), in tuple order, None-parts with size 0."""
    try:
        return _STATE_PARTS[family](tr)
    except KeyError:
        raise ValueError(f"unknown state layout {family!r}: expected one of {sorted(_STATE_PARTS)}") from None


@dataclass(frozen=True)
class StateLayout:
    """Columns of the flat state of one family (Python side)."""

    family: str
    parts: tuple  # ((name, start, size), ...) of the present parts
    size: int

    def slice(self, name: str) -> slice | None:
        for n, start, size in self.parts:
            if n == name:
                return slice(start, start + size)
        return None

    def has(self, name: str) -> bool:
        return self.slice(name) is not None


def state_layout(model, family: str) -> StateLayout:
    parts, col = [], 0
    for name, size in state_parts(traits(model), family):
        if size:
            parts.append((name, col, size))
            col += size
    return StateLayout(family, tuple(parts), col)


def _make_io(family: str):
    def load(model, buf, base, stride):
        out, col = [], 0
        for _, size in state_parts(traits(model), family):
            if size == 0:
                out.append(None)
            elif size == 1:
                out.append(float(buf[base + col * stride]))
            else:
                out.append(tuple(float(buf[base + (col + k) * stride]) for k in range(size)))
            col += size
        return tuple(out)

    def store(model, buf, base, stride, y):
        col = 0
        for p, (_, size) in enumerate(state_parts(traits(model), family)):
            if size == 1:
                buf[base + col * stride] = y[p]
            else:
                for k in range(size):
                    buf[base + (col + k) * stride] = y[p][k]
            col += size

    load.__name__ = load.__qualname__ = f"load_{family}_state"
    store.__name__ = store.__qualname__ = f"store_{family}_state"

    @overload(load, jit_options=LANE_OPTIONS)
    def _load(model, buf, base, stride):
        exprs, col = [], 0
        for _, size in state_parts(traits(model), family):
            if size == 0:
                exprs.append("None")
            elif size == 1:
                exprs.append(f"ld(buf, base + {col} * stride)")
            else:
                exprs.append("(" + ", ".join(f"ld(buf, base + {col + k} * stride)"
                                             for k in range(size)) + ")")
            col += size
        return compile_source(f"def impl(model, buf, base, stride):\n"
                              f"    return ({', '.join(exprs)})\n", {"ld": ld}, label=f"load_{family}_state")

    @overload(store, jit_options=LANE_OPTIONS)
    def _store(model, buf, base, stride, y):
        lines, col = ["def impl(model, buf, base, stride, y):"], 0
        for p, (_, size) in enumerate(state_parts(traits(model), family)):
            if size == 1:
                lines.append(f"    st(buf, base + {col} * stride, y[{p}])")
            else:
                for k in range(size):
                    lines.append(f"    st(buf, base + {col + k} * stride, y[{p}][{k}])")
            col += size
        lines.append("    return None")
        return compile_source("\n".join(lines) + "\n", {"st": st}, label=f"store_{family}_state")

    return load, store


load_rk_state, store_rk_state = _make_io("rk")
load_vi_state, store_vi_state = _make_io("vi")
load_split_state, store_split_state = _make_io("split")


@jit(nogil=True)
def start_rows(states, Y):
    """The output array before the kernels write it, in one pass: ``states[m, 0] = Y[m]``
    (the state at t = 0) and NaN in every later row (what a member that fails keeps from
    its failing step on)."""
    nan = np.nan
    for m in range(states.shape[0]):
        for k in range(states.shape[2]):
            states[m, 0, k] = Y[m, k]
        for t in range(1, states.shape[1]):
            for k in range(states.shape[2]):
                states[m, t, k] = nan
