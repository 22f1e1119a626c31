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

from .version import __version__

EXIT_INVALID = 2  # invalid input, refused run, failed write: one line on stderr
#: flags that do not change what a command writes, left out of the files' history
NOT_IN_HISTORY = {"--resume", "--force", "--no-progress"}
#: a run its model times before it starts (``Model.long_run``) prints the
#: estimate when it exceeds this
LONG_RUN_SECONDS = 60.0


def _error(msg) -> int:
    from .faults import one_line

    print(f"liethermo: error: {one_line(msg)}", file=sys.stderr)
    return EXIT_INVALID


def cmd_run(args) -> int:
    from .preflight import PreflightError, prepare_run
    from .scene import SceneError, load_scene

    try:
        scene = load_scene(args.scene, args.set + ([f'ensemble.device="{args.device}"'] if args.device else []))
        if args.resume and args.force:
            raise PreflightError("--resume keeps what an earlier run left and --force replaces it: "
                                 "give one of them")
        plan = prepare_run(scene, args.output, force=args.force, resume=args.resume,
                           dask=bool(args.dask), combine=not args.no_combine, clean=not args.check,
                           warn_conflicts=args.check, list_problems=args.check)
    except (SceneError, PreflightError) as exc:
        return _error(exc)
    try:
        from .faults import one_line

        for line in plan.notes:
            print(one_line(line), file=sys.stderr)
        if args.check:
            from .runner import estimate_time

            print(f"scene {scene['scene']['name']!r} is valid: {plan.check_line()}")
            for o in plan.outputs:
                if not o.skip and not args.dask:
                    est = estimate_time(o.scene, o.path)
                    print(est.line())
                    for w in est.warnings():
                        print(one_line(w), file=sys.stderr)
            plan.release()
            plan.remove_created()
            # every estimate is out; then every problem that would refuse the run
            for problem in plan.problems:
                _error(problem)
            return EXIT_INVALID if plan.problems else 0
        return _run_outputs(args, scene, plan)
    finally:
        plan.release()


def _run_outputs(args, scene, plan) -> int:
    from . import api
    from .faults import Interrupted, join_checking
    from .io import WriteError
    from .models import model_of

    progress = None if not args.no_progress else False
    written = []
    todo = [o for o in plan.outputs if not o.skip]
    # a second process compiles the kernels of the later methods (and the
    # variational integrators' start) into the cache while this one compiles the first
    warming = (None if (args.dask or not todo)
               else model_of(scene).warm(scene, [o.method for o in todo], progress))
    try:
        _announce_long_runs(todo, args)
        for i, o in enumerate(todo):
            if i == 1 and warming is not None:
                join_checking(warming)  # its kernels are in the cache now
            if args.dask:
                from .distributed import run_scene_dask

                _, summ = run_scene_dask(o.scene, o.path, address=args.dask, progress=progress,
                                         keep_parts=args.keep_parts, combine=not args.no_combine,
                                         history=args.command_line)
                lines = summ.lines() + [
                    f"  dask: {summ.tasks} task(s), {summ.tasks_skipped} already done (resumed); "
                    f"overhead {summ.task_overhead:.3f} s per task; combine {summ.combine_time:.2f} s"]
            else:
                # one method into its checked output; the figures of all of them are drawn below
                ds = api._run_one(o.scene.with_overrides({"output.compare": []}), o.path, progress=progress,
                                  force=False, resume=plan.resume_sources.get(o.path, False),
                                  preflight=False, history=args.command_line)
                lines = ds.attrs["summary"].splitlines()
                ds.close()
            written.append(str(o.path))
            print("\n".join(lines))
        if warming is not None and warming.is_alive():
            warming.terminate()  # what it still compiles, this run no longer needs
        if scene["output"]["figures"] and not (args.dask and args.no_combine):
            # named as the primary file: a run of another method cannot replace them
            stem = plan.outputs[0].path.stem
            for f in _figures(plan, stem):
                print(f"  figure {f}")
    except WriteError as exc:
        return _error(exc)
    except Interrupted as exc:
        from .faults import one_line

        done = [f"{w} written" for w in written] + exc.kept
        print(one_line(f"liethermo: interrupted by {exc.name}: {'; '.join(done) or 'nothing written'}"),
              file=sys.stderr)
        return exc.exit_code
    finally:
        if warming is not None and warming.is_alive():
            warming.terminate()
    return 0


def _announce_long_runs(todo, args) -> None:
    """A run that will take minutes or hours says so before it starts."""
    from .faults import one_line
    from .models import model_of
    from .runner import estimate_time

    if args.dask:
        return
    for o in todo:
        sc = o.scene
        if not model_of(sc).long_run(sc):
            continue
        est = estimate_time(sc)
        if est.seconds > LONG_RUN_SECONDS:
            print(one_line(f"liethermo: {o.path}: {est.line().strip()}"), file=sys.stderr)
        for w in est.cautions():
            print(one_line(w), file=sys.stderr)


def _figures(plan, stem: str) -> list[Path]:
    """The run's figures, next to its first output (see :func:`liethermo.api._draw_figures`)."""
    from .api import _draw_figures

    return _draw_figures({o.method: o.path for o in plan.outputs}, stem, plan.outputs[0].scene)


class _Parser(argparse.ArgumentParser):
    """argparse with its errors in one line (an unknown flag, a missing
    argument), like every other refusal: no usage block, exit status 2."""

    def error(self, message):
        from .faults import one_line

        self.exit(EXIT_INVALID, one_line(f"{self.prog}: error: {message} (see {self.prog} --help)") + "\n")


def build_parser() -> argparse.ArgumentParser:
    from .models import model_of, models
    from .scene_files import builtin_scene_tables

    tables = builtin_scene_tables()
    ms = models()
    owner = {n: model_of(t) for n, t in tables.items()}
    builtins = "; ".join(f"{m.title}: {', '.join(sorted(n for n in tables if owner[n] is m))}"
                         for m in ms if any(owner[n] is m for n in tables))
    ap = _Parser(
        prog="liethermo",
        description="Structure-preserving simulation of thermodynamic systems on Lie groups, over "
        f"ensembles of initial conditions: {' and '.join(m.description for m in ms)}.",
    )
    ap.add_argument("--version", action="version", version=f"liethermo {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run a scene and write a netCDF dataset",
                       description="Run SCENE (a TOML file or a built-in scene) and write a netCDF "
                       "dataset per method: data/runs/<scene name>_<method>.nc, or with -o OUT.nc that "
                       "file for the scene's method and <OUT>_<method>.nc next to it for the methods "
                       "in output.compare; figures are named after the first file (<OUT>_*.png). "
                       "An existing output is replaced only by a run of the same "
                       "scene (or with --force). Ctrl-C, SIGTERM and SIGHUP stop the run cleanly; "
                       "--resume continues it.")
    r.add_argument("scene", metavar="SCENE", help=f"TOML scene file, or a built-in scene: {builtins}")
    r.add_argument("-o", "--output", metavar="OUT.nc", help="output netCDF path (folders that do not exist are created)")
    r.add_argument("--resume", action="store_true",
                   help="continue an interrupted or killed run of the same scene from its last complete "
                   "member chunk (outputs already complete are kept)")
    r.add_argument("--force", action="store_true",
                   help="replace existing outputs even if they hold runs of another scene")
    r.add_argument("--check", action="store_true",
                   help="only check: validate the scene and the outputs, estimate disk, memory and "
                   "kernel time (from a short timed probe), and exit")
    r.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[],
                   help="override a scene key with a TOML value, e.g. --set integrator.h=0.05 "
                   "--set 'initial.omega=[2,-1,0.5]' (repeatable)")
    r.add_argument("--device", choices=("cpu", "gpu"), default=None,
                   help="where the steps run (the scene key ensemble.device): gpu on a CUDA device, "
                   "refused before any work where none can run them")
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

    from .studies import kinds, shipped_studies

    s = sub.add_parser("study", help="run a study (sweeps, convergence tables, statistics, figures)",
                       description="Run a study file from studies/ and write its folder: netCDF, "
                       "markdown report with tables (and CSV copies), PNG figures. An interrupted "
                       "study resumes: finished sweep points are not recomputed.",
                       epilog=f"study files shipped: {', '.join(shipped_studies()) or 'none here'}. "
                       f"Study kinds: {', '.join(kinds())}, or a module of your own "
                       "(kind = \"mypackage.mystudy\", docs/extending.md).")
    s.add_argument("study", metavar="STUDY.toml",
                   help="study file, e.g. studies/convergence.toml, or a study's name (convergence: "
                   "studies/convergence.toml here, else the one shipped with liethermo)")
    s.add_argument("-o", "--outdir", metavar="DIR",
                   help="output folder (default data/runs/<study name>, data/runs/<study name>-reduced with --reduced)")
    s.add_argument("--reduced", action="store_true", help="reduced-size mode (what the test suite runs)")
    s.add_argument("--scene", metavar="SCENE", default=None,
                   help="run the study on another base scene (a built-in scene or a scene file; the study "
                        "file's [model.<name>] table for that scene's model applies)")
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

    if args.markdown:
        sys.stdout.write(scenes_markdown())
        return 0
    from .models import UNMARKED_SCENES_MODEL, models

    parts = []  # the keys of a scene without a model's table first, then each model's under its title
    for m in sorted(models(), key=lambda m: m.name != UNMARKED_SCENES_MODEL):
        head = "" if m.name == UNMARKED_SCENES_MODEL else f"\n# {m.scene_model.title}\n\n"
        parts.append(head + keys_table(markdown=False, keys=m.keys()))
    sys.stdout.write("".join(parts))
    return 0


def cmd_study(args) -> int:
    from .studies.runner import main_study

    return main_study(args)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    # what the files' 'history' attribute records: the command that makes the
    # data, without the flags that do not change it (a resumed file then says
    # what an uninterrupted run's does)
    args.command_line = shlex.join(["liethermo", *[a for a in argv if a not in NOT_IN_HISTORY]])
    if args.command not in ("run", "study"):
        return args.func(args)
    import signal

    from .faults import Interrupted, stop_on_signals, stop_received, stopping

    if hasattr(signal, "SIGXFSZ"):
        # past a file-size limit, writes fail with EFBIG (reported) instead of killing the process
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    with stop_on_signals():
        try:
            rc = args.func(args)
        except Interrupted as exc:  # before any output was started
            print(f"liethermo: interrupted by {exc.name}: nothing written", file=sys.stderr)
            return exc.exit_code
        late = stop_received()
        if late is not None and not stopping():  # after the last check: the work is complete
            exc = Interrupted(late)
            print(f"liethermo: interrupted by {exc.name} as the command finished (its outputs are "
                  "complete)", file=sys.stderr)
            return exc.exit_code
        return rc


def entry() -> None:
    """The ``liethermo`` console script: :func:`main` with numba at -O2, then exit.

    After ``liethermo run`` (without ``--dask``) the process leaves with
    ``os._exit`` once its output is flushed: every file it wrote is closed by
    then, and the interpreter's own teardown (module and LLVM clean-up, no
    effect outside the process) is a noticeable part of a warm run."""
    # LLVM -O2 instead of numba's default -O3 for the kernels this command
    # compiles: a shorter cold start, kernels as fast (benchmarks/README.md) and
    # bitwise the same results (no fast-math: every optimization level keeps IEEE
    # semantics).  Set here, before anything is compiled, so only this process
    # is affected; a NUMBA_OPT of the user's own wins.  (The model terms are
    # declared with numba, so numba is imported already: its configuration is
    # read again from the environment.)
    os.environ.setdefault("NUMBA_OPT", "2")
    if "numba" in sys.modules:
        sys.modules["numba"].core.config.reload_config()
    argv = sys.argv[1:]
    rc = main(argv)
    if argv[:1] == ["run"] and "--dask" not in argv:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(rc or 0)
    sys.exit(rc)


if __name__ == "__main__":  # pragma: no cover
    entry()
