"""A whole run of the paper scene against its kernels, and where the rest goes.

    python benchmarks/whole_run.py [--members 1048576] [--steps 1000] [--method rk2] [--rounds 3]

runs ``liethermo run paper`` (h = 0.01 s, ``output.every`` = steps: two stored times, the
default variables, no comparison, no figures) ``--rounds`` times into new files of a temporary
folder (replacing an existing file adds what the file system spends freeing the old one) and
prints, per round, the summary's **whole run** (simulating, labelling and writing; not
compiling, start-up or figures) and **kernel** times and their ratio.  Then, for one member
chunk, the host's parts of a run, each the best of five on this process's threads: drawing
the initial conditions, ``simulate`` outside its kernels, labelling the chunk with its summary's
figures, and writing it (CF encoding, CRC-32, netCDF, flush).  Last, the run's chunk loop on
this process with parts of it left out: drawing the initial conditions and simulating only,
then with the stored variables labelled (what the file holds, without the summary's figures),
then labelled with the summary's figures as a run does (no writing in any), each with its wall
time, kernel time and ratio: the floor a run reaches when what is left out costs nothing.  Compare two checkouts
by running it in each, interleaved, on one machine.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench import cpu_name  # run as python benchmarks/whole_run.py: benchmarks/ is on the path


def whole_runs(members: int, steps: int, method: str, rounds: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(rounds):
            cmd = [sys.executable, "-m", "liethermo", "run", "paper", "-o", str(Path(tmp) / f"p{r}.nc"),
                   "--no-progress", "--set", f"ensemble.members={members}", "--set", f"integrator.steps={steps}",
                   "--set", "integrator.h=0.01", "--set", f"output.every={steps}", "--set",
                   f'integrator.method="{method}"', "--set", "output.compare=[]", "--set", "output.figures=false"]
            out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
            wall = float(out.split("wall time ")[1].split(" s")[0])
            kern = float(out.split(" ran ")[1].split(" s")[0])
            (Path(tmp) / f"p{r}.nc").unlink()
            print(f"round {r + 1}: whole run {wall:.2f} s, kernel {kern:.2f} s, whole run / kernel {wall / kern:.2f}")


def best(f, n: int = 5, own: bool = False) -> float:
    """The least of n timings of f(): its wall time, or (``own``) the seconds it returns."""
    f()
    out = float("inf")
    for _ in range(n):
        t = time.perf_counter()
        got = f()
        out = min(out, got if own else time.perf_counter() - t)
    return out


def host_parts(members: int, method: str) -> None:
    from liethermo import load_scene
    from liethermo.io import ChunkedWriter
    from liethermo.top.initial import initial_conditions
    from liethermo.top.model import label_chunk, scene_setup
    from liethermo.top.resolve import resolve

    sc = load_scene("paper", {"ensemble.members": members, "integrator.steps": 1000, "integrator.h": 0.01,
                              "output.every": 1000, "integrator.method": method})
    n = min(members, int(sc["output"]["member_chunk"]))
    run = resolve(sc)
    om0, R0 = initial_conditions(sc, 0, n)
    traj = run.simulate(om0, R0, steps=2, every=2)
    t_ic = best(lambda: initial_conditions(sc, 0, n))
    t_sim = best(lambda: (lambda t0, s: time.perf_counter() - t0 - s.wall_time)(
        time.perf_counter(), run.simulate(om0, R0, steps=2, every=2)), own=True)
    t_label = best(lambda: label_chunk(sc, traj, om0, R0))
    ds, _ = label_chunk(sc, traj, om0, R0)
    _, attrs, _ = scene_setup(sc)
    with tempfile.TemporaryDirectory() as tmp:
        chunks = max(1, min(members // n, 8))
        w = ChunkedWriter(Path(tmp) / "w.nc", n * chunks, attrs, member_chunk=n)  # disk chunks as the run's
        t0 = time.perf_counter()
        for k in range(chunks):
            w.write(ds, k * n)
            w.sync()
        t_write = (time.perf_counter() - t0) / chunks
        w.close()
    print(f"one chunk of {n} members ({method}, two stored times), best of 5:")
    for what, t in (("initial conditions", t_ic), ("simulate outside its kernels", t_sim),
                    ("labelling and the summary's figures", t_label), ("writing (on the writer thread)", t_write)):
        print(f"  {what:38s} {t * 1e3:7.1f} ms")


def chunk_loops(members: int, steps: int, method: str) -> None:
    from liethermo import load_scene
    from liethermo.models import model_of
    from liethermo.threads import pools, usable_cores
    from liethermo.top.dataset import chunk_labels, stored_variables
    from liethermo.top.model import _simulated, label_chunk

    sc = load_scene("paper", {"ensemble.members": members, "integrator.steps": steps, "integrator.h": 0.01,
                              "output.every": steps, "integrator.method": method})
    n = int(sc["output"]["member_chunk"])
    print("the chunk loop without writing (the run's thread pools, one round each):")
    with pools(model_of(sc).thread_counts(sc, usable_cores())):
        label_chunk(sc, *_simulated(sc, 0, min(n, members)))  # compiled or loaded: not timed
        for what, label in (("initial conditions and simulate", ""), ("... and the stored variables", "variables"),
                            ("... and the summary's figures too", "all")):
            kernel, t0 = 0.0, time.perf_counter()
            for lo in range(0, members, n):
                traj, om0, R0 = _simulated(sc, lo, min(lo + n, members))  # the run's own chunk step
                kernel += traj.wall_time
                if label == "variables":  # labelled as the file stores them, no summary figures
                    chunk_labels(traj, omega0=om0, R0=R0, member_offset=lo).dataset(stored_variables(sc, traj.layout))
                elif label:
                    label_chunk(sc, traj, om0, R0, lo)
            wall = time.perf_counter() - t0
            print(f"  {what:38s} {wall:6.2f} s, kernel {kernel:.2f} s, ratio {wall / kernel:.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--members", type=int, default=2 ** 20)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--method", default="rk2")
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args()
    print(f"{cpu_name()}, {time.strftime('%Y-%m-%d')}; paper, {a.members} members x {a.steps} steps, {a.method}")
    whole_runs(a.members, a.steps, a.method, a.rounds)
    host_parts(a.members, a.method)
    chunk_loops(a.members, a.steps, a.method)


if __name__ == "__main__":
    main()
