"""Shared fixtures of the kernel-level tests.

The paper scene is rebuilt here from the raw numbers of the paper (docs/model.md
§ "The paper scene"), not from any scene code in ``src/``, so that the tests check
the kernels against the model and not against themselves:

    m = 4/3 π a³ ρ,  m₁ = 0.6 m,  m₂ = m − m₁,
    G_z = 3m₁a/(8m) − m₂a/(2m),  ℓ = |G_z|,  χ = e₃,
    𝕀 (as printed) = diag(83a²m₁/320 + a²m₂/12, same, 2a²m₁/5 + a²m₂/3),
    c = 8πμa³,  c_v = 3 (m/M) R_gas,  g⃗ = m g ℓ χ,
    Ω₀ = (0, 1, 1),  R₀ = [[1,0,0],[0,0,−1],[0,1,0]],  Γ₀ = R₀ᵀe₃ = (0, 1, 0).

Other helpers: the spherical top (g = 0, 𝕀 = I₀·Id) with its exact solution,
random non-symmetric bodies with a tilted χ, and the least-squares fit of an
observed order of convergence.

Every figure a test saves (runs, studies) is checked for legibility at its
saved size by :func:`legible_figures` (tests/layout.py): the save fails if
tick labels of an axis overlap, if titles, labels or legends overlap each
other or a neighbouring panel, or if any of them is cut off.
"""

from __future__ import annotations

import atexit
import os
import re
import shutil
import tempfile

# the disk cache of slow values (the fluid's bases) is a temporary folder of the test
# session, never the user's; subprocesses inherit it
if "liethermo-test-cache-" not in os.environ.get("LIETHERMO_CACHE_DIR", ""):
    os.environ["LIETHERMO_CACHE_DIR"] = tempfile.mkdtemp(prefix="liethermo-test-cache-")
    atexit.register(shutil.rmtree, os.environ["LIETHERMO_CACHE_DIR"], True)
os.environ.pop("LIETHERMO_CACHE", None)

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest

from layout import SAVED_FIGURES, STUDY_FIGURES_CHECKED, layout_problems, readability_problems
from liethermo.top.physics import Physics


@pytest.fixture(scope="session", autouse=True)
def legible_figures():
    """Check every ``Figure.savefig`` of the session (session scope, so that the
    studies run by module-scoped fixtures are covered too)."""
    from matplotlib.figure import Figure

    save = Figure.savefig

    def checked_savefig(fig, fname, *args, **kwargs):
        out = save(fig, fname, *args, **kwargs)
        problems = layout_problems(fig, kwargs.get("dpi"))
        assert not problems, f"{fname}: illegible at its saved size:\n  " + "\n  ".join(problems)
        engine = fig.get_layout_engine()
        path = Path(str(fname)).resolve()
        atomic = re.fullmatch(r"\.(.+)\.\d+\.tmp", path.name)  # an atomic write's temporary
        path = path.with_name(atomic.group(1)) if atomic else path
        SAVED_FIGURES[str(path)] = type(engine).__name__ if engine is not None else None
        return out

    Figure.savefig = checked_savefig
    yield
    Figure.savefig = save


@pytest.fixture(scope="session", autouse=True)
def readable_study_figures():
    """Every figure a study draws in the session (each study's reduced run, in the
    module that runs it) also has a title and at least two tick labels on every
    axis (:func:`layout.readability_problems`); the names of the checked figures
    are kept in ``STUDY_FIGURES_CHECKED``."""
    from liethermo.studies import framework

    save = framework.save_figure

    def checked(fig, path):
        problems = readability_problems(fig, 120)
        assert not problems, f"{path}: unreadable study figure:\n  " + "\n  ".join(problems)
        STUDY_FIGURES_CHECKED.add(Path(path).name)
        return save(fig, path)

    framework.save_figure = checked
    yield
    framework.save_figure = save

A_RADIUS = 0.05  # m
MU = 0.1  # kg m^-1 s^-1
RHO = 2700.0  # kg m^-3
MOLAR_MASS = 26.981539e-3  # kg mol^-1
G_ACC = 9.81  # m s^-2
R_GAS = 8.314462618  # J mol^-1 K^-1
T0 = 300.0  # K
H_PAPER = 0.1  # s
OMEGA0 = np.array([0.0, 1.0, 1.0])
R0 = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
E3 = np.array([0.0, 0.0, 1.0])


def paper_numbers() -> dict:
    """The derived quantities of the paper scene."""
    a = A_RADIUS
    m = 4.0 / 3.0 * math.pi * a**3 * RHO
    m1 = 0.6 * m
    m2 = m - m1
    Gz = 3.0 * m1 * a / (8.0 * m) - m2 * a / (2.0 * m)
    I12 = 83.0 * a * a * m1 / 320.0 + a * a * m2 / 12.0
    I3 = 2.0 * a * a * m1 / 5.0 + a * a * m2 / 3.0
    return dict(m=m, m1=m1, m2=m2, Gz=Gz, ell=abs(Gz), inertia=np.array([I12, I12, I3]),
                c=8.0 * math.pi * MU * a**3, cv=3.0 * (m / MOLAR_MASS) * R_GAS,
                gvec=m * G_ACC * abs(Gz) * E3, G=np.array([0.0, 0.0, Gz]))


def make_physics(inertia, c, gvec, cv, T0_=T0, n=1, *, friction=None, alpha=0.0, lam=0.0,
                 G=None, mass=1.0) -> Physics:
    """Physics of n identical members; ``c`` an isotropic Stokes coefficient or
    ``friction`` a diagonal C."""
    C = np.array([c, c, c], dtype=float) if friction is None else np.asarray(friction, float)
    one = Physics(inertia=np.asarray(inertia, float)[None], center_of_mass=(
        np.zeros((1, 3)) if G is None else np.asarray(G, float)[None]), mass=np.array([mass]),
        stokes_resistance=C[None], gravity_torque=np.asarray(gvec, float)[None], heat_capacity=np.array([cv]),
        T0=np.array([T0_]), S0=np.array([0.0]), thermal_expansion=np.array([alpha]),
        internal_friction=np.array([lam]), isotropic_resistance=friction is None)
    return one.repeat(n) if n != 1 else one


def paper_physics(n: int = 1) -> Physics:
    d = paper_numbers()
    return make_physics(d["inertia"], d["c"], d["gvec"], d["cv"], n=n, G=d["G"], mass=d["m"])


def stack(physics_list) -> Physics:
    """One ensemble from several Physics (same terms)."""
    first = physics_list[0]
    kw = {}
    for f in first.__dataclass_fields__:
        v = getattr(first, f)
        if isinstance(v, np.ndarray):
            kw[f] = np.concatenate([getattr(p, f) for p in physics_list])
    return replace(first, **kw)


@pytest.fixture
def paper() -> tuple:
    """(physics, Ω₀ (1, 3), R₀ (1, 3, 3)) of the paper scene."""
    return paper_physics(), OMEGA0[None].copy(), R0[None].copy()


# ---------------------------------------------------------------- spherical top
@dataclass
class SphericalTop:
    """g = 0, 𝕀 = I₀·Id: Ω(t) = Ω₀e^{−ct/I₀}; Γ turns about Ω₀ by
    φ(t) = (I₀|Ω₀|/c)(1 − e^{−ct/I₀}) in the sense of Γ̇ = −Ω×Γ (i.e. by −φ
    with the right-hand rule); σ(t) = c_v ln(1 + I₀|Ω₀|²(1 − e^{−2ct/I₀})/(2c_vT₀))."""

    I0: float
    c: float
    cv: float
    T0: float
    omega0: np.ndarray
    R0: np.ndarray

    @property
    def physics(self) -> Physics:
        return make_physics([self.I0] * 3, self.c, [0.0, 0.0, 0.0], self.cv, self.T0)

    @property
    def gamma0(self):
        return self.R0[2]

    def omega(self, t):
        t = np.asarray(t, float)
        return np.exp(-self.c * t / self.I0)[..., None] * self.omega0

    def angle(self, t):
        t = np.asarray(t, float)
        return self.I0 * np.linalg.norm(self.omega0) / self.c * (-np.expm1(-self.c * t / self.I0))

    def gamma(self, t):
        """Rodrigues rotation of Γ₀ about k = Ω₀/|Ω₀| by −φ(t)."""
        k = self.omega0 / np.linalg.norm(self.omega0)
        ang = -self.angle(t)[..., None]
        v = self.gamma0
        return v * np.cos(ang) + np.cross(k, v) * np.sin(ang) + k * (k @ v) * (1.0 - np.cos(ang))

    def sigma(self, t):
        t = np.asarray(t, float)
        w2 = float(self.omega0 @ self.omega0)
        return self.cv * np.log1p(self.I0 * w2 * (-np.expm1(-2.0 * self.c * t / self.I0))
                                  / (2.0 * self.cv * self.T0))


@pytest.fixture
def spherical_top() -> SphericalTop:
    """Paper friction and thermodynamics, I₀ = 1e-3 kg m², Ω₀ = (0,1,1),
    Γ₀ = (0,1,0) (not parallel to Ω₀, so Γ really moves)."""
    d = paper_numbers()
    return SphericalTop(I0=1.0e-3, c=d["c"], cv=d["cv"], T0=T0, omega0=OMEGA0.copy(), R0=R0.copy())


# ---------------------------------------------------------------- random bodies
def random_rotation(rng) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def random_body(seed: int, *, omega_scale: float = 2.0, diagonal: bool = False):
    """A non-symmetric body (three distinct moments) with a tilted χ, paper-sized
    friction (isotropic, or a random diagonal C) and gravity torque, a random
    attitude and spin.  Returns (physics, Ω₀ (1, 3), R₀ (1, 3, 3))."""
    rng = np.random.default_rng(seed)
    d = paper_numbers()
    inertia = rng.uniform(0.5e-3, 2.0e-3, 3)
    chi = rng.normal(size=3)
    chi /= np.linalg.norm(chi)
    gvec = rng.uniform(0.005, 0.03) * chi
    c = d["c"] * rng.uniform(0.5, 2.0)
    C = c * rng.uniform(0.5, 2.0, 3) if diagonal else None
    phys = make_physics(inertia, c, gvec, d["cv"], friction=C)
    return phys, (omega_scale * rng.normal(size=3))[None], random_rotation(rng)[None]


def random_ensemble(n: int, seed: int = 0, scale: float = math.sqrt(2.0)):
    """(Ω₀, R₀) of n members: attitudes uniform on SO(3), spin directions
    uniform, |Ω₀| uniform in [0.5, 1.5]·scale."""
    rng = np.random.default_rng(seed)
    R = np.array([random_rotation(rng) for _ in range(n)])
    d = rng.standard_normal((n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * (rng.uniform(0.5, 1.5, n) * scale)[:, None], R


# ---------------------------------------------------------------- order fit
def fit_order(hs, errors, floor: float = 1e-11, min_levels: int = 3, last: int | None = 3) -> float:
    """Slope of log(error) against log(h) by least squares over the ``last``
    finest levels whose error is above the round-off ``floor`` (the
    asymptotic regime: coarse levels of a high-order method are often
    pre-asymptotic); at least ``min_levels`` levels must remain."""
    hs = np.asarray(hs, float)
    errors = np.asarray(errors, float)
    assert np.all(np.isfinite(errors)), errors
    keep = np.flatnonzero(errors >= floor)
    if last is not None:
        keep = keep[-last:]
    assert keep.size >= min_levels, f"only {keep.size} levels above {floor}: {errors}"
    return float(np.polyfit(np.log(hs[keep]), np.log(errors[keep]), 1)[0])


def interrupt_at_chunk(monkeypatch, k: int):
    """Make the k-th member chunk of the next in-process runs raise a stop signal
    (SIGTERM, as a signal handler would); returns the chunks' first members so far."""
    import signal

    import liethermo.runner as lr
    from liethermo.faults import Interrupted

    real = lr.run_chunk
    calls = []

    def chunk(scene, lo, hi, **kw):
        calls.append(lo)
        if len(calls) == k:
            raise Interrupted(signal.SIGTERM)
        return real(scene, lo, hi, **kw)

    monkeypatch.setattr(lr, "run_chunk", chunk)
    return calls


def kill_and_resume(tmp_path: Path, args: list[str], chunks: int = 3, name: str = "z.nc"):
    """Run ``liethermo`` ``args`` (a command line without ``-o``) to ``tmp_path/name``
    as a reference, then again, killed with SIGKILL once ``chunks`` member chunks
    are in its journal, and resumed.  Returns (the resumed output, the reference
    made at the same path, the resumed run's stdout); ``tmp_path`` then holds
    ``ref/<name>`` (the reference), ``ref.nc`` (a first run) and ``<name>``."""
    import json
    import os
    import signal
    import subprocess
    import sys
    import time

    cli = [sys.executable, "-m", "liethermo.cli"]
    ref = tmp_path / "ref" / name
    out = tmp_path / name
    r = subprocess.run(cli + args + ["-o", str(ref)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    ref.rename(tmp_path / "ref.nc")  # same_but_created compares the command too: run both at out's path
    r = subprocess.run(cli + args + ["-o", str(out)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    out.rename(ref)
    p = subprocess.Popen(cli + args + ["-o", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    journal = None
    while time.time() < deadline:  # once `chunks` member chunks are in the journal
        js = list(tmp_path.glob(f".{name}.*.tmp.json"))
        if js:
            try:
                if len(json.loads(js[0].read_text())["chunks"]) >= chunks:
                    journal = js[0]
                    break
            except (OSError, ValueError):
                pass
        assert p.poll() is None, p.communicate()
        time.sleep(0.005)
    assert journal is not None
    os.kill(p.pid, signal.SIGKILL)
    p.communicate()
    assert not out.exists()
    r = subprocess.run(cli + args + ["-o", str(out), "--resume"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return out, ref, r.stdout


#: the test files that take longest (``pytest --durations``, from an empty kernel cache),
#: longest first.  The two workers each take whole files (``--dist loadfile``) in the
#: order of the collection, so these go first: a long file started last would keep
#: one worker busy after the other has finished.
LONGEST_FILES = ("test_fast_kernels.py", "test_distributed.py", "test_studies_extra.py", "test_quadratic_drag.py",
                 "test_zeitlin_physics.py", "test_gpu_sim.py", "test_framework.py", "test_coupling_flat_spin.py",
                 "test_torus_model.py", "test_fuzz.py")


def pytest_collection_modifyitems(session, config, items):
    rank = {name: k for k, name in enumerate(LONGEST_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: the rest keep their order
