"""Runs of one scene by several methods as one dataset with a ``method`` dimension.

:func:`open_runs` opens the files of a compared run (``OUT.nc``,
``OUT_<method>.nc``) lazily, as dask arrays (as ``xarray.open_mfdataset``
does), and :func:`combine_runs` joins datasets already open or in memory:

* every data variable gains the dimension ``method`` (first), the methods
  in the order given;
* a variable that only some methods have (the variational integrators'
  ``omega_step``, ``energy_error_paper``, Newton iteration counts) is kept
  and **filled with NaN** for the other methods; an integer variable so
  filled becomes float64;
* coordinates other than ``method`` are joined outer (runs of the same
  scene have the same ``member``, ``t``, ``axis``; others are filled with NaN);
* per-method global attributes become coordinates along ``method``:
  ``method_order``, ``h`` and, for files, ``source`` (the path); global
  attributes that differ between the methods (``method_description``,
  ``scene``, ``created``, ``history``, ``summary``, …) are dropped, those
  that agree are kept.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

#: global attributes kept per method, as coordinates along ``method``
PER_METHOD_ATTRS = ("method_order", "h")


def dask_available() -> bool:
    try:
        import dask.array  # noqa: F401
    except ImportError:
        return False
    return True


def open_runs(paths, *, methods=None, lazy: bool = True, derived: bool = False):
    """One dataset of the runs in ``paths`` (``.nc`` files of liethermo runs
    of one scene, e.g. a run with its ``output.compare`` methods), with a
    ``method`` dimension labelled by each file's ``method`` attribute (or by
    ``methods``; ``paths`` may also be ``{method: path}``).

    Opened lazily: every variable is a dask array, read from the files only
    when computed, so an ensemble larger than the memory can be combined and
    reduced.  Without dask (``pip install dask``) — or with ``lazy=False`` —
    the files are loaded into memory instead (with a warning when dask is
    missing).  ``derived``: each run with every variable its model derives from
    the stored state (``ds.liethermo.derived()``, computed in memory) before they
    are combined.  Close the result (``ds.close()`` or ``with``) to close the files."""
    from . import cf

    if isinstance(paths, dict):
        if methods is not None:
            raise ValueError("give the methods either as the keys of paths or as methods=, not both")
        methods, paths = list(paths), list(paths.values())
    paths = [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]
    if not paths:
        raise ValueError("open_runs needs at least one file")
    if methods is not None and len(methods) != len(paths):
        raise ValueError(f"{len(methods)} method names for {len(paths)} files")
    for p in paths:
        if not p.is_file():
            raise FileNotFoundError(f"{p}: no such file")
    if lazy and not dask_available():
        warnings.warn("dask is not installed: open_runs loads the runs into memory "
                      "(pip install dask to open them lazily)", stacklevel=2)
        lazy = False
    datasets = {}
    opened = []
    try:
        for i, p in enumerate(paths):
            ds = cf.open_dataset(p, chunks={}) if lazy else cf.load_dataset(p)
            opened.append(ds)
            if derived:
                ds = ds.liethermo.derived()
            name = methods[i] if methods is not None else str(ds.attrs.get("method", p.stem))
            if name in datasets:
                raise ValueError(f"two runs of method {name!r} ({paths[list(datasets).index(name)]} and {p}): "
                                 "pass methods= to label them")
            datasets[name] = ds
        out = combine_runs(datasets, sources={m: str(p) for m, p in zip(datasets, paths)})
    except BaseException:
        for ds in opened:
            ds.close()
        raise

    def close():
        for ds in opened:
            ds.close()

    out.set_close(close)
    return out


def combine_runs(datasets: dict, *, sources: dict | None = None):
    """``{method: Dataset}`` → one Dataset with a leading ``method`` dimension
    (the rules: module docstring).  Lazy inputs stay lazy: a variable one
    method lacks is filled with a dask array of NaN when the others are dask."""
    import pandas as pd
    import xarray as xr

    if not datasets:
        raise ValueError("nothing to combine")
    names = list(datasets)
    all_vars: dict[str, object] = {}
    for ds in datasets.values():
        for v in ds.data_vars:
            all_vars.setdefault(v, ds[v])
    filled = []
    for m in names:
        ds = datasets[m]
        missing = {}
        for v, template in all_vars.items():
            if v in ds.data_vars:
                continue
            missing[v] = _nan_like(template)
        if missing:
            ds = ds.assign(missing)
        filled.append(ds)
    # variables filled with NaN elsewhere are float everywhere (NaN has no integer)
    nan_filled = {v for ds in datasets.values() for v in all_vars if v not in ds.data_vars}
    filled = [ds.assign({v: ds[v].astype(np.float64) for v in nan_filled if ds[v].dtype.kind in "iub"})
              for ds in filled]
    out = xr.concat(filled, dim=pd.Index(names, name="method"), data_vars="all", coords="minimal",
                    compat="override", join="outer", combine_attrs="drop_conflicts")
    coords = {}
    for key in PER_METHOD_ATTRS:
        values = [datasets[m].attrs.get(key) for m in names]
        if all(v is not None for v in values):
            coords[key] = ("method", np.asarray(values), {"long_name": _ATTR_NAMES[key][0],
                                                          "units": _ATTR_NAMES[key][1]})
    if sources is not None:
        coords["source"] = ("method", np.asarray([sources[m] for m in names]), {"long_name": "file of the run"})
    out = out.assign_coords(coords)
    out["method"].attrs.update({"long_name": "integration method"})
    for key in PER_METHOD_ATTRS + ("method",):
        out.attrs.pop(key, None)
    summaries = [datasets[m].attrs.get("summary") for m in names]
    if all(summaries):
        out.attrs["summary"] = "\n".join(summaries)
    return out


_ATTR_NAMES = {"method_order": ("order of the method", "1"), "h": ("time step h", "s")}


def _nan_like(template):
    """An all-NaN variable shaped like ``template`` (dask when it is)."""
    import xarray as xr

    data = template.data
    shape = template.shape
    if hasattr(data, "chunks") and type(data).__module__.startswith("dask"):
        import dask.array as da

        values = da.full(shape, np.nan, dtype=np.float64, chunks=data.chunks)
    else:
        values = np.full(shape, np.nan)
    attrs = dict(template.attrs)
    attrs.pop("flag_values", None)
    attrs.pop("flag_meanings", None)
    return xr.Variable(template.dims, values, attrs)
