"""The disk cache of the fluid's basis (:mod:`liethermo.diskcache`): a value
read back has the bits of one computed; it can be switched off; it keeps to
its size limit by removing what was used least recently; a damaged entry is
computed again; a folder that takes no files means no cache, not an error;
runs at the same time build an entry at most once each and all succeed."""

from __future__ import annotations

import multiprocessing as mp
import os
import subprocess
import sys

import numpy as np
import pytest

from liethermo import diskcache
from liethermo.zeitlin import kernels as zk


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("LIETHERMO_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("LIETHERMO_CACHE", raising=False)
    monkeypatch.delenv("LIETHERMO_CACHE_MAX_MB", raising=False)
    zk.basis.cache_clear()
    yield tmp_path / "cache"
    zk.basis.cache_clear()


def _counting(monkeypatch) -> list:
    calls = []
    real = zk.compute_basis

    def compute(N):
        calls.append(N)
        return real(N)

    monkeypatch.setattr(zk, "compute_basis", compute)
    return calls


def _same(a, b) -> bool:
    return all(np.array_equal(getattr(a, k), getattr(b, k)) and getattr(a, k).dtype == getattr(b, k).dtype
               for k in zk._BASIS_ARRAYS) and a.N == b.N and a.hbar == b.hbar


def test_a_basis_read_back_has_the_bits_of_one_computed(cache, monkeypatch):
    calls = _counting(monkeypatch)
    first = zk.basis(17)
    assert calls == [17] and len(list(cache.glob("*.npz"))) == 1 and zk.basis_on_disk(17)
    zk.basis.cache_clear()
    second = zk.basis(17)
    assert calls == [17]  # read, not computed
    assert _same(first, second) and _same(second, zk.compute_basis(17))
    assert not zk.basis_on_disk(18)


def test_the_cache_can_be_switched_off(cache, monkeypatch):
    monkeypatch.setenv("LIETHERMO_CACHE", "off")
    calls = _counting(monkeypatch)
    zk.basis(9)
    zk.basis.cache_clear()
    zk.basis(9)
    assert calls == [9, 9] and not cache.exists() and not zk.basis_on_disk(9)


def test_the_size_limit_removes_the_entries_used_least_recently(cache, monkeypatch):
    for N in (20, 21, 22):
        zk.basis(N)
    sizes = {p.name: p.stat().st_size for p in cache.glob("*.npz")}
    os.utime(next(cache.glob("*N20-*")), (1, 1))  # N = 20 used longest ago
    os.utime(next(cache.glob("*N21-*")), (2, 2))
    monkeypatch.setenv("LIETHERMO_CACHE_MAX_MB", str((max(sizes.values()) * 2.5) / 2**20))
    zk.basis(23)  # a store over the limit evicts 20 and 21, keeps 22 and the new 23
    names = sorted(p.name.split("-")[2] for p in cache.glob("*.npz"))
    assert names == ["N22", "N23"], names
    monkeypatch.setenv("LIETHERMO_CACHE_MAX_MB", "a lot")
    with pytest.raises(ValueError, match="LIETHERMO_CACHE_MAX_MB must be a number of MB, got 'a lot'"):
        diskcache.max_bytes()


def test_a_damaged_entry_is_computed_again_and_replaced(cache, monkeypatch):
    good = zk.basis(15)
    entry = next(cache.glob("*.npz"))
    data = bytearray(entry.read_bytes())
    data[len(data) // 2] ^= 0xFF  # one flipped byte inside an array: zip's CRC-32 finds it
    entry.write_bytes(bytes(data))
    zk.basis.cache_clear()
    calls = _counting(monkeypatch)
    again = zk.basis(15)
    assert calls == [15] and _same(good, again)
    zk.basis.cache_clear()
    assert _same(zk.basis(15), good) and calls == [15]  # the replaced entry reads back


def test_a_folder_that_takes_no_files_means_no_cache(tmp_path, monkeypatch):
    blocker = tmp_path / "a file"
    blocker.write_text("")
    monkeypatch.setenv("LIETHERMO_CACHE_DIR", str(blocker / "cache"))  # cannot be created
    zk.basis.cache_clear()
    try:
        assert _same(zk.basis(11), zk.compute_basis(11))
    finally:
        zk.basis.cache_clear()
    assert not list(tmp_path.glob("**/*.npz")) and not list(tmp_path.glob("**/*.tmp"))


def _build(N, q):
    from liethermo.zeitlin import kernels

    b = kernels.basis(N)
    q.put(np.asarray(b.vecs).tobytes())


def test_runs_at_the_same_time_build_it_safely(cache):
    """Four processes want the basis of su(40) at once: each gets the same bits,
    one entry stays, and no temporary is left."""
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    procs = [ctx.Process(target=_build, args=(40, q)) for _ in range(4)]
    for p in procs:
        p.start()
    got = [q.get(timeout=120) for _ in procs]
    for p in procs:
        p.join(60)
        assert p.exitcode == 0
    assert len(set(got)) == 1 and got[0] == zk.compute_basis(40).vecs.tobytes()
    assert [p.name.split("-")[2] for p in cache.iterdir()] == ["N40"]


def test_tests_never_use_the_users_cache():
    user = diskcache.Path(__import__("platformdirs").user_cache_dir("liethermo", appauthor=False))
    assert diskcache.cache_dir() != user and "liethermo-test-cache-" in os.environ["LIETHERMO_CACHE_DIR"]
