"""CF encoding of every netCDF file liethermo writes, and the reader that undoes it.

Every writer (:class:`liethermo.io.ChunkedWriter` for runs, Dask chunk files
and combined files; :func:`liethermo.io.write_netcdf_atomic` for
studies and their resume cache) passes its dataset through :func:`encode`,
which derives everything from names, dtypes, dims and units — never from a
list of variables — so variables added later are encoded the same way:

* the run's time is a plain coordinate ``t`` in seconds (``units = "s"``,
  long_name "time t"): it is not a calendar time, so
  it carries no ``standard_name = "time"`` and plain ``xarray.open_dataset``
  reads it as float64.  A coordinate that does claim to be a calendar time
  (named ``time``, or with ``standard_name = "time"`` or ``axis = "T"``) in
  plain seconds gets ``units = "seconds since 0001-01-01 00:00:00"``,
  ``calendar = "proleptic_gregorian"`` as CF requires; liethermo writes none;
* **string coordinate variables** (CF requires coordinate variables to be
  numeric) are stored as CF label variables ``<dim>_label(<dim>)`` listed in
  the ``coordinates`` attribute of the variables that use the dimension, with
  a ``comment`` giving the one line that selects by label in plain xarray
  (``ds.set_xindex("axis_label").sel(axis_label="z")``);
  :func:`open_dataset` makes them the dimension's index again;
* every data variable's ``coordinates`` attribute lists the auxiliary
  coordinates that exist (stale names are dropped); coordinate variables get
  no ``_FillValue``; booleans become int8 flags;
* a unit involving a temperature unit gets ``units_metadata`` (CF 1.11 §3.1.2)
  unless the variable has one: ``temperature: difference`` for compound
  units (J K-1), ``temperature: unknown`` for a bare K;
* global attributes: ``Conventions`` (:data:`CONVENTIONS`) and ``history``
  (a timestamped line with the command line or API call that made the file).

Integers of any width are stored as they are: CF 1.9 and later allow int64
and unsigned types, and the files declare CF-1.11.  See docs/netcdf.md.
"""

from __future__ import annotations

import datetime as _dt
import os
import re

import numpy as np
import xarray as xr

#: The CF version every file declares (``Conventions``) and is checked against.
CONVENTIONS = "CF-1.11"
#: Reference time of the time coordinates: t = 0 of a run (a placeholder, not a date).
TIME_EPOCH = "0001-01-01 00:00:00"
TIME_CALENDAR = "proleptic_gregorian"
TIME_UNITS = f"seconds since {TIME_EPOCH}"
#: Suffix of the label variable that replaces a string coordinate variable.
LABEL_SUFFIX = "_label"

_SECONDS = {"s", "sec", "secs", "second", "seconds"}
_TEMPERATURE_UNIT = re.compile(r"^(K|kelvin|degC|degree_C|degree_Celsius|celsius|Celsius|degF)(\^?-?\d+)?$")


# ----------------------------------------------------------------------------- time values

def decimal_times(steps, h: float) -> np.ndarray:
    """The times t_k = k h (s) of step indexes ``steps``, each the float nearest the
    decimal number k × h as h is written (``repr(h)``): 0.3, not 3 × 0.1 =
    0.30000000000000004, so that ``ds.sel(t=0.3)`` finds it.

    With h = m / 10^e written with e decimals, t_k = (k m) / 10^e: when k m < 2^53
    and e ≤ 22 both operands are exact doubles and IEEE division rounds the
    quotient correctly; otherwise Python's correctly rounded integer division
    does.  A step that has no short decimal (h = 1/3) keeps its 17 digits, and
    t_k then differs from k h in the last bit at most."""
    from decimal import Decimal

    k = np.asarray(steps, dtype=np.int64)
    d = Decimal(repr(float(h)))
    if not d.is_finite():
        return k * float(h)
    sign, digits, exp = d.as_tuple()
    m = int("".join(map(str, digits)) or "0") * (-1 if sign else 1)
    if exp >= 0:  # an integral h: k h is exact below 2^53
        return k * float(h)
    scale = 10 ** (-exp)
    if -exp <= 22 and k.size and int(np.abs(k).max()) * abs(m) < 2**53:
        return (k * m).astype(np.float64) / float(scale)
    return np.array([(int(j) * m) / scale for j in k.ravel()], dtype=np.float64).reshape(k.shape)


# ----------------------------------------------------------------------------- history

def timestamp(when: _dt.datetime | None = None) -> str:
    """UTC time to the second, ISO 8601 (``2024-05-01T12:00:00+00:00``)."""
    when = when or _dt.datetime.now(_dt.timezone.utc)
    return when.isoformat(timespec="seconds")


def history_entry(command: str, when: str | None = None) -> str:
    """One line of a CF ``history`` attribute: ``<timestamp>: <command>``."""
    return f"{when or timestamp()}: {command}"


def _arg(value) -> str:
    if isinstance(value, dict):
        name = value.get("scene", {}).get("name") if isinstance(value.get("scene"), dict) else None
        name = name or (value.get("study", {}).get("name") if isinstance(value.get("study"), dict) else None)
        return f"<dict {name!r}>" if name else "<dict>"
    if isinstance(value, os.PathLike):
        return repr(os.fspath(value))
    return repr(value)


def api_call(func: str, *args, **kwargs) -> str:
    """The text of a Python call, for ``history``: ``api_call("liethermo.runner.run_scene",
    "paper", out="x.nc")`` → ``liethermo.runner.run_scene('paper', out='x.nc')``.
    Dicts (resolved scenes, studies) appear by name; ``None`` keywords are left out."""
    parts = [_arg(a) for a in args] + [f"{k}={_arg(v)}" for k, v in kwargs.items() if v is not None]
    return f"{func}({', '.join(parts)})"


# ----------------------------------------------------------------------------- encoding

def is_time_coordinate(name: str, var: xr.Variable) -> bool:
    """A variable CF (and the IOOS checker) treats as time."""
    return name == "time" or var.attrs.get("standard_name") == "time" or var.attrs.get("axis") == "T"


def _is_string(var: xr.Variable) -> bool:
    if var.dtype.kind in "US":
        return True
    if var.dtype.kind == "O":
        return all(isinstance(x, (str, bytes)) for x in np.asarray(var.values).ravel())
    return False


def _temperature_metadata(units: str) -> str | None:
    tokens = str(units).split()
    if not any(_TEMPERATURE_UNIT.match(t) for t in tokens):
        return None
    bare = len(tokens) == 1 and _TEMPERATURE_UNIT.match(tokens[0]).group(2) is None
    return "temperature: unknown" if bare else "temperature: difference"


def encode_variables(ds: xr.Dataset) -> xr.Dataset:
    """The variables of ``ds`` as CF wants them in the file (see the module
    docstring); ``ds`` itself is not modified and no data is copied except
    booleans (cast) and string coordinates (relabelled).  Idempotent."""
    ds = ds.copy(deep=False)
    # string coordinate variables -> label variables <dim>_label(<dim>)
    for name in [n for n in ds.coords if n in ds.dims and _is_string(ds.variables[n])]:
        label = f"{name}{LABEL_SUFFIX}"
        if label in ds.variables:
            raise ValueError(f"cannot store the string coordinate {name!r} as {label!r}: "
                             f"a variable {label!r} exists already")
        var = ds.variables[name]
        values = np.asarray(var.values).astype(str)
        attrs = dict(var.attrs)
        attrs.setdefault("comment", f"labels of {name}; to select by label in plain xarray: "
                                    f"ds.set_xindex('{label}').sel({label}={str(values[0])!r})")
        ds = ds.drop_vars(name).assign_coords({label: xr.Variable((name,), values, attrs)})
    # booleans -> int8 flags (netCDF has no boolean type)
    for name in [n for n, v in ds.variables.items() if v.dtype.kind == "b"]:
        var = ds.variables[name]
        attrs = {"flag_values": np.array([0, 1], np.int8), "flag_meanings": "false true", **var.attrs}
        new = xr.Variable(var.dims, np.asarray(var.values).astype(np.int8), attrs)
        ds = ds.assign_coords({name: new}) if name in ds.coords else ds.assign({name: new})
    for name, var in ds.variables.items():
        attrs, enc = var.attrs, var.encoding
        # time coordinates: "<unit> since <epoch>", values unchanged
        if is_time_coordinate(name, var) and var.dtype.kind in "fiu":
            units = str(attrs.get("units", "")).strip()
            if units in _SECONDS:
                attrs["units"] = TIME_UNITS
                units = TIME_UNITS
            if " since " in units:
                attrs.setdefault("calendar", TIME_CALENDAR)
                attrs.setdefault("standard_name", "time")
                if name in ds.dims:
                    attrs.setdefault("axis", "T")
                if attrs["calendar"] in ("standard", "proleptic_gregorian", "julian"):
                    attrs.setdefault("units_metadata", "leap_seconds: none")
        elif "units_metadata" not in attrs and "units" in attrs:
            meta = _temperature_metadata(attrs["units"])
            if meta:
                attrs["units_metadata"] = meta
        if name in ds.coords:
            enc["_FillValue"] = None  # CF: no missing values in coordinates
            enc.pop("coordinates", None)
            continue
        # auxiliary coordinates of a data variable: those present whose dims it has
        listed = str(attrs.pop("coordinates", "") or "").split() + str(enc.pop("coordinates", "") or "").split()
        aux = [c for c in ds.coords if c not in ds.dims and set(ds.variables[c].dims) <= set(var.dims)]
        names = [c for c in dict.fromkeys(listed + aux) if c in ds.variables and c != name]
        if names:
            attrs["coordinates"] = " ".join(names)
    return ds


def encode_attrs(attrs: dict, history: str | None = None, conventions: bool = True) -> dict:
    """Global attributes for the file: ``Conventions`` set to :data:`CONVENTIONS`
    (removed with ``conventions=False``: a file that does not claim CF);
    ``history`` set to a timestamped line with ``history`` if given, else kept
    (or, if missing, a line naming the liethermo version that wrote the file)."""
    from .version import __version__

    out = dict(attrs)
    if conventions:
        out["Conventions"] = CONVENTIONS
    else:
        out.pop("Conventions", None)
    if history:
        out["history"] = history_entry(history)
    elif not out.get("history"):
        out["history"] = history_entry(f"written by liethermo {__version__}")
    return out


def encode(ds: xr.Dataset, history: str | None = None, conventions: bool = True) -> xr.Dataset:
    """:func:`encode_variables` and :func:`encode_attrs` together."""
    ds = encode_variables(ds)
    ds.attrs = encode_attrs(ds.attrs, history, conventions)
    return ds


# ----------------------------------------------------------------------------- reading

def decode(ds: xr.Dataset) -> xr.Dataset:
    """Undo what :func:`encode` did for convenience: label variables
    ``<dim>_label(<dim>)`` become the index of ``<dim>`` again (so that
    ``ds.sel(axis="x")`` works) and the label variables' selection hint is
    dropped.  ``ds`` itself is not modified."""
    ds = ds.copy(deep=False)
    for label in [n for n in ds.variables if n.endswith(LABEL_SUFFIX)]:
        var = ds.variables[label]
        dim = label[: -len(LABEL_SUFFIX)]
        if var.dims != (dim,) or dim in ds.variables or not _is_string(var):
            continue
        attrs = {k: v for k, v in var.attrs.items()
                 if not (k == "comment" and str(v).startswith(f"labels of {dim}; "))}
        ds = ds.drop_vars(label).assign_coords({dim: xr.Variable((dim,), np.asarray(var.values).astype(str),
                                                                 attrs)})
        for v in ds.variables.values():
            for d in (v.encoding, v.attrs):
                if "coordinates" in d:
                    rest = [c for c in str(d["coordinates"]).split() if c != label]
                    if rest:
                        d["coordinates"] = " ".join(rest)
                    else:
                        del d["coordinates"]
    return ds


def open_dataset(path, **kwargs) -> xr.Dataset:
    """``xarray.open_dataset`` for liethermo files: times as seconds
    (``decode_times=False``), string labels as indexes (:func:`decode`).
    Other keywords (``chunks={}``, ``engine``, …) are passed on."""
    kwargs.setdefault("decode_times", False)
    raw = xr.open_dataset(path, **kwargs)
    ds = decode(raw)
    ds.set_close(raw.close)  # closing the result closes the file
    return ds


def load_dataset(path, **kwargs) -> xr.Dataset:
    """:func:`open_dataset`, loaded into memory and the file closed."""
    kwargs.setdefault("decode_times", False)
    with xr.open_dataset(path, **kwargs) as raw:
        return decode(raw.load())
