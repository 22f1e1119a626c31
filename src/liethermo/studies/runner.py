"""``liethermo study STUDY.toml``: load, validate, dispatch, print the key table.

Invalid studies (unreadable TOML, unknown kind or keys, sweeps over unknown
scene keys, invalid scene values) are reported as one line
``liethermo: error: ...`` with exit status 2, no traceback and no output.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from ..scene import SceneError
from . import GENERIC_KINDS, get_study, is_module_kind, kinds, shipped_studies
from .common import (BASE_KEYS, STUDY_KEYS, StudyError, expand_sweep, first_table, resolve_study,
                     study_scene, terminal_table, with_scene)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

EXIT_INVALID = 2


def study_path(path: str | Path) -> Path:
    """A study file, or a study's name (``convergence``, ``convergence.toml``):
    the file ``studies/NAME.toml`` of the working folder, else the shipped one."""
    given = Path(path)
    if given.is_file() or len(given.parts) != 1:
        return given
    name = given.stem if given.suffix == ".toml" else given.name
    local = Path("studies") / f"{name}.toml"
    if local.is_file():
        return local
    return shipped_studies().get(name, given)


def load_study(path: str | Path) -> dict:
    """Parse a study file, given by its path or its name (:func:`study_path`);
    ``_source`` records its path (for relative scene files)."""
    given = path
    path = study_path(path)
    if not path.is_file():
        names = ", ".join(shipped_studies())
        raise StudyError(f"no such study file: {given}" + (f" (nor a study's name: {names})" if names else ""))
    try:
        study = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise StudyError(f"{path} is not valid TOML: {exc}") from None
    study["_source"] = str(path)
    kind = study.get("study", {}).get("kind") if isinstance(study.get("study"), dict) else None
    if isinstance(kind, str) and is_module_kind(kind):  # a study of the user's own, beside its file
        import sys

        folder = str(path.resolve().parent)
        if folder not in sys.path:
            sys.path.insert(0, folder)
    return study


def validate_study(study: dict) -> None:
    """Check kind, keys, sweeps and every sweep point's scene (full and reduced)."""
    st = study.get("study")
    if not isinstance(st, dict):
        raise StudyError("the study file needs a [study] table with kind = ...")
    kind = st.get("kind")
    if not isinstance(kind, str) or (kind not in kinds() and not is_module_kind(kind)):
        raise StudyError(f"study.kind: unknown study kind {kind!r}; known kinds: {', '.join(kinds())}, "
                         "or a module path of your own (mypkg.mystudy)")
    for k in st:
        if k not in STUDY_KEYS:
            raise StudyError(f"study.{k}: unknown key; known keys of [study]: {', '.join(sorted(STUDY_KEYS))}")
    try:
        mod = get_study(kind)
    except ModuleNotFoundError as exc:
        raise StudyError(f"study.kind: the {kind!r} study is not available ({exc})") from None
    except ValueError as exc:
        raise StudyError(f"study.kind: {exc}") from None
    decl = mod.STUDY
    from ..models import models

    names = [m.name for m in models()]
    per = study.get("model", {})
    tables = [("", study, BASE_KEYS), ("reduced.", study.get("reduced", {}), BASE_KEYS)]
    for name, sec in (per.items() if isinstance(per, dict) else [("", None)]):
        if name not in names or not isinstance(sec, dict):
            raise StudyError(f"model.{name}: must be a table named after a model ({', '.join(names)})")
        tables.append((f"model.{name}.", sec, BASE_KEYS - {"model"}))
    for where, table, allowed in tables:
        if not isinstance(table, dict):
            raise StudyError(f"{where.rstrip('.')}: must be a table")
        for k in table:
            if not k.startswith("_") and k not in allowed:
                raise StudyError(f"{where}{k}: unknown key in a {kind} study; known keys: {', '.join(sorted(allowed))}")
    for reduced in (False, True):
        s = resolve_study(study, reduced)
        if not isinstance(s.get("methods", []), list):
            raise StudyError("methods: must be a list")
        sweep = s.get("sweep", {})
        if not isinstance(sweep, dict):
            raise StudyError("sweep: must be a table of \"section.key\" = [values]")
        expand_sweep(sweep)  # refuses a key that maps to no list of values
        # every value of every sweep key must give a valid scene
        for key, values in sweep.items():
            for v in values:
                try:
                    study_scene(s, {key: v})
                except SceneError as exc:
                    raise StudyError(f"sweep {key!r}: {exc}") from None
        scene = study_scene(s, {k: v[0] for k, v in sweep.items() if v}) if sweep else study_scene(s)
        if kind in GENERIC_KINDS:  # a generic kind runs on the models that offer what it needs
            from ..models import model_of, study_support

            try:
                study_support(model_of(scene), f"the {kind} study")
            except ValueError as exc:
                raise StudyError(f"study.kind: {exc}") from None
        decl.validate(s)  # its options, methods (the scene's model knows them) and cross-option rules


def default_outdir(study: dict, reduced: bool) -> Path:
    name = study["study"].get("name") or study["study"]["kind"]
    return Path("data") / "runs" / (f"{name}-reduced" if reduced else str(name))


def run_study(study: dict, outdir: Path, *, reduced: bool = False, progress: bool | None = None,
              dask=None, history: str | None = None, notes=None) -> Path:
    """Run a validated study into ``outdir`` (locked for this process while it
    runs; what interrupted or killed studies left there is removed first,
    their finished sweep points stay and are not recomputed); returns the
    report's path.  Raises :class:`StudyError` (the folder), WriteError,
    OSError (a figure) or :class:`liethermo.faults.Interrupted`.
    ``notes(line)`` gets what is worth telling (removed leftovers)."""
    from ..faults import folder_leftovers, human_bytes, remove_files
    from ..threads import ThreadCounts, pools, usable_cores

    lock = _prepare_outdir(outdir)
    try:
        n, size = remove_files(folder_leftovers(outdir) + folder_leftovers(outdir / "points"))
        if n and notes is not None:
            notes(f"liethermo: removed {n} temporary file{'s' if n != 1 else ''} ({human_bytes(size)}) "
                  f"left by interrupted or killed runs in {outdir}")
        mod = get_study(study["study"]["kind"])
        # BLAS on one thread and the kernels on the usable cores unless a run or timing sets its own
        with pools(ThreadCounts(blas=1, kernel=usable_cores())):
            return Path(mod.STUDY.run(study, outdir, reduced=reduced, progress=progress, dask=dask,
                                      history=history))
    finally:
        lock.release()


def main_study(args) -> int:
    from ..faults import Busy, Interrupted, one_line
    from ..io import WriteError

    try:
        study = load_study(args.study)
        if getattr(args, "scene", None):
            study = with_scene(study, args.scene)
        validate_study(study)
    except (StudyError, SceneError) as exc:
        print(f"liethermo: error: {one_line(exc)}", file=sys.stderr)
        return EXIT_INVALID
    reduced = bool(getattr(args, "reduced", False))
    outdir = Path(args.outdir) if getattr(args, "outdir", None) else default_outdir(study, reduced)
    progress = False if getattr(args, "no_progress", False) else None
    t0 = time.perf_counter()
    try:
        report = run_study(study, outdir, reduced=reduced, progress=progress, dask=getattr(args, "dask", None),
                           history=getattr(args, "command_line", None),
                           notes=lambda line: print(one_line(line), file=sys.stderr))
    except (StudyError, Busy, WriteError) as exc:
        print(f"liethermo: error: {one_line(exc)}", file=sys.stderr)
        return EXIT_INVALID
    except OSError as exc:  # a figure (drawn straight to its file)
        what = f"cannot write {exc.filename or 'a figure in ' + str(outdir)}: {exc.strerror or exc}"
        print(f"liethermo: error: {one_line(what)}", file=sys.stderr)
        return EXIT_INVALID
    except Interrupted as exc:
        n = len(list((outdir / "points").glob("*.nc")))
        print(f"liethermo: interrupted by {exc.name}: {n} finished sweep point{'s' if n != 1 else ''} "
              f"kept in {outdir / 'points'} (rerun the same command to continue)", file=sys.stderr)
        return exc.exit_code
    wall = time.perf_counter() - t0
    table = first_table(report)
    if table:
        print(terminal_table(table))  # the report keeps its markdown
    print(f"study {study['study'].get('name', study['study']['kind'])!r}"
          f"{' (reduced)' if reduced else ''}: {wall:.1f} s, report {report}")
    return 0


def _prepare_outdir(outdir: Path):
    """The study's folder exists, takes files, and is locked for this process."""
    import os

    from ..faults import OutputLock

    if outdir.exists() and not outdir.is_dir():
        raise StudyError(f"cannot write the study to {outdir}: it is not a folder")
    try:
        outdir.mkdir(parents=True, exist_ok=True)
        probe = outdir / f".probe.{os.getpid()}"
        probe.touch()
        probe.unlink()
    except OSError as exc:
        raise StudyError(f"cannot write the study to {outdir}: {exc.strerror or exc}") from None
    try:
        return OutputLock(outdir, folder=True).acquire()
    except OSError as exc:
        raise StudyError(f"cannot write the study to {outdir}: {exc.strerror or exc}") from None
