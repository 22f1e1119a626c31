"""The kernels mean what they say: with NUMBA_DISABLE_JIT=1 every kernel runs as
plain Python (the generic functions dispatch on the terms at run time, the fused
multiply-add is computed exactly in rational arithmetic) and gives the jitted
numbers."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

TESTS_DIR = Path(__file__).resolve().parent

SCRIPT = r"""
import sys
import numpy as np
sys.path.insert(0, sys.argv[2])
from dataclasses import replace
from conftest import paper_physics, OMEGA0, R0
from liethermo.top.methods import MethodChoice
from liethermo.top.simulate import simulate
out = {}
phys = paper_physics(2)
om = np.array([OMEGA0, [0.5, -1.0, 2.0]])
R = np.array([R0, R0])
for kernel in ("fast", "simple"):
    out[f"vi_{kernel}"] = simulate(phys, om, R, 0.1, 12, MethodChoice.of("vi", start="node", entropy="explicit"),
                                   attitude=True, kernel=kernel).states
    out[f"vi4_{kernel}"] = simulate(phys, om, R, 0.1, 4, "vi4", kernel=kernel).states
    out[f"rk2_{kernel}"] = simulate(phys, om, R, 0.1, 12, "rk2", kernel=kernel).states
coupled = replace(phys, heat_capacity=np.full(2, 1e-3), thermal_expansion=np.full(2, 1e-3),
                  internal_friction=np.zeros(2))
out["coupled_fast"] = simulate(coupled, om, R, 0.05, 6, "vi").states
db = replace(phys, internal_friction=np.full(2, 5.0))
out["db_fast"] = simulate(db, om, R, 0.05, 6, "vi").states
np.savez(sys.argv[1], **out)
"""


@pytest.mark.slow
def test_plain_python_matches_jit(tmp_path):
    """VI (paper choices, attitude), vi4, RK2, the coupled top and double-bracket
    friction, block and straightforward kernels: plain Python and jitted
    agree to ≤ 1e-13 relative."""
    out = tmp_path / "nojit.npz"
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    r = subprocess.run([sys.executable, "-c", SCRIPT, str(out), str(TESTS_DIR)], env=env,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    jit = tmp_path / "jit.npz"
    r = subprocess.run([sys.executable, "-c", SCRIPT, str(jit), str(TESTS_DIR)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    plain, jitted = np.load(out), np.load(jit)
    for name in jitted.files:
        a, b = plain[name], jitted[name]
        assert a.shape == b.shape and np.all(np.isfinite(b)), name
        assert np.abs(a - b).max() <= 1e-13 * np.abs(b).max(), name
