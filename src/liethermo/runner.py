"""Run a scene: initial conditions → kernels → labelled dataset → netCDF.

:func:`run_scene` is what ``liethermo run`` calls.  Members are simulated in
chunks of ``output.member_chunk`` and each chunk is labelled and (with an
output path) written before the next starts, so memory is bounded by one
chunk whatever the ensemble size.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

from . import cf
from .dataset import global_attrs, trajectory_dataset
from .faults import check_stop
from .findings import chunk_findings, finding_lines, merge_findings, physics_lines
from .initial import initial_conditions
from .methods import get_method
from .resolve import resolve
from .scene import Scene, load_scene, scene_to_toml
from .simulate import STATUS_MEANINGS


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
    status_counts: dict = field(default_factory=dict)
    max_abs_energy_error: float = float("nan")
    max_rel_energy_error: float = float("nan")
    max_rel_energy_error_paper: float = float("nan")
    max_gamma_defect: float = float("nan")
    newton_mean: float = float("nan")
    newton_max: int = 0
    max_h_omega: float = float("nan")
    first_fail_step: int = 0  # earliest step at which a member failed (0: none failed)
    diverged: int = 0  # completed members whose energy error exceeds DIVERGED_REL_ENERGY
    path: Path | None = None
    resumed_members: int = 0  # members taken over from an interrupted run
    solves_per_step: int = 0  # Newton solves per step of a variational integrator
    #: what the run's physics shows (liethermo.findings): lines from its parameters,
    #: and {name: [min, max]} over the completed members
    physics_notes: list = field(default_factory=list)
    findings: dict = field(default_factory=dict)

    @property
    def throughput(self) -> float:
        """member-steps per second of kernel time (of the members this run computed)."""
        n = self.members - self.resumed_members
        return n * self.steps / self.kernel_time if self.kernel_time > 0 else float("nan")

    def lines(self) -> list[str]:
        m = get_method(self.method)
        counts = dict(self.status_counts)
        if m.family != "vi":  # no Newton solve: the status cannot occur
            counts.pop("newton_not_converged", None)
        n_ok = counts.get("ok", 0)
        st = ", ".join(f"{k}: {v}" + (f" (of which {self.diverged} diverged: max |E_k - E_0| > "
                                       f"{DIVERGED_REL_ENERGY:g} x E_mech,0)" if k == "ok" and v else "")
                       for k, v in counts.items())
        out = [
            f"scene {self.scene_name!r}, method {self.method}: {self.members} member(s) x {self.steps} steps, h = {self.h:g} s",
            f"  wall time {self.wall_time:.3g} s (simulating and writing; not the command's start-up or figures)",
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
            if paper == paper:
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
        if m.family == "vi":
            n = self.solves_per_step or m.evaluations_per_step
            per_solve = (f"mean {self.newton_mean / n:.3g} per solve ({self.newton_mean:.3g} per step "
                         f"of {n} solves)" if n > 1 else f"mean {self.newton_mean:.3g} per solve (one per step)")
            out.append(f"  Newton iterations         {per_solve}, max {self.newton_max} in one solve")
        if self.resumed_members:
            out.append(f"  resumed: members 0-{self.resumed_members - 1} came from the interrupted run "
                       "(not in the times above)")
        if self.path is not None:
            out.append(f"  wrote {self.path}")
        return out


def _nanmax(a) -> float:
    a = np.asarray(a, dtype=float)
    a = a[np.isfinite(a)]
    return float(a.max()) if a.size else float("nan")


@dataclass
class ChunkStats:
    """What one member chunk contributes to a :class:`RunSummary`.

    Mergeable (``merge``) and JSON-serialisable (``to_dict``/``from_dict``), so
    a chunk computed elsewhere (a Dask task, a chunk file from an earlier run)
    is summarised exactly like one computed in-process.
    """

    members: int = 0
    kernel_time: float = 0.0
    compile_time: float = 0.0
    counts: list = field(default_factory=lambda: [0] * len(STATUS_MEANINGS))
    e_abs: float = -np.inf
    e_rel: float = -np.inf
    e_rel_paper: float = -np.inf
    gdef: float = -np.inf
    hw: float = -np.inf
    nit_total: int = 0
    nsteps_total: int = 0
    nmax: int = 0
    first_fail: int = 0  # earliest failing step over the chunk's members (0: none)
    diverged: int = 0  # completed members with max |E_k - E_0| > DIVERGED_REL_ENERGY x E_mech,0
    findings: dict = field(default_factory=dict)  # liethermo.findings: {name: [min, max]}

    def merge(self, other: "ChunkStats") -> "ChunkStats":
        self.members += other.members
        self.kernel_time += other.kernel_time
        self.compile_time += other.compile_time
        self.counts = [a + b for a, b in zip(self.counts, other.counts)]
        self.e_abs = max(self.e_abs, other.e_abs)
        self.e_rel = max(self.e_rel, other.e_rel)
        self.e_rel_paper = max(self.e_rel_paper, other.e_rel_paper)
        self.gdef = max(self.gdef, other.gdef)
        self.hw = max(self.hw, other.hw)
        self.nit_total += other.nit_total
        self.nsteps_total += other.nsteps_total
        self.nmax = max(self.nmax, other.nmax)
        fails = [f for f in (self.first_fail, other.first_fail) if f]
        self.first_fail = min(fails) if fails else 0
        self.diverged += other.diverged
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


def scene_setup(scene, overrides=None, history: str | None = None) -> tuple[Scene, dict, RunSummary]:
    """Resolve a scene: ``(scene, global attributes, empty RunSummary)``;
    ``history`` is the command line or API call stored in the attributes."""
    if not isinstance(scene, Scene) or overrides:
        scene = load_scene(scene, overrides)
    run = resolve(scene)
    c = run.choice
    attrs = global_attrs(scene_to_toml(scene), method=c.name, h=run.h, friction=c.friction, start=c.start,
                         entropy=c.entropy, composition=c.composition, terms=list(run.terms),
                         history=history)
    summ = RunSummary(scene["scene"]["name"], c.name, run.members, run.steps, run.h)
    summ.solves_per_step = len(c.method.substeps(c.composition or "small_error")) if c.family == "vi" else 0
    summ.physics_notes = physics_lines(run.physics)
    return scene, attrs, summ


#: Size of the timed probe behind :func:`estimate_time`: large enough that the
#: vectorized kernel runs full blocks, small enough to take well under a second.
PROBE_MEMBERS = 8192
PROBE_STEPS = 200


@dataclass
class TimeEstimate:
    """Kernel time a run will take on this machine, from a timed probe."""

    method: str
    seconds: float          # whole run, extrapolated from the probe's member-steps
    probe_members: int
    probe_steps: int
    probe_seconds: float    # the faster of two probe runs (warm kernel)
    compile_seconds: float  # compiling or loading the kernels from the cache, once

    def line(self) -> str:
        return (f"  {self.method}: about {human_seconds(self.seconds)} of kernel time on this machine "
                f"(from a timed probe of {self.probe_members} members x {self.probe_steps} steps; "
                f"compiling or loading kernels took {human_seconds(self.compile_seconds)})")


def human_seconds(s: float) -> str:
    """``0.42 s``, ``3.1 min``, ``2.5 h``, ``1.3 days``."""
    if not np.isfinite(s):
        return "unknown"
    if s < 60:
        return f"{s:.2g} s" if s < 10 else f"{s:.0f} s"
    if s < 3600:
        return f"{s / 60:.1f} min"
    if s < 86400:
        return f"{s / 3600:.1f} h"
    return f"{s / 86400:.1f} days"


def estimate_time(scene: Scene) -> TimeEstimate:
    """Time a short probe of the scene's own first members on the kernel the
    full run will use (compiled first, then the faster of two runs) and scale
    it to the run's member-steps.  Members that fail stop early in the probe as
    in the run, so the figure is the run's, not a healthy ensemble's."""
    run = resolve(scene)
    members, steps = run.members, run.steps
    pm, ps = min(members, PROBE_MEMBERS), min(steps, PROBE_STEPS)
    om0, R0 = initial_conditions(scene, 0, pm)
    best, compile_s = np.inf, 0.0
    for _ in range(2):
        traj = run.simulate(om0, R0, steps=ps, every=ps)
        best = min(best, traj.wall_time)
        compile_s += traj.compile_time
    return TimeEstimate(run.choice.name, best * (members * steps) / (pm * ps), pm, ps, best, compile_s)


def run_chunk(scene: dict, lo: int, hi: int, *, progress_cb=None, kernel: str | None = None,
              threads: int | None = None) -> tuple[xr.Dataset, ChunkStats]:
    """Simulate members ``lo:hi`` of a resolved scene: the labelled chunk and its stats.

    The one code path shared by :func:`run_scene` and the Dask tasks of
    :mod:`liethermo.distributed`; member i's result depends only on (scene, i).
    ``progress_cb(n)`` gets the number of member-steps just done.
    """
    check_stop()
    run = resolve(scene)
    om0, R0 = initial_conditions(scene, lo, hi)
    traj = run.simulate(om0, R0, kernel=kernel or "auto", threads=threads,
                        progress=(lambda n, k=hi - lo: progress_cb(n * k)) if progress_cb else None)
    ds = trajectory_dataset(traj, omega0=om0, R0=R0, member_offset=lo)
    st = ChunkStats(members=hi - lo, kernel_time=traj.wall_time, compile_time=traj.compile_time)
    ncounts = len(STATUS_MEANINGS)
    st.counts = [int(c) for c in np.bincount(traj.status, minlength=ncounts)[:ncounts]]
    ok = traj.status == 0  # accuracy figures are over members that completed
    ee = np.abs(ds["energy_error"].values[ok])
    st.e_abs = max(st.e_abs, _nanmax(ee))
    em = np.abs(ds["mechanical_energy_initial"].values[ok])[:, None]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        rel = ee / em
        st.e_rel = max(st.e_rel, _nanmax(rel))
        worst = np.max(np.where(np.isnan(rel), 0.0, rel), axis=1, initial=0.0)  # 0/0: no energy to lose
        st.diverged = int(np.count_nonzero(worst > DIVERGED_REL_ENERGY))
        if "energy_error_paper" in ds:
            st.e_rel_paper = max(st.e_rel_paper,
                                 _nanmax(np.abs(ds["energy_error_paper"].values[ok]) / em))
        st.gdef = max(st.gdef, _nanmax(np.abs(np.linalg.norm(traj.gamma[ok], axis=-1) - 1.0)))
    st.hw = max(st.hw, _nanmax(traj.max_h_omega[ok]))
    st.nit_total = int(traj.newton_iterations.sum())
    st.nsteps_total = int(traj.steps_done.sum())
    st.nmax = int(traj.newton_max.max(initial=0))
    st.first_fail = int(traj.fail_step[~ok].min()) if not ok.all() else 0
    with np.errstate(over="ignore", invalid="ignore"):
        st.findings = chunk_findings(ds, traj.physics)
    return ds, st


def finish_summary(summ: RunSummary, st: ChunkStats) -> RunSummary:
    """Fill ``summ`` from the merged stats of all chunks (wall time and path are the caller's)."""
    summ.kernel_time = st.kernel_time
    summ.compile_time = st.compile_time
    summ.status_counts = {STATUS_MEANINGS[k]: int(st.counts[k]) for k in range(len(st.counts))}
    nan = float("nan")
    summ.max_abs_energy_error = st.e_abs if np.isfinite(st.e_abs) else nan
    summ.max_rel_energy_error = st.e_rel if np.isfinite(st.e_rel) else nan
    summ.max_rel_energy_error_paper = st.e_rel_paper if np.isfinite(st.e_rel_paper) else nan
    summ.max_gamma_defect = st.gdef if np.isfinite(st.gdef) else nan
    summ.max_h_omega = st.hw if np.isfinite(st.hw) else nan
    summ.newton_mean = (st.nit_total / st.nsteps_total
                        if (get_method(summ.method).family == "vi" and st.nsteps_total) else nan)
    summ.newton_max = st.nmax
    summ.first_fail_step = st.first_fail
    summ.diverged = st.diverged
    summ.findings = dict(st.findings)
    return summ


def run_scene(scene, out: str | Path | None = None, *, overrides=None,
              progress: bool | None = None, kernel: str | None = None,
              history: str | None = None, resume=False) -> tuple[xr.Dataset | None, RunSummary]:
    """Run one scene with its own method.

    With ``out``: streams member chunks into the netCDF file (atomically) and
    returns ``(None, summary)``; without: returns the in-memory dataset.
    ``history``: the command line or API call recorded in the ``history``
    attribute (default: this call, ``liethermo.runner.run_scene(...)``).

    ``resume``: go on from what an interrupted or killed run of the same
    scene left for ``out`` (``True``: the best of
    :func:`liethermo.io.resume_sources`, or a given :class:`liethermo.io.ResumeSource`); the scene must be
    the same (the caller checks it: :func:`liethermo.preflight.prepare_run`).
    On a stop signal (:class:`liethermo.faults.Interrupted`) the chunks done
    are kept in ``<out>.partial`` for a resume, and the exception goes on
    with a phrase saying so in its ``kept`` list.
    """
    if history is None:
        history = cf.api_call("liethermo.runner.run_scene", scene, out, overrides=overrides)
    scene, attrs, summ = scene_setup(scene, overrides, history)
    members, steps = summ.members, summ.steps
    chunk = int(scene["output"]["member_chunk"])
    t_wall = time.perf_counter()
    bar = _progress_bar(members * steps, progress, f"{scene['scene']['name']} [{summ.method}]")
    total = ChunkStats()
    try:
        if out is None:
            pieces = []
            for lo in range(0, members, chunk):
                hi = min(lo + chunk, members)
                ds, st = run_chunk(scene, lo, hi, progress_cb=bar.update if bar else None, kernel=kernel)
                total.merge(st)
                pieces.append(ds)
        else:
            _run_to_file(scene, attrs, Path(out), summ, total, bar, kernel, resume)
    finally:
        if bar:
            bar.close()
    summ.wall_time = time.perf_counter() - t_wall
    finish_summary(summ, total)
    if out is not None:
        summ.path = Path(out)
        return None, summ
    ds = xr.concat(pieces, dim="member", data_vars="minimal", coords="minimal", compat="override",
                   join="override") if len(pieces) > 1 else pieces[0]
    ds.attrs.update(attrs)
    return ds, summ


def _run_to_file(scene, attrs, out: Path, summ: RunSummary, total: ChunkStats, bar, kernel, resume) -> None:
    """The chunk loop of a run with an output file: write, flush and journal
    each chunk; resume; keep the partial file on a stop signal."""
    from .faults import Interrupted, critical
    from .io import ChunkedWriter, Journal, journal_path, resume_sources

    members, steps = summ.members, summ.steps
    chunk = int(scene["output"]["member_chunk"])
    plan = [(lo, min(lo + chunk, members)) for lo in range(0, members, chunk)]
    source = None
    if resume is True:
        found = resume_sources(out)
        source = found[0] if found else None
    elif resume:
        source = resume
    writer = ChunkedWriter(out, members, attrs)
    journal = Journal(out, scene_to_toml(scene), members, chunk)
    jpath = journal_path(writer.tmp)
    i = 0
    copying = finished = False
    try:
        if source is not None and source.journal.chunks:
            copying = True
            recs = source.journal.chunks[:len(plan)]
            if all([r["lo"], r["hi"]] == list(plan[k]) for k, r in enumerate(recs)):
                writer.define_like(source.data)  # the layout the earlier run wrote
                for rec, arrays in source.read_chunks(writer.member_vars):
                    check_stop()
                    with critical():
                        crc = writer.write_arrays(arrays, rec["lo"])
                        journal.chunks.append({"lo": rec["lo"], "hi": rec["hi"], "crc": crc, "stats": rec["stats"]})
                    st = ChunkStats.from_dict(rec["stats"])
                    st.kernel_time = 0.0  # spent by the earlier run: not this run's throughput
                    total.merge(st)
                    if bar:
                        bar.update((rec["hi"] - rec["lo"]) * steps)
                    i += 1
                    del arrays
                with critical():
                    writer.sync()
                    journal.save(jpath)
            copying = False
            summ.resumed_members = journal.members_done
            source.remove()  # superseded by this run's file and journal
            source = None
        for k in range(i, len(plan)):
            lo, hi = plan[k]
            ds, st = run_chunk(scene, lo, hi, progress_cb=bar.update if bar else None, kernel=kernel)
            with critical():
                crc = writer.write(ds, lo)
                writer.sync()
                journal.chunks.append({"lo": lo, "hi": hi, "crc": crc, "stats": st.to_dict()})
                journal.save(jpath)
            del ds
            total.merge(st)
        with critical():
            writer.close()
            _unlink(jpath)
            finished = True
    except Interrupted as exc:
        if finished:  # the signal came while the file was being completed
            exc.kept.append(f"{out} written")
            raise
        what = _interrupted(exc, writer, journal, jpath, out, plan, copying, source)
        exc.kept.append(what)
        raise
    except BaseException:
        writer.abort()
        _unlink(jpath)
        raise


def _unlink(p: Path) -> None:
    try:
        p.unlink()
    except FileNotFoundError:
        pass


def _interrupted(exc, writer, journal, jpath, out, plan, copying, source) -> str:
    """Keep what a stopped run completed; the phrase for the one line."""
    from .io import journal_path, partial_path

    done = len(journal.chunks)
    where = f"member chunk {min(done + 1, len(plan))}/{len(plan)} of {out}"
    if copying or not done:
        writer.abort()
        _unlink(jpath)
        if source is not None:
            return (f"stopped at {where} while resuming: {source.data} kept as it was "
                    "(rerun with --resume to continue)")
        return f"stopped at {where}: no member chunk was complete, nothing kept"
    part = partial_path(out)
    try:
        writer.keep(part)
        journal.save(journal_path(part))
    except Exception:  # the file could not be closed or kept: do not leave a broken one
        writer.abort()
        _unlink(part)
        _unlink(journal_path(part))
        return f"stopped at {where}: the partial file could not be kept"
    finally:
        _unlink(jpath)
    hi = journal.members_done
    return (f"stopped at {where}: members 0-{hi - 1} kept in {part} "
            "(rerun with --resume to continue)")


def _progress_bar(total: int, progress: bool | None, desc: str):
    """A tqdm bar over member-steps (auto: only on a terminal and for long runs)."""
    if progress is False:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="member-step", unit_scale=True, leave=False,
                disable=None if progress is None else False, mininterval=0.5)
