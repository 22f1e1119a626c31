"""Label a :class:`~liethermo.top.simulate.Trajectory` as a CF-style xarray Dataset,
keep the variables a run stores (:func:`select_variables`: the state by default,
``output.variables`` for more) and derive the others from a stored state
(:func:`derive`, behind ``ds.liethermo.derived()``).

Every variable has ``units`` and ``long_name`` (docs/netcdf.md lists them).
Values are node values at t_k = k h for every method: ``omega`` is Ω(t_k)
(for the variational integrators the node velocity 𝕀(S_k)⁻¹μ_k, from the node
momentum μ_k of the discrete Legendre transform), and ``energy_error`` is
E_k − E₀ on node values, computed without cancellation:

    E_k − E₀ = (K_k − K₀) + (V_k − V₀) + c_v T₀ expm1(σ_k/c_v),

with E₀ the energy of the initial data at t = 0.  The variational
integrators also report ``omega_step``, the step velocity Ω_k ≈ Ω(t_k + h/2)
of the step that starts at t_k (the paper's quantity), and
``energy_error_paper``, the energy in the paper's convention (Ω_k with Γ_k
and S_k): it mixes two instants and so carries a first-order error of its
own — it is kept to reproduce the paper's figure, not to judge the method.
"""

from __future__ import annotations

import platform

import numpy as np
import xarray as xr

from .. import cf
from ..version import __version__
from . import physics as ph
from .kernels.layout import STATUS_MEANINGS
from .methods import METHODS
from .simulate import Trajectory

AXIS = ["x", "y", "z"]


def _var(data, dims, units, long_name, **extra):
    return xr.Variable(dims, data, attrs={"units": units, "long_name": long_name, **extra})


def node_energies(traj: Trajectory) -> dict:
    """Node values of (Ω, K, V, U − U₀, T) in SI units, arrays (N, T[, 3])."""
    phys = traj.physics
    sigma = traj.sigma
    om = traj.omega
    s = sigma if traj.thermo else None
    K = ph.kinetic_energy(phys, om, s)
    V = ph.potential_energy(phys, traj.gamma)
    heat = traj.part("heat")  # the splittings carry U − U₀ itself
    dU = ph.internal_energy_change(phys, sigma) if heat is None else heat[..., 0]
    T = ph.temperature(phys, om, sigma)
    return {"omega": om, "K": K, "V": V, "dU": dU, "T": T}


def initial_energy(phys: ph.Physics, omega0: np.ndarray, R0: np.ndarray) -> tuple:
    """(K₀, V₀) of the initial data (N,)."""
    return ph.kinetic_energy(phys, omega0, None), ph.potential_energy(phys, R0[:, 2, :])


def _momentum(traj: Trajectory, omega: np.ndarray) -> np.ndarray:
    """μ at the nodes: the variational integrators' node momentum and the
    splittings' state, else 𝕀(S)Ω."""
    if traj.momentum is not None:
        return traj.momentum
    scale = ph.inertia_scale(traj.physics, traj.sigma if traj.thermo else None)
    scale = scale[..., None] if isinstance(scale, np.ndarray) else scale
    return scale * traj.physics.inertia[:, None, :] * omega


def _start_note(traj) -> str:
    """What a variational integrator's start does to the values at t = 0 (for
    the comments of ``omega`` and ``energy_error``): with the ``node`` and
    ``staggered`` starts the node momentum at t = 0 is not I Omega(0)."""
    first = {"node": "Omega(0) (the paper's start)", "staggered": "Omega(h/2)"}.get(traj.start)
    if first is None:
        return ""
    return (f"; start {traj.start!r} takes {first} as the first step velocity, so the node momentum at "
            "t = 0 is the step's Newton equation read backwards from it, not I Omega(0): at t = 0 "
            "omega is not Omega(0) and energy_error is not 0 (the paper scene at h = 0.1 s: 3.1 % of "
            "E_mech,0); docs/model.md, Starts")


def trajectory_dataset(traj: Trajectory, *, omega0: np.ndarray, R0: np.ndarray,
                       member_offset: int = 0, keep=None) -> xr.Dataset:
    """The dataset of one member chunk (no global attributes; see :func:`global_attrs`).

    omega0, R0: the members' initial data at t = 0 (N, 3), (N, 3, 3).  ``keep``:
    the names of the member variables to compute (None: every one); the
    parameters are always there.
    """
    return chunk_labels(traj, omega0=omega0, R0=R0, member_offset=member_offset).dataset(keep)


class ChunkLabels:
    """The labelled variables of one member chunk, each computed when first asked
    for (``labels[name]``, an :class:`xarray.Variable`; coordinates too) and kept;
    :meth:`dataset` gathers them in their fixed order.  A run computes what its
    summary reads and what its file stores, nothing else."""

    def __init__(self, build: dict, coords: dict, energy_parts=None):
        self._build, self._coords, self._done = build, coords, {}
        #: () -> (K, V, ΔU (M, T), K₀, V₀ (M,)), the parts of ``energy_error`` (None: not known)
        self.energy_parts = energy_parts

    def __contains__(self, name) -> bool:
        return name in self._build or name in self._coords

    def computed_on_demand(self) -> set[str]:
        """The variables computed when asked for (the others are the state's views and
        the members' run and parameters as they are)."""
        return {n for n, make in self._build.items() if callable(make)}

    def __getitem__(self, name: str) -> xr.Variable:
        if name in self._coords:
            return self._coords[name]
        v = self._done.get(name)
        if v is None:
            make = self._build[name]
            if callable(make):
                # a member that blew up (explicit RK2) has huge-but-finite values before its NaNs:
                # the energies of those values overflow to inf, which is the truthful answer
                with np.errstate(over="ignore", invalid="ignore"):
                    make = make()
            v = self._done[name] = make
        return v

    def dataset(self, keep=None) -> xr.Dataset:
        """The chunk's dataset: the member variables in ``keep`` (None: every one)
        and the parameters (variables without the member dimension, or named by
        :func:`liethermo.top.scene.parameter_names`)."""
        from .scene import parameter_names

        params = set(parameter_names())
        data = {n: self[n] for n, make in self._build.items()
                if keep is None or n in keep or n in params
                or (not callable(make) and "member" not in make.dims)}
        return xr.Dataset(data, coords=self._coords)


def _once(f):
    """f() computed on the first call and kept."""
    box = []

    def get():
        if not box:
            box.append(f())
        return box[0]

    return get


def chunk_labels(traj: Trajectory, *, omega0: np.ndarray, R0: np.ndarray, member_offset: int = 0) -> ChunkLabels:
    """The variables of one member chunk, computed on demand (:class:`ChunkLabels`);
    :func:`trajectory_dataset` is its dataset."""
    with np.errstate(over="ignore", invalid="ignore"):  # see ChunkLabels.__getitem__
        return _chunk_labels(traj, omega0, R0, member_offset)


def _chunk_labels(traj, omega0, R0, member_offset) -> ChunkLabels:
    phys = traj.physics
    N = traj.states.shape[0]
    om = traj.omega
    sigma = traj.sigma

    e = _once(lambda: node_energies(traj))
    K0V0 = _once(lambda: initial_energy(phys, omega0, R0))

    def parts():  # the energy error's parts: K, V, ΔU (N, T), K₀, V₀ (N,)
        return (e()["K"], e()["V"], e()["dU"]) + K0V0()

    dE = _once(lambda: (lambda K, V, dU, K0, V0: (K - K0[:, None]) + (V - V0[:, None]) + dU)(*parts()))
    U = _once(lambda: phys.heat_capacity[:, None] * ph.theta(phys, sigma))
    dims_t = ("member", "t")
    dims_v = ("member", "t", "axis")
    vi = traj.choice.method.node_form
    mom = _once(lambda: _momentum(traj, om))

    def now_if_stored(make):
        """``make`` itself where it only labels the state (the VI's and splittings' μ), else on demand."""
        return make() if traj.momentum is not None else make

    node_note = ("node velocity I(S_k)^-1 mu_k from the node momentum (discrete Legendre transform)"
                 if vi else "node value Omega(t_k)")
    start_note = _start_note(traj) if vi else ""
    build = {
        "omega": _var(om, dims_v, "rad s-1", "angular velocity",
                      comment=f"body angular velocity Omega at t_k: {node_note}{start_note}"),
        "angular_momentum": now_if_stored(lambda: _var(mom(), dims_v, "kg m2 s-1", "angular momentum",
                                                       comment="body angular momentum mu = I(S) Omega at t_k")),
        "angular_momentum_norm": lambda: _var(np.linalg.norm(mom(), axis=-1), dims_t, "kg m2 s-1",
                                              "|mu|, a Casimir",
                                              comment="|mu| = |I(S) Omega|: a Casimir, kept by friction of "
                                                      "the double-bracket form"),
        "vertical_angular_momentum": lambda: _var(np.sum(traj.gamma * mom(), axis=-1), dims_t, "kg m2 s-1",
                                                  "Gamma . mu",
                                                  comment="angular momentum about the vertical (the "
                                                          "Kelvin-Noether quantity; d/dt = -Gamma . C Omega)"),
        "gamma": _var(traj.gamma, dims_v, "1", "gravity direction (body)",
                      comment="direction of gravity in the body frame, Gamma = R^T e3"),
        **_heat_parts(traj, dims_t),
        "entropy": lambda: _var(phys.S0[:, None] + sigma, dims_t, "J K-1", "entropy S",
                                comment="entropy of body and fluid"),
        "temperature": lambda: _var(e()["T"], dims_t, "K", "temperature T",
                                    comment="T = -dL/dS (T0 exp((S - S0)/c_v) for a constant inertia)",
                                    units_metadata="temperature: on_scale"),
        "kinetic_energy": lambda: _var(e()["K"], dims_t, "J", "kinetic energy K",
                                       comment="K = 1/2 Omega . I(S) Omega"),
        "potential_energy": lambda: _var(e()["V"], dims_t, "J", "potential energy V",
                                         comment="V = m g l Gamma . chi"),
        "internal_energy": lambda: _var(U(), dims_t, "J", "internal energy U",
                                        comment="U(S) = c_v T0 exp((S - S0)/c_v)"),
        "total_energy": lambda: _var(e()["K"] + e()["V"] + U(), dims_t, "J", "total energy E = K + V + U"),
        "energy_error": lambda: _var(dE(), dims_t, "J", "energy error E_k - E_0",
                                     comment="total energy error on node values (computed without "
                                             "cancellation); E_0 is the energy of the initial data "
                                             "(Omega(0), Gamma_0, S_0) at t = 0" + start_note),
        "mechanical_energy_initial": lambda: _var(ph.mechanical_energy(phys, *K0V0()),  # K₀ + V₀ − min V
                                                  ("member",), "J", "initial mechanical energy",
                                                  comment="above the resting state: K_0 + V_0 + |m g l|"),
        "status": _var(traj.status.astype(np.int8), ("member",), "1", "member status",
                       **status_flags(np.int8)),
        "failed_at_step": _var(np.where(traj.status != 0, traj.fail_step, -1).astype(np.int64),
                               ("member",), "1", "step that failed",
                               comment="step k+1 whose computation failed (-1: none); "
                                       "values from that step on are NaN"),
        "steps_done": _var(traj.steps_done.astype(np.int64), ("member",), "1", "steps accepted"),
        "max_h_omega": _var(traj.max_h_omega, ("member",), "rad", "max of |h| |Omega|",
                            comment="max over (sub)steps of |h| |Omega|; the Cayley map turns by "
                                    "2 atan(h|Omega|/2): phase error ~ (h|Omega|)^3/12 per step"),
        "initial_omega": _var(omega0, ("member", "axis"), "rad s-1", "initial Omega(0)",
                              comment="initial body angular velocity"),
        "initial_attitude": _var(R0, ("member", "row", "col"), "1", "initial attitude R(0)"),
        "inertia": _parameter(phys.inertia, ("member", "axis"), "kg m2", "moments of inertia I0",
                              comment="principal moments of inertia about the fixed point"),
        "heat_capacity": _parameter(phys.heat_capacity, ("member",), "J K-1", "heat capacity c_v"),
    }
    build.update(term_variables(phys))
    if vi:
        step = traj.omega_step

        def paper_error():
            s = sigma if traj.thermo else None
            Kp = ph.kinetic_energy(phys, step, s)
            return (Kp - K0V0()[0][:, None]) + (e()["V"] - K0V0()[1][:, None]) + e()["dU"]

        build["omega_step"] = _var(step, dims_v, "rad s-1",
                                   "step velocity",
                                   comment="step velocity Omega_k = cay^-1(R_k^T R_k+1)/h of the step "
                                           "from t_k; approximates Omega(t_k + h/2); the paper's Omega_k")
        composed = ("; for a composition (vi4, vi6) Omega_k is a substep's velocity, so this is not the "
                    "paper's quantity: the summary and the figures leave it out" if METHODS[traj.method].composed
                    else "")
        build["energy_error_paper"] = lambda: _var(
            paper_error(), dims_t, "J", "paper's energy error",
            comment="total energy error in the paper's convention (step velocity Omega_k with "
                    "Gamma_k and S_k); it mixes two instants: a first-order error of the "
                    "diagnostic itself; energy_error is the node-value error" + composed)
        steps = np.maximum(traj.steps_done, 1)
        build["newton_iterations_mean"] = _var(traj.newton_iterations / steps, ("member",), "1",
                                               "mean Newton iterations",
                                               comment="mean Newton iterations per step, summed over the "
                                                       "step's solves (one for vi, 3 for vi4, 9 for vi6)")
        build["newton_iterations_max"] = _var(traj.newton_max.astype(np.int64), ("member",), "1",
                                              "max Newton iterations",
                                              comment="max Newton iterations in one solve")
    R = traj.attitude
    if R is not None:
        build["attitude"] = _var(R, ("member", "t", "row", "col"), "1", "attitude R (body to space)")
        build["center_of_mass"] = lambda: _var(np.einsum("mtij,mj->mti", R, phys.center_of_mass), dims_v, "m",
                                               "centre of mass R G",
                                               comment="centre of mass in space, relative to the fixed point")
    coords = {
        "member": _var(np.arange(member_offset, member_offset + N, dtype=np.int64), ("member",), "1",
                       "ensemble member"),
        "t": _var(cf.decimal_times(traj.step_index, traj.h), ("t",), "s", "time t",
                  comment="time since the start of the run, t_k = k h (the decimal value of k h)"),
        "step": _var(traj.step_index.astype(np.int64), ("t",), "1", "step index k"),
        "axis": xr.Variable(("axis",), np.array(AXIS), attrs={"units": "1", "long_name": "body-frame axis"}),
    }
    return ChunkLabels(build, coords, energy_parts=parts)


def _heat_parts(traj, dims_t) -> dict:
    """The state's own thermodynamic part, as the kernels store it: σ = S − S₀
    (variational integrators, Runge–Kutta) or the heat q = U − U₀ (splittings).
    The entropy, temperature and energies derive from it bit for bit; from
    S = S₀ + σ they would not (S₀ + σ − S₀ rounds)."""
    out = {}
    if traj.layout.has("sigma"):
        out["entropy_change"] = _var(traj.part("sigma")[..., 0], dims_t, "J K-1", "entropy change S - S0",
                                     comment="entropy produced since t = 0, as the integrator carries it")
    if traj.layout.has("heat"):
        out["heat"] = _var(traj.part("heat")[..., 0], dims_t, "J", "heat absorbed q = U - U0",
                           comment="internal energy gained since t = 0, as the splitting carries it")
    return out


def status_flags(dtype) -> dict:
    """CF ``flag_values``/``flag_meanings`` of a member status variable of ``dtype``."""
    return {"flag_values": np.array(sorted(STATUS_MEANINGS), dtype=dtype),
            "flag_meanings": " ".join(STATUS_MEANINGS[k] for k in sorted(STATUS_MEANINGS))}


def term_variables(phys) -> dict:
    """Every model term's parameters as dataset variables: those a term writes
    always, and the others where some member has them."""
    from .kernels.terms import registry

    out = {}
    for t in registry():
        for prm in t.parameters:
            if prm.shape is None or prm.variable_name == "":
                continue
            v = getattr(phys, prm.name)
            if prm.always or np.any(v != 0.0):
                dims = ("member",) + (("axis",) if prm.shape == (3,) else ())
                extra = {"comment": prm.comment} if prm.comment else {}
                out[prm.variable_name] = _parameter(v, dims, prm.unit, prm.long_name, **extra)
    return out


def _parameter(v: np.ndarray, dims: tuple, units: str, long_name: str, **extra) -> xr.Variable:
    """A per-member parameter: stored once, without the member dimension, where every
    member has it bit for bit (every run of a scene: the scene gives one body), else
    per member (an ensemble of bodies built through the API)."""
    v = np.asarray(v)
    if v.shape[0] and v.strides[0] == 0:  # one row seen by every member (Physics.repeat)
        alike = True
    else:
        rows = np.ascontiguousarray(v).reshape(v.shape[0], -1).view(np.uint8) if v.shape[0] else None
        alike = rows is not None and bool((rows == rows[0]).all())
    if alike:
        note = "the same for every member"
        extra["comment"] = f"{extra['comment']}; {note}" if extra.get("comment") else note
        return _var(v[0], dims[1:], units, long_name, **extra)
    return _var(v, dims, units, long_name, **extra)


def global_attrs(scene_toml: str, *, method: str, h: float, friction: str | None,
                 start: str, entropy: str | None, composition: str | None = None, terms=(),
                 extra: dict | None = None, history: str | None = None) -> dict:
    """Global attributes of a run's dataset.  ``history``: the command line or
    API call that makes it (stored as a timestamped CF ``history`` line)."""
    m = METHODS[method]
    created = cf.timestamp()
    attrs = {
        "Conventions": cf.CONVENTIONS,
        "title": "liethermo ensemble: rigid body in Stokes flow",
        "method": method,
        "method_description": m.description,
        "method_order": m.order(start, friction or "trapezoid"),
        "h": h,
        "h_units": "s",
        "friction": friction or "none",
        "start": start,
        "entropy_update": entropy or "none",
        "composition": composition or "none",
        "model_terms": " ".join(terms),
        "scene": scene_toml,
        "software": f"liethermo {__version__}",
        "software_version": __version__,
        "python": platform.python_version(),
        "created": created,
        "history": cf.history_entry(history or f"liethermo {__version__}", created),
        "references": "Coueraud & Gay-Balmaz, Variational discretization of thermodynamical simple "
                      "systems on Lie groups; liethermo docs/model.md (errata E1-E5)",
    }
    if extra:
        attrs.update(extra)
    return attrs


# ----------------------------------------------------------------------------- what a file stores


def stored_variables(scene, traj_layout) -> set[str] | None:
    """The variables a run of ``scene`` stores (None: every one): the state parts of
    the method's layout (``traj_layout``, a :class:`~liethermo.top.kernels.layout.StateLayout`),
    the members' run, the parameters, the initial data of an ``initial.file`` scene,
    and what ``output.variables`` names (:data:`liethermo.top.scene.VARIABLE_GROUPS`)."""
    from ..scene import requested_variables
    from .scene import RUN_VARIABLES, STATE_VARIABLES, VARIABLE_GROUPS

    asked = requested_variables(scene, VARIABLE_GROUPS)
    if asked is None:
        return None
    # Ω(t_k) of every method: the state of the Runge-Kutta methods, the node velocity
    # 𝕀(S_k)⁻¹μ_k of the others (derived, and stored too: the variable a reader looks for first)
    out = set(asked) | set(RUN_VARIABLES) | {"omega"} | {STATE_VARIABLES[n] for n, _, _ in traj_layout.parts
                                                        if n in STATE_VARIABLES}
    if scene["initial"]["file"]:  # the initial data live in a file the run may not find again
        out |= {"initial_omega", "initial_attitude"}
    return out


def select_variables(ds: xr.Dataset, scene, traj_layout) -> xr.Dataset:
    """``ds`` with the data variables a run of ``scene`` stores (:func:`stored_variables`);
    the parameters (no time dimension, no member dimension) always."""
    from .scene import parameter_names

    keep = stored_variables(scene, traj_layout)
    if keep is None:
        return ds
    params = parameter_names()
    drop = [n for n, v in ds.data_vars.items() if n not in keep and "member" in v.dims and n not in params]
    return ds.drop_vars(drop)


def derive(ds: xr.Dataset) -> xr.Dataset:
    """Every variable a run of the file's scene can write, from the stored state of
    ``ds`` (a top's run file or its in-memory dataset, any subset of its members and
    times): the stored parts are put back into the kernels' state layout and labelled
    by the very code a run labels its chunks with (:func:`trajectory_dataset`), with the
    members' initial data and parameters rebuilt from the stored scene, so every value
    equals, bit for bit, the one a run storing every variable writes.  Raises
    ValueError for a dataset that does not hold the state."""
    from ..scene import load_scene
    from .initial import initial_conditions
    from .resolve import resolve
    from .scene import STATE_VARIABLES, parameter_names

    text = ds.attrs.get("scene")
    if not isinstance(text, str) or not text:
        if all(n in ds for n in ("kinetic_energy", "energy_error", "mechanical_energy_initial")):
            return ds  # a chunk labelled whole (a study's run): it holds them already
        raise ValueError("the dataset has no 'scene' attribute: the derived variables need the run's scene")
    scene = load_scene(_scene_tables(text))
    run = resolve(scene)
    layout = run.model.layout(run.method.layout)
    members = np.asarray(ds["member"].values, dtype=np.int64)
    N, T = members.size, ds.sizes["t"]
    states = np.full((N, T, layout.size), np.nan)
    for part, start, size in layout.parts:
        name = STATE_VARIABLES.get(part)
        if name is None:  # sigma_next: the coupled VI's next entropy, read by nothing the file shows
            continue
        if name not in ds:
            raise ValueError(f"the dataset has no {name!r}: it does not hold the state of its method "
                             f"{run.choice.name} (store it, or run with output.variables = \"all\")")
        v = np.asarray(ds[name].transpose("member", "t", ...).values, dtype=np.float64)
        states[..., start:start + size] = v.reshape(N, T, size)
    member_vals = lambda n: np.asarray(ds[n].values)  # noqa: E731
    status = member_vals("status").astype(np.int8)
    fail = member_vals("failed_at_step").astype(np.int64)
    zeros = np.zeros(N, dtype=np.int64)
    traj = Trajectory(choice=run.choice, h=run.h, steps=run.steps, every=run.every,
                      physics=run.physics_for(N), layout=layout, terms=run.terms, states=states, status=status,
                      fail_step=fail, newton_iterations=zeros, newton_max=zeros,
                      steps_done=member_vals("steps_done").astype(np.int64),
                      max_h_omega=member_vals("max_h_omega").astype(np.float64))
    if "initial_omega" in ds and "initial_attitude" in ds:
        om0 = np.asarray(ds["initial_omega"].values, dtype=np.float64)
        R0 = np.asarray(ds["initial_attitude"].values, dtype=np.float64)
    else:
        lo, hi = (int(members.min()), int(members.max()) + 1) if N else (0, 0)
        om_all, R_all = initial_conditions(scene, lo, hi) if N else (np.zeros((0, 3)), np.zeros((0, 3, 3)))
        om0, R0 = om_all[members - lo], R_all[members - lo]
    out = trajectory_dataset(traj, omega0=om0, R0=R0)
    for n in ("newton_iterations_mean", "newton_iterations_max"):  # per member, not rebuilt: the stored ones
        if n in out:
            if n not in ds:
                out = out.drop_vars(n)
            else:
                out[n] = ds[n].variable
    for n in parameter_names():
        if n in ds and n in out and not np.array_equal(np.asarray(ds[n].values), out[n].values):
            raise ValueError(f"the dataset's {n!r} is not its scene's: its members were not run from the "
                             "stored scene alone, and their derived variables cannot be rebuilt")
    out = out.assign_coords({c: ds[c].variable for c in ("member", "t", "step") if c in ds.coords})
    out.attrs = dict(ds.attrs)
    return out


def _scene_tables(text: str) -> dict:
    import sys

    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib
    return tomllib.loads(text)
