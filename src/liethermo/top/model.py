"""The heavy top as a model of the run layer (:mod:`liethermo.models`).

What a run of the top needs beyond the common runner: its summary
(:class:`RunSummary`) and mergeable per-chunk figures (:class:`ChunkStats`),
its member chunk (:func:`run_chunk`: initial conditions → kernels → labelled
dataset), its global attributes (:func:`scene_setup`), its timed probe
(:func:`estimate_time`) and its preflight (:func:`estimate`,
:func:`check_parameters`).  The kernels and the dataset's variables live in
:mod:`liethermo.top.simulate` and :mod:`liethermo.top.dataset`; this module imports
them on first use, so that loading a scene stays light.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..models import MethodInfo, Model, StudyDefaults, closing_lines, register


def _status_meanings() -> dict:
    from .kernels.layout import STATUS_MEANINGS

    return STATUS_MEANINGS


#: a member that completed (status ok) counts as diverged when its largest
#: |E_k - E_0| exceeds this multiple of its initial mechanical energy E_mech,0
DIVERGED_REL_ENERGY = 1.0


@dataclass
class RunSummary:
    """What a run did, for the one-screen report."""

    scene_name: str
    method: str
    members: int
    steps: int
    h: float
    wall_time: float = 0.0
    kernel_time: float = 0.0
    compile_time: float = 0.0
    #: what ``wall_time`` measures, as the summary says it
    wall_what: str = "simulating and writing; not compiling, the command's start-up or figures"
    status_counts: dict = field(default_factory=dict)
    max_abs_energy_error: float = float("nan")
    max_rel_energy_error: float = float("nan")
    max_rel_energy_error_paper: float = float("nan")
    max_rel_energy_error_t0: float = float("nan")  # of the node values at t = 0 (a VI's start)
    start: str = ""  # the variational integrators' start
    max_gamma_defect: float = float("nan")
    newton_mean: float = float("nan")
    newton_max: int = 0
    max_h_omega: float = float("nan")
    first_fail_step: int = 0  # earliest step at which a member failed (0: none failed)
    diverged: int = 0  # completed members whose energy error exceeds DIVERGED_REL_ENERGY
    path: Path | None = None
    resumed_members: int = 0  # members taken over from an interrupted run
    solves_per_step: int = 0  # Newton solves per step of a variational integrator
    #: what the run's physics shows (liethermo.top.findings): lines from its parameters,
    #: and {name: [min, max]} over the completed members
    physics_notes: list = field(default_factory=list)
    findings: dict = field(default_factory=dict)

    @property
    def throughput(self) -> float:
        """member-steps per second of kernel time (of the members this run computed)."""
        n = self.members - self.resumed_members
        return n * self.steps / self.kernel_time if self.kernel_time > 0 else float("nan")

    def finish(self, st: "ChunkStats") -> "RunSummary":
        """Fill in the figures of the merged stats of every chunk."""
        return finish_summary(self, st)

    def lines(self) -> list[str]:
        from .findings import finding_lines
        from .methods import get_method

        m = get_method(self.method)
        counts = dict(self.status_counts)
        if not m.solves_newton:  # no Newton solve: the status cannot occur
            counts.pop("newton_not_converged", None)
        n_ok = counts.get("ok", 0)
        st = ", ".join(f"{k}: {v}" + (f" (of which {self.diverged} diverged: max |E_k - E_0| > "
                                       f"{DIVERGED_REL_ENERGY:g} x E_mech,0)" if k == "ok" and v else "")
                       for k, v in counts.items())
        out = [
            f"scene {self.scene_name!r}, method {self.method}: {self.members} member(s) x {self.steps} steps, h = {self.h:g} s",
            f"  wall time {self.wall_time:.3g} s ({self.wall_what})",
            f"  kernels  compiled or loaded in {self.compile_time:.3g} s, ran {self.kernel_time:.3g} s "
            f"({self.throughput:.3g} member-steps/s)",
            f"  status   {st}",
        ]
        if self.first_fail_step:
            out.append(f"  first failure at step {self.first_fail_step} "
                       f"(t = {self.first_fail_step * self.h:g} s)")
        if n_ok:
            paper = self.max_rel_energy_error_paper
            out += [
                f"  over the {n_ok} member(s) that completed:",
                f"  max |E_k - E_0|           {self.max_abs_energy_error:.3e} J = "
                f"{self.max_rel_energy_error:.3e} x E_mech,0 (node values)",
            ]
            t0 = self.max_rel_energy_error_t0
            first = {"node": "Omega(0)", "staggered": "Omega(h/2)"}.get(self.start)
            if first is not None and t0 == t0 and t0 > T0_ERROR_SHOWN:
                out += [f"                            {t0:.3e} x E_mech,0 of it already at t = 0 (start "
                        f"{self.start!r}: {first} is the first",
                        "                            step velocity, so the node momentum is not I Omega(0); "
                        "docs/model.md, Starts)"]
            if paper == paper and not m.composed:
                out.append(f"                            {paper:.3e} x E_mech,0 in the paper's convention "
                           "(step velocity with node values)")
            out += [
                f"  max ||Gamma| - 1|         {self.max_gamma_defect:.3e}",
                f"  max h|Omega|              {self.max_h_omega:.3g} rad (the largest angle turned in one step)",
                "  E_mech,0                  initial mechanical energy K_0 + V_0 + |m g l| (gravity's V_0 from "
                "its lowest value)",
            ]
            out += finding_lines(self.findings)
        else:
            out.append("  no member completed: no accuracy figures")
        out += self.physics_notes
        if m.solves_newton:
            n = self.solves_per_step or m.evaluations_per_step
            per_solve = (f"mean {self.newton_mean / n:.3g} per solve ({self.newton_mean:.3g} per step "
                         f"of {n} solves)" if n > 1 else f"mean {self.newton_mean:.3g} per solve (one per step)")
            out.append(f"  Newton iterations         {per_solve}, max {self.newton_max} in one solve")
        return out + closing_lines(self.resumed_members, self.path, "not in the times above")


def _nanmax(a) -> float:
    """The largest finite value of ``a`` (NaN if none)."""
    a = np.asarray(a, dtype=float)
    if a.size:
        m = float(np.max(a))  # one pass: finite and not 0 means no NaN, no +inf and one sign of zero
        if m != 0.0 and np.isfinite(m):
            return m
    m = float(np.max(a, where=np.isfinite(a), initial=-np.inf))
    return m if m != -np.inf else float("nan")


#: an energy error at t = 0 above this (relative to E_mech,0) is not round-off: the summary explains it
T0_ERROR_SHOWN = 1e-12


@dataclass
class ChunkStats:
    """What one member chunk contributes to a :class:`RunSummary`.

    Mergeable (``merge``) and JSON-serialisable (``to_dict``/``from_dict``), so
    a chunk computed elsewhere (a Dask task, a chunk file from an earlier run)
    is summarised exactly like one computed in-process.
    """

    members: int = 0
    kernel_time: float = 0.0
    #: the process's CPU time over the kernels of ``kernel_time``, s (0: not measured, e.g. on the GPU)
    kernel_cpu_time: float = 0.0
    compile_time: float = 0.0
    counts: list = field(default_factory=lambda: [0] * len(_status_meanings()))
    e_abs: float = -np.inf
    e_rel: float = -np.inf
    e_rel_paper: float = -np.inf
    e_rel_t0: float = -np.inf
    gdef: float = -np.inf
    hw: float = -np.inf
    nit_total: int = 0
    nsteps_total: int = 0
    nmax: int = 0
    first_fail: int = 0  # earliest failing step over the chunk's members (0: none)
    diverged: int = 0  # completed members with max |E_k - E_0| > DIVERGED_REL_ENERGY x E_mech,0
    findings: dict = field(default_factory=dict)  # liethermo.top.findings: {name: [min, max]}

    def merge(self, other: "ChunkStats") -> "ChunkStats":
        self.members += other.members
        self.kernel_time += other.kernel_time
        self.kernel_cpu_time += other.kernel_cpu_time
        self.compile_time += other.compile_time
        self.counts = [a + b for a, b in zip(self.counts, other.counts)]
        self.e_abs = max(self.e_abs, other.e_abs)
        self.e_rel = max(self.e_rel, other.e_rel)
        self.e_rel_paper = max(self.e_rel_paper, other.e_rel_paper)
        self.e_rel_t0 = max(self.e_rel_t0, other.e_rel_t0)
        self.gdef = max(self.gdef, other.gdef)
        self.hw = max(self.hw, other.hw)
        self.nit_total += other.nit_total
        self.nsteps_total += other.nsteps_total
        self.nmax = max(self.nmax, other.nmax)
        fails = [f for f in (self.first_fail, other.first_fail) if f]
        self.first_fail = min(fails) if fails else 0
        self.diverged += other.diverged
        from .findings import merge_findings

        merge_findings(self.findings, other.findings)
        return self

    def to_dict(self) -> dict:
        # -inf (no completed member yet) is not JSON: store it as None
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v)
                for k, v in self.__dict__.items()}

    @classmethod
    def from_dict(cls, d: dict) -> "ChunkStats":
        kw = {k: (-np.inf if v is None else v) for k, v in d.items()}
        return cls(**kw)


def scene_setup(scene, overrides=None, history: str | None = None) -> tuple:
    """Resolve a scene: ``(scene, global attributes, empty RunSummary)``;
    ``history`` is the command line or API call stored in the attributes."""
    from .dataset import global_attrs
    from .findings import physics_lines
    from .resolve import resolve
    from ..scene import load_scene, scene_to_toml
    from .scene import Scene

    if not isinstance(scene, Scene) or overrides:
        scene = load_scene(scene, overrides)
    run = resolve(scene)
    c = run.choice
    attrs = global_attrs(scene_to_toml(scene), method=c.name, h=run.h, friction=c.friction, start=c.start,
                         entropy=c.entropy, composition=c.composition, terms=list(run.terms),
                         history=history)
    summ = RunSummary(scene["scene"]["name"], c.name, run.members, run.steps, run.h)
    summ.start = c.start if c.method.solves_newton else ""
    summ.solves_per_step = len(c.method.substeps(c.composition or "small_error")) if c.method.solves_newton else 0
    summ.physics_notes = physics_lines(run.physics)
    return scene, attrs, summ


#: Size of the first probe call behind :func:`estimate_time`: large enough that the
#: vectorized kernel runs full blocks, small enough to take well under a second.
PROBE_MEMBERS = 8192
PROBE_STEPS = 200
#: a probe call at least this long (s) is timed; a shorter one grows, steps first
PROBE_MIN_SECONDS = 0.1
#: timed probe calls after the first (which compiles or loads the kernels): the fastest counts
PROBE_REPEATS = 3
#: at most this many calls to grow the probe (each scaled by the last call's time)
PROBE_GROWTHS = 3


@dataclass
class TimeEstimate:
    """Kernel time a run will take on this machine, from a timed probe."""

    method: str
    seconds: float          # whole run, extrapolated from the probe's member-steps
    probe_members: int
    probe_steps: int
    probe_seconds: float    # the fastest of the timed probe calls (warm kernel)
    compile_seconds: float  # compiling or loading the kernels from the cache, once
    #: labelling the chunks (energies, statistics; outside the kernels), scaled from
    #: the probe's by members x stored times
    host_seconds: float = 0.0

    @property
    def total_seconds(self) -> float:
        """Kernels and labelling (writing is the run layer's: :func:`liethermo.runner.estimate_time`)."""
        return self.seconds + self.host_seconds

    def line(self) -> str:
        from ..runner import human_seconds

        return (f"  {self.method}: about {human_seconds(self.seconds)} of kernel time on this machine "
                f"(from a timed probe of {self.probe_members} members x {self.probe_steps} steps; "
                f"compiling or loading kernels took {human_seconds(self.compile_seconds)}); labelling "
                f"the member chunks about {human_seconds(self.host_seconds)}")

    def warnings(self) -> list[str]:
        return []


def estimate_time(scene) -> TimeEstimate:
    """Time a probe of the scene's own first members on the kernel the full run
    will use and scale it to the run's member-steps.  The first call compiles or
    loads the kernels; while a call is shorter than :data:`PROBE_MIN_SECONDS` the
    probe grows (more steps, up to the run's, then more members, up to a member
    chunk), and the fastest of :data:`PROBE_REPEATS` calls of that size counts.  Members that fail stop
    early in the probe as in the run, so the figure is the run's, not a healthy
    ensemble's."""
    import math

    from .initial import initial_conditions
    from .resolve import resolve

    run = resolve(scene)
    members, steps = run.members, run.steps
    pm, ps = min(members, PROBE_MEMBERS), min(steps, PROBE_STEPS)
    om0, R0 = initial_conditions(scene, 0, pm)
    traj = run.simulate(om0, R0, steps=ps, every=ps)
    compile_s = traj.compile_time
    most = min(members, max(pm, int(scene["output"]["member_chunk"])))
    for _ in range(PROBE_GROWTHS):  # a few milliseconds weigh a call's fixed costs and a core waking from idle
        grow = 1.1 * PROBE_MIN_SECONDS / max(traj.wall_time, 1e-6)
        if grow <= 1.1 or (ps == steps and pm == most):
            break
        ps2 = min(steps, math.ceil(ps * grow))
        pm2 = min(most, max(pm, math.ceil(pm * grow * ps / ps2)))
        if pm2 > pm:
            om0, R0 = initial_conditions(scene, 0, pm2)
        pm, ps = pm2, ps2
        traj = run.simulate(om0, R0, steps=ps, every=ps)
        compile_s += traj.compile_time
    best = np.inf
    for _ in range(PROBE_REPEATS):
        traj = run.simulate(om0, R0, steps=ps, every=ps)
        best = min(best, traj.wall_time)
        compile_s += traj.compile_time
    # labelling: the probe's chunk as a run labels it (two stored times), scaled by stored values;
    # the faster of two, as for the kernels (the first call pays for one-time imports, about 3 s)
    import time

    label = np.inf
    for _ in range(2):
        t = time.perf_counter()
        label_chunk(scene, traj, om0, R0)
        label = min(label, time.perf_counter() - t)
    host = label * (members / pm) * ((steps // int(scene["output"]["every"]) + 1) / 2)
    return TimeEstimate(run.choice.name, best * (members * steps) / (pm * ps), pm, ps, best, compile_s, host)


#: members per slice, at least, when a chunk's summary figures are computed in slices on several threads
STATS_SLICE_MEMBERS = 8192


def label_chunk(scene: dict, traj, om0, R0, lo: int = 0) -> tuple:
    """(dataset, stats) of a simulated member chunk starting at member ``lo``: the
    stats from what the summary reads, the dataset with the variables the scene
    stores; nothing else is computed.

    Where the file stores only the state (nothing computed for it), the stats are
    computed over member slices on as many threads as the kernels are given
    (:func:`liethermo.threads.kernel_threads`; numpy releases the GIL in its loops):
    every figure is a count, a max, a min or a sum of integers, so the slices give the
    stats of the whole chunk exactly."""
    from .dataset import chunk_labels, stored_variables
    from .kernels import parallel as _par

    labels = chunk_labels(traj, omega0=om0, R0=R0, member_offset=lo)
    keep = stored_variables(scene, traj.layout)
    n = traj.states.shape[0]
    parts = min(_par.default_threads(), n // STATS_SLICE_MEMBERS)
    if parts < 2 or keep is None or keep & labels.computed_on_demand():
        return labels.dataset(keep), _labelled_stats(traj, labels)
    bounds = np.linspace(0, n, parts + 1).astype(int)
    slices = [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]

    def stats_of(sl):
        part = traj.take(sl)
        return _labelled_stats(part, chunk_labels(part, omega0=om0[sl], R0=R0[sl]))

    pending = _par.pool(parts).map(stats_of, slices)  # the kernels' pool: they wait meanwhile
    ds = labels.dataset(keep)  # the stored variables only label the state: nothing shared is computed
    got = list(pending)
    stats = got[0]
    for other in got[1:]:
        stats.merge(other)
    stats.kernel_time, stats.kernel_cpu_time = traj.wall_time, traj.cpu_time  # once, not per slice
    stats.compile_time = traj.compile_time
    return ds, stats


def run_chunk(scene: dict, lo: int, hi: int, *, progress_cb=None, kernel: str | None = None,
              threads: int | None = None) -> tuple:
    """Simulate members ``lo:hi`` of a resolved scene: the labelled chunk and its stats.

    The one code path shared by :func:`liethermo.runner.run_scene` and the Dask tasks of
    :mod:`liethermo.distributed`; member i's result depends only on (scene, i).
    ``progress_cb(n)`` gets the number of member-steps just done.
    """
    traj, om0, R0 = _simulated(scene, lo, hi, progress_cb=progress_cb, kernel=kernel, threads=threads)
    return label_chunk(scene, traj, om0, R0, lo)


def _labelled_stats(traj, ds) -> "ChunkStats":
    """The stats of a chunk from its trajectory and its labelled variables (a
    dataset, or the :class:`~liethermo.top.dataset.ChunkLabels` that compute
    them when asked)."""
    from .findings import chunk_findings
    from .kernels.terms import norm3
    from .simulate import STATUS_MEANINGS

    st = ChunkStats(members=traj.states.shape[0], kernel_time=traj.wall_time, kernel_cpu_time=traj.cpu_time,
                    compile_time=traj.compile_time)
    ncounts = len(STATUS_MEANINGS)
    st.counts = [int(c) for c in np.bincount(traj.status, minlength=ncounts)[:ncounts]]
    ok = traj.status == 0  # accuracy figures are over members that completed
    every = bool(ok.all())
    if every:
        ok = slice(None)  # the same members, without copies
    em = np.abs(ds["mechanical_energy_initial"].values[ok])[:, None]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if every and _compiled_figures(ds):
            _energy_figures_compiled(st, ds, em, traj.gamma)
        else:
            ee = np.abs(ds["energy_error"].values[ok])
            st.e_abs = max(st.e_abs, _nanmax(ee))
            rel = ee / em
            st.e_rel = max(st.e_rel, _nanmax(rel))
            st.e_rel_t0 = max(st.e_rel_t0, _nanmax(rel[:, :1]))
            worst = np.fmax.reduce(rel, axis=1, initial=0.0)  # NaN (0/0: no energy to lose) counts as 0
            st.diverged = int(np.count_nonzero(worst > DIVERGED_REL_ENERGY))
            st.gdef = max(st.gdef, _nanmax(np.abs(norm3(traj.gamma[ok]) - 1.0)))
        if "energy_error_paper" in ds:
            st.e_rel_paper = max(st.e_rel_paper,
                                 _nanmax(np.abs(ds["energy_error_paper"].values[ok]) / em))
    st.hw = max(st.hw, _nanmax(traj.max_h_omega[ok]))
    st.nit_total = int(traj.newton_iterations.sum())
    st.nsteps_total = int(traj.steps_done.sum())
    st.nmax = int(traj.newton_max.max(initial=0))
    st.first_fail = int(traj.fail_step[~ok].min()) if not every else 0
    with np.errstate(over="ignore", invalid="ignore"):
        st.findings = chunk_findings(ds, traj.physics)
    return st


def _compiled_figures(ds) -> bool:
    """Whether the energy figures of a chunk whose members all completed come from the
    compiled pass (:func:`_energy_figures_compiled`): the labels know the energy's parts
    and numba compiles (not under ``NUMBA_DISABLE_JIT``)."""
    from .kernels.reductions import energy_error_figures

    return getattr(ds, "energy_parts", None) is not None and hasattr(energy_error_figures, "overloads")


def _energy_figures_compiled(st: "ChunkStats", ds, em: np.ndarray, gamma: np.ndarray) -> None:
    """``st``'s energy figures and |Γ| defect from the energy's parts in one compiled pass
    each (:mod:`liethermo.top.kernels.reductions`), with the values numpy's arrays give:
    the same operations in the same order, maxima over the finite values."""
    from .kernels.reductions import energy_error_figures, unit_norm_defect

    K, V, dU, K0, V0 = (np.asarray(a, dtype=np.float64) for a in ds.energy_parts())
    K, V, dU = np.broadcast_arrays(K, V, dU)  # a part the same at every time (none acting) broadcasts
    out = np.empty(4)
    energy_error_figures(K, V, dU, K0, V0, em[:, 0], float(DIVERGED_REL_ENERGY), out)
    st.e_abs = max(st.e_abs, float(out[0]))
    st.e_rel = max(st.e_rel, float(out[1]))
    st.e_rel_t0 = max(st.e_rel_t0, float(out[2]))
    st.diverged = int(out[3])
    g = np.empty(1)
    unit_norm_defect(gamma, g)
    st.gdef = max(st.gdef, float(g[0]))


def _simulated(scene, lo: int, hi: int, *, progress_cb=None, kernel=None, threads=None) -> tuple:
    """(trajectory, Ω₀, R₀) of members ``lo:hi``."""
    from .initial import initial_conditions
    from .resolve import resolve

    run = resolve(scene)
    om0, R0 = initial_conditions(scene, lo, hi)
    traj = run.simulate(om0, R0, kernel=kernel or "auto", threads=threads,
                        progress=(lambda n, k=hi - lo: progress_cb(n * k)) if progress_cb else None)
    return traj, om0, R0


def _chunk(scene, lo: int, hi: int, *, progress_cb=None, kernel=None, threads=None) -> tuple:
    """(trajectory, labelled dataset with every variable) of members ``lo:hi``."""
    from .dataset import trajectory_dataset

    traj, om0, R0 = _simulated(scene, lo, hi, progress_cb=progress_cb, kernel=kernel, threads=threads)
    return traj, trajectory_dataset(traj, omega0=om0, R0=R0, member_offset=lo)


def law_defects(traj) -> dict:
    """Per member, the defects of the exact laws a run of the top can be held to:
    |Γ| = 1 on the stored nodes and, where every step is stored, the
    Kelvin–Noether law (discrete for the variational integrators, continuous by
    the trapezoid rule for every method: :mod:`liethermo.top.laws`)."""
    from .laws import continuous_kelvin_noether_residual, kelvin_noether_residual

    with np.errstate(invalid="ignore"):
        gdef = np.nanmax(np.abs(np.linalg.norm(traj.gamma, axis=-1) - 1.0), axis=1)
    out = {"gamma_norm": (gdef, "1", "max over stored nodes of ||Gamma_k| - 1|")}
    if traj.every == 1:
        out["kelvin_noether_discrete"] = (
            kelvin_noether_residual(traj), "1", "max residual of the discrete Kelvin-Noether law / max |mu| "
            "(variational integrators; NaN where it does not apply)")
        out["kelvin_noether_continuous"] = (
            continuous_kelvin_noether_residual(traj), "1", "max defect of the continuous Kelvin-Noether law "
            "by the trapezoid rule between nodes / max |mu|")
    return out


def finish_summary(summ: RunSummary, st: ChunkStats) -> RunSummary:
    """Fill ``summ`` from the merged stats of all chunks (wall time and path are the caller's)."""
    from .methods import get_method

    STATUS_MEANINGS = _status_meanings()
    summ.kernel_time = st.kernel_time
    summ.compile_time = st.compile_time
    summ.status_counts = {STATUS_MEANINGS[k]: int(st.counts[k]) for k in range(len(st.counts))}
    nan = float("nan")
    summ.max_abs_energy_error = st.e_abs if np.isfinite(st.e_abs) else nan
    summ.max_rel_energy_error = st.e_rel if np.isfinite(st.e_rel) else nan
    summ.max_rel_energy_error_paper = st.e_rel_paper if np.isfinite(st.e_rel_paper) else nan
    summ.max_rel_energy_error_t0 = st.e_rel_t0 if np.isfinite(st.e_rel_t0) else nan
    summ.max_gamma_defect = st.gdef if np.isfinite(st.gdef) else nan
    summ.max_h_omega = st.hw if np.isfinite(st.hw) else nan
    summ.newton_mean = (st.nit_total / st.nsteps_total
                        if (get_method(summ.method).solves_newton and st.nsteps_total) else nan)
    summ.newton_max = st.nmax
    summ.first_fail_step = st.first_fail
    summ.diverged = st.diverged
    summ.findings = dict(st.findings)
    return summ


#: Memory of a chunk per byte of its labelled output, beyond the kernel state
#: (Ω, Γ and R are views of the state; the energies are new arrays): 1.0
#: matched the measured peak to within 6 % (docs/operations.md, "Disk and memory estimates").
MEMORY_FACTOR = 1.0

def top_device_bytes(members: int, width: int, nparam: int, shared: bool, n_out: int) -> int:
    """Device memory of one member chunk of the top (bytes): state, parameters
    (one row when the members share them), status and the outputs of one
    kernel call (at most :data:`OUT_BYTES`, at least one output)."""
    from .kernels.layout import NFSTAT, NISTAT, OUT_BYTES

    out = min(max(1, n_out) * width * members * 8, max(OUT_BYTES, width * members * 8))
    return 8 * (width * members + (nparam if shared else nparam * members)
                + (NISTAT + NFSTAT) * members) + out


def estimate(scene: dict):
    """Output size and chunk memory of a resolved scene, from the layout of a
    one-member, two-time dataset labelled like a run's, with the variables the
    scene stores (``output.variables``; no kernel runs)."""
    from .dataset import select_variables, trajectory_dataset
    from ..io import disk_chunk_members
    from ..preflight import Estimate
    from .resolve import resolve
    from .simulate import Trajectory

    integ, outp = scene["integrator"], scene["output"]
    steps, every = int(integ["steps"]), int(outp["every"])
    n_t = steps // every + 1
    run = resolve(scene)
    phys = run.physics
    layout = run.model.layout(run.method.layout)
    width = layout.size
    one = lambda dt: np.zeros(1, dtype=dt)  # noqa: E731
    traj = Trajectory(choice=run.choice, h=run.h, steps=every,
                      every=every, physics=phys, layout=layout, terms=run.terms,
                      states=np.zeros((1, 2, width)), status=one(np.int8), fail_step=one(np.int64),
                      newton_iterations=one(np.int64), newton_max=one(np.int64), steps_done=one(np.int64),
                      max_h_omega=one(np.float64))
    with np.errstate(all="ignore"):
        full = trajectory_dataset(traj, omega0=np.zeros((1, 3)), R0=np.eye(3)[None])
    members = int(scene["ensemble"]["members"])

    def per_member(ds):
        out = []
        for var in ds.variables.values():
            if "member" not in var.dims:
                continue
            n = var.dtype.itemsize if var.dtype.kind != "O" else 16
            for d in var.dims[1:]:
                n *= n_t if d == "t" else ds.sizes[d]
            out.append((n, disk_chunk_members(members, n, int(outp["member_chunk"])) if var.ndim > 1 else 0))
        return out

    kept = select_variables(full, scene, layout)
    stored = per_member(kept)  # the file: the variables the scene stores
    per = sum(n for n, _ in stored)
    # a chunk computes the variables its file stores and those its summary reads (energies,
    # temperature, |mu|): every variable bounds that from above
    memory = int(MEMORY_FACTOR * sum(n for n, _ in per_member(full))) + n_t * width * 8
    est = Estimate(per, memory, members, int(outp["member_chunk"]), stored,
                   variables=tuple(sorted(n for n, v in kept.data_vars.items() if "member" in v.dims)))
    if scene["ensemble"]["device"] == "gpu":

        est.device_memory = top_device_bytes(est.chunk_members, width, run.model.nparam,
                                             run.model.shared is not None, (steps // every))
    return est


def _parameter_keys() -> tuple[str, ...]:
    from .kernels.terms import registry

    return (("body.radius", "body.semi_axes", "body.density", "body.mass", "body.molar_mass",
             "body.upper_mass_fraction", "body.inertia", "thermo.heat_capacity", "body.center_of_mass")
            + tuple(st.path for t in registry() for st in t.settings) + ("thermo.T0",))




#: Integer keys the kernels and arrays take as 64-bit integers.
INT64_KEYS = ("integrator.steps", "integrator.newton_maxiter", "output.every", "output.member_chunk",
              "ensemble.members")


def check_parameters(scene: dict) -> None:
    """The kernels get numbers they can take: integers that fit in 64 bits, and
    finite parameters (every key may be valid on its own and the derived mass,
    moments, friction, heat capacity or gravity torque still overflow or
    vanish: a radius of 1e-300 m)."""
    from ..preflight import PreflightError
    from .resolve import resolve

    if scene["ensemble"]["device"] == "gpu":
        from ..gpu import gpu_available

        ok, why = gpu_available()
        if not ok:
            raise PreflightError(f"scene key 'ensemble.device': \"gpu\" cannot run here: {why}")
        if scene["integrator"]["method"] == "reference":
            raise PreflightError("scene key 'ensemble.device': the reference method runs on the CPU only "
                                 "(\"gpu\" runs vi, vi4, vi6, split, split4, split6, rk2 and rk4)")
    for key in INT64_KEYS:
        section, name = key.split(".")
        v = scene[section][name]
        if isinstance(v, int) and v > np.iinfo(np.int64).max:
            raise PreflightError(f"scene key '{key}': too large for the kernels (at most "
                                 f"{np.iinfo(np.int64).max}) (got {v})")

    try:
        with np.errstate(all="ignore"):
            run = resolve(scene)
            phys, p = run.physics, run.model.P
        bad = not all(np.all(np.isfinite(v)) for v in vars(phys).values() if isinstance(v, np.ndarray))
        bad = bad or not np.all(np.isfinite(p))
        why = "not finite numbers"
    except ArithmeticError as exc:
        bad, why = True, f"not computable ({exc})"
    if bad:
        raise PreflightError(f"the kernel parameters derived from the scene (mass, moments of inertia, friction, "
                             f"heat capacity, gravity torque) are {why}; check {', '.join(_parameter_keys())}")
    _check_start(scene, phys)


def _check_start(scene: dict, phys) -> None:
    """Every term's condition on the start (e.g. the coupled top's temperature
    must start positive), with Ω·𝕀₀Ω bounded over the members: the members'
    spins reach spin_range[1] × |Ω(0)| in any direction, so the bound uses
    the largest moment."""
    from .initial import file_members
    from .kernels.terms import registry

    omega = np.asarray(scene["initial"]["omega"], dtype=np.float64)
    given = file_members(scene)
    if given is not None:
        kin2 = float(np.max(np.einsum("mi,i,mi->m", given[0], phys.inertia[0], given[0])))
        what = "max over the members of initial.file of Ω·𝕀₀Ω"
    elif int(scene["ensemble"]["members"]) == 1:
        kin2, what = float(omega @ (phys.inertia[0] * omega)), "Ω·𝕀₀Ω"
    else:
        from .initial import max_spin

        kin2, what = float(phys.inertia[0].max()) * max_spin(scene) ** 2, "I_max (spin_range[1] |Ω(0)|)²"
    for t in registry():
        problem = t.start_problem(scene, phys, kin2, what)
        if problem is not None:
            from ..preflight import PreflightError

            key, why = problem
            raise PreflightError(f"scene key '{key}': {why}")


#: Runs of more member-steps than this are timed by a probe before they start
#: (the command line says how long one will take when it exceeds a minute).
LONG_RUN_MEMBER_STEPS = 2**26

#: the top's own study kinds ({kind: module})
STUDY_KINDS = {k: f"liethermo.top.studies.{k}" for k in ("paper", "stability", "viscosity_sweep", "coupling",
                                                          "flat_spin", "entropy_rate")}


class HeavyTop(StudyDefaults, Model):
    """The heavy top in a Stokes fluid (its keys: :data:`liethermo.top.scene.KEYS`; a scene
    without another model's table is the top's, :data:`liethermo.models.UNMARKED_SCENES_MODEL`)."""

    name = "top"
    title = "the heavy top"
    description = ("the heavy top in Stokes flow (variational integrators, splittings and Runge-Kutta "
                   "methods)")

    @property
    def scene_model(self):
        from .scene import SCENE_MODEL

        return SCENE_MODEL

    study_kinds = STUDY_KINDS
    stats_type = ChunkStats
    store_less = "output.every, output.attitude, output.variables"
    #: a study reads the derived variables of the datasets it runs
    study_outputs = {"output.variables": ["all"]}

    def derived(self, ds):
        """Every variable a run can write, from the state ``ds`` stores, bit for bit
        (:func:`liethermo.top.dataset.derive`)."""
        from .dataset import derive

        with np.errstate(over="ignore", invalid="ignore"):
            return derive(ds)

    def methods(self) -> dict[str, MethodInfo]:
        from .methods import METHODS

        return {n: MethodInfo(n, m.order(), tuple(m.laws), m.description) for n, m in METHODS.items()}

    def _full(self, ds):
        """``ds`` with the derived variables (a dataset of the default variables gets them)."""
        return ds if "energy_error" in ds else self.derived(ds)

    def study_state(self, ds) -> dict:
        ds = self._full(ds)
        return {"omega": (ds["omega"].values, "rad s-1", "body angular velocity Omega (node values)", None),
                "gamma": (ds["gamma"].values, "1", "direction of gravity Gamma", None),
                "entropy": (ds["entropy"].values, "J K-1", "entropy S", None),
                # the energy that moves between the mechanical and the internal one
                "total_energy": (ds["energy_error"].values, "J", "total energy E (node values)",
                                 float(np.max(np.abs(ds["mechanical_energy_initial"].values))))}

    def method_overrides(self, label: str) -> dict:
        from .methods import MethodChoice

        return MethodChoice.parse(label).overrides()

    def method_details(self, label: str) -> dict:
        from .methods import MethodChoice

        c = MethodChoice.parse(label)
        vi = c.method.solves_newton
        return {"start": c.start if vi else "—", "friction": c.friction if vi else "—",
                "entropy update": c.entropy if vi else "—"}

    def method_order(self, label: str) -> int:
        from .methods import MethodChoice

        return MethodChoice.parse(label).order()

    def relative_energy_error(self, ds):
        ds = self._full(ds)
        with np.errstate(divide="ignore", invalid="ignore"):
            return ds["energy_error"].values / np.abs(ds["mechanical_energy_initial"].values)[:, None]

    energy_convention_names = ("paper",)  # the step velocity with node values (the paper's)

    def energy_error_of(self, ds, convention: str = "node"):
        """(E_k − E₀)/E_mech,0 (dimensionless) with E_mech,0 = K₀ + V₀ + |m g ℓ|, the
        energy friction can turn into heat.  ``convention="node"``: node values
        (every method); ``"paper"``: the variational integrators' step velocity
        with the node values (the paper's figure)."""
        name = {"node": "energy_error", "paper": "energy_error_paper"}.get(convention)
        if name is None:
            raise ValueError(f"convention must be 'node' or 'paper', got {convention!r}")
        ds = self._full(ds)
        if name not in ds:
            raise KeyError(f"{name}: this dataset has no energy error in the {convention} convention "
                           "(it exists for the variational integrators only)")
        rel = ds[name] / ds["mechanical_energy_initial"]
        rel.attrs = {"units": "1", "long_name": f"relative total energy error ({convention} values)"}
        return rel

    def energy_conventions(self, ds) -> dict:
        ds = self._full(ds)
        if "energy_error_paper" not in ds:
            return {}
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return {"paper": ds["energy_error_paper"].values / np.abs(ds["mechanical_energy_initial"].values)[:, None]}

    def dissipation_overrides(self, scene, factor: float) -> dict:
        from .kernels.terms import registry

        return {s.path: float(f"{float(factor) * scene[s.section][s.name]:.15g}") for t in registry()
                if t.friction for s in t.settings
                if isinstance(scene[s.section][s.name], (int, float)) and not isinstance(scene[s.section][s.name], bool)}

    def kernel_for(self, scene) -> str:
        from .simulate import kernel_for

        return kernel_for(scene["integrator"]["method"], int(scene["ensemble"]["members"]),
                          int(scene["integrator"]["steps"]))

    def run_with_laws(self, scene, *, kernel=None, threads=None):
        traj, ds = _chunk(scene, 0, int(scene["ensemble"]["members"]), kernel=kernel, threads=threads)
        return ds, ChunkStats(members=ds.sizes["member"], kernel_time=traj.wall_time, kernel_cpu_time=traj.cpu_time,
                              compile_time=traj.compile_time), law_defects(traj)

    def ode(self, scene, lo, hi):
        from .initial import initial_conditions
        from .physics import physics_of_scene
        from .laws import continuous_rhs

        om, R = initial_conditions(scene, lo, hi)
        phys = physics_of_scene(scene, hi - lo)  # the same physics for every member
        y0 = np.concatenate([om, R[:, 2, :], np.zeros((hi - lo, 1))], axis=1)  # y = (Ω, Γ, σ)
        return y0, [continuous_rhs(phys, m) for m in range(hi - lo)], lambda y: {"omega": y[0:3], "gamma": y[3:6]}

    def initial_conditions(self, scene, lo: int, hi: int):
        from .initial import initial_conditions

        return initial_conditions(scene, lo, hi)

    def setup(self, scene, history):
        _, attrs, summ = scene_setup(scene, None, history)
        return attrs, summ

    def run_chunk(self, scene, lo, hi, *, progress_cb=None, kernel=None, threads=None):
        return run_chunk(scene, lo, hi, progress_cb=progress_cb, kernel=kernel, threads=threads)

    def warm(self, scene, methods, progress):
        from .warmup import start_warming

        return start_warming(scene, methods)

    def figures(self, outputs, folder, stem):
        from .plotting import scene_figures

        return scene_figures(dict(outputs), folder, stem=stem)

    def check_parameters(self, scene) -> None:
        check_parameters(scene)

    def estimate(self, scene):
        return estimate(scene)

    def estimate_time(self, scene):
        return estimate_time(scene)

    def long_run(self, scene) -> bool:
        return int(scene["ensemble"]["members"]) * int(scene["integrator"]["steps"]) > LONG_RUN_MEMBER_STEPS


register(HeavyTop())
