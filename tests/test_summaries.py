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


def test_the_gpu_extra_installs_cupy_for_numba_cudas_cuda_and_the_refusal_says_so(monkeypatch):
    """The fluid on a GPU needs CuPy: the ``gpu`` extra brings the wheel of
    numba-cuda's CUDA major version, and a refusal names that route."""
    import re
    import sys
    from pathlib import Path

    import pytest

    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib
    from liethermo.zeitlin import xpstep

    root = Path(__file__).resolve().parents[1]
    gpu = tomllib.loads((root / "pyproject.toml").read_text())["project"]["optional-dependencies"]["gpu"]
    cuda = {m.group(1) for d in gpu if (m := re.match(r"numba-cuda\[cu(\d+)\]", d))}
    cupy = [d for d in gpu if d.startswith("cupy-cuda")]
    assert len(cuda) == 1 and len(cupy) == 1
    assert cupy[0].startswith(f"cupy-cuda{cuda.pop()}x[ctk]")
    assert cupy[0].split(">=")[0] == xpstep.CUPY_WHEEL
    monkeypatch.setitem(sys.modules, "cupy", None)  # as where CuPy is not installed
    with pytest.raises(RuntimeError) as err:
        xpstep.namespace("gpu")
    assert "pip install 'liethermo[gpu]'" in str(err.value) and xpstep.CUPY_WHEEL in str(err.value)
    assert xpstep.CUPY_WHEEL in (root / "docs" / "api.md").read_text(encoding="utf-8")
