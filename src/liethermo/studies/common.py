"""What the study framework (:mod:`liethermo.studies.framework`) and the
runner share: resolving a study file (its ``[reduced]`` and ``[model.<name>]``
tables), sweep points and their keys, the scene of a point, the atomic
writers and the resume cache (from the I/O layer), tables and reports.

The method axis of a study dataset is called ``scheme`` (a dimension named
``method`` clashes with ``DataArray.sel(method=...)``); its labels are the
method labels of the base scene's model (``"vi:staggered"``, ``"split4"``, …).
See docs/studies.md for the study file.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import os
from pathlib import Path
from typing import Any, Iterable

import numpy as np
import xarray as xr

from .. import cf
from ..scene import builtin_scene_text, load_scene

#: Top-level keys every study accepts.
BASE_KEYS = frozenset({"study", "scene", "sweep", "methods", "report", "reduced", "options", "model"})
#: Keys of the ``[study]`` table.
STUDY_KEYS = frozenset({"kind", "name", "base_scene", "description", "title"})


class StudyError(ValueError):
    """An invalid study file: the message names the key and the rule."""


# ----------------------------------------------------------------------------- study resolution

def _deep_merge(base: dict, new: dict) -> None:
    for key, value in new.items():
        if isinstance(value, dict) and isinstance(base.get(key), dict):
            _deep_merge(base[key], value)
        else:
            base[key] = copy.deepcopy(value)


def resolve_study(study: dict, reduced: bool) -> dict:
    """A copy of ``study`` with, in this order, the ``[reduced]`` table (if
    ``reduced``), the ``[model.<name>]`` table of the base scene's model and
    that table's own ``[reduced]`` table applied; both removed.  Idempotent.

    ``[model.<name>]`` holds what a model's scenes need besides the base scene
    (their time scales, sizes, methods): the same study file then runs on a
    scene of either model (``liethermo study FILE --scene NAME``)."""
    out = copy.deepcopy(study)
    red = out.pop("reduced", None) or {}
    per = out.pop("model", None) or {}
    if reduced:
        _deep_merge(out, red)
    if per:
        if not isinstance(per, dict):
            raise StudyError("model: must be a table of [model.<name>] tables")
        section = copy.deepcopy(per.get(base_model(out), {}))
        sec_red = section.pop("reduced", None) or {}
        _deep_merge(out, section)
        if reduced:
            _deep_merge(out, sec_red)
    return out


def with_scene(study: dict, scene: str) -> dict:
    """The study run on another base scene (its name gets the scene's, so its folder differs)."""
    out = copy.deepcopy(study)
    st = out.setdefault("study", {})
    st["name"] = f"{st.get('name') or st.get('kind', 'study')}_{Path(str(scene)).stem}"
    st["base_scene"] = str(scene)
    return out


def base_model(study: dict) -> str:
    """The name of the model whose scene the study's base scene is."""
    from ..models import model_of

    return model_of(load_scene(_base_scene(study), validate_scene=False)).name


def study_scene(study: dict, overrides: dict | None = None) -> dict:
    """The validated scene of a study point: base scene ← inline ``[scene]``
    table ← ``overrides`` (``{"section.key": value}``)."""
    scene = load_scene(load_scene(_base_scene(study), study.get("scene") or None, validate_scene=False))
    return scene.with_overrides(overrides) if overrides else scene


def _base_scene(study: dict):
    """The base scene as ``load_scene`` takes it (a scene file relative to the study file)."""
    base = study.get("study", {}).get("base_scene", "paper")
    builtin = (isinstance(base, str) and "/" not in base and not base.endswith(".toml")
               and builtin_scene_text(base) is not None)
    if isinstance(base, str) and not builtin:
        p = Path(base)
        src = study.get("_source")
        # a scene file named in the study file may be relative to it; a name
        # that is neither there nor here is reported as it was written
        if not p.is_absolute() and src is not None and not p.is_file() and (Path(src).parent / p).is_file():
            p = Path(src).parent / p
        base = str(p)
    return base


def study_name(study: dict) -> str:
    return str(study.get("study", {}).get("name") or study.get("study", {}).get("kind", "study"))


def study_history(kind: str, study: dict, outdir, reduced: bool, history: str | None) -> str:
    """``history`` if given (the command line), else the API call that runs the study."""
    if history:
        return history
    src = study.get("_source")
    if src:  # a study file: the public call that runs it
        return cf.api_call("liethermo.study", str(src), reduced=bool(reduced), output=str(outdir))
    return cf.api_call(f"liethermo.studies.get_study({kind!r}).STUDY.run", study, str(outdir), reduced=bool(reduced))


def study_netcdf_path(study: dict, outdir: Path) -> Path:
    """Where a study writes its netCDF: ``outdir/<study name>.nc``."""
    return Path(outdir) / f"{study_name(study)}.nc"


# ----------------------------------------------------------------------------- sweeps


def expand_sweep(sweep: dict | None) -> list[dict]:
    """Cartesian product of ``{"section.key": [values]}``, in the order given
    (the last key varies fastest).  An empty sweep is one empty point."""
    sweep = sweep or {}
    keys = list(sweep)
    for k in keys:
        if not isinstance(sweep[k], list) or not sweep[k]:
            raise StudyError(f"sweep key {k!r} must map to a non-empty list of values")
    return [dict(zip(keys, combo)) for combo in itertools.product(*(sweep[k] for k in keys))]


def _key_default(v):
    return v.to_dict() if hasattr(v, "to_dict") else str(v)


def point_key(d: dict) -> str:
    """Stable hash of a sweep point (plus method and anything else in ``d``)."""
    text = json.dumps(d, sort_keys=True, default=_key_default, separators=(",", ":"))
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def dim_name(key: str) -> str:
    """netCDF dimension name of a sweep key: ``"fluid.viscosity"`` → ``"fluid_viscosity"``."""
    return key.replace(".", "_")


def coord_value(v):
    """A sweep value as a coordinate value (lists become their TOML-ish text)."""
    if isinstance(v, (bool, int, float, str)):
        return v
    return json.dumps(v)


# ----------------------------------------------------------------------------- files

# The atomic writers and the points' resume cache live in the I/O layer (the
# Dask tasks of liethermo.distributed use them too); re-exported for the studies.
from ..io import (cached_point, point_is_cached, write_atomic,  # noqa: E402,F401
                  write_netcdf_atomic, write_text_atomic)


# ----------------------------------------------------------------------------- tables and reports

def fmt(v) -> str:
    """A table cell: integers as such, floats to 3–4 significant digits."""
    if v is None:
        return "—"
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        v = float(v)
        if math.isnan(v):
            return "—"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        if v == 0.0:
            return "0"
        if 1e-3 <= abs(v) < 1e4:
            return f"{v:.4g}"
        return f"{v:.3e}"
    return str(v).replace("|", "\\|")


def write_table(df_or_records, outdir: str | os.PathLike, name: str, title: str) -> str:
    """Write ``outdir/<name>.csv`` and return the table as markdown (with a
    ``### title`` heading and a link to the CSV)."""
    import pandas as pd

    df = df_or_records if isinstance(df_or_records, pd.DataFrame) else pd.DataFrame(list(df_or_records))
    write_atomic(Path(outdir) / f"{name}.csv", lambda tmp: df.to_csv(tmp, index=False))
    return markdown_table(df, title, f"(CSV: `{name}.csv`)")


def markdown_table(df, title: str, footer: str) -> str:
    """``df`` as a markdown table under a ``### title`` heading, values through
    :func:`fmt`, with a ``footer`` line."""
    cols = [str(c) for c in df.columns]
    lines = [f"### {title}", "", "| " + " | ".join(c.replace("|", "\\|") for c in cols) + " |",
             "|" + "|".join("---" for _ in cols) + "|"]
    for row in df.itertuples(index=False):
        lines.append("| " + " | ".join(fmt(v) for v in row) + " |")
    lines += ["", footer, ""]
    return "\n".join(lines)


def write_report(outdir: str | os.PathLike, title: str, sections: Iterable[str]) -> Path:
    """Write ``outdir/report.md`` (atomically) and return its path."""
    text = f"# {title}\n\n" + "\n\n".join(s.strip("\n") for s in sections) + "\n"
    return write_text_atomic(text, Path(outdir) / "report.md")


def first_table(report: str | os.PathLike) -> str:
    """The first table of a markdown report, with its heading (the key table)."""
    lines = Path(report).read_text().splitlines()
    start = next((i for i, ln in enumerate(lines) if ln.startswith("|")), None)
    if start is None:
        return ""
    head = start - 2 if start >= 2 and lines[start - 2].startswith("#") else start
    end = start
    while end < len(lines) and lines[end].startswith("|"):
        end += 1
    return "\n".join(lines[head:end])


def terminal_table(markdown: str) -> str:
    """A markdown table (with its ``### heading``) as plain text for a terminal:
    columns aligned, no ``\\|`` escapes, backticks or bold markers."""
    import re

    def clean(cell: str) -> str:
        return cell.strip().replace("\\|", "|").replace("**", "").replace("`", "")

    out, rows = [], []
    for ln in markdown.splitlines():
        if ln.startswith("|"):
            cells = [clean(c) for c in re.split(r"(?<!\\)\|", ln.strip())[1:-1]]
            if all(set(c) <= set("-: ") for c in cells):
                rows.append(None)  # the header's rule
            else:
                rows.append(cells)
        elif ln.startswith("#"):
            out.append(clean(ln.lstrip("#")))
        elif ln.strip():
            out.append(clean(ln))
    widths = [max(len(r[i]) for r in rows if r is not None and i < len(r))
              for i in range(max((len(r) for r in rows if r is not None), default=0))]
    for r in rows:
        if r is None:
            out.append("  ".join("-" * w for w in widths))
        else:
            out.append("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())
    return "\n".join(out)


def progress_bar(total: int, progress: bool | None, desc: str):
    """A tqdm bar over sweep points (``progress=None``: only on a terminal)."""
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="point", leave=False,
                disable=None if progress is None else not progress)


# ----------------------------------------------------------------------------- assembling

def stack_points(datasets: list[xr.Dataset], points: list[dict], keys: list[str] | None = None) -> xr.Dataset:
    """Combine per-point datasets into one with the sweep keys as dimensions
    (named :func:`dim_name`, attribute ``scene_key``).  ``points`` are the
    point dicts (e.g. from :func:`expand_sweep`, possibly with a ``method``
    entry); every dataset must have the same variables and shapes."""
    keys = list(points[0]) if keys is None else keys
    if not keys:
        return datasets[0]
    dims = [dim_name(k) for k in keys]
    ds = xr.concat(datasets, dim="point", data_vars="all", coords="minimal", compat="override",
                   join="override")
    ds = ds.assign_coords({d: ("point", [coord_value(p[k]) for p in points]) for d, k in zip(dims, keys)})
    if len(dims) == 1:  # set_index on one level makes no MultiIndex: nothing to unstack
        ds = ds.swap_dims({"point": dims[0]}).transpose(*dims, ...)
    else:
        ds = ds.set_index(point=dims).unstack("point").transpose(*dims, ...)
    order = {}
    for d, k in zip(dims, keys):  # keep the order of the study file, not the sorted one
        order[d] = list(dict.fromkeys(coord_value(p[k]) for p in points))
    ds = ds.reindex(order)
    for d, k in zip(dims, keys):
        ds[d].attrs.update({"scene_key": k, "long_name": f"sweep over {k}"})
    return ds
