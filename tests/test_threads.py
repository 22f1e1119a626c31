"""Thread pools that fit the machine (:mod:`liethermo.threads`): the usable
cores follow the affinity mask and the cgroup quota; every run sets the BLAS
pool and the kernels' threads; and the thread counts change no value — the
top's file is the same on one and two kernel threads, the fluid's on one and
two BLAS threads and with its members' fixed points on one or two threads."""

from __future__ import annotations

import os
import subprocess
import sys
import threading

import netCDF4
import numpy as np
import pytest
from threadpoolctl import threadpool_info

import liethermo.top.kernels.parallel as par
from liethermo import threads as lt
from liethermo.models import model_of
from liethermo.runner import run_scene
from liethermo.scene import load_scene

TOP = ["output.compare=[]", "output.figures=false", "integrator.steps=40", "output.every=10",
       "ensemble.members=512", "output.member_chunk=256", "integrator.method=\"rk2\""]
FLUID = ["zeitlin.N=24", "ensemble.members=3", "integrator.steps=20", "output.every=5",
         "output.compare=[]", "output.figures=false"]


def _values(path) -> dict:
    with netCDF4.Dataset(path) as nc:
        nc.set_auto_mask(False)
        return {k: v[...] for k, v in nc.variables.items()}


def _equal(a: dict, b: dict) -> bool:
    return list(a) == list(b) and all(
        a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind in "fc") for k in a)


def test_cgroup_quota_in_cores(tmp_path):
    v2 = tmp_path / "cpu.max"
    v2.write_text("150000 100000\n")
    assert lt.cgroup_quota_cores(v2, ()) == 1.5
    v2.write_text("max 100000\n")
    assert lt.cgroup_quota_cores(v2, ()) is None
    q, p = tmp_path / "quota", tmp_path / "period"
    q.write_text("-1\n"), p.write_text("100000\n")
    assert lt.cgroup_quota_cores(tmp_path / "none", (q, p)) is None
    q.write_text("300000\n")
    assert lt.cgroup_quota_cores(tmp_path / "none", (q, p)) == 3.0


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity on this system")
def test_usable_cores_follow_the_affinity_mask():
    code = ("import os; os.sched_setaffinity(0, {min(os.sched_getaffinity(0))}); "
            "from liethermo.threads import usable_cores, kernel_threads; print(usable_cores(), kernel_threads())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["1", "1"]


def test_top_file_is_the_same_on_one_and_two_kernel_threads(tmp_path, monkeypatch):
    used = []
    real = par.run_ranges

    def counting(fn, n_items, a, b, threads=None, min_items=1):
        used.append(par.default_threads() if threads is None else threads)
        return real(fn, n_items, a, b, threads, min_items)

    monkeypatch.setattr(par, "run_ranges", counting)
    for n in (1, 2):
        monkeypatch.setattr(lt, "usable_cores", lambda n=n: n)
        run_scene("paper", tmp_path / f"t{n}.nc", overrides=TOP, progress=False)
        assert set(used) == {n}, used  # the kernels ran on n threads
        used.clear()
    assert _equal(_values(tmp_path / "t1.nc"), _values(tmp_path / "t2.nc"))


def test_fluid_bits_do_not_depend_on_blas_threads(tmp_path, monkeypatch):
    from liethermo.zeitlin import model as zm

    sc = load_scene("zeitlin_decay", FLUID)
    assert model_of(sc).thread_counts(sc, 2).blas == 1  # N = 24 < BLAS_THREADED_N
    monkeypatch.setattr(zm, "BLAS_THREADED_N", 2)  # now the pool is the usable cores
    monkeypatch.setattr(lt, "usable_cores", lambda: 2)
    seen = []
    real = zm.Fluid.run_chunk

    def recording(self, *a, **k):
        seen.append(max(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"))
        return real(self, *a, **k)

    monkeypatch.setattr(zm.Fluid, "run_chunk", recording)
    run_scene("zeitlin_decay", tmp_path / "b2.nc", overrides=FLUID, progress=False)
    monkeypatch.setattr(zm, "BLAS_THREADED_N", 10**6)
    run_scene("zeitlin_decay", tmp_path / "b1.nc", overrides=FLUID, progress=False)
    if len(threadpool_info()) and os.cpu_count() and os.cpu_count() >= 2:
        assert seen == [2, 1], seen
    assert _equal(_values(tmp_path / "b1.nc"), _values(tmp_path / "b2.nc"))


def test_fluid_bits_do_not_depend_on_the_threads_its_members_take(tmp_path, monkeypatch):
    """Below BLAS_THREADED_N a fluid run splits each batch's fixed points into groups of
    members over the kernel threads: the file is the one a single thread writes."""
    from liethermo.zeitlin import kernels as zk

    over = FLUID + ["zeitlin.N=40"]  # at least MEMBERS_SPLIT_N: the members are split
    sc = load_scene("zeitlin_decay", over)
    assert model_of(sc).thread_counts(sc, 2).kernel == 2 and model_of(sc).thread_counts(sc, 2).blas == 1
    groups = []
    real = zk._isomp

    def recording(W, *a, **k):
        groups.append((threading.current_thread().name, W.shape[0]))
        return real(W, *a, **k)

    monkeypatch.setattr(zk, "_isomp", recording)
    monkeypatch.setattr(lt, "usable_cores", lambda: 2)
    run_scene("zeitlin_decay", tmp_path / "k2.nc", overrides=over, progress=False)
    members = int(sc["ensemble"]["members"])
    assert any(name.startswith("liethermo-members") for name, _ in groups)  # a group on the second thread
    assert all(m < members for _, m in groups)
    groups.clear()
    monkeypatch.setattr(lt, "usable_cores", lambda: 1)
    run_scene("zeitlin_decay", tmp_path / "k1.nc", overrides=over, progress=False)
    assert groups and all(m == members for _, m in groups)  # one group: the whole batch
    assert _equal(_values(tmp_path / "k1.nc"), _values(tmp_path / "k2.nc"))
    assert lt.pooled_kernel_threads() == 1  # outside a run's pools: no split, no file read per call


def test_pools_are_restored_after_a_run(tmp_path):
    before = [(i["prefix"], i["num_threads"]) for i in threadpool_info()]
    k = lt.kernel_threads()
    run_scene("zeitlin_decay", tmp_path / "x.nc", overrides=FLUID, progress=False)
    assert [(i["prefix"], i["num_threads"]) for i in threadpool_info()] == before
    assert lt.kernel_threads() == k


def test_a_run_sets_its_pools_once_and_its_chunks_keep_them(tmp_path, monkeypatch):
    """The chunk loop of a run sets the pools once (threadpoolctl's scan of the loaded libraries
    costs milliseconds a chunk): each chunk asks for the same counts and finds them set, and its
    kernels run on them. A chunk run on its own, or inside a block of other counts (a study's),
    sets the counts its scene asks for."""
    import threadpoolctl

    from liethermo.runner import run_chunk, scene_setup
    from liethermo.top import model as tm

    limits, seen = [], []
    real_limits = threadpoolctl.threadpool_limits

    def counting(*a, **k):
        limits.append(k.get("limits"))
        return real_limits(*a, **k)

    monkeypatch.setattr(threadpoolctl, "threadpool_limits", counting)
    real = tm.label_chunk
    monkeypatch.setattr(tm, "label_chunk", lambda *a, **k: seen.append((lt._active, lt.kernel_threads()))
                        or real(*a, **k))
    over = {"ensemble.members": 96, "output.member_chunk": 32, "integrator.steps": 4}
    sc = scene_setup("paper", over)[0]
    want = model_of(sc).thread_counts(sc, lt.usable_cores())
    run_scene("paper", tmp_path / "p.nc", overrides=over, progress=False)
    assert len(seen) == 3 and len(limits) == 1, (seen, limits)
    assert all(s == (want, max(1, want.kernel)) for s in seen) and lt._active is None
    run_chunk(sc, 0, 32)  # on its own: sets them for itself
    assert len(limits) == 2 and seen[-1][0] == want
    other = lt.ThreadCounts(blas=want.blas + 1, kernel=1)
    with lt.pools(other):  # a study's block: the chunk sets its scene's counts inside it
        run_chunk(sc, 0, 32)
    assert len(limits) == 4 and seen[-1][0] == want
