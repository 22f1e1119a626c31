"""The scene key ``ensemble.device`` (and ``--device``): where the steps run.

The top's GPU kernels run here in numba-cuda's simulator (a subprocess with
``NUMBA_ENABLE_CUDASIM=1``) through the whole command line: the file equals
the CPU's bit for bit.  The fluids' GPU steps (the sphere's and the torus's)
are the array-namespace steps with CuPy; here the namespace is numpy, through
the same run layer.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["--set", "ensemble.members=5", "--set", "integrator.steps=40", "--set", "output.every=4",
         "--set", "output.member_chunk=3", "--set", "output.compare=[]", "--set", "output.figures=false",
         "--no-progress"]


def _cli(*args, env=None):
    return subprocess.run([sys.executable, "-m", "liethermo.cli", *args], capture_output=True, text=True,
                          env={**os.environ, **(env or {})}, timeout=600)


def _same_arrays(a: Path, b: Path) -> list[str]:
    with xr.open_dataset(a) as x, xr.open_dataset(b) as y:
        assert sorted(x.variables) == sorted(y.variables)
        return [v for v in y.variables
                if not np.array_equal(x[v].values, y[v].values, equal_nan=x[v].dtype.kind == "f")]


def test_a_gpu_run_writes_the_cpu_file(tmp_path):
    """`liethermo run paper --device gpu` (the simulator) against the CPU: every
    array bit for bit, in member chunks of 3; `--check` names the GPU memory."""
    if importlib.util.find_spec("numba_cuda") is None:
        pytest.skip("numba-cuda is not installed (it is in the test extra: pip install -e '.[test]')")
    sim = {"NUMBA_ENABLE_CUDASIM": "1"}
    p = _cli("run", "paper", "-o", str(tmp_path / "gpu.nc"), "--device", "gpu", *SMALL, env=sim)
    assert p.returncode == 0, p.stderr[-3000:]
    p = _cli("run", "paper", "-o", str(tmp_path / "cpu.nc"), *SMALL)
    assert p.returncode == 0, p.stderr[-3000:]
    assert _same_arrays(tmp_path / "gpu.nc", tmp_path / "cpu.nc") == []
    with xr.open_dataset(tmp_path / "gpu.nc") as ds:
        assert 'device = "gpu"' in ds.attrs["scene"]
    p = _cli("run", "paper", "-o", str(tmp_path / "gpu2.nc"), "--device", "gpu", "--check", *SMALL, env=sim)
    assert p.returncode == 0, p.stderr[-3000:]
    assert "of GPU memory" in p.stdout + p.stderr


def test_gpu_without_a_device_is_refused_in_one_line(tmp_path):
    from liethermo.gpu import gpu_available

    ok, why = gpu_available()
    if ok:
        pytest.skip(f"this machine has a device: {why}")
    for scene in ("paper", "zeitlin_decay", "torus_euler"):
        out = tmp_path / f"{scene}.nc"
        p = _cli("run", scene, "-o", str(out), "--device", "gpu", "--no-progress")
        assert p.returncode != 0
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1 and "scene key 'ensemble.device'" in lines[0] and "cannot run here" in lines[0]
        assert not out.exists() and not list(tmp_path.glob(f"{scene}*"))


def test_the_fluid_on_the_array_namespace_through_the_run_layer(monkeypatch):
    """ensemble.device = "gpu" sends every member chunk of the fluid through the
    array-namespace steps (numpy standing in for CuPy): the CPU's run to
    round-off, with the same status and fixed-point iterations."""
    import liethermo
    from liethermo import gpu

    real = gpu.namespace
    monkeypatch.setattr(gpu, "namespace", lambda backend: np if backend == "gpu" else real(backend))
    small = {"zeitlin.N": 8, "initial.lmax": 4, "ensemble.members": 5, "integrator.steps": 30,
             "output.every": 5, "output.member_chunk": 2, "output.compare": [], "output.figures": False}
    cpu = liethermo.run("zeitlin_decay", small, compare=False)
    gpu = liethermo.run("zeitlin_decay", {**small, "ensemble.device": "gpu"}, compare=False)
    assert 'device = "gpu"' in gpu.attrs["scene"]
    checked = 0
    energy = float(np.nanmax(np.abs(cpu["energy"].values)))  # the scale of differences of energies
    for v in cpu.data_vars:
        a, b = cpu[v].values, gpu[v].values
        if a.dtype.kind == "f":
            np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
            ok = np.isfinite(a)
            scale = max(float(np.abs(a[ok]).max(initial=0.0)), energy if "energy" in v else 1e-300)
            assert np.abs(a[ok] - b[ok]).max(initial=0.0) <= 1e-12 * scale, v
            checked += 1
        else:
            np.testing.assert_array_equal(a, b, err_msg=v)
    assert checked >= 8


def test_the_torus_on_the_array_namespace_through_the_run_layer(monkeypatch):
    """ensemble.device = "gpu" sends every member chunk of the torus through its
    array-namespace steps (numpy standing in for CuPy): the CPU's run bit for
    bit (the same kernels, written once over the array module), every variable."""
    import liethermo
    from liethermo import gpu

    calls = []

    def stand_in(backend):
        calls.append(backend)
        return np

    monkeypatch.setattr(gpu, "namespace", stand_in)
    small = {"torus.N": 9, "ensemble.members": 3, "integrator.steps": 10, "output.every": 5,
             "output.member_chunk": 2, "integrator.h": 0.05, "output.compare": [], "output.figures": False}
    cpu = liethermo.run("torus_convection", small, compare=False)
    assert calls == []
    gpu_run = liethermo.run("torus_convection", {**small, "ensemble.device": "gpu"}, compare=False)
    assert calls.count("gpu") >= 3  # the preflight and each of the two member chunks
    assert 'device = "gpu"' in gpu_run.attrs["scene"]
    assert sorted(cpu.data_vars) == sorted(gpu_run.data_vars) and len(cpu.data_vars) >= 15
    for v in cpu.data_vars:
        np.testing.assert_array_equal(cpu[v].values, gpu_run[v].values, err_msg=v)
    assert np.abs(np.diff(cpu["entropy"].values, axis=1)).max() > 0  # heat moved: the run is not trivial


def test_the_device_is_a_scene_difference_only_where_it_changes_bits():
    """The top's GPU kernels give the CPU's bits: a file of one device is the
    same run as the other's (replaced, resumed).  The fluid's products round
    differently on the GPU: its file holds one device's run (the sphere's and the torus's)."""
    from liethermo.models import get_model
    from liethermo.preflight import scene_difference
    from liethermo.scene import load_scene, scene_to_toml

    for name, model, same in (("paper", "top", True), ("zeitlin_decay", "zeitlin", False),
                              ("torus_euler", "torus", False)):
        a = scene_to_toml(load_scene(name))
        b = scene_to_toml(load_scene(name, {"ensemble.device": "gpu"}))
        diff = scene_difference(a, b, get_model(model).not_in_results)
        if same:
            assert diff is None
        else:
            assert diff == "ensemble.device ('cpu' there, 'gpu' here)"
