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
from .initial import initial_conditions
from .io import ChunkedWriter
from .methods import get_method
from .physics import build_model, physics_of_scene
from .scene import Scene, load_scene, scene_to_toml
from .simulate import STATUS_MEANINGS, simulate


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
    path: Path | None = None

    @property
    def throughput(self) -> float:
        """member-steps per second of kernel time."""
        return self.members * self.steps / self.kernel_time if self.kernel_time > 0 else float("nan")

    def lines(self) -> list[str]:
        st = ", ".join(f"{k}: {v}" for k, v in self.status_counts.items())
        out = [
            f"scene {self.scene_name!r}, method {self.method}: {self.members} member(s) x {self.steps} steps, h = {self.h:g} s",
            f"  wall time {self.wall_time:.2f} s (kernels {self.kernel_time:.2f} s, compiling or "
            f"loading them {self.compile_time:.2f} s), throughput {self.throughput:,.0f} member-steps/s",
            f"  status   {st}",
        ]
        if self.first_fail_step:
            out.append(f"  first failure at step {self.first_fail_step} "
                       f"(t = {self.first_fail_step * self.h:g} s)")
        n_ok = self.status_counts.get("ok", 0)
        if n_ok:
            out += [
                f"  over the {n_ok} member(s) that completed:",
                f"  max |E_k - E_0|           {self.max_abs_energy_error:.3e} J "
                f"({self.max_rel_energy_error:.3e} of the initial mechanical energy; node values)",
                f"  max ||Gamma| - 1|         {self.max_gamma_defect:.3e}",
                f"  max h|Omega|              {self.max_h_omega:.3f} rad",
            ]
            if self.max_rel_energy_error_paper == self.max_rel_energy_error_paper:
                out.append(f"  (paper convention, step velocity with node values: "
                           f"{self.max_rel_energy_error_paper:.3e})")
        else:
            out.append("  no member completed: no accuracy figures")
        if get_method(self.method).family == "vi":
            out.append(f"  Newton iterations/step    mean {self.newton_mean:.2f}, max {self.newton_max}")
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
    integ = scene["integrator"]
    method, h, steps = integ["method"], float(integ["h"]), int(integ["steps"])
    members = int(scene["ensemble"]["members"])
    m = get_method(method)
    terms = build_model(physics_of_scene(scene), bool(scene["output"]["attitude"])).terms()
    attrs = global_attrs(scene_to_toml(scene), method=method, h=h,
                         friction=m.effective_friction(integ["friction"]),
                         start=m.effective_start(integ["start"]),
                         entropy=m.effective_entropy(integ["entropy"]), terms=terms,
                         history=history)
    return scene, attrs, RunSummary(scene["scene"]["name"], method, members, steps, h)


def run_chunk(scene: dict, lo: int, hi: int, *, progress_cb=None, kernel: str | None = None,
              threads: int | None = None) -> tuple[xr.Dataset, ChunkStats]:
    """Simulate members ``lo:hi`` of a resolved scene: the labelled chunk and its stats.

    The one code path shared by :func:`run_scene` and the Dask tasks of
    :mod:`liethermo.distributed`; member i's result depends only on (scene, i).
    ``progress_cb(n)`` gets the number of member-steps just done.
    """
    integ = scene["integrator"]
    method, h, steps = integ["method"], float(integ["h"]), int(integ["steps"])
    every = int(scene["output"]["every"])
    attitude = bool(scene["output"]["attitude"])
    phys = physics_of_scene(scene, hi - lo)
    om0, R0 = initial_conditions(scene, lo, hi)
    traj = simulate(phys, om0, R0, h, steps, method, friction=integ["friction"],
                    start=integ["start"], entropy=integ["entropy"], attitude=attitude,
                    every=every, newton_tol=float(integ["newton_tol"]),
                    newton_maxiter=int(integ["newton_maxiter"]),
                    progress=(lambda n, k=hi - lo: progress_cb(n * k)) if progress_cb else None,
                    threads=threads, **({"kernel": kernel} if kernel else {}))
    ds = trajectory_dataset(traj, omega0=om0, R0=R0, member_offset=lo)
    st = ChunkStats(members=hi - lo, kernel_time=traj.wall_time, compile_time=traj.compile_time)
    ncounts = len(STATUS_MEANINGS)
    st.counts = [int(c) for c in np.bincount(traj.status, minlength=ncounts)[:ncounts]]
    ok = traj.status == 0  # accuracy figures are over members that completed
    ee = np.abs(ds["energy_error"].values[ok])
    st.e_abs = max(st.e_abs, _nanmax(ee))
    em = np.abs(ds["mechanical_energy_initial"].values[ok])[:, None]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        st.e_rel = max(st.e_rel, _nanmax(ee / em))
        if "energy_error_paper" in ds:
            st.e_rel_paper = max(st.e_rel_paper,
                                 _nanmax(np.abs(ds["energy_error_paper"].values[ok]) / em))
        st.gdef = max(st.gdef, _nanmax(np.abs(np.linalg.norm(traj.gamma[ok], axis=-1) - 1.0)))
    st.hw = max(st.hw, _nanmax(traj.max_h_omega[ok]))
    st.nit_total = int(traj.newton_iterations.sum())
    st.nsteps_total = int(traj.steps_done.sum())
    st.nmax = int(traj.newton_max.max(initial=0))
    st.first_fail = int(traj.fail_step[~ok].min()) if not ok.all() else 0
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
    return summ


def run_scene(scene, out: str | Path | None = None, *, overrides=None,
              progress: bool | None = None, kernel: str | None = None,
              history: str | None = None) -> tuple[xr.Dataset | None, RunSummary]:
    """Run one scene with its own method.

    With ``out``: streams member chunks into the netCDF file (atomically) and
    returns ``(None, summary)``; without: returns the in-memory dataset.
    ``history``: the command line or API call recorded in the ``history``
    attribute (default: this call, ``liethermo.runner.run_scene(...)``).
    """
    if history is None:
        history = cf.api_call("liethermo.runner.run_scene", scene, out, overrides=overrides)
    scene, attrs, summ = scene_setup(scene, overrides, history)
    members, steps = summ.members, summ.steps
    chunk = int(scene["output"]["member_chunk"])
    t_wall = time.perf_counter()
    bar = _progress_bar(members * steps, progress, f"{scene['scene']['name']} [{summ.method}]")
    total = ChunkStats()
    pieces = []
    writer = ChunkedWriter(out, members, attrs) if out is not None else None
    try:
        for lo in range(0, members, chunk):
            hi = min(lo + chunk, members)
            ds, st = run_chunk(scene, lo, hi, progress_cb=bar.update if bar else None, kernel=kernel)
            total.merge(st)
            if writer is not None:
                writer.write(ds, lo)
            else:
                pieces.append(ds)
        if writer is not None:
            writer.close()
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    finally:
        if bar:
            bar.close()
    summ.wall_time = time.perf_counter() - t_wall
    finish_summary(summ, total)
    if writer is not None:
        summ.path = Path(out)
        return None, summ
    ds = xr.concat(pieces, dim="member", data_vars="minimal", coords="minimal", compat="override",
                   join="override") if len(pieces) > 1 else pieces[0]
    ds.attrs.update(attrs)
    return ds, summ


def _progress_bar(total: int, progress: bool | None, desc: str):
    """A tqdm bar over member-steps (auto: only on a terminal and for long runs)."""
    if progress is False:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="member-step", unit_scale=True, leave=False,
                disable=None if progress is None else False, mininterval=0.5)
