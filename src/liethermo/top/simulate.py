"""Array-level driver: run an ensemble with any method, in chunks.

This layer knows numpy, the physics and the kernels, not xarray or files.  It
builds the kernels' model (:func:`liethermo.top.physics.build_model`), the
initial states (with the variational integrator's start), advances the
kernels chunk by chunk (reporting progress) and returns a :class:`Trajectory`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numba
import numpy as np

from ..faults import check_stop
from .kernels import fast as _fast
from .kernels import layout as _lay
from .kernels import parallel as _par
from .kernels import simple as _simple
from .kernels.layout import STATUS_MEANINGS, STATUS_NEWTON, STATUS_NONFINITE, STATUS_OK  # noqa: F401
from .kernels.layout import StateLayout
from .methods import Method, MethodChoice
from .physics import KernelModel, Physics, build_model, entropy_of_heat, node_velocity, potential_span

#: Reference substep: h_ref · ω_bound ≤ this, small enough that the reference's
#: own error stays at round-off on the built-in scenes (tests/test_convergence.py)
REFERENCE_STEP_ANGLE = 0.05
DEFAULT_NEWTON_TOL = 1e-14
DEFAULT_NEWTON_MAXITER = 30
#: the first kernel call of a run covers this many member-steps (a few tens of
#: milliseconds of the paper scene's VI; benchmarks/README.md has the figures) ...
CHUNK_MEMBER_STEPS = 2_000_000
#: ... and the later ones grow (at most 4× per call) towards this wall time:
#: frequent enough for a progress bar and for a stop signal to be acted on
#: promptly, rare enough that what each call costs besides its steps (loading
#: every block's state into its buffer and back, waking the threads) does not show
CALL_SECONDS = 0.1
#: below this many members one thread is faster than waking others
SMALL_ENSEMBLE = 64
#: below this many member-steps "auto" runs the one-member-per-iteration
#: kernel: it compiles in about half the time of the vectorized one and costs
#: a few tens of milliseconds more to run (benchmarks/README.md)
SMALL_RUN_MEMBER_STEPS = 2**20


def kernel_for(method: str, members: int, steps: int, kernel: str = "auto") -> str:
    """The ensemble loop a run uses: "fast" (vectorized blocks) or "simple";
    ``kernel="auto"`` picks "simple" for the reference and for small runs."""
    if kernel not in ("auto", "fast", "simple"):
        raise ValueError(f"unknown kernel {kernel!r}: expected 'auto', 'fast' or 'simple'")
    if method == "reference":
        return "simple"
    if kernel == "auto":
        return "simple" if members * steps <= SMALL_RUN_MEMBER_STEPS else "fast"
    return kernel


@dataclass
class Trajectory:
    """Result of :func:`simulate`.

    ``states[m, j]`` is the state (columns of ``layout``) of member m at step
    ``k = j * every`` (time ``k h``); ``j = 0`` is the initial state.  Values
    after a member's failure are NaN.  For the variational integrators the
    state holds the node values (Γ_k, σ_k, the node momentum μ_k) and the
    step velocity Ω_k of the step that starts at t_k; :attr:`omega` is the
    node velocity Ω(t_k) = 𝕀(S_k)⁻¹μ_k for every method.  ``choice``: the
    method and the variants it ran (also read as ``method``, ``family``,
    ``start``, ``friction``, ``entropy`` and ``composition``).
    """

    choice: MethodChoice
    h: float
    steps: int
    every: int
    physics: Physics
    layout: StateLayout
    terms: tuple
    states: np.ndarray
    status: np.ndarray
    fail_step: np.ndarray
    newton_iterations: np.ndarray  # total per member
    newton_max: np.ndarray  # max per solve, per member
    steps_done: np.ndarray
    max_h_omega: np.ndarray
    wall_time: float = 0.0  # kernel time, s (compilation excluded)
    compile_time: float = 0.0  # compiling the kernels or loading them from the cache, s
    reference_substeps: int = 0
    #: where the steps ran: "cpu" or "gpu"
    device: str = "cpu"
    #: the time of the stepping kernels alone, s: on the GPU the kernel launches
    #: (CUDA events, summed), without the copies; on the CPU the same as ``wall_time``
    kernel_seconds: float = 0.0
    #: the process's CPU time over the chunk loop of ``wall_time`` (all its threads), s, on the CPU; 0 on the GPU.
    #: Unlike wall time it does not grow while the machine's other load holds the cores.
    cpu_time: float = 0.0

    @property
    def method(self) -> str:
        return self.choice.name

    @property
    def family(self) -> str:
        return self.choice.family

    @property
    def start(self) -> str:
        return self.choice.start

    @property
    def friction(self) -> str | None:
        return self.choice.friction

    @property
    def entropy(self) -> str | None:
        return self.choice.entropy

    @property
    def composition(self) -> str | None:
        """vi4, vi6, split4, split6: the composition they ran ("small_error" | "triple_jump")."""
        return self.choice.composition

    @property
    def step_index(self) -> np.ndarray:
        return np.arange(self.states.shape[1]) * self.every

    @property
    def times(self) -> np.ndarray:
        return self.step_index * self.h

    def take(self, members: slice) -> "Trajectory":
        """The members ``members`` (a slice: views, no copies)."""
        from dataclasses import replace

        return replace(self, physics=self.physics.take(members), states=self.states[members],
                       status=self.status[members], fail_step=self.fail_step[members],
                       newton_iterations=self.newton_iterations[members], newton_max=self.newton_max[members],
                       steps_done=self.steps_done[members], max_h_omega=self.max_h_omega[members])

    def part(self, name: str) -> np.ndarray | None:
        sl = self.layout.slice(name)
        return None if sl is None else self.states[..., sl]

    @property
    def gamma(self) -> np.ndarray:
        return self.part("gamma")

    @property
    def thermo(self) -> bool:
        """Whether the state carries the entropy (or the heat): something dissipates."""
        return self.layout.has("sigma") or self.layout.has("heat")

    @property
    def sigma(self) -> np.ndarray:
        """σ = S − S₀ (J K⁻¹); zeros when nothing dissipates (S stays S₀).
        The splittings carry the heat q = U − U₀ instead: σ = S(U₀ + q) − S₀."""
        q = self.part("heat")
        if q is not None:
            return entropy_of_heat(self.physics, q[..., 0])
        s = self.part("sigma")
        if s is None:
            z = np.zeros(self.states.shape[:-1])
            z[np.isnan(self.states[..., 0])] = np.nan
            return z
        return s[..., 0]

    @property
    def omega(self) -> np.ndarray:
        """The node velocity Ω(t_k) (rad s⁻¹) of every method."""
        if self.layout.has("momentum"):  # the VI's node momentum, the splittings' state
            return node_velocity(self.physics, self.part("momentum"), self.part("sigma")[..., 0]
                                 if self.layout.has("sigma") else None)
        return self.part("omega")

    @property
    def omega_step(self) -> np.ndarray | None:
        """VI: the step velocity Ω_k ≈ Ω(t_k + h/2) of the step that starts at t_k."""
        return self.part("omega_step")

    @property
    def momentum(self) -> np.ndarray | None:
        return self.part("momentum")

    def newton_condition(self) -> np.ndarray:
        """VI family: per member, the largest 2-norm condition number of the Newton Jacobian
        (:func:`liethermo.top.kernels.vi.newton_jacobian`, every term of the member's model) at the stored step
        velocities, over the accepted steps and the substep sizes f_i h; NaN where no step was accepted."""
        from .kernels.vi import FRICTION_WEIGHTS, newton_jacobian
        from .methods import METHODS
        from .physics import build_model

        wl, wr = FRICTION_WEIGHTS[self.friction]
        X, out = self.omega_step, np.full(self.states.shape[0], np.nan)
        for m in range(X.shape[0]):
            model, best = build_model(self.physics.take(slice(m, m + 1))).model, 0.0
            for k in range(X.shape[1] - 1):
                if not np.all(np.isfinite(X[m, k + 1])):
                    break
                for f in METHODS[self.method].substeps(self.composition or "small_error"):
                    best = max(best, float(np.linalg.cond(newton_jacobian(model, f * self.h, wl, wr,
                                                                          *map(float, X[m, k])))))
            out[m] = best if best > 0 else np.nan
        return out

    @property
    def attitude(self) -> np.ndarray | None:
        R = self.part("attitude")
        return None if R is None else R.reshape(R.shape[:-1] + (3, 3))


def omega_bound(physics: Physics, omega0: np.ndarray) -> np.ndarray:
    """Per-member upper bound (rad s⁻¹) on |Ω(t)| of the continuous flow: the
    mechanical energy can only decrease, so K(t) ≤ K₀ + (max V − min V);
    plus the rate each term adds at that spin (friction, pendulum)."""
    from .kernels.terms import registry

    I = physics.inertia
    Imin = I.min(axis=1)
    K0 = 0.5 * np.sum(I * omega0 ** 2, axis=1)
    w = np.sqrt(2.0 * (K0 + potential_span(physics)) / Imin)
    bound = w
    for t in registry():
        bound = bound + t.rate_bound(physics, w)
    return bound


def reference_substeps(h: float, physics: Physics, omega0: np.ndarray) -> np.ndarray:
    """Per-member DOP853 substep count for a step h, from each member's own data."""
    wb = omega_bound(physics, omega0)
    n = np.ceil(abs(h) * np.where(np.isfinite(wb), wb, 0.0) / REFERENCE_STEP_ANGLE)
    return np.maximum(1, n).astype(np.int64)


#: (kernel, _type_key of its arguments) of the calls already compiled or loaded in this process
_READY: set = set()


def _type_key(a):
    """What numba's type of an argument depends on: an array's dtype, dimensions, layout,
    writability and alignment, a tuple's class and items, a scalar's Python type.  Cheaper
    than ``numba.typeof`` of the model's nested tuples (1.5 ms a chunk)."""
    if isinstance(a, np.ndarray):
        f = a.flags
        return a.dtype.str, a.ndim, f.c_contiguous, f.f_contiguous, f.writeable, f.aligned
    if isinstance(a, tuple):
        return (type(a),) + tuple(_type_key(x) for x in a)
    return type(a)


def _ensure_compiled(fn, args) -> float:
    """Compile (or load from the cache) ``fn`` for these arguments; seconds spent.  A call
    whose arguments have the types of one made before is ready (a key that missed a type
    would only leave its compiling in the kernels' time: the call itself dispatches on numba's
    own types)."""
    if not hasattr(fn, "overloads"):  # NUMBA_DISABLE_JIT: plain Python
        return 0.0
    t0 = time.perf_counter()
    key = (fn, tuple(_type_key(a) for a in args))
    if key in _READY:
        return time.perf_counter() - t0
    sig = tuple(numba.typeof(a) for a in args)
    if sig not in fn.overloads:
        fn.compile(sig)
    _READY.add(key)
    return time.perf_counter() - t0


def staggered_omega(physics: Physics, omega0: np.ndarray, R0: np.ndarray, h: float) -> np.ndarray:
    """Ω(h/2) from the initial data, by the high-accuracy reference (N, 3)."""
    tr = simulate(physics, omega0, R0, 0.5 * h, 1, "reference", kernel="simple")
    return tr.states[:, 1, tr.layout.slice("omega")]


def simulate(
    physics: Physics,
    omega0: np.ndarray,
    R0: np.ndarray,
    h: float,
    steps: int,
    method: str | MethodChoice = "vi",
    *,
    attitude: bool = False,
    every: int = 1,
    newton_tol: float = DEFAULT_NEWTON_TOL,
    newton_maxiter: int = DEFAULT_NEWTON_MAXITER,
    ref_substeps: int | None = None,
    heat_bound: float | None = None,
    chunk_steps: int | None = None,
    progress: Callable[[int], None] | None = None,
    threads: int | None = None,
    kernel: str = "auto",
    compile_only: bool | str = False,
    device: str = "cpu",
) -> Trajectory | None:
    """Integrate an ensemble.

    ``physics`` (N members), initial body angular velocities ``omega0``
    (N, 3, rad s⁻¹) and attitudes ``R0`` (N, 3, 3; Γ₀ = R₀ᵀe₃), S = S₀;
    ``steps`` steps of size h (s), keeping every ``every``-th.  ``method``:
    a :class:`~liethermo.top.methods.MethodChoice` (a run's, a study's, or
    :meth:`MethodChoice.of` a name and its variants: the variational
    integrators' ``friction``, ``start`` and ``entropy``, the compositions'
    ``composition``), or a method's name, which runs with the package's
    defaults (legendre start, trapezoid friction, symmetric update,
    small_error compositions).
    ``progress(n)`` is called with the number of steps just advanced.
    ``chunk_steps``: steps per kernel call; by default the first call covers
    CHUNK_MEMBER_STEPS member-steps and later calls grow towards CALL_SECONDS
    of wall time each (the results do not depend on it, bit for bit).
    ``kernel``: "fast" (vectorized blocks), "simple" (one member at a time)
    or "auto" ("simple" below SMALL_RUN_MEMBER_STEPS member-steps, where
    compiling dominates, else "fast"; the reference always runs on
    "simple"): :func:`kernel_for`.  Both give bitwise the same results.  ``compile_only``: compile the kernels this
    run needs (or load them from numba's cache) and return None — what a
    process warming the cache for another one does; ``"start"``: only the
    variational integrators' start kernel.  ``heat_bound``: an upper bound
    (J) of the heat any member can produce; given, an ensemble whose heat can
    take σ/c_v beyond 2⁻¹⁶ (a small heat capacity) evaluates 1/T with a wider
    polynomial and keeps the vectorized path (runs pass their scene's,
    :func:`liethermo.top.initial.heat_bound`, the same for every member chunk);
    left out, the cubic, with the exact fallback beyond its range.
    ``device``: "cpu", or "gpu": the steps run on a CUDA device through
    numba-cuda, one thread per member (:mod:`liethermo.top.kernels.cuda`; every
    method but the reference); the state goes to the device once, each
    kernel call's outputs come back after it, and the results agree with
    the CPU's to round-off, with the same status flags and statistics.  A
    machine without a usable device (:func:`liethermo.gpu.gpu_available`)
    is refused before any work.  ``Trajectory.kernel_seconds`` is then the
    kernels' own time (``wall_time``: the chunk loop with its copies);
    ``kernel`` and ``threads`` only concern the variational integrators'
    start, which stays on the CPU.  Without ``chunk_steps``, a kernel call
    makes as many outputs as fit in
    :data:`liethermo.top.kernels.cuda.OUT_BYTES` of device memory and
    :data:`liethermo.top.kernels.cuda.CALL_MEMBER_STEPS`.
    """
    if isinstance(method, MethodChoice):
        choice = method
    else:
        kernel_for(str(method), 0, 0, kernel)  # rejects an unknown kernel before any work
        choice = MethodChoice.of(method)
    m: Method = choice.method
    kernel_for(m.name, 0, 0, kernel)
    if device not in ("cpu", "gpu"):
        raise ValueError(f"unknown device {device!r}: expected 'cpu' or 'gpu'")
    gpu = device == "gpu"
    if gpu and m.name == "reference":
        raise ValueError("method 'reference' runs on the CPU only (device='gpu' runs "
                         "vi, vi4, vi6, split, split4, split6, rk2 and rk4)")
    if gpu:
        from ..gpu import require_gpu

        require_gpu()
    if steps % every:
        raise ValueError(f"steps ({steps}) must be a multiple of every ({every})")
    omega0, R0 = _float_array(omega0, 2), _float_array(R0, 3)  # read only: no copies
    N = physics.n
    if omega0.shape != (N, 3) or R0.shape != (N, 3, 3):
        raise ValueError(f"omega0 must be ({N}, 3) and R0 ({N}, 3, 3) for {N} members, got "
                         f"{omega0.shape} and {R0.shape}")
    km: KernelModel = build_model(physics, attitude, heat=heat_bound)
    problem = m.refusal(km.model)
    if problem is not None:
        raise ValueError(problem)
    layout = km.layout(m.layout)
    eff_start, eff_friction = choice.start, choice.friction
    if m.solves_newton and layout.has("sigma_next"):  # the entropy joins the Newton unknowns
        from .kernels.terms import registry

        for t in registry():
            problem = t.vi_refusal(eff_start, eff_friction)
            if problem is not None:
                raise ValueError(f"{problem[1]} (got {problem[0].split('.')[1]}="
                                 f"{eff_start if problem[0].endswith('start') else eff_friction!r})")
    fast = kernel_for(m.name, N, steps, kernel) == "fast"
    n_out = steps // every
    IS = np.zeros((N, _lay.NISTAT), np.int64)
    FS = np.zeros((N, _lay.NFSTAT))
    compile_time = 0.0
    nsub = 0
    if threads is None and N < SMALL_ENSEMBLE:
        threads = 1  # a few members: waking threads costs more than it gains

    x0 = staggered_omega(physics, omega0, R0, h) if (choice.start == "staggered" and N) else None
    Y = m.initial_state(layout, physics, omega0, R0, x0)
    start_args = None
    if m.solves_newton:
        stepper = m.stepper(choice, newton_tol=newton_tol, newton_maxiter=newton_maxiter)
        # the start kernel: the first step velocity or the node momentum (see vi_start_members)
        start_args = (km.model, km.shared, Y, km.P, 0, N, float(stepper.factors[0] * h), stepper.wl,
                      stepper.wr, eff_start == "legendre", float(newton_tol), int(newton_maxiter), IS)
    else:
        nsub = 1
        if m.name == "reference":
            nsub = int(ref_substeps) if ref_substeps else 0
            IS[:, _lay.IS_NSUB] = reference_substeps(h, physics, omega0)
        stepper = m.stepper(choice, nsub)

    states = np.empty((N, n_out + 1, layout.size))  # row 0: the initial state; later rows NaN until written
    adapt = chunk_steps is None
    if gpu:
        states[:, 1:] = np.nan  # a failed member's later rows stay NaN
        from .kernels import cuda as _cuda

        out_per_chunk = (_cuda.outputs_per_call(N, layout.size, n_out, every) if adapt
                         else max(1, chunk_steps // every))
        traj = dict(choice=choice, h=float(h), steps=int(steps), every=int(every), physics=physics,
                    layout=layout,
                    terms=tuple(km.terms()))
        return _simulate_gpu(m, km, stepper, Y, IS, FS, states,
                             start_args, float(h), int(every), n_out,
                             out_per_chunk, progress, threads, compile_only, traj)
    if adapt:
        chunk_steps = max(every, min(steps, CHUNK_MEMBER_STEPS // max(N, 1)))
    out_per_chunk = max(1, chunk_steps // every)

    # one driver per memory layout, for every method
    if fast:
        fn, n_items = _fast.advance_blocks, -(-N // _fast.BLOCK)
    else:
        fn, n_items = _simple.advance_members, N

    def args_for(j0, nj):
        # outputs into states[:, j0:j0 + nj]: the whole array goes in, so a kernel's types
        # (its numba specialization) do not depend on the slice being contiguous (one member)
        return (stepper, km.model, km.shared, Y, km.P), (float(h), int(every), int(nj), states, int(j0), IS, FS)

    # compile the main kernel first, then the variational integrators' start:
    # a process warming the cache for this run compiles the start meanwhile
    if n_out and N and compile_only != "start":
        a, b = args_for(1, min(out_per_chunk, n_out))
        compile_time += _ensure_compiled(fn, a + (0, min(1, n_items)) + b)
    if start_args is not None and N:
        compile_time += _ensure_compiled(_simple.vi_start_members, start_args)
        if not compile_only:
            _par.run_ranges(_simple.vi_start_members, N, start_args[:4], start_args[6:], threads)
    if compile_only:
        return None
    if hasattr(_lay.start_rows, "overloads"):
        _lay.start_rows(states, Y)  # Y after the start kernel; a failed member's later rows stay NaN
    else:  # NUMBA_DISABLE_JIT: the same in numpy
        states[:, 0], states[:, 1:] = Y, np.nan
    t0, c0 = time.perf_counter(), time.process_time()
    j = 0
    while j < n_out:
        check_stop()  # a stop signal is acted on between kernel calls
        nj = min(out_per_chunk, n_out - j)
        a, b = args_for(1 + j, nj)  # written in place
        tc = time.perf_counter()
        _par.run_ranges(fn, n_items, a, b, threads)
        if adapt:
            grow = CALL_SECONDS / max(time.perf_counter() - tc, 1e-6)
            out_per_chunk = max(out_per_chunk, min(4 * out_per_chunk, int(out_per_chunk * grow)))
        j += nj
        if progress is not None:
            progress(nj * every)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    # a member that failed keeps NaN from its failing step on (the kernels
    # leave its later outputs untouched), and its initial row if it could not start
    return Trajectory(
        choice=choice, h=float(h), steps=int(steps), every=int(every), physics=physics,
        layout=layout, terms=tuple(km.terms()), states=states, **_member_stats(IS, FS),
        wall_time=wall, compile_time=compile_time, kernel_seconds=wall, cpu_time=cpu,
        reference_substeps=((int(nsub) if nsub else int(IS[:, _lay.IS_NSUB].max(initial=0)))
                            if m.name == "reference" else 0),
    )


def _float_array(a, ndim: int) -> np.ndarray:
    """``a`` as float64 with at least ``ndim`` dimensions (leading ones added), copied only where
    its type asks for it."""
    a = np.asarray(a, dtype=np.float64)
    return a.reshape((1,) * (ndim - a.ndim) + a.shape) if a.ndim < ndim else a


def _member_stats(IS: np.ndarray, FS: np.ndarray) -> dict:
    """The Trajectory's per-member run statistics from the kernels' (N, NISTAT) and (N, NFSTAT)
    tables: their columns as views (no copies; what reads them copies what it keeps), the
    status as int8."""
    return dict(status=IS[:, _lay.IS_STATUS].astype(np.int8), fail_step=IS[:, _lay.IS_FAIL_STEP],
                newton_iterations=IS[:, _lay.IS_NEWTON_TOTAL], newton_max=IS[:, _lay.IS_NEWTON_MAX],
                steps_done=IS[:, _lay.IS_STEPS], max_h_omega=FS[:, _lay.FS_MAX_H_OMEGA])


def _simulate_gpu(m: Method, km: KernelModel, stepper, Y, IS, FS, states, start_args, h: float,
                  every: int, n_out: int, out_per_chunk: int, progress, threads, compile_only,
                  traj: dict) -> Trajectory | None:
    """The chunk loop of :func:`simulate` on the device
    (:func:`liethermo.top.kernels.cuda.advance_on_device`), after the variational
    integrators' start on the CPU; ``traj``: the Trajectory's other fields."""
    from .kernels import cuda as _cuda

    N = Y.shape[0]
    compile_time = 0.0
    if start_args is not None and N:
        compile_time += _ensure_compiled(_simple.vi_start_members, start_args)
        if not compile_only:
            _par.run_ranges(_simple.vi_start_members, N, start_args[:4], start_args[6:], threads)
    run_args = (stepper, km.model, km.shared, Y, km.P, h, every, n_out, states, IS, FS, out_per_chunk)
    if compile_only:
        if n_out and N and compile_only != "start":
            compile_time += _cuda.advance_on_device(*run_args, compile_only=True)[1]
        return None
    states[:, 0] = Y
    kernel_seconds = wall = 0.0
    if n_out and N:
        t0 = time.perf_counter()
        kernel_seconds, ct = _cuda.advance_on_device(*run_args, progress=progress)
        compile_time += ct
        wall = time.perf_counter() - t0 - ct
    return Trajectory(
        **traj, states=states, **_member_stats(IS, FS),
        wall_time=wall, compile_time=compile_time, device="gpu", kernel_seconds=kernel_seconds,
    )
