"""The Python interface: what the command line does, for notebooks and scripts.

.. code-block:: python

    import liethermo

    scene = liethermo.load_scene("paper", {"integrator.h": 0.05})
    ds = liethermo.run(scene, compare=False)            # the VI only, in memory, writes nothing
    runs = liethermo.run("paper", {"ensemble.members": 64}, output="paper64.nc", compare=True)
    runs["vi"], runs["rk2"]                             # the scene's method and the one it compares with
    res = liethermo.study("studies/convergence.toml", reduced=True, output="conv")
    ds = liethermo.open_dataset("paper64.nc")           # time in seconds, labels as indexes
    ds.liethermo.relative_energy_error()                # (E_k − E₀)/E_mech,0 on node values
    ds.liethermo.ok                                     # members that completed
    ds.liethermo.quantiles("energy_error")              # 5 / 50 / 95 % over the members
    both = liethermo.open_runs(["paper64.nc", "paper64_rk2.nc"])   # one dataset, dims (method, member, t, …)

The command line (``liethermo run``, ``liethermo study``) calls these same
functions.  Inputs are validated before any work, as on the command line:
an invalid scene raises :class:`liethermo.scene.SceneError` naming the key
and the rule.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import xarray as xr

from . import cf
from .accessor import LiethermoAccessor  # noqa: F401  (registers ds.liethermo)
from .preflight import PreflightError  # noqa: F401  (re-exported)
from .scene import SceneError  # noqa: F401  (re-exported)

#: a loaded scene, of whichever model (its model's scene class)
Scene = Any
from .scene import load_scene as _load_scene


def load_scene(scene: str | Path | dict | Scene = "paper", overrides: dict | list | None = None) -> Scene:
    """The typed, validated scene: a built-in name (``liethermo.scene.builtin_scenes()``),
    a TOML file, a dict of tables, or a Scene; ``overrides`` as ``{"section.key": value}``
    (or ``--set`` strings)."""
    return _load_scene(scene, overrides)


def run(scene: str | Path | dict | Scene = "paper", overrides: dict | list | None = None, *,
        output: str | Path | None = None, compare: bool | None = None, figures: bool | None = None,
        progress: bool = False, force: bool = False, resume: Any = False, preflight: bool = True,
        history: str | None = None, combine: bool = False) -> xr.Dataset | dict[str, xr.Dataset]:
    """Run a scene with its own method and return its dataset.

    Runs in memory and writes nothing unless ``output`` (a ``.nc`` path) is
    given: then the dataset is written there atomically, member chunk by
    member chunk, and returned opened lazily from the file.  Before any
    work, the output is checked as on the command line
    (:func:`liethermo.preflight.prepare_run`: its folder takes files, no
    other process writes it, an existing file holds a run of the same scene
    unless ``force``, disk and memory suffice), raising
    :class:`liethermo.preflight.PreflightError`; ``resume=True`` goes on from
    what an interrupted or killed run of the same scene left.

    ``compare``: what to do with the scene's ``output.compare`` methods (the
    paper scene compares its VI with RK2).  ``True`` runs them too and returns
    ``{method: Dataset}``, the scene's own method first (with ``output``, the
    other methods' files are named as on the command line,
    ``<stem>_<method>.nc``); ``False`` runs the scene's method only.  Left
    out, a scene that compares with other methods raises
    :class:`SceneError` saying so, rather than dropping them unnoticed.

    ``combine``: with ``compare=True``, return one Dataset with a ``method``
    dimension instead of the dict (:func:`open_runs`: variables that only
    some methods have are filled with NaN); with ``output``, it is opened
    lazily from the files (dask arrays), without, it joins the in-memory
    datasets.

    ``figures``: draw the scene's figures beside ``output`` (named
    ``<stem>_*.png`` as on the command line); left out, as the scene's
    ``output.figures`` says.  An in-memory run draws none (its summary says
    so); ``figures=True`` without ``output`` raises :class:`SceneError`.

    ``progress``: a progress bar over member-steps.  Each returned dataset
    carries the run's summary as ``ds.attrs["summary"]`` (one line per fact,
    as the command line prints it).  A write that fails raises
    :class:`liethermo.io.WriteError` and leaves no file; Ctrl-C keeps the
    complete member chunks in ``<output>.partial`` for ``resume=True``."""
    from .preflight import method_scene, output_paths

    sc = load_scene(scene, overrides)
    if output is None:  # an output's checks (prepare_run) include these
        from .preflight import check_parameters

        try:
            check_parameters(sc)
        except PreflightError as exc:
            raise PreflightError(_in_python_words(exc)) from None
    method, others = _methods_to_run(sc, compare, figures, output)
    if combine and not compare:
        raise SceneError("output.compare", "combine=True joins the compared methods into one dataset: pass "
                         "compare=True too", show_value=False)
    draw = bool(sc["output"]["figures"] if figures is None else figures) and output is not None
    if history is None:
        history = cf.api_call("liethermo.run", scene if isinstance(scene, (str, Path, dict)) else sc.name,
                              overrides=overrides, output=output)
    methods = [method] + (others if compare else [])
    sc = sc.with_overrides({"output.compare": []})
    paths = output_paths(sc.with_overrides({"output.compare": methods[1:]}), output) if output else {}
    results = {}
    for m in methods:
        msc = sc if m == method else method_scene(sc, m)
        results[m] = _run_one(msc, paths.get(m), progress=progress, force=force, resume=resume,
                              preflight=preflight, history=history)
    wanted = bool(sc["output"]["figures"] if figures is None else figures)
    if not wanted:
        line = "  figures: none asked for (figures=False or output.figures = false)"
    elif output is not None:
        drawn = _draw_figures(paths, Path(output).stem, sc) if draw else []
        line = (f"  figures: {', '.join(str(f) for f in drawn)}" if drawn else "  figures: none drawn")
    else:
        line = "  figures: none drawn (an in-memory run; pass output= to draw them beside the file)"
    for ds in results.values():
        ds.attrs["summary"] += "\n" + line
    if combine:
        from .combine import combine_runs

        if output is None:
            return combine_runs(results)
        for ds in results.values():
            ds.close()
        combined = open_runs({m: paths[m] for m in methods})
        combined.attrs["summary"] = "\n".join(results[m].attrs["summary"] for m in methods)
        return combined
    return results if compare else results[method]


def _methods_to_run(sc, compare, figures, output) -> tuple[str, list[str]]:
    """The scene's method and the other methods of its output.compare; a scene
    that compares but was called without ``compare``, or ``figures`` without
    ``output``, raises SceneError saying what to pass."""
    method = sc["integrator"]["method"]
    others = [m for m in dict.fromkeys(sc["output"]["compare"]) if m != method]
    if others and compare is None:
        raise SceneError("output.compare", f"scene {sc.name!r} compares its method {method} with "
                         f"{', '.join(others)}: pass compare=True to run those too (a dict "
                         f"{{method: Dataset}} is returned) or compare=False to run {method} only",
                         show_value=False)
    if figures and output is None:
        raise SceneError("output.figures", "figures are drawn beside the output file: pass output= "
                         "(a .nc path) or figures=False", show_value=False)
    return method, others


def _run_one(sc: Scene, out: Path | None, *, progress, force, resume, preflight, history) -> xr.Dataset:
    """One method of a run: in memory (``out`` None) or into ``out``."""
    from .runner import run_scene

    if out is None:
        ds, summ = run_scene(sc, None, progress=progress, history=history)
        ds.attrs["summary"] = "\n".join(summ.lines())
        return ds
    out = Path(out)
    plan = None
    if preflight:
        from .preflight import prepare_run

        try:
            plan = prepare_run(sc, out, force=force, resume=bool(resume))
        except PreflightError as exc:
            raise PreflightError(_in_python_words(exc)) from None
        resume = plan.resume_sources.get(out, False) if resume is True else resume
    try:
        if plan is not None and plan.outputs[0].skip:  # complete already: resume has nothing to do
            summ = None
        else:
            _, summ = run_scene(sc, out, progress=progress, history=history, resume=resume)
    finally:
        if plan is not None:
            plan.release()
    ds = open_dataset(out)
    ds.attrs["summary"] = "\n".join(summ.lines()) if summ is not None else f"{out}: complete, kept"
    return ds


def _draw_figures(outputs: dict, stem: str, scene) -> list[Path]:
    """Draw a run's figures next to its first output file, each complete or
    not at all: drawn in a temporary folder there, then renamed into place.
    Unfinished figure folders of killed runs are removed (one line on stderr)."""
    import os
    import shutil
    import sys
    import tempfile

    from .faults import figure_drafts, one_line
    from .io import WriteError, io_cause
    from .models import model_of

    folder = Path(next(iter(outputs.values()))).parent
    drafts = figure_drafts(folder, stem)  # of runs killed while drawing
    for d in drafts:
        shutil.rmtree(d, ignore_errors=True)
    if drafts:
        print(one_line(f"liethermo: removed {len(drafts)} unfinished figure folder{'s' if len(drafts) > 1 else ''} "
                       f"left by killed runs in {folder}"), file=sys.stderr)
    tmp = Path(tempfile.mkdtemp(prefix=f".{stem}_figures.{os.getpid()}.", dir=folder))
    try:
        try:
            drawn = model_of(scene).figures(dict(outputs), tmp, stem)
            final = []
            for f in drawn:
                os.replace(f, folder / f.name)
                final.append(folder / f.name)
            return final
        except OSError as exc:
            raise WriteError(folder / f"{stem}_*.png", io_cause(exc)) from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _in_python_words(exc: PreflightError) -> str:
    """A refusal's message with its remedies spelled for Python callers."""
    from .preflight import PYTHON_WORDS

    return exc.in_words(PYTHON_WORDS)


@dataclass(frozen=True)
class StudyResult:
    """What :func:`study` made: the folder, its report, its netCDF (opened) and figures."""

    outdir: Path
    report: Path
    dataset: xr.Dataset | None
    figures: tuple[Path, ...]

    def report_text(self) -> str:
        return self.report.read_text()


def study(path: str | Path, *, reduced: bool = False, output: str | Path | None = None,
          dask: Any = None, progress: bool = False, history: str | None = None,
          scene: str | None = None) -> StudyResult:
    """Run a study file (``studies/*.toml``) and return its results.

    ``scene``: run it on another base scene (``liethermo study --scene``).

    ``output``: the study's folder (default ``data/runs/<name>``, with
    ``-reduced`` in reduced mode); an interrupted study resumes there.
    ``dask``: ``"local"``, a scheduler address or a Client, to run sweep
    points as Dask tasks."""
    from .studies.common import study_netcdf_path
    from .studies.common import with_scene
    from .studies.runner import default_outdir, load_study, run_study, validate_study

    s = load_study(path)
    if scene is not None:
        s = with_scene(s, scene)
    validate_study(s)
    outdir = Path(output) if output is not None else default_outdir(s, reduced)
    if history is None:
        history = cf.api_call("liethermo.study", str(path), reduced=reduced, output=output, scene=scene)
    report = run_study(s, outdir, reduced=reduced, progress=progress, dask=dask, history=history)
    from .studies.common import resolve_study

    nc = study_netcdf_path(resolve_study(s, reduced), outdir)
    ds = cf.open_dataset(nc) if nc.is_file() else None
    figs = tuple(sorted(outdir.glob("*.png")))
    return StudyResult(outdir, report, ds, figs)


def open_dataset(path: str | Path, **kwargs) -> xr.Dataset:
    """Open a liethermo netCDF file: time in seconds (not decoded to dates),
    label variables (``axis``, ``scheme``, …) as the indexes of their
    dimensions.  Keywords go to ``xarray.open_dataset`` (e.g. ``chunks={}``
    for a lazy, chunked read of a large ensemble)."""
    return cf.open_dataset(path, **kwargs)


def open_runs(paths, *, methods=None, lazy: bool = True, derived: bool = False) -> xr.Dataset:
    """The runs of one scene by several methods (their ``.nc`` files: a list,
    or ``{method: path}``) as one Dataset with a ``method`` dimension.

    Every data variable gains ``method`` as its first dimension; a variable
    that only some methods have (e.g. the VI's ``omega_step``) is filled with
    NaN for the others (float64 then, even if it counts iterations); the
    methods' orders and steps h become coordinates along ``method``
    (``method_order``, ``h`` in s, and ``source``, the file).  Global
    attributes that differ between the files are dropped.

    Opened lazily, as ``xarray.open_mfdataset`` does: the variables are dask
    arrays read chunk by chunk when computed, so 10⁶ members do not load into
    memory.  Without dask installed (or with ``lazy=False``) the files are
    loaded into memory, with a warning when dask is missing.  ``derived``: each
    run with the variables its model derives from the stored state
    (``ds.liethermo.derived()``, in memory), before they are combined."""
    from .combine import open_runs as _open_runs

    return _open_runs(paths, methods=methods, lazy=lazy, derived=derived)
