"""Kernel benchmark: ``python benchmarks/bench.py`` (same as ``liethermo bench``).

Prints a table (ns per member-step, wall time with all cores, for the VI,
RK2 and RK4 at 4096 and 65536 members x 1000 steps keeping every 100th step,
fast kernel against the straightforward one-member-per-iteration prange
kernel, agreement, memory, start-up) and writes benchmarks/results.json.
Options: ``python benchmarks/bench.py --help``.
"""

from __future__ import annotations

import os
import sys

if __name__ == "__main__":
    os.environ.setdefault("NUMBA_OPT", "2")  # as the liethermo console script (see cli.entry)
    argv = sys.argv[1:]
    if not any(a == "--json" or a.startswith("--json=") for a in argv):
        argv += ["--json", os.path.join(os.path.dirname(os.path.abspath(__file__)), "results.json")]
    from liethermo.bench import main  # after NUMBA_OPT is set: numba reads it on import

    raise SystemExit(main(argv))
