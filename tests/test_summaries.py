"""What a run's summary and ``--check`` print: each figure says what it
measures, and it measures that."""

from __future__ import annotations

import time

import liethermo
from liethermo import simulate


def test_the_summarys_wall_time_leaves_out_compiling(monkeypatch):
    """A first run compiles its kernels inside the first chunk; the summary's
    wall time is the simulating and writing, the compiling is reported apart."""
    real = simulate._ensure_compiled

    def slow_compile(fn, args):
        time.sleep(0.6)
        return real(fn, args) + 0.6

    monkeypatch.setattr(simulate, "_ensure_compiled", slow_compile)
    ds = liethermo.run("spherical_top", {"integrator.steps": 10}, compare=False)
    summary = ds.attrs["summary"]
    wall = float(summary.split("wall time ")[1].split(" s")[0])
    compiled = float(summary.split("compiled or loaded in ")[1].split(" s")[0])
    assert compiled >= 0.6
    assert wall < 0.5, summary
    assert "not compiling" in summary
