"""What a Zeitlin fluid's run will cost, said before it starts (``liethermo run --check``).

* **Set-up**: the basis of su(N) (:func:`liethermo.zeitlin.kernels.basis`, built
  once per N) takes about c·N³ seconds, with this machine's c from a timed build
  of su(``BASIS_PROBE_N``) (:func:`basis_seconds_per_n3`; machines differ by 6×:
  su(512) took 3.5 s on a 2-core Intel Xeon, 23 s on a 2-core AMD EPYC Zen 4).
  It holds the eigenvectors of the N blocks of the Laplacian and their
  transposes, S = Σ_{d<N} (N−d)² = N(N+1)(2N+1)/6 float64 numbers each: 24·S
  bytes at the peak of a build (1.1 GB at N = 512, 8.6 GB at N = 1024), 16·S
  when it is read from the disk cache (:func:`basis_bytes`).
* **Steps**: a step costs about c·N³ per member (dense complex N×N products:
  per fixed-point iteration of each isospectral substep, or per RK4 stage).
  c is measured by a short probe of the scene's own method, initial field and
  step at N = min(N, PROBE_N) and scaled by (N/N_probe)³ and the members.
* **Memory** of the steps: about ``STATE_COPIES`` working copies of W for the
  whole ensemble (16 bytes per complex entry), the splitting's predictor of
  the next fixed point (at most 512 MiB), and what is kept for the output
  (:func:`run_bytes`).  What ``--check`` prints is the run layer's count of the
  same run (a member chunk, the writer and the program besides), the one its
  memory check uses.

The run layer's disk and memory checks use :meth:`liethermo.zeitlin.model.Fluid.estimate`;
this module gives the time (``--check``, and before a long run) and the basis's cost.
"""

from __future__ import annotations

import functools
import sys
import time
from dataclasses import dataclass, field

import numpy as np

#: seconds per N³ to build the basis of su(N) on the slowest machine measured (23 s at
#: N = 512, a 2-core AMD EPYC Zen 4): an upper bound, which decides whether a build is
#: worth timing a probe for before it is announced
BASIS_SECONDS_PER_N3 = 1.7e-7
#: the basis timed for this machine's cost per N³ (about 0.1 s to build on a 2-core Xeon)
BASIS_PROBE_N = 128
#: the probe's matrix size (a step there takes a few hundredths of a second)
PROBE_N = 96
PROBE_STEPS = 5
#: working copies of W per member while stepping (W, the guess, the fixed point's
#: D, X, A, XA and W̃, the active members' copies, the new W)
STATE_COPIES = 12
#: a run estimated longer than this, or needing more than half the memory, is warned of
LONG_SECONDS = 600.0


def basis_numbers(N: int) -> int:
    """S = Σ_{d<N} (N−d)²: the entries of one copy of the basis's eigenvectors."""
    return N * (N + 1) * (2 * N + 1) // 6


@functools.lru_cache(maxsize=1)
def basis_seconds_per_n3() -> float:
    """This machine's seconds per N³ to build a basis: the faster of two timed builds of
    su(BASIS_PROBE_N) (no cache), once per process.  The rate varies with N (on a 2-core
    Xeon 4.8·10⁻⁸ s at N = 128, 2.6–3.1·10⁻⁸ at 512, 3.8–4.3·10⁻⁸ at 1024): the probe's is
    the highest there up to N = 1024, so the figure errs long, by less than 2×."""
    from .kernels import compute_basis

    best = float("inf")
    for _ in range(2):
        t0 = time.perf_counter()
        compute_basis(BASIS_PROBE_N)
        best = min(best, time.perf_counter() - t0)
    return best / BASIS_PROBE_N ** 3


def basis_seconds(N: int) -> float:
    """About how long building the basis of su(N) takes on this machine (s)."""
    return basis_seconds_per_n3() * float(N) ** 3


def basis_bytes(N: int, cached: bool = False) -> int:
    """Peak memory of the basis of su(N) (bytes): building it holds three copies of its
    S eigenvector entries at once (24·S); one read from the disk cache, two (the
    eigenvectors and their transposed copy, 16·S)."""
    return (16 if cached else 24) * basis_numbers(N)


def run_bytes(scene, method: str | None = None) -> int:
    """Memory of the steps and outputs of one method's run (bytes), beside the basis:
    of one member chunk (``output.member_chunk`` members at a time)."""
    from .run import factors

    N = int(scene["zeitlin"]["N"])
    M = min(int(scene["ensemble"]["members"]), int(scene["output"]["member_chunk"]))
    T = int(scene["integrator"]["steps"]) // int(scene["output"]["every"]) + 1
    method = method or scene["integrator"]["method"]
    W = 16 * M * N * N
    need = STATE_COPIES * W
    if method not in ("rk4", "reference"):
        need += min(4 * len(factors(method, scene["integrator"]["composition"])) * W, 2**29)
    need += 16 * T * N * N  # member 0's W at every output, for the figures
    if scene["output"]["vorticity"]:
        need += W * T
    need += 8 * M * T * (N + 12)  # the diagnostics
    return need


def _run_memory(scene, method: str) -> int:
    """A method's whole memory as the run layer's checks count it (the
    basis, a member chunk, the writer, the program): the figure ``--check``'s
    first line gives, so that both lines say the same."""
    from ..preflight import estimate, method_scene

    return estimate(method_scene(scene, method)).memory


def _available_bytes() -> int | None:
    from ..preflight import available_memory

    return available_memory()


def fixed_point(method: str) -> bool:
    """Whether ``method``'s steps solve a fixed point (the splittings; not rk4 or the reference)."""
    return method not in ("rk4", "reference")


def _fixed_point_converged(traj) -> bool:
    """Whether no member of a run stopped with ``fixed_point_not_converged`` (a member
    that blew up, or rk4's, is not counted: it solves no fixed point that failed)."""
    from ..numerics.matrix_flow import STATUS_NOT_CONVERGED

    return not bool(np.any(traj.status == STATUS_NOT_CONVERGED))


def _probe_scene(scene, h: float):
    """The scene at N_probe = min(N, PROBE_N): its first members (at most two), PROBE_STEPS
    steps of ``h``, its initial field up to the degree N_probe allows."""
    from ..scene import load_scene

    N = int(scene["zeitlin"]["N"])
    Np = min(N, PROBE_N)
    lmax = min(int(scene["initial"]["lmax"]), Np - 1)
    over = {"zeitlin.N": Np, "ensemble.members": min(int(scene["ensemble"]["members"]), 2),
            "integrator.steps": PROBE_STEPS, "integrator.h": h, "output.every": 1,
            "output.vorticity": False, "output.compare": [], "initial.lmax": lmax,
            "initial.m": min(int(scene["initial"]["m"]), lmax)}
    return load_scene(scene.to_dict(), over)


def probe_step_seconds(scene, method: str) -> tuple[float, int, int, bool]:
    """Seconds per step of ``method`` on the scene's first members, measured at
    N_probe = min(N, PROBE_N): ``(seconds, N_probe, members_probe, converged)``, the
    faster of three timed runs after one untimed step (kernels compiled or loaded).

    ``converged``: whether a splitting's fixed point converged for every probe member, at
    the run's h and at its h·N (:func:`converges`; always True for rk4, which has none).  The steps are timed at the
    run's own h: at its h·N the probe takes the iterations of the run's first step, but
    not the fewer of its later ones, whose predicted first guess is better at the run's
    smaller h (N = 256, h = 0.01 s, 2 members × 20 steps on a 2-core Xeon: the run's
    first step 15.5 iterations, then 9; the probe at h·N 17.5, then 16; timed at the run's
    h the estimate is 1.5–2.0× the run's 2.7–2.9 s, at its h·N 2.3×)."""
    from .run import initial_fields, integrate

    N = int(scene["zeitlin"]["N"])
    Np = min(N, PROBE_N)
    sc = _probe_scene(scene, float(scene["integrator"]["h"]))
    W0 = initial_fields(sc)
    ok = _fixed_point_converged(integrate(sc.with_overrides({"integrator.steps": 1}), W0, method=method,
                                          progress=False))
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        ok &= _fixed_point_converged(integrate(sc, W0, method=method, progress=False))
        best = min(best, (time.perf_counter() - t0) / PROBE_STEPS)
    if ok and Np != N and fixed_point(method):
        ok = converges(scene, method, float(scene["integrator"]["h"]))
    return best, Np, int(sc["ensemble"]["members"]), ok


def probe_h(scene, h: float) -> float:
    """The step at N_probe = min(N, PROBE_N) with the same h·N as ``h`` at the scene's N."""
    N = int(scene["zeitlin"]["N"])
    return h * N / min(N, PROBE_N)


def converges(scene, method: str, h: float) -> bool:
    """Whether ``method``'s fixed point converges at N with step ``h``, as a probe of
    PROBE_STEPS steps at N_probe = min(N, PROBE_N) with the same h·N says.  Its iterations
    contract by a factor that depends on h·N (at N = 256 with h = 0.01 s as at N = 1024
    with h = 0.0025 s: about 8× per iteration; docs/model.md), so the probe steps
    h·N/N_probe."""
    from .run import initial_fields, integrate

    sc = _probe_scene(scene, probe_h(scene, h))
    return _fixed_point_converged(integrate(sc, initial_fields(sc), method=method, progress=False))


def converging_step(scene, method: str, halvings: int = 8) -> float | None:
    """The largest h/2^k (k = 1 … ``halvings``) at which ``method``'s fixed point converges
    by :func:`converges`, or None."""
    h = float(scene["integrator"]["h"])
    for k in range(1, halvings + 1):
        if converges(scene, method, h / 2 ** k):
            return h / 2 ** k
    return None


@dataclass
class Estimate:
    """A Zeitlin run's time and memory on this machine, per method."""

    N: int
    members: int
    steps: int
    basis_seconds: float
    basis_bytes: int
    methods: dict = field(default_factory=dict)  # method -> (seconds, bytes, probe N)
    available: int | None = None
    basis_cached: bool = False  # the disk cache holds it (liethermo.diskcache)
    #: method -> (the probe's h at N_probe where its fixed point did not converge, the
    #: largest h/2^k that converged or None): :func:`probe_step_seconds`
    not_converging: dict = field(default_factory=dict)
    h: float = 0.0

    @property
    def seconds(self) -> float:
        return self.basis_seconds + sum(s for s, _, _ in self.methods.values())

    @property
    def peak_bytes(self) -> int:
        return self.basis_bytes + max((b for _, b, _ in self.methods.values()), default=0)

    def lines(self) -> list[str]:
        from ..faults import human_bytes
        from ..runner import human_seconds

        out = [f"  basis of su({self.N}): {human_bytes(self.basis_bytes)}, read from the disk cache"
               if self.basis_cached else
               f"  basis of su({self.N}): about {human_seconds(self.basis_seconds)} and "
               f"{human_bytes(self.basis_bytes)} to build (timed at N = {BASIS_PROBE_N} on this machine and "
               "scaled by N³; once per N, then read from the disk cache)"]
        for m, (s, b, Np) in self.methods.items():
            scaled = f", scaled by (N/{Np})³ from a timed probe at N = {Np}" if Np != self.N else " from a timed probe"
            out.append(f"  {m}: about {human_seconds(s)} for {self.members} member(s) x {self.steps} steps"
                       f"{scaled}; about {human_bytes(b)} of memory beside the basis")
        avail = f", {human_bytes(self.available)} available" if self.available else ""
        out.append(f"  in all: about {human_seconds(self.seconds)} and at most about "
                   f"{human_bytes(self.peak_bytes)} of memory{avail}")
        return out

    def warnings(self) -> list[str]:
        from ..faults import human_bytes
        from ..runner import human_seconds

        out = []
        if self.seconds > LONG_SECONDS:
            out.append(f"liethermo: warning: this run would take about {human_seconds(self.seconds)} "
                       f"on this machine (N = {self.N}: a step costs ~N³ per member); a smaller zeitlin.N, "
                       "fewer steps or members run sooner")
        out += self.cautions()
        if self.available and self.peak_bytes > self.available / 2:
            out.append(f"liethermo: warning: this run needs about {human_bytes(self.peak_bytes)} of memory, "
                       f"more than half of the {human_bytes(self.available)} available")
        return out

    def cautions(self) -> list[str]:
        """The warnings a run gives before it starts whatever its length: a fixed point that
        will probably not converge."""
        out = []
        for m, (hp, h_ok) in self.not_converging.items():
            Np = self.methods[m][2]
            fix = (f"at h = {h_ok:.3g} s it converged (the same probe)" if h_ok is not None
                   else "no step down to h/256 converged")
            probe = (f"its iterations contract by a factor that depends on h·N, and at N = {Np} with the same "
                     f"h·N (h = {hp:.3g} s) they did not" if Np != self.N else
                     f"in a probe of {PROBE_STEPS} steps they did not")
            out.append(f"liethermo: warning: {m}'s fixed point will probably not converge at N = {self.N} "
                       f"and h = {self.h:.3g} s: {probe}; its members would stop with fixed_point_not_converged. "
                       f"{fix[0].upper()}{fix[1:]}; set integrator.h")
        return out


def estimate(scene, methods: list[str] | None = None) -> Estimate:
    """Time and memory of running ``methods`` (default: the scene's method and
    its output.compare) on this machine; probes each method at a small N."""
    N, M = int(scene["zeitlin"]["N"]), int(scene["ensemble"]["members"])
    steps = int(scene["integrator"]["steps"])
    if methods is None:
        methods = list(dict.fromkeys([scene["integrator"]["method"], *scene["output"]["compare"]]))
    from . import kernels as zk

    on_disk = zk.basis_on_disk(N)
    est = Estimate(N, M, steps, 0.0 if on_disk else basis_seconds(N), basis_bytes(N, on_disk),
                   available=_available_bytes(), basis_cached=on_disk, h=float(scene["integrator"]["h"]))
    for m in methods:
        if m == "reference":  # scipy's DOP853 per member: not probed (a study's reference, not a run's)
            continue
        s, Np, Mp, ok = probe_step_seconds(scene, m)
        est.methods[m] = (s * (N / Np) ** 3 * (M / Mp) * steps, _run_memory(scene, m) - est.basis_bytes, Np)
        if not ok:
            est.not_converging[m] = (probe_h(scene, est.h), converging_step(scene, m))
    return est


def build_basis(N: int, progress: bool | None = None) -> None:
    """Build (and cache) the basis of su(N), saying so on stderr first when it
    takes more than two seconds (unless ``progress`` is False)."""
    from . import kernels as zk

    loud = (progress is not False and BASIS_SECONDS_PER_N3 * float(N) ** 3 > 2.0  # might take long
            and not zk.basis_on_disk(N))
    if loud:
        seconds = basis_seconds(N)
        loud = seconds > 2.0
    if loud:
        from ..faults import human_bytes
        from ..runner import human_seconds

        print(f"liethermo: building the basis of su({N}): about {human_seconds(seconds)} and "
              f"{human_bytes(basis_bytes(N))} of memory ...", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    zk.basis(N)
    if loud:
        print(f"liethermo: basis of su({N}) built in {time.perf_counter() - t0:.3g} s", file=sys.stderr, flush=True)
