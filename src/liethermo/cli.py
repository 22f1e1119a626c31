"""Command line: ``liethermo run SCENE [-o OUT.nc] [--set SECTION.KEY=VALUE ...]``.

Invalid input is reported as one line naming the key and the rule, with exit
status 2 and no output file; no traceback.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from pathlib import Path

from . import __version__

EXIT_INVALID = 2


def _default_out(scene: dict) -> Path:
    return Path("data") / "runs" / f"{scene['scene']['name']}.nc"


def _compare_path(out: Path, method: str) -> Path:
    return out.with_name(f"{out.stem}_{method}{out.suffix}")


def cmd_run(args) -> int:
    from .scene import SceneError, load_scene

    try:
        scene = load_scene(args.scene, args.set)
        out = Path(args.output) if args.output else _default_out(scene)
        if out.suffix != ".nc":
            raise SceneError("-o/--output", "the output file must end in .nc", str(out))
        if out.exists() and out.is_dir():
            raise SceneError("-o/--output", "is a directory", str(out))
    except SceneError as exc:
        print(f"liethermo: error: {exc}", file=sys.stderr)
        return EXIT_INVALID

    from .run import run_scene

    progress = None if not args.no_progress else False
    outputs = {scene["integrator"]["method"]: out}
    for m in scene["output"]["compare"]:
        if m != scene["integrator"]["method"]:
            outputs[m] = _compare_path(out, m)
    summaries = []
    for method, path in outputs.items():
        sc = scene.with_overrides({"integrator.method": method})
        if args.dask:
            from .distributed import run_scene_dask

            _, summ = run_scene_dask(sc, path, address=args.dask, progress=progress,
                                     keep_parts=args.keep_parts, combine=not args.no_combine,
                                     history=args.command_line)

        else:
            _, summ = run_scene(sc, path, progress=progress, history=args.command_line)
        summaries.append(summ)
        print("\n".join(summ.lines()))
        if args.dask:
            print(f"  dask: {summ.tasks} task(s), {summ.tasks_skipped} already done (resumed); "
                  f"overhead {summ.task_overhead:.3f} s per task; combine {summ.combine_time:.2f} s")
    if scene["output"]["figures"]:
        from .plotting import scene_figures

        figs = scene_figures(outputs, out.parent, stem=out.stem)
        for f in figs:
            print(f"  figure {f}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="liethermo",
        description="Structure-preserving simulation of the heavy top in Stokes flow "
        "(variational integrator vs Runge-Kutta), over ensembles of initial conditions.",
    )
    ap.add_argument("--version", action="version", version=f"liethermo {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run a scene and write a netCDF dataset",
                       description="Run SCENE (a TOML file or the built-in 'paper') and write a netCDF "
                       "dataset (default: data/runs/<scene name>.nc). Methods listed in output.compare "
                       "are run too and written next to it as <OUT>_<method>.nc.")
    r.add_argument("scene", metavar="SCENE", help="TOML scene file, or 'paper'")
    r.add_argument("-o", "--output", metavar="OUT.nc", help="output netCDF path")
    r.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[],
                   help="override a scene key with a TOML value, e.g. --set integrator.h=0.05 "
                   "--set 'initial.omega=[2,-1,0.5]' (repeatable)")
    r.add_argument("--no-progress", action="store_true", help="no progress bar")
    r.add_argument("--dask", metavar="local|ADDRESS", default=None,
                   help="run member chunks as tasks on a Dask cluster: 'local' starts a LocalCluster "
                   "sized to this machine, otherwise the scheduler address (tcp://host:8786)")
    r.add_argument("--keep-parts", action="store_true",
                   help="with --dask: keep the per-task chunk files (OUT.nc.parts/) after combining")
    r.add_argument("--no-combine", action="store_true",
                   help="with --dask: leave the chunk files and their index.json (open_mfdataset-ready) "
                   "instead of one combined file")
    r.set_defaults(func=cmd_run)

    s = sub.add_parser("study", help="run a study (sweeps, convergence tables, statistics, figures)",
                       description="Run a study file from studies/ and write its folder: netCDF, "
                       "markdown report with tables (and CSV copies), PNG figures. An interrupted "
                       "study resumes: finished sweep points are not recomputed.")
    s.add_argument("study", metavar="STUDY.toml", help="study definition, e.g. studies/convergence.toml")
    s.add_argument("-o", "--outdir", metavar="DIR", help="output folder (default data/runs/<study name>)")
    s.add_argument("--reduced", action="store_true", help="reduced-size mode (what the test suite runs)")
    s.add_argument("--no-progress", action="store_true", help="no progress bar")
    s.add_argument("--dask", metavar="local|ADDRESS", default=None,
                   help="run sweep points as tasks on a Dask cluster ('local' or a scheduler address)")
    s.set_defaults(func=cmd_study)

    k = sub.add_parser("keys", help="list every scene key with its unit, default and rule",
                       description="Print every scene key with its unit, default, rule and meaning "
                       "(the tables of docs/scenes.md, as plain text).")
    k.add_argument("--markdown", action="store_true",
                   help="print docs/scenes.md instead (introduction, built-in scenes, key tables)")
    k.set_defaults(func=cmd_keys)
    return ap


def cmd_keys(args) -> int:
    from .scene import keys_table, scenes_markdown

    sys.stdout.write(scenes_markdown() if args.markdown else keys_table(markdown=False))
    return 0


def cmd_study(args) -> int:
    from .studies.runner import main_study

    return main_study(args)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    # what the files' 'history' attribute records
    args.command_line = shlex.join(["liethermo", *argv])
    return args.func(args)


def entry() -> None:
    """The ``liethermo`` console script: :func:`main` with numba at -O2, then exit.

    After ``liethermo run`` (without ``--dask``) the process leaves with
    ``os._exit`` once its output is flushed: every file it wrote is closed by
    then, and the interpreter's own teardown (module and LLVM clean-up, no
    effect outside the process) took ~0.7 s of a ~4 s warm
    ``liethermo run paper`` on the 2-core benchmark machine."""
    # LLVM -O2 instead of numba's default -O3 for the kernels this command
    # compiles: a cold `liethermo run paper` compiles in ~22 s instead of ~28 s
    # on the 2-core benchmark VM, the kernels run as fast (liethermo bench: VI
    # 12.2 / RK2 1.76 / RK4 7.0 ns against 12.3 / 1.77 / 7.5), and the results are
    # bitwise the same (no fast-math: every optimization level must keep IEEE
    # semantics; checked on VI, RK2 and RK4 ensembles).  Set here, before numba
    # is imported, so only this process is affected; a NUMBA_OPT of the user's
    # own wins.
    os.environ.setdefault("NUMBA_OPT", "2")
    argv = sys.argv[1:]
    rc = main(argv)
    if argv[:1] == ["run"] and "--dask" not in argv:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(rc or 0)
    sys.exit(rc)


if __name__ == "__main__":  # pragma: no cover
    entry()
