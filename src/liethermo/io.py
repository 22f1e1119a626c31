"""Atomic, member-chunked netCDF4 output.

:class:`ChunkedWriter` writes a dataset whose leading dimension ``member`` is
filled chunk by chunk (so memory stays bounded by one chunk), into a
temporary file in the destination folder, and renames it onto the output
path only when everything was written: a run that is killed leaves either no
file at the path or the previous complete one.  Variables are chunked along
``member`` on disk so that ``xarray.open_dataset(path, chunks={})`` reads a
large result lazily.  Every dataset passes through :func:`liethermo.cf.encode`
(time units, string labels, ``coordinates``, ``Conventions`` and
``history``): the files are CF-1.11 (docs/netcdf.md).
"""

from __future__ import annotations

import os
from pathlib import Path

import netCDF4
import numpy as np
import xarray as xr

from . import cf

CHUNK_BYTES = 4 * 2**20  # target on-disk chunk size


def _nc_attr(value):
    if isinstance(value, (bool, np.bool_)):
        return int(value)
    return value


class ChunkedWriter:
    """Write ``n_members`` members in chunks: ``write(ds_chunk, offset)``.

    Variables without a ``member`` dimension are written from the first chunk.
    Use as a context manager; on an exception the temporary file is removed.
    ``attrs`` are the global attributes; ``history`` (the command line or API
    call that makes the file) replaces the ``history`` of ``attrs`` if given.
    """

    def __init__(self, path: str | os.PathLike, n_members: int, attrs: dict | None = None,
                 history: str | None = None):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        self.n_members = int(n_members)
        self.attrs = cf.encode_attrs(attrs or {}, history)
        self.nc: netCDF4.Dataset | None = None
        self.written = 0

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            self.abort()
        return False

    def _define(self, ds: xr.Dataset) -> None:
        nc = netCDF4.Dataset(self.tmp, "w", format="NETCDF4")
        self.nc = nc
        for dim, size in ds.sizes.items():
            nc.createDimension(dim, self.n_members if dim == "member" else size)
        for name, var in list(ds.coords.items()) + list(ds.data_vars.items()):
            if var.dtype.kind in "US":
                v = nc.createVariable(name, str, var.dims)
                v[:] = np.asarray(var.values, dtype=object)
            else:
                chunks = None
                if "member" in var.dims and var.ndim > 1:
                    other = int(np.prod([ds.sizes[d] for d in var.dims if d != "member"]))
                    budget = max(1, CHUNK_BYTES // max(1, other * var.dtype.itemsize))
                    # a power of two, so that member chunks of a run (powers of two) fill
                    # whole disk chunks and none is read back to be completed
                    m = min(self.n_members, 1 << (budget.bit_length() - 1))
                    chunks = [m if d == "member" else ds.sizes[d] for d in var.dims]
                v = nc.createVariable(name, var.dtype, var.dims, chunksizes=chunks)
                if chunks is not None:
                    # every disk chunk is written once, in order: a cache of two chunks is
                    # enough. netCDF's default (64 MiB per variable, ~25 variables) made the
                    # peak memory grow with the ensemble size (1.3 GB at 10^6 members)
                    nbytes = int(np.prod(chunks)) * var.dtype.itemsize
                    v.set_var_chunk_cache(size=2 * nbytes + 1024, nelems=17, preemption=1.0)
                if "member" not in var.dims:
                    v[...] = var.values
            v.setncatts({k: _nc_attr(a) for k, a in var.attrs.items()})
        nc.setncatts({k: _nc_attr(a) for k, a in self.attrs.items()})

    def write(self, ds: xr.Dataset, offset: int) -> None:
        ds = cf.encode_variables(ds)
        if self.nc is None:
            self._define(ds)
        n = ds.sizes["member"]
        if offset < 0 or offset + n > self.n_members:
            raise ValueError(f"chunk [{offset}, {offset + n}) outside 0..{self.n_members}")
        for name, var in list(ds.coords.items()) + list(ds.data_vars.items()):
            if "member" in var.dims:
                if var.dims[0] != "member":
                    raise ValueError(f"variable {name}: 'member' must be its first dimension")
                self.nc.variables[name][offset:offset + n, ...] = var.values
        self.written += n

    def close(self) -> None:
        if self.nc is None:
            raise RuntimeError("nothing was written")
        if self.written != self.n_members:
            self.abort()
            raise RuntimeError(f"only {self.written} of {self.n_members} members were written")
        self.nc.close()
        self.nc = None
        os.replace(self.tmp, self.path)

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
