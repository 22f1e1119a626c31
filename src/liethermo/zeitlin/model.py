"""The thermodynamic Zeitlin fluid as a model of the run layer (:mod:`liethermo.models`).

A fluid run goes through the common runner: members in chunks of
``output.member_chunk`` (:meth:`Fluid.run_chunk`), each written as it
finishes, with the journal, the lock, ``--resume`` and ``--dask`` of every
run.  Member k's field depends on (scene, k) only, and the fixed point's
predictor takes its order from the chunk size the scene sets, not from the
chunk a member lands in, so a resumed or a Dask run gives the same bits.

This module is light: the kernels, xarray and the basis load on first use.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..numerics.matrix_flow import budget_members
from ..models import BaseSummary, MethodInfo, Model, StudyDefaults, closing_lines, register, wall_line

#: a run of at least this N is timed before it starts (its basis alone takes seconds)
ANNOUNCE_N = 256

def _max(a) -> float:
    a = np.asarray(a, dtype=float)
    a = a[np.isfinite(a)]
    return float(a.max()) if a.size else -np.inf


@dataclass
class FluidStats:
    """What one member chunk contributes to a fluid run's summary (mergeable, JSON-serialisable)."""

    members: int = 0
    kernel_time: float = 0.0
    failed: int = 0
    energy_error: float = -np.inf       # max |H + q − H(0)| / H(0)
    casimir2: float = -np.inf           # max |relative change of tr W²|
    momentum_change: float = -np.inf    # max |L − L(0)|
    momentum: float = -np.inf           # max |L(0)|
    heat_sum: float = 0.0               # Σ over members of q(end) / H(0)
    heat_n: int = 0
    its_sum: float = 0.0                # Σ of the mean fixed-point iterations per step, per output
    its_n: int = 0
    its_max: float = -np.inf
    #: members per status flag, by its meaning (ok, fixed_point_not_converged, non_finite)
    status: dict = field(default_factory=dict)

    def merge(self, o: "FluidStats") -> "FluidStats":
        self.members += o.members
        self.kernel_time += o.kernel_time
        self.failed += o.failed
        for k, n in o.status.items():
            self.status[k] = self.status.get(k, 0) + n
        for k in ("energy_error", "casimir2", "momentum_change", "momentum", "its_max"):
            setattr(self, k, max(getattr(self, k), getattr(o, k)))
        self.heat_sum += o.heat_sum
        self.heat_n += o.heat_n
        self.its_sum += o.its_sum
        self.its_n += o.its_n
        return self

    def to_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in self.__dict__.items()}

    @classmethod
    def from_dict(cls, d: dict) -> "FluidStats":
        return cls(**{k: (-np.inf if v is None else v) for k, v in d.items()})

    @classmethod
    def of(cls, ds, kernel_time: float) -> "FluidStats":
        """The figures of a chunk's dataset (failed members are NaN there)."""
        from .run import STATUS_MEANINGS

        st = cls(members=ds.sizes["member"], kernel_time=kernel_time)
        st.failed = int((ds["status"].values != 0).sum())
        st.status = {name: int((ds["status"].values == flag).sum()) for flag, name in STATUS_MEANINGS.items()}
        with np.errstate(invalid="ignore", divide="ignore"):
            st.energy_error = _max(np.abs(ds["energy_error"].values))
            st.casimir2 = _max(np.abs(ds["casimir_drift"].sel(k=2).values))
            L = ds["angular_momentum"].values
            st.momentum_change = _max(np.abs(L - L[:, :1]))
            st.momentum = _max(np.abs(L[:, :1]))
            heat = ds["heat"].values[:, -1] / ds["energy"].values[:, 0]
        fin = np.isfinite(heat)
        st.heat_sum, st.heat_n = float(heat[fin].sum()), int(fin.sum())
        its = ds["fixed_point_iterations"].values[:, 1:]
        fin = np.isfinite(its)
        st.its_sum, st.its_n, st.its_max = float(its[fin].sum()), int(fin.sum()), _max(its)
        return st


@dataclass(kw_only=True)
class FluidSummary(BaseSummary):
    """What a fluid run did, for the one-screen report."""

    N: int
    t_end: float
    viscous: bool
    stats: FluidStats = field(default_factory=FluidStats)

    def lines(self) -> list[str]:
        st = self.stats
        nan = float("nan")
        fin = lambda v: v if np.isfinite(v) else nan  # noqa: E731
        dL = fin(st.momentum_change) / max(fin(st.momentum), 1e-300) if np.isfinite(st.momentum) else nan
        heat = st.heat_sum / st.heat_n if st.heat_n else nan
        words = ("tr W² (∫ω² dA) changed by {:.2e} (viscosity dissipates it)" if self.viscous
                 else "tr W² drift ≤ {:.2e} (∫ω² dA)")
        from .run import status_line, stepping_line

        out = [f"{self.method}: {self.members} member(s), N = {self.N}, h = {self.h:g} s, t = {self.t_end:g} s",
               stepping_line(st.kernel_time),
               wall_line(self.wall_time),
               status_line(st.status, self.method),
               f"  |H + q − H(0)|/H(0) ≤ {fin(st.energy_error):.2e}; {words.format(fin(st.casimir2))}; "
               f"angular momentum drift ≤ {dL:.2e} (relative); heat {100 * heat:.1f} % of H(0)"]
        if st.its_n and st.its_max > 0:
            out.append(f"  fixed-point iterations per step: mean {st.its_sum / st.its_n:.2f}, max {st.its_max:.2f}")
        if st.failed:
            out.append(f"  {st.failed} member(s) failed: see status and failed_step")
        return out + closing_lines(self.resumed_members, self.path, "not in the stepping time above")


@dataclass
class TimeEstimate:
    """A fluid run's time on this machine (:mod:`liethermo.zeitlin.estimate`)."""

    estimate: object

    @property
    def seconds(self) -> float:
        return self.estimate.seconds

    def line(self) -> str:
        return "\n".join(self.estimate.lines())

    def warnings(self) -> list[str]:
        return self.estimate.warnings()

    def cautions(self) -> list[str]:
        return self.estimate.cautions()


#: From this matrix size N on, a run's BLAS products use every usable core; below
#: it one thread.  benchmarks/blas_threads.py on the 2-core machine: one thread was
#: faster at every N measured (64 to 256: 2 threads took 5-29 times as long on a
#: loaded machine, where OpenBLAS's spinning threads wait for the scheduler).
#: Below it the members' fixed points are split over the cores instead
#: (:func:`liethermo.zeitlin.kernels.isomp`).  The bits are the same on
#: either count (tests/test_threads.py).
BLAS_THREADED_N = 512



class Fluid(StudyDefaults, Model):
    """The thermodynamic Zeitlin fluid on the sphere (a scene with a ``[zeitlin]`` table)."""

    name = "zeitlin"
    title = "the Zeitlin fluid"
    description = ("a viscous Zeitlin fluid on the sphere that turns its energy into heat "
                   "(isospectral splitting vs RK4)")
    scene_table = "zeitlin"

    @property
    def scene_model(self):
        from .scene import SCENE_MODEL

        return SCENE_MODEL
    stats_type = FluidStats
    study_kinds = {k: f"liethermo.zeitlin.studies.{k}" for k in ("zeitlin_decay", "zeitlin_structure",
                                                                   "zeitlin_resolution")}
    store_less = "output.every, output.vorticity"
    # the diagnostics go through BLAS products over the chunk's members (last bits)
    chunk_sets_bits = True
    not_in_results = frozenset({("output", "figures"), ("output", "compare")})

    def methods(self) -> dict[str, MethodInfo]:
        from . import run as zr

        return MethodInfo.table(zr.METHOD_ORDER, zr.METHOD_LAWS, zr.METHOD_DESCRIPTION)

    study_outputs = {"output.vorticity": True}

    def study_state(self, ds) -> dict:
        W = ds["vorticity_real"].values + 1j * ds["vorticity_imag"].values
        H0 = float(np.max(ds["energy"].values[:, 0]))  # the energy the heat comes from
        return {"vorticity": (W, ds["vorticity_real"].attrs.get("units", "s-1"), "vorticity matrix W", None),
                "heat": (ds["heat"].values, "J", "heat q", H0),
                "entropy": (ds["entropy"].values, "J K-1", "entropy produced",
                            H0 / float(np.min(ds["temperature"].values[:, 0])))}

    def relative_energy_error(self, ds):
        return ds["energy_error"].values

    def dissipation_overrides(self, scene, factor: float) -> dict:
        return {"fluid.kinematic_viscosity": float(f"{float(factor) * scene['fluid']['kinematic_viscosity']:.15g}")}

    def thread_counts(self, scene, cores: int):
        from ..threads import ThreadCounts

        N = int(scene["zeitlin"]["N"])
        if N < BLAS_THREADED_N:
            return ThreadCounts(blas=1, kernel=max(1, int(cores)),
                                why=f"BLAS on one thread below N = {BLAS_THREADED_N}, the members' fixed points "
                                    "on every core")
        return ThreadCounts(blas=max(1, int(cores)), kernel=1, why=f"BLAS on every core from N = {BLAS_THREADED_N}")

    def run_with_laws(self, scene, *, kernel=None, threads=None):
        ds, st = self.run_chunk(scene, 0, int(scene["ensemble"]["members"]), kernel=kernel, threads=threads)
        with np.errstate(invalid="ignore"):
            cas = np.nanmax(np.abs(ds["casimir_drift"].values), axis=(1, 2))
            L = ds["angular_momentum"].values
            dL = np.nanmax(np.linalg.norm(L - L[:, :1], axis=-1), axis=1)
        if scene["fluid"]["kinematic_viscosity"] > 0:  # viscosity changes the spectrum of W
            cas = np.full_like(cas, np.nan)
        return ds, st, {"casimirs": (cas, "1", "max over t and k of the relative Casimir change "
                                                    "(the law at zero viscosity; NaN with viscosity)"),
                        "angular_momentum": (dL, "kg m2 s-1", "max over t of |L - L(0)|")}

    def initial_conditions(self, scene, lo: int, hi: int):
        from .run import initial_fields

        return initial_fields(scene, np.arange(lo, hi))

    def setup(self, scene, history):
        from .run import run_attrs

        itg = scene["integrator"]
        method = itg["method"]
        attrs = run_attrs(scene, method, history)
        steps = int(itg["steps"])
        summ = FluidSummary(scene.name, method, int(scene["ensemble"]["members"]), steps, float(itg["h"]),
                            N=int(scene["zeitlin"]["N"]), t_end=float(steps * float(itg["h"])),
                            viscous=scene["fluid"]["kinematic_viscosity"] > 0)
        return attrs, summ

    def run_chunk(self, scene, lo, hi, *, progress_cb=None, kernel=None, threads=None):
        from .run import integrate, run_attrs, trajectory_dataset

        method = scene["integrator"]["method"]
        W0 = self.initial_conditions(scene, lo, hi)
        if scene["ensemble"]["device"] == "gpu":
            from ..gpu import namespace
            from .xpstep import integrate_xp

            traj = integrate_xp(namespace("gpu"), scene, W0, method=method, progress=False,
                                budget_members=budget_members(scene))
        else:
            traj = integrate(scene, W0, method=method, progress=False, budget_members=budget_members(scene))
        ds = trajectory_dataset(scene, traj, method, member_offset=lo, attrs=run_attrs(scene, method))
        if progress_cb is not None:
            progress_cb((hi - lo) * int(scene["integrator"]["steps"]))
        return ds, FluidStats.of(ds, traj.kernel_seconds)

    def warm(self, scene, methods, progress):
        from .estimate import build_basis

        build_basis(int(scene["zeitlin"]["N"]), progress=progress)
        return None

    def figures(self, outputs, folder, stem):
        from ..cf import open_dataset
        from . import plotting

        datasets = {}
        for m, p in outputs.items():
            with open_dataset(p) as ds:
                datasets[m] = ds.load()
        first = next(iter(datasets.values()))
        W = self.member0(first)
        return plotting.draw(datasets, W if W is not None and np.isfinite(W).all() else None, folder, stem)

    def member0(self, ds) -> np.ndarray | None:
        """W of member 0 at every output time of a run's dataset: stored, or
        integrated again (one member) from the scene the file stores, so that the
        figures come from the file alone."""
        if "vorticity_real" in ds:
            return ds["vorticity_real"].values[0] + 1j * ds["vorticity_imag"].values[0]
        import tomllib

        from ..scene import load_scene
        from .run import initial_fields, integrate

        tables = tomllib.loads(ds.attrs["scene"])
        if tables["initial"].get("kind") == "file" and "initial_vorticity_real" in ds:
            # the field the run started from, as stored: the same even if its file has changed or gone
            from . import kernels as zk
            from .field import triangle_to_modes

            C = ds["initial_vorticity_real"].values[:1] + 1j * ds["initial_vorticity_imag"].values[:1]
            tables["initial"].update(kind="random", file="", sha256="")
            scene = load_scene(tables)
            b = zk.basis(int(scene["zeitlin"]["N"]))
            W0 = zk.from_modes(triangle_to_modes(C, b.N), b)
        else:
            scene = load_scene(tables)
            W0 = initial_fields(scene, np.arange(1))
        traj = integrate(scene, W0, progress=False, budget_members=budget_members(scene))
        return traj.out.W_first

    # ---------------------------------------------------------- preflight
    def check_parameters(self, scene) -> None:
        from ..gpu import device_refusal
        from ..preflight import PreflightError
        from .xpstep import METHODS as XP_METHODS

        why = device_refusal(scene, XP_METHODS)
        if why is not None:
            raise PreflightError(why)

        for key in ("integrator.steps", "output.every", "output.member_chunk", "ensemble.members"):
            section, name = key.split(".")
            v = scene[section][name]
            if v > np.iinfo(np.int64).max:
                raise PreflightError(f"scene key '{key}': too large for the arrays (at most "
                                     f"{np.iinfo(np.int64).max}) (got {v})")

    def estimate(self, scene):
        from ..io import disk_chunk_members
        from ..preflight import Estimate
        from . import estimate as ze
        from .run import factors

        N, M = int(scene["zeitlin"]["N"]), int(scene["ensemble"]["members"])
        T = int(scene["integrator"]["steps"]) // int(scene["output"]["every"]) + 1
        per_var = [8 * T] * 8 + [8 * T * 3] * 3 + [8 * T * (N - 1)]  # (member, t[, k | axis | l]) values
        if scene["output"]["vorticity"]:
            per_var += [8 * T * N * N] * 2
        if scene["initial"]["kind"] == "file":  # the initial coefficients, stored per member
            per_var += [8 * N * N] * 2
        chunk = int(scene["output"]["member_chunk"])
        layout = [(n, disk_chunk_members(M, n, chunk)) for n in per_var] + [(1, 0), (8, 0), (8, 0)]
        file_per = sum(n for n, _ in layout)
        W = 16 * N * N
        method = scene["integrator"]["method"]
        work = ze.STATE_COPIES * W + 8 * T * (N + 12)
        if method not in ("rk4", "reference"):
            work += 4 * len(factors(method, scene["integrator"]["composition"])) * W
        if scene["output"]["vorticity"]:
            work += W * T  # kept by the run, then labelled (in the file's bytes below)
        memory_per = work + 2 * file_per  # the labelled chunk and its encoded copy
        from .kernels import basis_on_disk

        fixed = ze.basis_bytes(N, basis_on_disk(N)) + W * T  # the basis; member 0's W for the figures
        est = Estimate(file_per, memory_per, M, chunk, layout, fixed)
        if scene["ensemble"]["device"] == "gpu" and method != "reference":
            from .xpstep import memory_bytes

            est.device_memory = memory_bytes(N, est.chunk_members, method, scene["integrator"]["composition"])
        return est

    def estimate_time(self, scene):
        from .estimate import estimate

        return TimeEstimate(estimate(scene, [scene["integrator"]["method"]]))

    def long_run(self, scene) -> bool:
        return int(scene["zeitlin"]["N"]) >= ANNOUNCE_N


register(Fluid())
