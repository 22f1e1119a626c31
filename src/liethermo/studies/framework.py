"""Studies as declarations: what a study says, and what the framework does with it.

A study module defines one :class:`Study`: its options with their rules, its
stages (pure functions ``fn(ctx, coords, **needed) -> xr.Dataset`` over the
sweep points, the methods and the study's own axes), its quantities with
units, derived quantities, tables, verdicts, findings, figures and report
template (docs/studies.md; ``convergence.py`` and ``entropy_rate.py`` are
complete examples).  The framework owns the rest: the one-line option errors,
task planning, the resume cache (a task's result is a file: a rerun after any
signal computes only what is missing), Dask, the progress bar, stacking with
the sweep keys and axes as dimensions, CF attributes, atomic netCDF, CSV and
PNG files, the figures and the report with its verdict table.
"""

from __future__ import annotations

import contextlib
import copy
import itertools
import json
import math
import platform
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import xarray as xr

from .. import cf
from ..version import __version__

from .common import (StudyError, cached_point, coord_value, dim_name, expand_sweep, markdown_table, point_key,
                     progress_bar, resolve_study, stack_points, study_history, study_name, study_netcdf_path,
                     study_scene, write_atomic, write_netcdf_atomic, write_report, write_table)

# ----------------------------------------------------------------------------- options

def _num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


_RULES = {
    "number>0": ("a number > 0", lambda v: _num(v) and v > 0),
    "number>=0": ("a number ≥ 0", lambda v: _num(v) and v >= 0),
    "number": ("a number", _num),
    "fraction": ("a number in (0, 1)", lambda v: _num(v) and 0 < v < 1),
    "bool": ("true or false", lambda v: isinstance(v, bool)),
    "str": ("a string", lambda v: isinstance(v, str)),
    **{f"int>={n}": (f"an integer ≥ {n}", lambda v, n=n: isinstance(v, int) and not isinstance(v, bool) and v >= n)
       for n in range(4)},
}


def _check_rule(rule: str, v) -> str | None:
    """None if ``v`` follows ``rule``, else what it must be."""
    if rule.startswith(("list[", "list?[")) and rule.endswith("]"):  # "list?": may be empty
        inner = rule[rule.index("[") + 1:-1]
        what, _ = _RULES[inner]
        empty_ok = rule.startswith("list?")
        if not isinstance(v, list) or not (v or empty_ok) or any(_check_rule(inner, x) for x in v):
            return f"a {'' if empty_ok else 'non-empty '}list of {what.replace('a ', '', 1).replace('an ', '', 1)}s"
        return None
    if rule.startswith("one of "):
        choices = [c.strip() for c in rule[7:].split("|")]
        return None if v in choices else "one of " + ", ".join(f'"{c}"' for c in choices)
    what, ok = _RULES[rule]
    return None if ok(v) else what


@dataclass(frozen=True)
class Option:
    """One ``[options]`` entry: name, default, rule (``"number>0"``, ``"int>=5"``,
    ``"fraction"``, ``"bool"``, ``"list[number>0]"``, ``"one of a|b"``, …), unit, meaning."""

    name: str
    default: Any
    rule: str
    units: str = ""
    doc: str = ""
    optional: bool = False  # None allowed (the default then means "not set")

    def check(self, v):
        if v is None and self.optional:
            return
        why = _check_rule(self.rule, v)
        if why:
            unit = f" ({self.units})" if self.units and self.units != "1" else ""
            raise StudyError(f"options.{self.name}: must be {why}{unit}, got {v!r}")


# ----------------------------------------------------------------------------- declarations

@dataclass(frozen=True)
class Stage:
    """Tasks of one kind: ``fn(ctx, coords, **needed)`` over the Cartesian
    product of the axes ``over``; ``needs``: earlier stages, passed by name
    (one dataset where their axes are a subset of these, else the list of
    ``(coords, dataset)`` of their tasks at these coordinates); ``prefix``: put before every variable name;
    ``serial``: run in this process even under Dask (timings)."""

    name: str
    fn: Callable
    over: tuple[str, ...] = ("point",)
    needs: tuple[str, ...] = ()
    prefix: str = ""
    serial: bool = False
    keep: tuple[str, ...] | None = None  # the variables the study's dataset keeps (None: all)


@dataclass(frozen=True)
class Figure:
    """A declared figure.  ``kind``: "lines" (``y`` against ``x``, one line per
    ``hue`` value, one panel per ``y`` variable), "heatmap" (``y[0]`` over the
    dims ``x`` and ``hue``; non-finite cells hatched, not coloured) or
    "custom" (``draw(ds, ctx, fig)`` returns the axes it drew).  ``claim``:
    the sentence the figure supports, stated in the report under it."""

    name: str
    claim: str
    kind: str = "lines"
    x: str = ""
    y: tuple[str, ...] | Callable = ()  # names (``*`` patterns), or ds -> names
    hue: str = "scheme"
    facet: str | None = None  # a dimension: one panel per value (wrapped, at most 3 columns)
    logx: bool | None = None  # None: where the values span more than two decades
    logy: bool | None = None
    title: str | Callable = ""  # the suptitle ("{opt[h]}" fields), or (ds, ctx) -> it; default "<study>: <name>"
    draw: Callable | None = None
    select: Callable | None = None  # ds, ctx -> the part of ds drawn (default: the first sweep point)
    size: tuple[float, float] | None = None
    band: str | None = None  # a dimension of stored quantiles: its middle value drawn as the line, the outer ones
    #                         as a shaded band (lines figures)
    points: bool = False  # markers only, not joined (values sampled too sparsely for a curve, or categories)
    categories: tuple[str, ...] = ()  # heatmap of codes 0, 1, …: one colour per named category, a legend
    decorate: Callable | None = None  # (ax, var, ds, ctx) -> None: drawn on each lines panel (reference slopes)


@dataclass(frozen=True)
class Table:
    """A table of the report, also written as ``<name>.csv``."""

    name: str
    title: str
    rows: list


@dataclass(frozen=True)
class Verdict:
    """One row of a report's verdict table: the claim, what was measured, the
    rule, and whether the numbers above say it holds (None: not decided)."""

    claim: str
    measured: str
    rule: str
    holds: bool | None


@dataclass
class Study:
    kind: str
    title: str
    description: str
    options: tuple[Option, ...]
    stages: tuple[Stage, ...]
    quantities: dict[str, tuple[str, str]] | Callable  # {name: (units, long name)}, or ctx -> that
    report: str = ""
    models: tuple[str, ...] | None = None
    axes: Callable | None = None  # ctx -> {axis: [values]} besides "point" and "scheme"
    check: Callable | None = None  # ctx -> None (cross-option rules; raise StudyError)
    needs_methods: bool = True
    derive: Callable | None = None  # (ds, ctx) -> ds
    tables: Callable | None = None  # (ds, ctx) -> [Table]
    verdicts: Callable | None = None  # (ds, ctx) -> [Verdict]
    findings: Callable | None = None  # (ds, ctx) -> [sentence]
    facts: Callable | None = None  # (ds, ctx) -> {name: value} for the report template
    figures: tuple[Figure, ...] = ()

    def option_values(self, s: dict) -> dict:
        given = s.get("options", {}) or {}
        if not isinstance(given, dict):
            raise StudyError("options: must be a table")
        known = {o.name: o for o in self.options}
        for k in given:
            if k not in known:
                raise StudyError(f"options.{k}: unknown option of a {self.kind} study; known: "
                                 f"{', '.join(sorted(known))}")
        out = {}
        for o in self.options:
            v = given.get(o.name, copy.deepcopy(o.default))
            o.check(v)
            out[o.name] = v
        return out

    def context(self, study: dict, reduced: bool, outdir=None) -> "Context":
        s = resolve_study(study, reduced)
        opt = self.option_values(s)
        methods = list(s.get("methods", []) or [])
        if self.needs_methods and not methods:
            raise StudyError(f"methods: a {self.kind} study needs at least one method")
        ctx = Context(study=s, opt=opt, kind=self.kind, reduced=reduced, methods=methods,
                      points=expand_sweep(s.get("sweep")), outdir=Path(outdir) if outdir is not None else None)
        model = ctx.model
        if self.models is not None and model.name not in self.models:
            raise StudyError(f"study.base_scene: a {self.kind} study runs on a scene of "
                             f"{' or '.join(self.models)}, not of {model.name} ({ctx.scene_name!r})")
        for m in methods:
            if not isinstance(m, str):
                raise StudyError(f"methods: {m!r} is not a method name")
            try:
                model.method_overrides(m)
            except ValueError as exc:
                raise StudyError(f"methods: {exc}") from None
        ctx.axes = dict(self.axes(ctx)) if self.axes else {}
        if self.check:
            self.check(ctx)
        return ctx

    def validate(self, s: dict) -> None:
        self.context(s, reduced=False)

    def run(self, study: dict, outdir, *, reduced: bool, progress=None, dask=None, history=None) -> Path:
        ctx = self.context(study, reduced, outdir)
        ctx.outdir.mkdir(parents=True, exist_ok=True)
        results = _compute(self, ctx, progress, dask)
        ds = _assemble(self, ctx, results)
        if self.derive:
            ds = self.derive(ds, ctx)
        _label(self, ctx, ds)
        ctx.dataset = ds
        created = cf.timestamp()
        ds.attrs.update(created=created, history=cf.history_entry(
            study_history(self.kind, ctx.study, ctx.outdir, reduced, history), created))
        nc = write_netcdf_atomic(ds, study_netcdf_path(ctx.study, ctx.outdir))
        return _report(self, ctx, ds, nc)


@dataclass
class Context:
    """What a stage function and the report see: the resolved study, its
    options, sweep points, methods, the study's axes, and the scenes."""

    study: dict
    opt: dict
    kind: str
    reduced: bool
    methods: list[str]
    points: list[dict]
    outdir: Path | None = None
    axes: dict = field(default_factory=dict)
    dataset: Any = None
    _scenes: dict = field(default_factory=dict, repr=False)

    def __getstate__(self):  # Dask ships contexts: no dataset, no cached scenes
        d = dict(self.__dict__)
        d["dataset"] = None
        d["_scenes"] = {}
        return d

    @property
    def name(self) -> str:
        return study_name(self.study)

    @property
    def sweep_keys(self) -> list[str]:
        return list(self.points[0]) if self.points and self.points[0] else []

    @property
    def scene_name(self) -> str:
        return str(self.study.get("study", {}).get("base_scene", "paper"))

    def scene(self, point: dict | None = None, **overrides):
        """The validated scene of a sweep point (and further ``{"section.key": v}`` overrides)."""
        pt = dict(point or {})
        pt.update({k.replace("__", "."): v for k, v in overrides.items()})
        key = point_key(pt)
        if key not in self._scenes:
            self._scenes[key] = study_scene(self.study, pt)
        return self._scenes[key]

    @property
    def model(self):
        from ..models import model_of

        return model_of(self.scene(self.points[0] if self.points else None))

    def color(self, method: str) -> str:
        """The colour of a method, the same in every panel and figure of the study."""
        return method_color(self.methods, method)


# ----------------------------------------------------------------------------- runs

def run_scene(scene, method: str, *, h: float, steps: int, every: int = 1, members: int | None = None,
              threads: int | None = None, kernel: str | None = None, **overrides):
    """Members ``0:members`` of ``scene`` run with ``method`` (a label of the
    scene's model) at step ``h``: ``(labelled dataset, stats)`` from the model
    (:meth:`liethermo.models.Model.run_chunk`), storing what the model's
    :meth:`~liethermo.models.Model.study_state` reads.  ``stats.kernel_time``
    is the integration's wall time, compilation excluded; ``kernel``, ``threads``:
    the ensemble loop and its threads (the model's choice by default)."""
    from ..models import model_of

    model = model_of(scene)
    over = {**model.study_outputs, **model.method_overrides(method), "integrator.h": float(h),
            "integrator.steps": int(steps), "output.every": int(every),
            **{k.replace("__", "."): v for k, v in overrides.items()}}
    if members is not None:
        over["ensemble.members"] = int(members)
    sc = scene.with_overrides(over)
    n = int(sc["ensemble"]["members"])
    from ..runner import run_chunk  # with the thread pools a run of sc uses

    return run_chunk(sc, 0, n, threads=threads, kernel=kernel)


# ----------------------------------------------------------------------------- computing

def _stage_axes(study: Study, ctx: Context, stage: Stage) -> list[tuple[str, list]]:
    out = []
    for ax in stage.over:
        if ax == "point":
            out.append(("point", ctx.points or [{}]))
        elif ax == "scheme":
            out.append(("scheme", ctx.methods))
        elif ax in ctx.axes:
            out.append((ax, list(ctx.axes[ax])))
        else:
            raise StudyError(f"stage {stage.name!r} of the {study.kind} study runs over an unknown axis {ax!r}")
    return out


def _tasks(study: Study, ctx: Context, stage: Stage) -> list[dict]:
    axes = _stage_axes(study, ctx, stage)
    return [dict(zip([a for a, _ in axes], combo)) for combo in itertools.product(*(v for _, v in axes))]


def task_key(study: Study, ctx: Context, stage: Stage, coords: dict) -> str:
    """The name of a task's file in the resume cache (``ctx.outdir/points/<key>.nc``)."""
    scene = ctx.scene(coords.get("point"))
    return point_key({"kind": study.kind, "stage": stage.name, "coords": coords, "opt": ctx.opt,
                      "scene": scene})


def run_stage_task(kind: str, stage_name: str, ctx: Context, coords: dict, needed: dict) -> xr.Dataset:
    """A stage function called by name (what a Dask worker runs)."""
    from . import get_study

    study = get_study(kind).STUDY
    stage = next(s for s in study.stages if s.name == stage_name)
    return stage.fn(ctx, coords, **needed)


def _compute(study: Study, ctx: Context, progress, dask) -> dict[str, list[tuple[dict, xr.Dataset]]]:
    from ..io import point_is_cached

    stages = {s.name: s for s in study.stages}
    plan = {s.name: _tasks(study, ctx, s) for s in study.stages}
    keys = {s.name: [task_key(study, ctx, s, c) for c in plan[s.name]] for s in study.stages}
    results: dict[str, list[tuple[dict, xr.Dataset]]] = {}
    done: dict[tuple[str, str], xr.Dataset] = {}

    def needed(stage: Stage, coords: dict) -> dict:
        """The results of the stages ``stage`` needs at ``coords``: one dataset, or where the needed stage runs
        over more axes, the ``[(coords, dataset)]`` of its tasks that match these coordinates, in plan order."""
        out = {}
        for n in stage.needs:
            shared = [k for k in stages[n].over if k in coords]
            if len(shared) == len(stages[n].over):
                out[n] = done[(n, point_key({k: coords[k] for k in stages[n].over}))]
            else:
                out[n] = [(c, done[(n, point_key(c))]) for c in plan[n] if all(c[k] == coords[k] for k in shared)]
        return out

    with contextlib.ExitStack() as stack:
        if dask is not None:
            from ..distributed import client_for

            client = stack.enter_context(client_for(dask))
        bar = stack.enter_context(progress_bar(sum(len(v) for v in plan.values()), progress, f"{ctx.name} tasks"))
        for stage in study.stages:
            todo = plan[stage.name]
            if dask is not None and not stage.serial:
                from ..distributed import map_cached_points

                # the needed stages are complete (stages run in order): their results travel with the task
                missing = [(k, run_stage_task, (study.kind, stage.name, ctx, c, needed(stage, c)))
                           for c, k in zip(todo, keys[stage.name]) if not point_is_cached(ctx.outdir, k)]
                if missing:
                    map_cached_points(ctx.outdir, missing, client, progress=False)
            out = []
            for c, k in zip(todo, keys[stage.name]):
                ds = cached_point(ctx.outdir, k, lambda c=c: stage.fn(ctx, c, **needed(stage, c)))
                done[(stage.name, point_key(c))] = ds
                out.append((c, ds))
                bar.update(1)
            results[stage.name] = out
    return results


def _assemble(study: Study, ctx: Context, results) -> xr.Dataset:
    """One dataset: every stage's results stacked over its axes (the sweep keys
    and the study's axes as dimensions), the stages merged."""
    parts = []
    for stage in study.stages:
        rows = results[stage.name]
        if stage.keep == () or not rows:  # a stage over an empty axis has nothing to stack
            continue
        flat, dsets = [], []
        for coords, ds in rows:
            p = {}
            for ax in stage.over:
                if ax == "point":
                    p.update(coords["point"])
                else:
                    p[ax] = coords[ax]
            flat.append(p)
            dsets.append(ds if stage.keep is None else ds[[v for v in stage.keep if v in ds]])
        keys = list(flat[0]) if flat else []
        ds = stack_points(dsets, flat, keys) if keys else dsets[0]
        if stage.prefix:
            ds = ds.rename({v: stage.prefix + v for v in ds.data_vars})
        parts.append(ds)
    ds = xr.merge(parts, compat="override", join="outer", combine_attrs="override")
    for ax, values in ctx.axes.items():
        if ax in ds.dims:
            ds = ds.reindex({ax: [coord_value(v) for v in values]})
    return ds


def _label(study: Study, ctx: Context, ds: xr.Dataset) -> None:
    """CF attributes from the declared quantities; global attributes that describe the whole study."""
    q = dict(COMMON_QUANTITIES)
    q.update(study.quantities(ctx) if callable(study.quantities) else study.quantities)
    for name in list(ds.variables):
        if name in q:
            units, long_name = q[name]
            ds[name].attrs.update(units=units, long_name=long_name)
        elif name in ds.data_vars and "units" not in ds[name].attrs:
            raise RuntimeError(f"the {study.kind} study writes {name!r} without declaring its quantity")
    units = {f"{k.section}.{k.name}": k.unit for k in ctx.model.keys()}
    for k in ctx.sweep_keys:
        d = dim_name(k)
        if d in ds.coords:  # a sweep key's coordinate: its unit is the key's
            ds[d].attrs.update(scene_key=k, long_name=k, **({"units": units[k]} if units.get(k) else {}))
    sweep = ctx.study.get("sweep") or {}
    ds.attrs = {"title": f"liethermo {study.kind} study: {study.title}", "study": ctx.name, "kind": study.kind,
                "model": ctx.model.name, "base_scene": ctx.scene_name, "reduced": int(ctx.reduced),
                "methods": ", ".join(ctx.methods), "sweep": json.dumps(sweep) if sweep else "none",
                "description": str(ctx.study.get("study", {}).get("description", study.description)),
                "software": f"liethermo {__version__}", "software_version": __version__,
                "python": platform.python_version(),
                **{f"option_{k}": (json.dumps(v) if not isinstance(v, (int, float, str)) or isinstance(v, bool)
                                   else v) for k, v in ctx.opt.items()}}


#: quantities several studies write (one definition each)
COMMON_QUANTITIES = {
    "h": ("s", "time step"), "scheme": ("1", "method"), "member": ("1", "ensemble member"), "t": ("s", "time"),
    "axis": ("1", "body axis"), "status": ("1", "member status (0 ok)"),
    "gamma_defect": ("1", "max_k ||Gamma_k| - 1|"),
    "max_relative_energy_error": ("1", "max_k |E_k - E_0| / E_mech,0, node values (failed: inf)"),
}


# ----------------------------------------------------------------------------- figures

#: a method's colour by its place in the study's list; from the ninth on its lines are dashed
#: (:func:`method_style`), and each colour differs in hue from the one eight places before it
PALETTE = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf",
           "#7f7f7f", "#bcbd22", "#000000", "#0b6e4f", "#ad494a", "#393b79", "#7b4173", "#e6ab02")
MARKERS = ("o", "s", "^", "v", "D", "P", "X", "*", "<", ">", "h", "p")
#: colours of a heatmap's categories (good to bad): green, yellow, orange, red, dark purple, …
CATEGORY_COLORS = ("#1a9850", "#fee08b", "#fc8d59", "#d73027", "#542788", "#4d4d4d", "#91bfdb")
#: colours of hues that are not methods (members, quantiles): none of them a method's
OTHER_COLORS = ("#000000", "#8a8a8a", "#b8860b", "#4b0082", "#2f4f4f", "#c71585")


def method_color(methods: list[str], method: str) -> str:
    i = list(methods).index(method) if method in methods else len(methods) + hash(method) % 7
    return PALETTE[i % len(PALETTE)]


def method_style(methods: list[str], method: str) -> str:
    """The line style of a method: solid for the first eight of the study's list, dashed after."""
    return "-" if method not in methods or list(methods).index(method) < 8 else "--"


def sci_label(v: float) -> str:
    """A tick label: ``0.02``, ``3×10⁻⁵`` (mathtext) for values far from 1."""
    if v == 0 or not np.isfinite(v):
        return f"{v:g}"
    k = int(np.floor(np.log10(abs(v)) + 1e-9))
    if -3 <= k <= 3:
        return f"{v:.3g}"
    m = v / 10.0 ** k
    return f"$10^{{{k}}}$" if abs(m - 1) < 1e-6 else f"${m:.2g}\\times10^{{{k}}}$"


def readable_log_ticks(ax) -> None:
    """Give each log axis of ``ax`` at least two tick labels: where its view holds fewer than two powers of ten
    (a log axis spanning less than a decade shows no number otherwise), labelled ticks at 1, 2, 5 × 10^k (or
    denser, or the view's ends) replace the decades."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullFormatter

    for axis in (ax.xaxis, ax.yaxis):
        if axis.get_scale() != "log" or not axis.get_visible():
            continue
        lo, hi = sorted(float(v) for v in axis.get_view_interval())
        if not (lo > 0 and hi > lo and np.isfinite(hi)):
            continue
        axis.set_minor_formatter(NullFormatter())  # minor labels run into each other
        k0, k1 = int(np.ceil(np.log10(lo) - 1e-9)), int(np.floor(np.log10(hi) + 1e-9))
        if k1 - k0 + 1 >= 2:
            continue
        ticks = []
        for subs in ((1, 2, 5), (1, 2, 3, 5, 7), tuple(range(1, 10))):
            ticks = [m * 10.0 ** k for k in range(k0 - 1, k1 + 2) for m in subs if lo <= m * 10.0 ** k <= hi]
            if len(ticks) >= 2:
                break
        if len(ticks) < 2:  # less than a factor 10/9: the ends, with the digits that tell them apart
            ticks = list(np.geomspace(lo, hi, 5)[[1, 3]])
            digits = max(2, int(np.ceil(-np.log10(np.log10(hi / lo)))) + 2)
            axis.set_major_locator(FixedLocator(ticks))
            axis.set_major_formatter(FuncFormatter(lambda v, _, d=digits: f"{v:.{d}g}"))
            continue
        axis.set_major_locator(FixedLocator(ticks[::-(-len(ticks) // 6)]))  # at most 6 labelled
        axis.set_major_formatter(FuncFormatter(lambda v, _: sci_label(v)))


def spans_decades(values, decades: float = 2.0) -> bool:
    """Whether the finite values, mostly positive, span more than ``decades``
    decades (a log axis then; zeros are left out of it)."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    pos = v[v > 0]
    return pos.size > 1 and pos.size >= 0.5 * v.size and not (v < 0).any() and pos.max() / pos.min() > 10 ** decades


def axis_label(da) -> str:
    units = da.attrs.get("units", "")
    name = da.attrs.get("long_name", da.name)
    return f"{name} ({units})" if units and units != "1" else str(name)


def save_figure(fig, path: Path) -> Path:
    """Write a figure atomically (a killed study leaves no half PNG)."""
    import matplotlib.pyplot as plt

    write_atomic(path, lambda tmp: fig.savefig(tmp, format="png", dpi=120))
    plt.close(fig)
    return path


def first_point(ds: xr.Dataset, ctx: Context, keep=()) -> xr.Dataset:
    sel = {dim_name(k): 0 for k in ctx.sweep_keys if dim_name(k) in ds.dims and dim_name(k) not in keep}
    return ds.isel(sel) if sel else ds


def _grid(n: int, size=None):
    import matplotlib.pyplot as plt

    cols = min(3, n)
    rows = -(-n // cols)
    w, h = size or (4.6, 3.6)
    fig, axes = plt.subplots(rows, cols, figsize=(w * cols + 1.8, h * rows), layout="constrained", squeeze=False)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    return fig, list(axes.ravel()[:n])


def _expand(names, ds) -> list[str]:
    """Variable names, ``*`` patterns expanded over the dataset's variables."""
    import fnmatch

    if callable(names):
        return list(names(ds))
    out = []
    for n in names:
        out += [v for v in ds.data_vars if fnmatch.fnmatchcase(v, n)] if "*" in n else [n]
    return out


def _draw_lines(f: Figure, ds: xr.Dataset, ctx: Context):
    from matplotlib.ticker import NullLocator

    ys = _expand(f.y, ds)
    panels = [(v, None) for v in ys] if f.facet is None else [(ys[0], i) for i in range(ds.sizes[f.facet])]
    fig, axes = _grid(len(panels), f.size)
    hues = [str(h) for h in ds[f.hue].values] if f.hue in ds.dims else [None]
    handles, nonfinite = {}, False
    for ax, (var, fi) in zip(axes, panels):
        d = ds if fi is None else ds.isel({f.facet: fi})
        lines = []
        for j, hv in enumerate(hues):
            dd = d if hv is None else d.isel({f.hue: j})  # by position: a numeric hue is not its text
            x = np.asarray(dd[f.x].values, float).ravel()
            band = None
            if f.band and f.band in dd[var].dims:  # the middle quantile, the outer ones as a band
                qd = dd[var].sortby(f.band)
                y = np.asarray(qd.isel({f.band: qd.sizes[f.band] // 2}).values, float).ravel()
                band = [np.asarray(qd.isel({f.band: i}).values, float).ravel() for i in (0, -1)]
            else:
                y = np.asarray(dd[var].values, float).ravel()
            ok = np.isfinite(x) & np.isfinite(y)
            bad = np.isfinite(x) & ~np.isfinite(y)  # a blow-up, a failed or censored run: marked, not dropped
            if ok.any() or bad.any():
                order = np.argsort(x[ok])
                lines.append((j, hv, x[ok][order], y[ok][order], x[bad],
                              None if band is None else [b[ok][order] for b in band]))
        xs = np.concatenate([ln[2] for ln in lines]) if lines else np.array([])
        yv = np.concatenate([ln[3] for ln in lines] + [b for ln in lines if ln[5] for b in ln[5]]) if lines else xs
        logs = [on if on is not None else spans_decades(vals) for on, vals in ((f.logx, xs), (f.logy, yv))]
        for on, axis in zip(logs, ("x", "y")):
            if on:
                (ax.set_xscale if axis == "x" else ax.set_yscale)("log")
        for j, hv, x, y, xbad, band in lines:
            if logs[1]:  # a zero on a log axis is a gap, not a line to the bottom
                y = np.where(y > 0, y, np.nan)
            is_method = hv in ctx.methods
            color = ctx.color(hv) if is_method else OTHER_COLORS[j % len(OTHER_COLORS)]
            style = "none" if f.points else method_style(ctx.methods, hv) if is_method else "-"
            (ln,) = ax.plot(x, y, color=color, marker=MARKERS[j % len(MARKERS)], ms=7 - 2 * (j % 2), mfc="none",
                            ls=style, lw=1.2, label=hv or var, markevery=1 if f.points else max(1, len(x) // 12))
            if band is not None:
                lo_, hi_ = (np.where(b > 0, b, np.nan) if logs[1] else b for b in band)
                ax.fill_between(x, lo_, hi_, color=color, alpha=0.15, lw=0)
            if xbad.size:
                nonfinite = True
                ax.plot(xbad, np.full(xbad.size, 0.97), transform=ax.get_xaxis_transform(), ls="none", marker="X",
                        ms=8, color=color, clip_on=False)
            handles.setdefault(hv or var, ln)
        if f.decorate is not None:
            f.decorate(ax, var, d, ctx)
        if f.x in ds.dims and 1 < ds.sizes[f.x] <= 16:  # ticks at the swept values, labelled where they part
            xv = np.asarray(ds[f.x].values, float)
            ax.set_xticks(xv, _spaced_labels(xv, logs[0]))
            ax.xaxis.set_minor_locator(NullLocator())
        ax.set_xlabel(axis_label(ds[f.x]))
        units = ds[var].attrs.get("units", "")
        ax.set_ylabel(axis_label(ds[var]) if len(panels) == 1 else f"{var} ({units})" if units else var)
        if fi is not None:
            ax.set_title(f"{f.facet} = {_fmt_coord(ds[f.facet].values[fi])}")
        elif len(panels) > 1:
            ax.set_title(str(ds[var].attrs.get("long_name", var)))
        ax.grid(True, which="both", alpha=0.3)
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    extra = {}
    if f.band:
        extra[f"band: {f.band} {_band_span(ds, f.band)}"] = Patch(color="0.5", alpha=0.3)
    if nonfinite:
        extra["× at the top: no finite value"] = Line2D([], [], ls="none", marker="X", color="0.3")
    if len(handles) > 1 or extra:  # one legend for every panel, outside the axes: it covers no data
        unit = ds[f.hue].attrs.get("units", "") if f.hue in ds.coords else ""
        title = f"{f.hue} ({unit})" if unit and unit != "1" else f.hue  # a legend of values says their unit
        allh = {**(handles if len(handles) > 1 else {}), **extra}
        fig.legend(allh.values(), allh.keys(), fontsize=8, title=title if len(handles) > 1 else None,
                   loc="outside right center")
    return fig


def _spaced_labels(xv, log: bool) -> list[str]:
    """Labels of ticks at swept values: from the largest down, a value is labelled when it lies at least a
    seventh of the axis (in decades on a log axis) from the last labelled one; at most 6."""
    pos = np.log10(np.where(xv > 0, xv, np.nan)) if log else np.asarray(xv, float)
    span = np.nanmax(pos) - np.nanmin(pos) if np.isfinite(pos).sum() > 1 else 0.0
    out, last = [""] * len(xv), None
    for i in np.argsort(-np.nan_to_num(pos, nan=-np.inf)):
        if np.isfinite(pos[i]) and (last is None or abs(last - pos[i]) >= span / 7) and sum(map(bool, out)) < 6:
            out[i], last = f"{xv[i]:.3g}", pos[i]
    return out


def _band_span(ds, dim) -> str:
    q = np.sort(np.asarray(ds[dim].values, float)) if dim in ds.coords else np.array([])
    return f"{q[0]:g} – {q[-1]:g}, line {q[q.size // 2]:g}" if q.size > 1 else ""


def _fmt_coord(v) -> str:
    return f"{v:.3g}" if isinstance(v, (float, np.floating)) else str(v)


def _draw_heatmap(f: Figure, ds: xr.Dataset, ctx: Context):
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    var = _expand(f.y, ds)[0]
    sweep = [dim_name(k) for k in ctx.sweep_keys if dim_name(k) in ds.dims]
    xdim = f.x or sweep[-1]  # default: the sweep's last key across, its first one up
    ydim = f.hue if f.x else (sweep[0] if len(sweep) > 1 else None)
    if ydim is None:
        ds = ds.expand_dims(row=[""])
        ydim = "row"
    panels = [None] if f.facet is None else list(range(ds.sizes[f.facet]))
    fig, axes = _grid(len(panels), f.size)
    if f.categories:
        from matplotlib.colors import BoundaryNorm, ListedColormap

        cmap = ListedColormap(CATEGORY_COLORS[:len(f.categories)])
        cnorm = BoundaryNorm(np.arange(len(f.categories) + 1) - 0.5, len(f.categories))
    finite_all = np.asarray(ds[var].values, float)
    finite_all = finite_all[np.isfinite(finite_all)]
    log = f.logy if f.logy is not None else spans_decades(finite_all)
    vmin = float(finite_all[finite_all > 0].min()) if log and (finite_all > 0).any() else None
    vmax = float(finite_all.max()) if finite_all.size else None
    for ax, fi in zip(axes, panels):
        d = ds if fi is None else ds.isel({f.facet: fi})
        z = np.asarray(d[var].transpose(ydim, xdim).values, float)
        bad = ~np.isfinite(z)
        ax.set_facecolor("none")
        if f.categories:  # codes 0, 1, …: one colour each, named in a legend
            im = ax.imshow(np.ma.masked_invalid(z), aspect="auto", origin="lower", cmap=cmap, norm=cnorm,
                           interpolation="nearest")
        else:
            norm = LogNorm(vmin=vmin, vmax=vmax) if log and vmin else None
            im = ax.imshow(np.ma.masked_invalid(z), aspect="auto", origin="lower", norm=norm,
                           vmin=None if norm else vmin, vmax=None if norm else vmax, cmap="viridis")
        for (i, j) in zip(*np.nonzero(bad)):
            ax.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, hatch="xx", color="0.4", lw=0))
        ax.set_xticks(range(z.shape[1]), [_fmt_coord(v) for v in d[xdim].values], rotation=45, fontsize=7)
        ax.set_yticks(range(z.shape[0]), [_fmt_coord(v) for v in d[ydim].values], fontsize=7)
        ax.set_xlabel(axis_label(ds[xdim]) if xdim in ds.coords else xdim)
        ax.set_ylabel(axis_label(ds[ydim]) if ydim in ds.coords else ydim)
        if fi is not None:
            ax.set_title(f"{f.facet} = {_fmt_coord(ds[f.facet].values[fi])}")
    bad_any = not np.isfinite(np.asarray(ds[var].values, float)).all()
    if f.categories:
        from matplotlib.patches import Patch

        patches = [Patch(color=CATEGORY_COLORS[i], label=c) for i, c in enumerate(f.categories)]
        if bad_any:
            patches.append(Patch(fill=False, hatch="xx", color="0.4", label="not finite"))
        fig.legend(handles=patches, title=axis_label(ds[var]), fontsize=8, loc="outside right center")
        return fig
    fig.colorbar(im, ax=axes, label=axis_label(ds[var]) + ("; hatched: not finite" if bad_any else ""))
    return fig


def draw_figures(study: Study, ctx: Context, ds: xr.Dataset) -> list[tuple[Figure, Path]]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = []
    for f in study.figures:
        keep = tuple(dim_name(k) for k in ctx.sweep_keys) if f.kind == "heatmap" else (f.facet,) if f.facet else ()
        d = f.select(ds, ctx) if f.select else first_point(ds, ctx, keep=keep)
        if f.kind == "lines":
            fig = _draw_lines(f, d, ctx)
        elif f.kind == "heatmap":
            fig = _draw_heatmap(f, d, ctx)
        else:
            fig = plt.figure(figsize=f.size or (7, 4.5), layout="constrained")
            f.draw(d, ctx, fig)
        title = f.title(d, ctx) if callable(f.title) else f.title.format(opt=ctx.opt, scene=ctx.scene_name)
        if title or fig._suptitle is None or not fig._suptitle.get_text():
            fig.suptitle(title or f"{ctx.name}: {f.name.replace('_', ' ')}")
        for ax in fig.axes:
            readable_log_ticks(ax)
        out.append((f, save_figure(fig, ctx.outdir / f"{f.name}.png")))
    return out


# ----------------------------------------------------------------------------- the report

def _report(study: Study, ctx: Context, ds: xr.Dataset, nc: Path) -> Path:
    import pandas as pd

    facts = dict(study.facts(ds, ctx)) if study.facts else {}
    fields = {"opt": ctx.opt, "scene": ctx.scene_name, "model": ctx.model.name, "name": ctx.name,
              "methods": ", ".join(ctx.methods), **facts}
    sections = []
    tables = list(study.tables(ds, ctx)) if study.tables else []
    verdicts = list(study.verdicts(ds, ctx)) if study.verdicts else []
    md = [write_table(pd.DataFrame(list(t.rows)), ctx.outdir, t.name, t.title).rstrip("\n") for t in tables]
    if md:
        sections.append(md[0])
    text = (study.report or study.description).format_map(fields)
    sections.append(text)
    sections += md[1:]
    for f, path in draw_figures(study, ctx, ds):
        sections.append(f"![{f.name}]({path.name})\n\n*{f.name}.png:* {f.claim.format_map(fields)}")
    if verdicts:
        rows = [{"claim": v.claim, "measured": v.measured, "rule": v.rule,
                 "verdict": "holds" if v.holds else "—" if v.holds is None else "FAILS"} for v in verdicts]
        sections.append(markdown_table(pd.DataFrame(rows), "Verdicts",
                                       "Each verdict follows from the tables above by its rule: holds, FAILS, "
                                       "or — : not decided (the data cannot decide it: the measured column says why, "
                                       "e.g. a tie, a value the ladder does not bracket, or a loaded machine)."))
    found = list(study.findings(ds, ctx)) if study.findings else []
    if found:
        sections.append("**Findings.** " + " ".join(found))
    files = [f"`{t.name}.csv`" for t in tables] + [f"`{f.name}.png`" for f in study.figures]
    sections.append(f"Files: `{nc.name}` (every number above, with units)" + "".join(f", {f}" for f in files) + ".")
    title = f"{study.title}: {ctx.name}" + (" (reduced)" if ctx.reduced else "")
    return write_report(ctx.outdir, title, sections)

