"""Helpers shared by the study modules: sweeps, resume cache, tables, reports.

Contract of a study module ``liethermo.studies.<kind>``:

1. It exposes ``run(study, outdir, *, reduced, progress, dask=None, history=None) -> Path``
   returning the path of its markdown report (``outdir/report.md``);
   ``history`` (the command line, or by default the API call, see
   :func:`study_history`) goes into the netCDF's ``history`` attribute.
   ``study`` is the parsed TOML as given (the ``[reduced]`` table still in
   it); the module calls :func:`resolve_study` to apply the reduced mode.
2. It may expose ``EXTRA_KEYS`` (top-level TOML keys it accepts besides
   :data:`BASE_KEYS`) and ``validate(study)`` raising :class:`StudyError`;
   the runner calls both before any work starts.
3. Each sweep point (and method) is computed through :func:`cached_point`,
   so an interrupted study resumes without recomputing finished points.
4. It writes one netCDF (:func:`study_netcdf_path`: sweep keys as dimensions
   named by :func:`dim_name`, the run datasets' variable names plus the
   study's statistics), tables as CSV (:func:`write_table`), PNG figures, and the
   report; the first table of the report is its key table, which the
   command line prints.
5. The method axis of a study dataset is called ``scheme`` (a dimension
   named ``method`` clashes with ``DataArray.sel(method=...)``); its labels
   are the method specs of :func:`parse_method` (``"vi:staggered"``, …).

Study TOML layout::

    [study]
    kind = "convergence"
    name = "convergence"
    base_scene = "paper"          # a built-in scene, a scene file (relative to the study file) or an inline table
    [scene.integrator]            # optional: scene keys applied on top of the base scene
    steps = 100
    [sweep]
    "integrator.h" = [0.1, 0.05]
    methods = ["vi", "rk2"]       # (top-level key, before any table)
    [reduced.sweep]               # reduced mode: tables merge key by key, other values replace
    "integrator.h" = [0.1]
"""

from __future__ import annotations

import copy
import functools
import hashlib
import itertools
import json
import math
import os
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np
import xarray as xr

from .. import cf
from ..scene import builtin_scene_text, load_scene

#: Top-level keys every study accepts.
BASE_KEYS = frozenset({"study", "scene", "sweep", "methods", "report", "reduced", "options"})
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
    """A copy of ``study`` with the ``[reduced]`` table applied (if ``reduced``)
    and removed (always).  Idempotent."""
    out = copy.deepcopy(study)
    red = out.pop("reduced", None) or {}
    if reduced:
        _deep_merge(out, red)
    return out


def start_study(study: dict, outdir, reduced: bool, validate: Callable[[dict], None],
                options: Callable[[dict], dict]) -> tuple[dict, Path, dict]:
    """The opening of every study's ``run``: the resolved study (reduced mode
    applied), validated, its options, and the output folder (created once the
    study and its options are known to be valid)."""
    s = resolve_study(study, reduced)
    validate(s)
    opt = options(s)
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    return s, out, opt


def nested(overrides: dict | None) -> dict:
    """``{"section.key": v}`` (or already nested ``{section: {key: v}}``) → nested dict."""
    out: dict[str, dict[str, Any]] = {}
    for k, v in (overrides or {}).items():
        if isinstance(v, dict) and "." not in k:
            out.setdefault(k, {}).update(v)
            continue
        if k.count(".") != 1:
            raise StudyError(f"sweep/override key {k!r} must read 'section.key'")
        section, key = k.split(".")
        out.setdefault(section, {})[key] = v
    return out


def study_scene(study: dict, overrides: dict | None = None) -> dict:
    """The validated scene of a study point: base scene ← inline ``[scene]``
    table ← ``overrides`` (``{"section.key": value}`` or nested)."""
    st = study.get("study", {})
    base = st.get("base_scene", "paper")
    builtin = (isinstance(base, str) and "/" not in base and not base.endswith(".toml")
               and builtin_scene_text(base) is not None)
    if isinstance(base, str) and not builtin:  # a scene file, relative to the study file
        p = Path(base)
        src = study.get("_source")
        if not p.is_absolute() and src is not None and not p.is_file():
            p = Path(src).parent / p
        base = str(p)
    scene = load_scene(base, study.get("scene") or None, validate_scene=False)
    return load_scene(scene, nested(overrides) or None)


def scene_value(scene: dict, key: str):
    """The value of the dotted scene key ``key`` ("section.name") in a resolved scene."""
    section, name = key.split(".", 1)
    return scene[section][name]


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

def study_options(study: dict, defaults: dict, kind: str) -> dict:
    """The study's ``[options]`` over its kind's defaults; an unknown option is an error."""
    opt = copy.deepcopy(defaults)
    for k, v in (study.get("options", {}) or {}).items():
        if k not in defaults:
            raise StudyError(f"options.{k}: unknown option of a {kind} study; known: "
                             f"{', '.join(sorted(defaults))}")
        opt[k] = v
    return opt


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

def status_units(not_run: bool = False) -> tuple[str, str]:
    """(units, long_name) of a member status variable of a study; ``not_run``:
    -1 marks a member the method did not run."""
    from ..simulate import STATUS_MEANINGS

    codes = ([(-1, "not run")] if not_run else []) + sorted(STATUS_MEANINGS.items())
    return "1", "member status (" + ", ".join(f"{k} {v}" for k, v in codes) + ")"


#: (units, long_name) of the variables several studies write, under one name
_SHARED_UNITS = {
    "gamma_defect": ("1", "max_k ||Gamma_k| - 1|"),
    "max_relative_energy_error": ("1", "max_k |E_k - E_0| / E_mech,0, node values (failed: inf)"),
    "final_relative_energy_error": ("1", "|E_K - E_0| / E_mech,0 at t_end, node values"),
    "relative_energy_error_quantiles": ("1", "quantiles over members of |E_k - E_0| / E_mech,0, node values"),
}


def shared_units(*names: str) -> dict:
    """The (units, long_name) of variables several studies write (one spelling)."""
    return {k: _SHARED_UNITS[k] for k in names}


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


# ----------------------------------------------------------------------------- method variants

def parse_method(spec: str) -> dict:
    """A method spec → ``{"label", "method", "family", "start", "friction",
    "entropy", "composition"}`` (what the studies key their cached points on).

    The spec is a :class:`liethermo.methods.MethodChoice` label (``"vi"``,
    ``"vi:node:explicit"``, ``"vi4:triple_jump"``; :meth:`MethodChoice.parse`
    says what it takes); the values are its effective ones (None where a
    choice does not apply: an explicit method has no start), so the dict
    says what really ran.  :func:`method_choice` gives the choice itself."""
    choice = method_choice(spec)
    return {"label": spec, "method": choice.name, "family": choice.family,
            "start": choice.start if choice.family == "vi" else None, "friction": choice.friction,
            "entropy": choice.entropy, "composition": choice.composition}


@functools.lru_cache(maxsize=256)
def _parse_choice(label):
    from ..methods import MethodChoice

    try:
        return MethodChoice.parse(label)
    except ValueError as exc:
        raise StudyError(f"methods: {exc}") from None


def method_choice(spec) -> "MethodChoice":
    """The :class:`liethermo.methods.MethodChoice` of a method label or of a
    parsed spec (:func:`parse_method`)."""
    return _parse_choice(spec["label"] if isinstance(spec, dict) else spec)


def method_kwargs(spec: dict) -> dict:
    """The ``simulate`` keywords of a parsed method spec (passing
    :func:`method_choice` as the method, :func:`simulate` needs none)."""
    return method_choice(spec).asked()


def method_overrides(spec: dict) -> dict:
    """Scene overrides that make a scene run a parsed method spec."""
    return method_choice(spec).overrides()


# ----------------------------------------------------------------------------- closing table

#: the laws the closing tables report, in the words of the reports
CLOSING_LAWS = (("unit_gamma", "|Γ| = 1"), ("kelvin_noether", "Kelvin–Noether"),
                ("entropy_monotone", "entropy monotone"))
#: costs within this factor of the least count as a tie: the figures are timings on a shared machine
COST_TIE = 1.1


def step_text(hs) -> str:
    """"h = a s", or "h = a–b s" where a method ran at several steps."""
    lo, hi = float(min(hs)), float(max(hs))
    return f"h = {lo:.3g} s" if f"{lo:.3g}" == f"{hi:.3g}" else f"h = {lo:.3g}–{hi:.3g} s"


def kept_laws(label: str) -> str:
    """The laws of :data:`CLOSING_LAWS` that the method of spec ``label``
    declares (:mod:`liethermo.methods`), e.g. "|Γ| = 1, Kelvin–Noether";
    a method from outside liethermo (scipy's) declares none."""
    from ..methods import METHODS

    name = str(label).split(":")[0]
    laws = METHODS[name].laws if name in METHODS else ()
    kept = [text for law, text in CLOSING_LAWS if law in laws]
    return ", ".join(kept) if kept else "none of these"


def keeps_geometry(label: str) -> bool:
    """Whether the method of spec ``label`` declares both |Γ| = 1 and the
    discrete Kelvin–Noether law (the variational family)."""
    from ..methods import LAW_KELVIN_NOETHER, LAW_UNIT_GAMMA, METHODS

    name = str(label).split(":")[0]
    return name in METHODS and {LAW_UNIT_GAMMA, LAW_KELVIN_NOETHER} <= set(METHODS[name].laws)


def error_levels(errors, count: int = 3) -> list[float]:
    """Up to ``count`` powers of ten, from the least accurate level the data
    reach to the most accurate one, evenly spread over the decades."""
    e = np.asarray([x for x in errors if np.isfinite(x) and x > 0], float)
    if e.size == 0:
        return []
    hi = math.ceil(math.log10(e.max()))
    lo = math.ceil(math.log10(e.min()))  # the finest power of ten some point reaches
    if hi <= lo:
        return [10.0 ** lo]
    ks = np.unique(np.round(np.linspace(hi, lo, min(count, hi - lo + 1))).astype(int))[::-1]
    return [10.0 ** int(k) for k in ks]


def cheapest_per_level(points, levels) -> list[dict]:
    """For each error level ε: the points (dicts with ``method``, ``error``,
    ``cost`` and optionally ``setting``) whose error is ≤ ε, the cheapest
    first, with every method whose own cheapest such point costs at most
    :data:`COST_TIE` × the least (a tie on a shared machine).  Returns
    ``{"level", "winners": [point, …]}`` per level (``winners`` empty: no
    point reached it)."""
    out = []
    for eps in levels:
        best: dict[str, dict] = {}
        for p in points:
            if np.isfinite(p["error"]) and p["error"] <= eps and np.isfinite(p["cost"]):
                if p["method"] not in best or p["cost"] < best[p["method"]]["cost"]:
                    best[p["method"]] = p
        ranked = sorted(best.values(), key=lambda p: p["cost"])
        if ranked:
            ranked = [p for p in ranked if p["cost"] <= COST_TIE * ranked[0]["cost"]]
        out.append({"level": float(eps), "winners": ranked})
    return out


def closing_section(points, *, regime: str, error: str, cost: str, levels=None, unit: str = "s",
                    outdir=None) -> str:
    """The closing section of a study report, from the study's own numbers:
    for each error level, the method that reaches it at least cost and what
    it keeps (its declared laws) — and, where it keeps neither |Γ| = 1 nor
    the Kelvin–Noether law, the cheapest method that keeps both and its cost
    relative to the winner — then one sentence naming the winners.

    ``points``: dicts ``{"method": spec label, "error": …, "cost": …,
    "setting": text (e.g. "h = 0.1 s")}``; ``error`` and ``cost`` say what the
    numbers are (with units); ``levels``: the error levels (default
    :func:`error_levels` of the points' errors); ``outdir``: also write the
    table as ``closing.csv``."""
    import pandas as pd

    points = list(points)
    levels = error_levels([p["error"] for p in points]) if levels is None else [float(x) for x in levels]
    rows = []
    said = []
    for r in cheapest_per_level(points, levels):
        w = r["winners"]
        if not w:
            rows.append({"error ≤": r["level"], "cheapest method": "not reached", "at": "—",
                         "error": float("nan"), f"cost ({unit})": float("nan"), "keeps": "—",
                         "cheapest keeping |Γ| = 1 and Kelvin–Noether": "—"})
            said.append(f"no method reached {r['level']:.0e}")
            continue
        geo = None  # the cheapest point reaching the level with a method that keeps |Γ| and Kelvin–Noether
        if not any(keeps_geometry(p["method"]) for p in w):
            ok = [p for p in points if keeps_geometry(p["method"]) and np.isfinite(p["error"])
                  and p["error"] <= r["level"] and np.isfinite(p["cost"])]
            geo = min(ok, key=lambda p: p["cost"]) if ok else None
        alt = (f"{geo['method']} ({geo['cost'] / w[0]['cost']:.3g}× the cost)" if geo is not None
               else "the same" if any(keeps_geometry(p["method"]) for p in w) else "none reached it")
        for p in w:
            rows.append({"error ≤": r["level"], "cheapest method": p["method"], "at": p.get("setting", "—"),
                         "error": float(p["error"]), f"cost ({unit})": float(p["cost"]),
                         "keeps": kept_laws(p["method"]), "cheapest keeping |Γ| = 1 and Kelvin–Noether": alt})
        names = " and ".join(f"{p['method']} ({p['cost']:.3g} {unit})" for p in w)
        said.append(f"to {r['level']:.0e}: {names}" + (" — a tie within "
                                                       f"{round(100 * (COST_TIE - 1))} %" if len(w) > 1 else "")
                    + (f" (keeping |Γ| = 1 and Kelvin–Noether: {alt})" if geo is not None else ""))
    df = pd.DataFrame(rows, columns=["error ≤", "cheapest method", "at", "error", f"cost ({unit})", "keeps",
                                     "cheapest keeping |Γ| = 1 and Kelvin–Noether"])
    title = f"Closing: the cheapest method per error level ({regime})"
    footer = (f"Error: {error}. Cost: {cost}. \"keeps\": the laws the method declares "
              f"(`liethermo.methods`) among |Γ| = 1, Kelvin–Noether and entropy monotone.")
    if outdir is not None:
        table = write_table(df, outdir, "closing", title)
    else:
        table = markdown_table(df, title, "")
    sentence = ("**Cheapest here** " + ("; ".join(said) if said else "— no point has a finite error and cost")
                + ".")
    return "\n\n".join([table.rstrip("\n"), footer, sentence])


def closing_fact(regime: str, missing: str, fact_rows=None, fact_title: str = "", sentence: str = "") -> str:
    """The closing section of a study that measures no cost against error:
    one sentence on what the cheapest-method table would need (``missing``),
    and the analogous fact the study does measure (``fact_rows`` under
    ``fact_title``, with ``sentence`` built from them)."""
    import pandas as pd

    parts = [f"### Closing: cost against error ({regime})", "", missing]
    if fact_rows:
        parts += ["", markdown_table(pd.DataFrame(list(fact_rows)), fact_title, "").rstrip("\n")]
    if sentence:
        parts += ["", sentence]
    return "\n".join(parts)
