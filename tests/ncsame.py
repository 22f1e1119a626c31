"""Comparing two netCDF outputs of liethermo runs."""

from __future__ import annotations

from pathlib import Path

import netCDF4
import numpy as np


def same_but_created(a: Path, b: Path) -> bool:
    """The two files are the same but for when they were made: the same
    dimensions, variables (types, chunking, filters, attributes) and values
    bit for bit, the same global attributes but ``created``, and the same
    ``history`` command but for its time stamp and the file's own path."""
    def glob(nc, path):
        out = {k: str(nc.getncattr(k)) for k in nc.ncattrs() if k != "created"}
        stamp, _, command = out.get("history", "").partition(": ")
        if stamp != nc.getncattr("created"):
            return None
        out["history"] = command.replace(str(path), "<this file>")
        return out

    with netCDF4.Dataset(a) as x, netCDF4.Dataset(b) as y:
        gx = glob(x, a)
        if gx is None or gx != glob(y, b) or {k: len(d) for k, d in x.dimensions.items()} != \
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
