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
               for k in zk._BASIS_ARRAYS + ("vecs_t",)) and a.N == b.N and a.hbar == b.hbar


def test_a_basis_read_back_has_the_bits_of_one_computed(cache, monkeypatch):
    calls = _counting(monkeypatch)
    first = zk.basis(17)
    assert calls == [17] and len(list(cache.glob("*.npz"))) == 1 and zk.basis_on_disk(17)
    zk.basis.cache_clear()
    second = zk.basis(17)
    assert calls == [17]  # read, not computed
    assert _same(first, second) and _same(second, zk.compute_basis(17))
    assert not zk.basis_on_disk(18)


def _entry_bytes(N: int) -> int:
    """The bytes of the arrays of su(N)'s entry: the eigenvectors once (Σ (N−d)²
    numbers), five numbers per mode, g0 (N²) and two offsets (N + 1 each)."""
    from liethermo.zeitlin.estimate import basis_numbers

    modes = N * (N + 1) // 2
    return 8 * (basis_numbers(N) + 5 * modes + N * N + 2 * (N + 1))


def test_an_entry_holds_the_eigenvectors_once_and_the_default_limit_holds_su_1024(cache):
    """The transposed copy of the eigenvectors that the CPU's steps use is made from
    the entry, not stored: the entry of su(1024) is 2.9 GB, not 5.8 GB, and fits the
    default size limit (the first run at N = 1024 leaves it for the next)."""
    b = zk.basis(24)
    with np.load(next(cache.glob("*.npz"))) as z:
        assert sorted(z.files) == sorted(zk._BASIS_ARRAYS)
        assert sum(z[k].nbytes for k in z.files) == _entry_bytes(24)
    assert b.vecs_t.shape == b.vecs.shape
    for d in range(24):  # block d of the transposed copy is block d of the eigenvectors, transposed
        n, blk = 24 - d, slice(b.voff[d], b.voff[d + 1])
        assert np.array_equal(b.vecs_t[blk].reshape(n, n), b.vecs[blk].reshape(n, n).T)
    assert 2.8e9 < _entry_bytes(1024) < diskcache.DEFAULT_MAX_MB * 2**20 == diskcache.max_bytes()


def test_an_entry_larger_than_the_limit_is_not_written_and_the_user_is_told(cache, monkeypatch, capsys):
    monkeypatch.setenv("LIETHERMO_CACHE_MAX_MB", str(0.5 * _entry_bytes(30) / 2**20))
    calls = _counting(monkeypatch)
    assert _same(zk.basis(30), zk.compute_basis(30)) and calls == [30, 30]
    err = capsys.readouterr().err
    assert "not caching zeitlin-basis N30" in err and "LIETHERMO_CACHE_MAX_MB" in err and "set it higher" in err
    assert not cache.exists() or not list(cache.iterdir())  # nothing written, no temporary left
    monkeypatch.setenv("LIETHERMO_CACHE_MAX_MB", str(2 * _entry_bytes(30) / 2**20))
    zk.basis.cache_clear()
    zk.basis(30)
    assert zk.basis_on_disk(30) and capsys.readouterr().err == ""


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


def test_an_entry_without_one_of_the_arrays_is_computed_again(cache, monkeypatch):
    """A file under the entry's name that lacks an array of the basis (another build's
    layout) is not read: the basis is computed, with the bits of a fresh one."""
    good = zk.basis(13)
    entry = next(cache.glob("*.npz"))
    with np.load(entry) as z:
        kept = {k: z[k] for k in z.files if k != "tinv"}
    with open(entry, "wb") as f:
        np.savez(f, **kept)
    zk.basis.cache_clear()
    calls = _counting(monkeypatch)
    assert _same(zk.basis(13), good) and calls == [13]


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
