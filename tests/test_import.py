"""Importing liethermo compiles no kernel (issue 4: fast start)."""

import subprocess
import sys


def test_import_compiles_nothing():
    code = """
import numba.core.dispatcher as d
import liethermo, liethermo.cli, liethermo.scene, liethermo.simulate, liethermo.run
from liethermo.kernels import ensemble, vi, rk, so3, model
import liethermo.kernels.fast as fast
jitted = [obj for mod in (ensemble, vi, rk, so3, model, fast) for obj in vars(mod).values()
          if isinstance(obj, d.Dispatcher)]
assert len(jitted) > 10, len(jitted)
compiled = [f.py_func.__name__ for f in jitted if f.signatures]
assert not compiled, compiled
print('OK', len(jitted))
"""
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0 and "OK" in p.stdout, p.stdout + p.stderr
