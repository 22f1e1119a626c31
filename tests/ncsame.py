"""Comparing two netCDF outputs of liethermo runs."""

from __future__ import annotations

from pathlib import Path

import netCDF4
import numpy as np


def same_but_created(a: Path, b: Path) -> bool:
    """The two files are the same but for when they were made: the same
    dimensions, variables (types, chunking, filters, attributes) and values
    bit for bit, the same global attributes but ``created``, and the same
    ``history`` command but for its time stamp and the files' paths."""
    def glob(nc):
        out = {k: str(nc.getncattr(k)) for k in nc.ncattrs() if k != "created"}
        stamp, _, command = out.get("history", "").partition(": ")
        if stamp != nc.getncattr("created"):
            return None
        for path in sorted((str(a), str(b)), key=len, reverse=True):
            command = command.replace(path, "<file>")
        out["history"] = command
        return out

    with netCDF4.Dataset(a) as x, netCDF4.Dataset(b) as y:
        gx = glob(x)
        if gx is None or gx != glob(y) or {k: len(d) for k, d in x.dimensions.items()} != \
                {k: len(d) for k, d in y.dimensions.items()} or list(x.variables) != list(y.variables):
            return False
        for name, va in x.variables.items():
            vb = y.variables[name]
            va.set_auto_maskandscale(False)
            vb.set_auto_maskandscale(False)
            attrs = lambda v: {k: str(v.getncattr(k)) for k in v.ncattrs()}  # noqa: E731
            if (va.dtype != vb.dtype or va.dimensions != vb.dimensions or va.chunking() != vb.chunking()
                    or va.filters() != vb.filters() or attrs(va) != attrs(vb)):
                return False
            da, db = np.asarray(va[...]), np.asarray(vb[...])
            if da.dtype.kind in "fiu":
                if da.tobytes() != db.tobytes():
                    return False
            elif not np.array_equal(da, db):
                return False
    return True


def same_bytes_but_time(a: Path, b: Path) -> bool:
    """Two files written to the same path by the same command are byte for
    byte equal once their time stamps (``created``, and the one that starts
    ``history``) are overwritten with the same characters in copies."""
    import shutil
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        copies = [Path(d) / "a.nc", Path(d) / "b.nc"]
        for src, dst in zip((a, b), copies):
            shutil.copyfile(src, dst)
            with netCDF4.Dataset(dst, "a") as nc:
                created = nc.getncattr("created")
                history = nc.getncattr("history")
                assert history.startswith(created)
                nc.setncattr("created", "#" * len(created))
                nc.setncattr("history", "#" * len(created) + history[len(created):])
        return copies[0].read_bytes() == copies[1].read_bytes()
