"""Atomic, member-chunked netCDF4 output, resumable.

:class:`ChunkedWriter` writes a dataset whose leading dimension ``member`` is
filled chunk by chunk (so memory stays bounded by one chunk), into a
temporary file in the destination folder (``.<name>.<pid>.tmp``, locked
while its writer lives: :mod:`liethermo.faults`), and renames it onto the
output path only when everything was written: a run that is killed leaves
either no file at the path or the previous complete one.  Variables are
chunked along ``member`` on disk so that ``xarray.open_dataset(path,
chunks={})`` reads a large result lazily.  Every dataset passes through
:func:`liethermo.cf.encode` (time units, string labels, ``coordinates``,
``Conventions`` and ``history``): the files are CF-1.11 (docs/netcdf.md).

Resume: after each member chunk a run flushes the file and records the chunk
in a journal next to it (:class:`Journal`: the resolved scene, and per chunk
its member range, a CRC-32 of every variable's values as written and its
summary statistics).  An interrupted run keeps the file as ``<name>.partial``
with its journal; a run killed outright leaves its temporary and journal
behind.  Either is a :class:`ResumeSource`: a resumed run reads the recorded
chunks back, checks their CRCs (a chunk that does not match is recomputed),
writes them into a fresh file in the same order as an uninterrupted run, and
goes on from there, so the finished file has the same bytes as an
uninterrupted run's but for its creation time.

Errors of the netCDF/HDF5 library or the operating system while writing are
raised as :class:`WriteError`, naming the file and the cause (the cause of
an HDF5 failure, which the library does not report, is found by a probe
write: disk full, file-size limit, quota); the temporary is removed.
"""

from __future__ import annotations

import errno
import json
import os
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import netCDF4
import numpy as np
import xarray as xr

from . import cf
from .version import __version__
from .faults import check_stop, create_temp, leftovers, release_temp

try:
    from zlib_ng.zlib_ng import crc32 as _crc32
except ImportError:  # pragma: no cover - a dependency; zlib gives the same values
    _crc32 = zlib.crc32

CHUNK_BYTES = 4 * 2**20  # target on-disk chunk size
RESUME_FORMAT = "liethermo-resume-1"


class WriteError(Exception):
    """Writing an output failed: ``path`` and ``cause`` (one line)."""

    def __init__(self, path, cause: str):
        self.path, self.cause = Path(path), cause
        super().__init__(f"cannot write {path}: {cause}")


def _nc_attr(value):
    if isinstance(value, (bool, np.bool_)):
        return int(value)
    return value


def _errno_text(exc: OSError) -> str:
    name = errno.errorcode.get(exc.errno or 0)
    return f"{exc.strerror or exc}" + (f" ({name})" if name else "")


def io_cause(exc: BaseException, probe: Path | None = None) -> str:
    """A one-line cause for a failed write: the OS error if there is one,
    else (the netCDF library says only "HDF error") the error of a probe
    write at the end of ``probe``, else the library's message."""
    if isinstance(exc, OSError) and exc.errno:
        return _errno_text(exc)
    if probe is not None:
        try:
            fd = os.open(probe, os.O_WRONLY | os.O_APPEND)
        except OSError as e:
            return _errno_text(e)
        try:
            block = b"\0" * (1 << 16)
            for _ in range(64):  # up to 4 MiB: more than HDF5 writes at once here
                os.write(fd, block)
            os.fsync(fd)
        except OSError as e:
            return _errno_text(e)
        finally:
            os.close(fd)
    return f"{exc}" or type(exc).__name__


def disk_chunk_members(n_members: int, member_bytes: int, member_chunk: int | None = None) -> int:
    """Members per on-disk chunk of a variable with ``member_bytes`` per member:
    at most about CHUNK_BYTES, a power of two, and no more than the run's
    ``member_chunk``.  A run's member chunks (powers of two by default) then fill
    whole disk chunks, each written once: a disk chunk larger than a member
    chunk would be flushed part-filled after every member chunk and rewritten
    by the next ones (the bytes of a narrow variable written four times over)."""
    budget = max(1, CHUNK_BYTES // max(1, member_bytes))
    if member_chunk:
        budget = min(budget, int(member_chunk))
    return min(n_members, 1 << (budget.bit_length() - 1))


def checksum(values: np.ndarray) -> int:
    """CRC-32 of an array's values (C order): zlib's, computed by zlib-ng where it is
    installed (the same values; 0.8 ms instead of 4.1 ms for a chunk's 18 MiB)."""
    a = np.asarray(values)
    if a.dtype.kind == "O":
        return _crc32("\0".join(map(str, a.ravel())).encode())
    return _crc32(memoryview(np.ascontiguousarray(a)).cast("B"))


def _create_netcdf(tmp: Path) -> netCDF4.Dataset:
    """A new netCDF-4 file at the (empty, locked) temporary ``tmp``.

    HDF5 creates the file by truncating the temporary, which ext4 (its default
    ``auto_da_alloc``) takes for a file being replaced by a rewrite: when the
    writer's descriptor is closed it would allocate and start writing out every
    block still in the page cache, on the run's critical path (0.1 s per 300 MB
    measured).  Closing a descriptor of our own while the file is still empty
    spends that one-off flush on nothing; the data then reaches the disk by the
    system's usual writeback, as any file written without fsync.  Elsewhere
    this is one open and close."""
    nc = netCDF4.Dataset(tmp, "w", format="NETCDF4")
    try:
        os.close(os.open(tmp, os.O_WRONLY))
    except OSError:  # pragma: no cover - only a missed speed-up
        pass
    return nc


class ChunkedWriter:
    """Write ``n_members`` members in chunks: ``write(ds_chunk, offset)``.

    Variables without a ``member`` dimension are written from the first chunk.
    Use as a context manager; on an exception the temporary file is removed.
    ``attrs`` are the global attributes; ``history`` (the command line or API
    call that makes the file) replaces the ``history`` of ``attrs`` if given.
    ``member_chunk``: the members the writer is given at a time (the run's
    ``output.member_chunk``), which bounds the disk chunks
    (:func:`disk_chunk_members`).
    The temporary is created (and the folder checked) at construction.
    """

    def __init__(self, path: str | os.PathLike, n_members: int, attrs: dict | None = None,
                 history: str | None = None, member_chunk: int | None = None):
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.tmp, self._lock_fd = create_temp(self.path)
        except OSError as exc:
            raise WriteError(self.path, _errno_text(exc)) from None
        self.n_members = int(n_members)
        self.member_chunk = int(member_chunk) if member_chunk else None
        self.attrs = cf.encode_attrs(attrs or {}, history)
        self.nc: netCDF4.Dataset | None = None
        self.written = 0
        self.member_vars: list[str] = []  # in the order they are written

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            self.abort()
        return False

    def _fail(self, exc: BaseException):
        """Remove the temporary and raise a WriteError naming the output and the cause."""
        cause = io_cause(exc, self.tmp)
        self.abort()
        raise WriteError(self.path, cause) from None

    def define(self, ds: xr.Dataset) -> None:
        """Create the file's dimensions and variables from a chunk's layout
        (member count aside, any chunk gives the same file), CF-encoded."""
        try:
            self._define(cf.encode_variables(ds))
        except (OSError, RuntimeError) as exc:
            self._fail(exc)

    def _define(self, ds: xr.Dataset) -> None:
        nc = self.nc = _create_netcdf(self.tmp)
        for dim, size in ds.sizes.items():
            nc.createDimension(dim, self.n_members if dim == "member" else size)
        for name, var in list(ds.coords.items()) + list(ds.data_vars.items()):
            if "member" in var.dims:
                self.member_vars.append(name)
            if var.dtype.kind in "US":
                v = nc.createVariable(name, str, var.dims)
                v[:] = np.asarray(var.values, dtype=object)
            else:
                v = self._numeric_variable(name, var.dtype, var.dims, ds.sizes)
                if "member" not in var.dims:
                    v[...] = var.values
            v.setncatts({k: _nc_attr(a) for k, a in var.attrs.items()})
        nc.setncatts({k: _nc_attr(a) for k, a in self.attrs.items()})

    def _numeric_variable(self, name: str, dtype, dims: tuple, sizes) -> netCDF4.Variable:
        """A numeric variable of the new file: one with ``member`` and more dimensions
        chunked on disk by :func:`disk_chunk_members`; ``sizes``: the other dimensions'."""
        chunks = None
        if "member" in dims and len(dims) > 1:
            other = int(np.prod([sizes[d] for d in dims if d != "member"]))
            m = disk_chunk_members(self.n_members, other * dtype.itemsize, self.member_chunk)
            chunks = [m if d == "member" else sizes[d] for d in dims]
        v = self.nc.createVariable(name, dtype, dims, chunksizes=chunks)
        if chunks is not None:
            # every disk chunk is written once, in order: a cache of two chunks is
            # enough. netCDF's default (64 MiB per variable, ~25 variables) made the
            # peak memory grow with the ensemble size (1.3 GB at 10^6 members)
            nbytes = int(np.prod(chunks)) * dtype.itemsize
            v.set_var_chunk_cache(size=2 * nbytes + 1024, nelems=17, preemption=1.0)
        return v

    def define_like(self, source: Path) -> None:
        """Create the file's dimensions and variables as the partial file
        ``source`` of an earlier run of the same scene has them (the layout a
        resumed run continues; nothing is simulated to learn it)."""
        try:
            with netCDF4.Dataset(source, "r") as src:
                src.set_auto_mask(False)
                self._define_from(src)
        except (OSError, RuntimeError) as exc:
            self._fail(exc)

    def _define_from(self, src) -> None:
        nc = self.nc = _create_netcdf(self.tmp)
        for dim, d in src.dimensions.items():
            nc.createDimension(dim, self.n_members if dim == "member" else len(d))
        for name, var in src.variables.items():
            dims = var.dimensions
            if "member" in dims:
                self.member_vars.append(name)
            if var.dtype is str:
                v = nc.createVariable(name, str, dims)
                v[:] = var[:]
            else:
                v = self._numeric_variable(name, var.dtype, dims, {d: len(n) for d, n in src.dimensions.items()})
                if "member" not in dims:
                    v[...] = var[...]
            v.setncatts({k: var.getncattr(k) for k in var.ncattrs()})
        nc.setncatts({k: _nc_attr(a) for k, a in self.attrs.items()})

    def write(self, ds: xr.Dataset, offset: int, pause=None) -> dict[str, int]:
        """Write a chunk at ``offset`` (CF-encoded: :func:`liethermo.cf.encode_variables`);
        returns the CRC-32 of each member variable's values as written.  ``pause()``, if
        given, is called before each variable (a writer thread giving way to the kernels)."""
        if self.nc is None or any(n not in ds.variables for n in self.member_vars):
            ds = cf.encode_variables(ds)  # a relabelled variable's name is the encoding's
        if self.nc is None:
            self.define(ds)
        arrays = {}
        for name in self.member_vars:
            var = ds.variables[name]
            if var.dims[0] != "member":
                raise ValueError(f"variable {name}: 'member' must be its first dimension")
            # once the file is defined, the encoding's only change to a member variable's values is
            # a boolean's cast to int8 (the rest is attributes, which the file has)
            arrays[name] = var.values.astype(np.int8) if var.dtype.kind == "b" else var.values
        return self.write_arrays(arrays, offset, pause)

    def write_arrays(self, arrays: dict, offset: int, pause=None) -> dict[str, int]:
        """Write the member variables' values of members ``offset:offset+n``
        (as :meth:`write` does); returns their CRC-32s."""
        n = len(next(iter(arrays.values()))) if arrays else 0
        if offset < 0 or offset + n > self.n_members:
            raise ValueError(f"chunk [{offset}, {offset + n}) outside 0..{self.n_members}")
        crc = {}
        try:
            for name in self.member_vars:
                if pause is not None:
                    pause()
                a = arrays[name]
                if a.dtype.kind != "O":
                    a = np.ascontiguousarray(a)
                crc[name] = checksum(a)
                self.nc.variables[name][offset:offset + n, ...] = a
        except (OSError, RuntimeError) as exc:
            self._fail(exc)
        self.written += n
        return crc

    def sync(self) -> None:
        """Flush everything written so far to the file."""
        try:
            self.nc.sync()
        except (OSError, RuntimeError) as exc:
            self._fail(exc)

    def close(self) -> None:
        if self.nc is None:
            raise RuntimeError("nothing was written")
        if self.written != self.n_members:
            self.abort()
            raise RuntimeError(f"only {self.written} of {self.n_members} members were written")
        try:
            self.nc.close()
            self.nc = None
            os.replace(self.tmp, self.path)
        except (OSError, RuntimeError) as exc:
            self.nc = None
            self._fail(exc)
        release_temp(self._lock_fd)
        self._lock_fd = None

    def keep(self, dest: Path) -> None:
        """Close the file as it is (the chunks written so far) and move it to ``dest``."""
        if self.nc is not None:
            self.nc.close()
            self.nc = None
        os.replace(self.tmp, dest)
        release_temp(self._lock_fd)
        self._lock_fd = None

    def abort(self) -> None:
        if self.nc is not None:
            try:
                self.nc.close()
            except Exception:  # pragma: no cover
                pass
            self.nc = None
        try:
            self.tmp.unlink()
        except FileNotFoundError:
            pass
        release_temp(self._lock_fd)
        self._lock_fd = None


#: bytes the write probe of ``--check`` writes (:func:`write_rate`): at most this ...
WRITE_PROBE_BYTES = 64 * 2**20
#: ... and at least this, for a smaller file: the probe costs no more than writing the file
WRITE_PROBE_MIN_BYTES = 2**20


def write_rate(folder: str | os.PathLike, nbytes: int = WRITE_PROBE_BYTES) -> float:
    """Bytes per second a run's writer reaches in ``folder`` (or the nearest
    folder above it that exists), measured: ``nbytes`` of member variables
    written in four chunks through :class:`ChunkedWriter` (CF encoding,
    CRC-32, netCDF/HDF5, a flush after each chunk, as a run does) into a
    temporary file that is removed afterwards.  The operating system's page
    cache absorbs what it can, as it does for a run.  Measured once per file
    system and process (a sweep of checks probes its disk once)."""
    import time

    folder = Path(folder)
    while not folder.is_dir() and folder != folder.parent:
        folder = folder.parent
    key = (os.stat(folder).st_dev, int(nbytes))
    if key not in _WRITE_RATES:
        _WRITE_RATES[key] = _measure_write_rate(folder, nbytes)
    return _WRITE_RATES[key]


#: (file system, probe bytes) → bytes per second, measured in this process
_WRITE_RATES: dict = {}


def _measure_write_rate(folder: Path, nbytes: int) -> float:
    import time

    width = 8
    # chunks of up to 32768 members, as a run's disk chunks; fewer for a small probe
    members = 4 * max(1024, min(32768, nbytes // (4 * width * 8)))
    per = max(1, nbytes // (members * width * 8))  # variables of (member, width) float64
    rng = np.random.default_rng(0)
    ds = xr.Dataset({f"v{k}": (("member", "w"), rng.random((members // 4, width)),
                               {"units": "1", "long_name": "probe"}) for k in range(per)})
    w = ChunkedWriter(folder / ".liethermo-write-probe.nc", members)
    try:
        t = time.perf_counter()
        for k in range(4):
            w.write(ds, k * (members // 4))
            w.sync()
        seconds = time.perf_counter() - t
    finally:
        w.abort()
    return per * members * width * 8 / max(seconds, 1e-9)


# ---------------------------------------------------------------- resume
def partial_path(out: Path) -> Path:
    """Where an interrupted run keeps its completed members: ``<OUT>.partial``."""
    return out.with_name(out.name + ".partial")


def parts_dir(out: str | os.PathLike) -> Path:
    """Where a Dask run keeps its tasks' chunk files: ``<OUT>.parts/``."""
    out = Path(out)
    return out.with_name(out.name + ".parts")


def journal_path(data: Path) -> Path:
    """The journal of a partial or temporary file (a hidden side file)."""
    return data.with_name(f"{'' if data.name.startswith('.') else '.'}{data.name}.json")


class Journal:
    """The resume record of one output: the resolved scene and the chunks done.

    ``chunks``: ``[{"lo", "hi", "crc": {variable: CRC-32}, "stats": ChunkStats dict}]``,
    a prefix of the run's chunk plan.
    """

    def __init__(self, out: Path, scene_toml: str, members: int, member_chunk: int,
                 chunks: list | None = None, version: str = __version__):
        self.out, self.scene_toml, self.members, self.member_chunk = Path(out), scene_toml, members, member_chunk
        self.chunks = list(chunks or [])
        self.version = version

    def to_dict(self) -> dict:
        return {"format": RESUME_FORMAT, "software_version": self.version, "output": self.out.name,
                "members": self.members, "member_chunk": self.member_chunk, "scene": self.scene_toml,
                "chunks": self.chunks}

    @classmethod
    def load(cls, path: Path, out: Path) -> "Journal | None":
        try:
            d = json.loads(Path(path).read_text())
            if d.get("format") != RESUME_FORMAT:
                return None
            return cls(out, d["scene"], int(d["members"]), int(d["member_chunk"]), d["chunks"],
                       d["software_version"])
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def save(self, path: Path) -> None:
        """Write atomically (a side temporary ``<path>.new``, then rename)."""
        text = json.dumps(self.to_dict())
        write_atomic(path, lambda tmp: tmp.write_text(text), temp=path.with_name(path.name + ".new"),
                     error_path=self.out)

    @property
    def members_done(self) -> int:
        return self.chunks[-1]["hi"] if self.chunks else 0


@dataclass
class ResumeSource:
    """A file with completed member chunks of an earlier run of ``out`` and its journal."""

    data: Path
    journal_file: Path
    journal: Journal

    def remove(self) -> None:
        for p in (self.data, self.journal_file):
            try:
                p.unlink()
            except FileNotFoundError:
                pass

    def read_chunks(self, names: list[str]):
        """Yield ``(chunk record, arrays)`` of the recorded chunks whose values
        match their CRC-32s, in order, stopping at the first that does not (or
        cannot be read)."""
        try:
            nc = netCDF4.Dataset(self.data, "r")
        except (OSError, RuntimeError):
            return
        try:
            nc.set_auto_mask(False)
            for rec in self.journal.chunks:
                check_stop()
                lo, hi = int(rec["lo"]), int(rec["hi"])
                arrays = {}
                try:
                    for name in names:
                        a = nc.variables[name][lo:hi, ...]
                        if checksum(a) != rec["crc"].get(name):
                            return
                        arrays[name] = a
                except (OSError, RuntimeError, KeyError, IndexError, ValueError):
                    return
                yield rec, arrays
        finally:
            nc.close()


def resume_sources(out: Path) -> list[ResumeSource]:
    """Files an earlier run of ``out`` left to resume from, most members first:
    its ``.partial`` (interrupted) and the temporaries of dead processes
    (killed) that have a journal."""
    out = Path(out)
    cands = [partial_path(out)]
    cands += [p for p in leftovers(out) if p.suffix == ".tmp"]
    found = []
    for data in cands:
        jp = journal_path(data)
        if not (data.is_file() and jp.is_file()):
            continue
        j = Journal.load(jp, out)
        if j is not None:
            found.append(ResumeSource(data, jp, j))
    found.sort(key=lambda s: (-s.journal.members_done, -s.journal_file.stat().st_mtime))
    return found


# ----------------------------------------------------------------------------- atomic files, resume cache

def _clean_attrs(attrs: dict) -> dict:
    out = {}
    for k, v in attrs.items():
        if isinstance(v, (bool, np.bool_)):
            v = int(v)
        elif v is None:
            v = ""
        elif isinstance(v, (dict, list, tuple)) and not (isinstance(v, (list, tuple)) and v
                                                         and all(isinstance(x, (int, float)) for x in v)):
            v = json.dumps(v, default=str)
        out[k] = v
    return out


def write_atomic(path: str | os.PathLike, write: Callable[[Path], None], *, temp: Path | None = None,
                 error_path: Path | None = None) -> Path:
    """The one atomic writer: ``write(tmp)`` into a temporary next to ``path``,
    then rename it onto ``path``, so a killed process leaves no file or a
    complete one; the temporary is removed on any error (raised as a
    WriteError naming ``error_path`` or ``path``).  The temporary is created
    exclusively and locked (a live writer's is told from a dead one's), or,
    for a small record that only its own writer rewrites (a resume journal,
    a parts index), is the given ``temp``."""
    path = Path(path)
    err = Path(error_path) if error_path is not None else path
    fd = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if temp is None:
            tmp, fd = create_temp(path)
        else:
            tmp = Path(temp)
    except OSError as exc:
        raise WriteError(err, io_cause(exc)) from None
    try:
        try:
            write(tmp)
            os.replace(tmp, path)
        except (OSError, RuntimeError) as exc:
            raise WriteError(err, io_cause(exc, tmp)) from None
    finally:
        if tmp.exists():
            tmp.unlink()
        if fd is not None:
            release_temp(fd)
    return path


def write_netcdf_atomic(ds: xr.Dataset, path: str | os.PathLike, history: str | None = None,
                        conventions: bool = True) -> Path:
    """Write ``ds`` to a temporary file next to ``path``, then rename it onto
    ``path``: a killed process leaves no file or a complete one.  The file is
    CF-encoded (:func:`liethermo.cf.encode`); ``history``, the command line or
    API call that makes it, replaces the dataset's own ``history``;
    ``conventions=False`` leaves out the ``Conventions`` attribute (the resume
    cache, whose variables are not all labelled, claims no CF conformance)."""
    ds = cf.encode(ds, history, conventions)
    ds.attrs = _clean_attrs(ds.attrs)
    for name in list(ds.variables):
        ds[name].attrs = _clean_attrs(ds[name].attrs)
    return write_atomic(path, lambda tmp: ds.to_netcdf(tmp, engine="netcdf4", format="NETCDF4"))


def write_text_atomic(text: str, path: str | os.PathLike) -> Path:
    return write_atomic(path, lambda tmp: tmp.write_text(text))


def cached_point(outdir: str | os.PathLike, key: str, compute: Callable[[], xr.Dataset]) -> xr.Dataset:
    """Resume cache: load ``outdir/points/<key>.nc`` if present, else compute
    the point's dataset and write it there atomically.  Either way the point
    comes back as read from the file (:func:`liethermo.cf.load_dataset`).
    The cache files are an internal format: same encoding as the study's
    netCDF, but no ``Conventions`` attribute (docs/netcdf.md)."""
    check_stop()
    path = Path(outdir) / "points" / f"{key}.nc"
    if path.is_file():
        try:
            return cf.load_dataset(path)
        except (OSError, ValueError):  # unreadable leftover: recompute
            path.unlink()
    ds = compute()
    write_netcdf_atomic(ds, path, conventions=False)
    out = cf.load_dataset(path)
    check_stop()
    return out


def point_is_cached(outdir: str | os.PathLike, key: str) -> bool:
    return (Path(outdir) / "points" / f"{key}.nc").is_file()
