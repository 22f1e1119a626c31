"""The fluid on the torus as a model of the run layer (:mod:`liethermo.models`).

Runs go through the common runner: members in chunks of ``output.member_chunk``,
each written as it finishes, with the journal, the lock, ``--resume`` and
``--dask`` of every run.  Member k's fields depend on (scene, k) only, and the
fixed point's predictor takes its order from the chunk size the scene sets.

This module is light: the kernels and xarray load on first use.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..numerics.matrix_flow import budget_members
from ..models import BaseSummary, MethodInfo, Model, StudyDefaults, closing_lines, register, wall_line


def _max(a) -> float:
    a = np.asarray(a, dtype=float)
    a = a[np.isfinite(a)]
    return float(a.max()) if a.size else -np.inf


def _min(a) -> float:
    a = np.asarray(a, dtype=float)
    a = a[np.isfinite(a)]
    return float(a.min()) if a.size else np.inf


@dataclass
class TorusStats:
    """What one member chunk adds to a torus run's summary (mergeable, JSON-serialisable)."""

    members: int = 0
    kernel_time: float = 0.0
    failed: int = 0
    energy_error: float = -np.inf       # max |H − H(0)| / H(0)
    entropy_drop: float = -np.inf       # max fall of S_tot between kept times (J K-1)
    theta_min: float = np.inf           # least eigenvalue of Θ (K)
    conduction_substeps: int = 0
    conduction_rejected: int = 0
    conduction_seconds: float = 0.0
    its_sum: float = 0.0
    its_n: int = 0
    status: dict = field(default_factory=dict)

    def merge(self, o: "TorusStats") -> "TorusStats":
        for k in ("members", "kernel_time", "failed", "conduction_substeps", "conduction_rejected",
                  "conduction_seconds", "its_sum", "its_n"):
            setattr(self, k, getattr(self, k) + getattr(o, k))
        self.energy_error = max(self.energy_error, o.energy_error)
        self.entropy_drop = max(self.entropy_drop, o.entropy_drop)
        self.theta_min = min(self.theta_min, o.theta_min)
        for k, n in o.status.items():
            self.status[k] = self.status.get(k, 0) + n
        return self

    def to_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in self.__dict__.items()}

    @classmethod
    def from_dict(cls, d: dict) -> "TorusStats":
        inf = {"theta_min": np.inf}
        return cls(**{k: (inf.get(k, -np.inf) if v is None else v) for k, v in d.items()})

    @classmethod
    def of(cls, ds, traj) -> "TorusStats":
        from .kernels import STATUS_MEANINGS

        st = cls(members=ds.sizes["member"], kernel_time=traj.kernel_seconds)
        flags = ds["status"].values
        st.failed = int((flags != 0).sum())
        st.status = {name: int((flags == f).sum()) for f, name in STATUS_MEANINGS.items()}
        with np.errstate(invalid="ignore"):
            st.energy_error = _max(np.abs(ds["energy_error"].values))
            st.entropy_drop = _max(-np.diff(ds["entropy"].values, axis=1)) if ds.sizes["t"] > 1 else -np.inf
        st.theta_min = _min(ds["theta_min"].values)
        st.conduction_substeps = traj.conduction.substeps
        st.conduction_rejected = traj.conduction.rejected
        st.conduction_seconds = traj.conduction_seconds
        its = ds["fixed_point_iterations"].values[:, 1:]
        fin = np.isfinite(its)
        st.its_sum, st.its_n = float(its[fin].sum()), int(fin.sum())
        return st


@dataclass(kw_only=True)
class TorusSummary(BaseSummary):
    """What a torus run did, for the one-screen report."""

    N: int
    stats: TorusStats = field(default_factory=TorusStats)

    def lines(self) -> list[str]:
        st = self.stats
        fin = lambda v: v if np.isfinite(v) else float("nan")  # noqa: E731
        out = [f"{self.method}: {self.members} member(s), N = {self.N}, h = {self.h:g} s, "
               f"t = {self.steps * self.h:g} s",
               f"  stepping {st.kernel_time:.3g} s (the members' steps and diagnostics; not the writing or figures)",
               wall_line(self.wall_time),
               "  status   " + ", ".join(f"{k}: {v}" for k, v in st.status.items()),
               f"  |H − H(0)|/H(0) ≤ {fin(st.energy_error):.2e}; "
               + ("S_tot never fell between kept times" if not st.entropy_drop > 0 else
                  f"S_tot fell by at most {st.entropy_drop:.2e} J K-1 between kept times")
               + f"; least eigenvalue of Θ {fin(st.theta_min):.4g} K",
               f"  conduction: {st.conduction_substeps} sub-step(s), {st.conduction_rejected} halved, "
               f"{st.conduction_seconds:.3g} s"]
        if st.its_n and st.its_sum > 0:  # rk4 solves no fixed point
            out.append(f"  fixed-point iterations per step: mean {st.its_sum / st.its_n:.2f}")
        if st.failed:
            why = ", ".join(f"{v} {k}" for k, v in st.status.items() if k != "ok" and v)
            out.append(f"  {st.failed} member(s) stopped ({why}): see status and failed_step")
        return out + closing_lines(self.resumed_members, self.path, "not in the stepping time above")


#: steps of one member that ``--check`` times (the first ones: where a step too large fails)
PROBE_STEPS = 3


@dataclass
class TimeEstimate:
    seconds: float
    per_step: float
    steps: int
    members: int
    #: what stopped the probe's member in its steps ("" where it did not stop), and at which step
    stopped: str = ""
    stopped_at: int = -1

    def line(self) -> str:
        return (f"time: about {self.seconds:.3g} s ({1e3 * self.per_step:.3g} ms per member-step measured here, "
                f"{self.members} member(s) × {self.steps} steps)")

    def warnings(self) -> list[str]:
        long = [f"this run takes about {self.seconds / 3600:.2g} hours"] if self.seconds > 3600 else []
        return long + self.cautions()

    def cautions(self) -> list[str]:
        """The warnings a run gives before it starts whatever its length."""
        if not self.stopped:
            return []
        return [f"liethermo: warning: the timed probe's first member stopped with {self.stopped} at step "
                f"{self.stopped_at} of its first {PROBE_STEPS}: this run's members will probably stop too "
                "(a smaller integrator.h, or a larger integrator.max_iter for a fixed point)"]



class Torus(StudyDefaults, Model):
    """Zeitlin's sine-bracket fluid on the torus with heat (a scene with a ``[torus]`` table)."""

    name = "torus"
    title = "the fluid on the torus"
    description = ("Zeitlin's sine-bracket fluid on the torus with viscosity, heat conduction and buoyancy "
                   "(energy-exact Cayley midpoint, Lie-Poisson midpoint, RK4)")
    scene_table = "torus"
    stats_type = TorusStats
    study_kinds = {"torus_convection": "liethermo.torus.studies.torus_convection",
                   "torus_resolution": "liethermo.torus.studies.torus_resolution"}
    store_less = "output.every, output.vorticity, output.entropy_field"
    chunk_sets_bits = True
    not_in_results = frozenset({("output", "figures"), ("output", "compare"), ("output", "theta_map"),
                                ("output", "animation")})
    study_outputs = {"output.vorticity": True, "output.entropy_field": True}

    @property
    def scene_model(self):
        from .scene import SCENE_MODEL

        return SCENE_MODEL

    def methods(self) -> dict[str, MethodInfo]:
        from . import run as tr

        return MethodInfo.table(tr.METHOD_ORDER, tr.METHOD_LAWS, tr.METHOD_DESCRIPTION)

    # ---------------------------------------------------------- studies
    def study_state(self, ds) -> dict:
        W = ds["vorticity_real"].values + 1j * ds["vorticity_imag"].values
        out = {"vorticity": (W, "s-1", "vorticity matrix W", None)}
        if "entropy_density_real" in ds:
            S = ds["entropy_density_real"].values + 1j * ds["entropy_density_imag"].values
            out["entropy_density"] = (S, "J K-1 m-2", "entropy density matrix S", None)
        return out

    def relative_energy_error(self, ds):
        return ds["energy_error"].values

    def dissipation_overrides(self, scene, factor: float) -> dict:
        f = float(factor)
        return {"fluid.kinematic_viscosity": float(f"{f * scene['fluid']['kinematic_viscosity']:.15g}"),
                "thermo.conductivity": float(f"{f * scene['thermo']['conductivity']:.15g}")}

    def method_overrides(self, label: str) -> dict:
        if label not in self.methods():
            raise ValueError(f"{label!r} is not a method of {self.title} ({', '.join(self.methods())})")
        return {"integrator.method": label}

    def run_with_laws(self, scene, *, kernel=None, threads=None):
        ds, st = self.run_chunk(scene, 0, int(scene["ensemble"]["members"]), kernel=kernel, threads=threads)
        with np.errstate(invalid="ignore"):
            S = ds["entropy"].values
            drop = np.nanmax(np.maximum(-np.diff(S, axis=1), 0.0), axis=1) if S.shape[1] > 1 else np.zeros(len(S))
        return ds, st, {"entropy_drop": (drop, "J K-1", "largest fall of S_tot between kept times")}

    # ---------------------------------------------------------- a run
    def initial_conditions(self, scene, lo: int, hi: int):
        from .run import initial_fields

        return initial_fields(scene, np.arange(lo, hi))

    def setup(self, scene, history):
        from .run import run_attrs

        itg = scene["integrator"]
        attrs = run_attrs(scene, itg["method"], history)
        return attrs, TorusSummary(scene.name, itg["method"], int(scene["ensemble"]["members"]), int(itg["steps"]),
                                   float(itg["h"]), N=int(scene["torus"]["N"]))

    def run_chunk(self, scene, lo, hi, *, progress_cb=None, kernel=None, threads=None):
        from .run import integrate, run_attrs, trajectory_dataset

        method = scene["integrator"]["method"]
        W0, S0 = self.initial_conditions(scene, lo, hi)
        kw = dict(method=method, progress=False, budget_members=budget_members(scene), threads=threads)
        if scene["ensemble"]["device"] == "gpu":
            from ..gpu import namespace
            from .run import integrate_xp

            traj = integrate_xp(namespace("gpu"), scene, W0, S0, **kw)
        else:
            traj = integrate(scene, W0, S0, **kw)
        ds = trajectory_dataset(scene, traj, method, member_offset=lo, attrs=run_attrs(scene, method))
        if progress_cb is not None:
            progress_cb((hi - lo) * int(scene["integrator"]["steps"]))
        return ds, TorusStats.of(ds, traj)

    def figures(self, outputs, folder, stem):
        from ..cf import open_dataset
        from . import plotting

        datasets = {}
        for m, p in outputs.items():
            with open_dataset(p) as ds:
                datasets[m] = ds.load()
        return plotting.draw(datasets, folder, stem)

    def check_parameters(self, scene) -> None:
        from ..gpu import device_refusal
        from ..preflight import PreflightError
        from . import step as ts
        from .run import thermo_of

        why = device_refusal(scene, ts.XP_METHODS)
        if why is not None:
            raise PreflightError(why)
        try:
            ts.check_method(scene["integrator"]["method"], thermo_of(scene))
        except ValueError as e:
            raise PreflightError(str(e)) from None

    # ---------------------------------------------------------- estimates
    def estimate(self, scene):
        from ..io import disk_chunk_members
        from ..preflight import Estimate

        N, M = int(scene["torus"]["N"]), int(scene["ensemble"]["members"])
        T = int(scene["integrator"]["steps"]) // int(scene["output"]["every"]) + 1
        per_var = [8 * T] * 13 + [8 * T * 3]
        n_fields = 2 * (bool(scene["output"]["vorticity"]) + bool(scene["output"]["entropy_field"]))
        per_var += [8 * T * N * N] * n_fields
        chunk = int(scene["output"]["member_chunk"])
        layout = [(n, disk_chunk_members(M, n, chunk)) for n in per_var] + [(1, 0), (8, 0)]
        file_per = sum(n for n, _ in layout)
        mat = 16 * N * N
        work = 40 * mat + 16 * T * 13 + n_fields * 8 * T * N * N
        est = Estimate(file_per, work + 2 * file_per, M, chunk, layout, 2 * mat * T)
        method = scene["integrator"]["method"]
        if scene["ensemble"]["device"] == "gpu" and method != "reference":
            from .step import memory_bytes

            est.device_memory = memory_bytes(N, est.chunk_members, method, scene["integrator"]["composition"],
                                             budget_members(scene))
        return est

    def estimate_time(self, scene):
        """Times two steps of one member here and scales to the run."""
        import time

        from .run import initial_fields, integrate

        from .kernels import STATUS_MEANINGS

        probe = scene.with_overrides({"integrator.steps": PROBE_STEPS, "output.every": 1, "ensemble.members": 1,
                                      "output.vorticity": False, "output.entropy_field": False})
        W0, S0 = initial_fields(probe, np.arange(1))
        integrate(probe, W0, S0, progress=False)  # warm
        t0 = time.perf_counter()
        traj = integrate(probe, W0, S0, progress=False)
        per = (time.perf_counter() - t0) / PROBE_STEPS
        steps, M = int(scene["integrator"]["steps"]), int(scene["ensemble"]["members"])
        status = int(traj.status[0])
        return TimeEstimate(per * steps * M, per, steps, M, STATUS_MEANINGS.get(status, str(status)) if status else "",
                            int(traj.failed_step[0]))

    def long_run(self, scene) -> bool:
        return int(scene["torus"]["N"]) >= 127


register(Torus())
