"""How far two kernels' costs can be told apart on this machine.

``python benchmarks/timing_noise.py`` times the paper scene's ``vi`` and ``rk4``
(``--members`` members of the scene's own ensemble, ``--steps`` steps, keeping
the last state) with :func:`liethermo.timing.measure`: one warm-up call
each (compilation or the numba cache), then ``--repeats`` interleaved rounds in
rotated order, numba and BLAS pinned to ``--threads`` threads.  A sample is the
kernel time the run reports (``Trajectory.wall_time``).  It prints per method the
best, median and spread (median / best − 1) of the whole run and per member-step,
the samples, and the ranking: an order only where the gap between two bests
exceeds the larger spread and ``NOISE_FLOOR`` (2 %), else a tie within noise.  ``--twin`` adds a second,
independent copy of the first method (``vi'``): a control that should tie with it.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("NUMBA_OPT", "2")  # as the liethermo console script (numba reads it on import)

from bench import cpu_name  # noqa: E402  (run as python benchmarks/timing_noise.py: benchmarks/ is on the path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--methods", nargs="+", default=["vi", "rk4"])
    ap.add_argument("--members", type=int, default=1024)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--twin", action="store_true", help="time the first method twice, as a control")
    args = ap.parse_args(argv)

    from liethermo.top.initial import initial_conditions
    from liethermo.top.resolve import resolve
    from liethermo.scene import load_scene
    from liethermo.timing import describe, format_seconds, measure

    def candidate(method: str):
        scene = load_scene("paper", {"ensemble.members": args.members, "integrator.steps": args.steps,
                                     "integrator.method": method, "output.every": args.steps})
        run = resolve(scene)
        om0, R0 = initial_conditions(scene)
        return lambda: run.simulate(om0, R0, threads=args.threads).wall_time

    candidates = {m: candidate(m) for m in args.methods}
    if args.twin:
        candidates[args.methods[0] + "'"] = candidate(args.methods[0])
    costs = measure(candidates, repeats=args.repeats, threads=args.threads)
    member_steps = args.members * args.steps
    print(f"{cpu_name()}, {os.cpu_count()} logical CPUs; paper scene, {args.members} members × "
          f"{args.steps} steps, {args.threads} thread(s), {args.repeats} interleaved rounds")
    print(f"{'method':<8}{'best':>10}{'median':>10}{'spread':>8}{'best ns/member-step':>22}  samples (ms)")
    for m, c in costs.items():
        samples = " ".join(f"{1e3 * s:.3g}" for s in c.samples)
        print(f"{m:<8}{format_seconds(c.best):>10}{format_seconds(c.median):>10}{100 * c.spread:>7.1f}%"
              f"{1e9 * c.per(member_steps).best:>22.1f}  {samples}")
    print("rank:", describe(costs))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
