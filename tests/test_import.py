"""Importing liethermo compiles no kernel, and the kernel cache never runs stale code."""

import re
import subprocess
import sys
from pathlib import Path


def test_import_compiles_nothing():
    code = """
import numba.core.dispatcher as d
import liethermo, liethermo.cli, liethermo.scene, liethermo.top.simulate, liethermo.runner
from liethermo.top.kernels import simple, vi, rk, so3, equations, gen
import liethermo.top.kernels.fast as fast
jitted = [obj for mod in (simple, vi, rk, so3, equations, gen, fast) for obj in vars(mod).values()
          if isinstance(obj, d.Dispatcher)]
assert len(jitted) > 10, len(jitted)
compiled = [f.py_func.__name__ for f in jitted if f.signatures]
assert not compiled, compiled
print('OK', len(jitted))
"""
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0 and "OK" in p.stdout, p.stdout + p.stderr


def test_import_and_help_are_light():
    """``import liethermo`` and ``liethermo --help`` load neither xarray nor numba (each a
    sizeable part of a second); ``ds.liethermo`` exists as soon as xarray is imported,
    whichever comes first, and the public names load on first use."""
    code = """
import sys
import liethermo
from liethermo.cli import build_parser
build_parser().format_help()
heavy = [m for m in ("xarray", "numba", "scipy", "matplotlib", "pandas") if m in sys.modules]
assert not heavy, heavy
import xarray as xr
assert hasattr(xr.Dataset(), "liethermo")
assert liethermo.run.__module__ == "liethermo.api" and "run" in dir(liethermo)
assert callable(liethermo.load_scene) and issubclass(liethermo.SceneError, Exception)
print('OK')
"""
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0 and "OK" in p.stdout, p.stdout + p.stderr
    code_after = "import xarray as xr, liethermo; assert hasattr(xr.Dataset(), 'liethermo'); print('OK')"
    p = subprocess.run([sys.executable, "-c", code_after], capture_output=True, text=True)
    assert p.returncode == 0 and "OK" in p.stdout, p.stdout + p.stderr


def test_stale_kernel_cache_is_dropped(tmp_path, monkeypatch):
    """numba checks only the defining file of a cached function; liethermo stamps a hash of
    all kernel sources beside the cache and drops the cache when any source changes."""
    import numba

    from liethermo.top.kernels._jit import _drop_stale_cache

    monkeypatch.setattr(numba.config, "CACHE_DIR", "")
    (tmp_path / "terms").mkdir()
    (tmp_path / "terms" / "gravity.py").write_text("x = 1\n")
    (tmp_path / "model.py").write_text("x = 1\n")
    (tmp_path / "terms" / "__pycache__").mkdir()
    (tmp_path / "terms" / "__pycache__" / "gravity.g-1.py311.nbi").write_text("fresh")
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    (cache / "ensemble.f-1.py311.nbi").write_text("fresh")
    _drop_stale_cache(tmp_path)                       # no stamp yet: adopted and stamped
    assert (cache / "liethermo-kernels.sha256").exists()
    assert (cache / "ensemble.f-1.py311.nbi").exists()
    _drop_stale_cache(tmp_path)                       # sources unchanged: kept
    assert (cache / "ensemble.f-1.py311.nbi").exists()
    (tmp_path / "terms" / "gravity.py").write_text("x = 2\n")   # a term's source changes
    _drop_stale_cache(tmp_path)
    assert not (cache / "ensemble.f-1.py311.nbi").exists()
    assert not (tmp_path / "terms" / "__pycache__" / "gravity.g-1.py311.nbi").exists()


def test_cache_guard_targets_numbas_own_folder(tmp_path, monkeypatch):
    """With NUMBA_CACHE_DIR the guard touches exactly the folder numba uses for the kernels
    (so a shared cache directory's other projects are never deleted)."""
    from pathlib import Path

    import numba
    from numba.core.caching import _CacheLocator

    import liethermo.top.kernels.simple as simple
    from liethermo.top.kernels._jit import _cache_dirs

    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path))
    here = Path(simple.__file__).resolve().parent
    expected = [tmp_path / _CacheLocator.get_suitable_cache_subpath(str(here / "simple.py")),
                tmp_path / _CacheLocator.get_suitable_cache_subpath(str(here / "terms" / "gravity.py"))]
    assert _cache_dirs(here) == expected


def test_generated_code_is_named_readable_and_dumpable(tmp_path):
    """Generated source has a file name that says what it is, tracebacks show
    its lines, and LIETHERMO_DUMP_SOURCE writes every piece a run compiles."""
    import linecache
    import os
    import subprocess
    import sys
    import traceback

    from liethermo.top.kernels.gen import compile_source

    f = compile_source("def impl(x):\n    return 1.0 / x\n", {}, label="demo reciprocal")
    try:
        f(0.0)
    except ZeroDivisionError as exc:
        frame = traceback.extract_tb(exc.__traceback__)[-1]
    assert frame.filename.startswith("<liethermo-generated demo reciprocal #")
    assert frame.line == "return 1.0 / x"
    assert linecache.getline(frame.filename, 2).strip() == "return 1.0 / x"

    code = ("from liethermo import run\n"
            "run('paper', {'integrator.steps': 5, 'integrator.method': 'rk4'}, compare=False)\n")
    env = dict(os.environ, LIETHERMO_DUMP_SOURCE=str(tmp_path / "src"), LIETHERMO_NUMBA_CACHE="0")
    subprocess.run([sys.executable, "-c", code], check=True, env=env, capture_output=True)
    names = sorted(p.name for p in (tmp_path / "src").glob("*.py"))
    assert any(n.startswith("explicit_step_ClassicalRK4") for n in names), names
    assert any(n.startswith("unflatten_") for n in names), names
    assert any(n.startswith("tree_fma_") for n in names), names
    text = next((tmp_path / "src").glob("explicit_step_ClassicalRK4*.py")).read_text()
    assert "# <liethermo-generated explicit_step ClassicalRK4 #" in text and "rk_rhs(model" in text

    # with the dump, a traceback names the dumped file, whose line is the one that failed
    code = ("from liethermo.top.kernels.gen import compile_source\n"
            "f = compile_source('def impl(x):\\n    return 1.0 / x\\n', {}, label='demo reciprocal')\n"
            "f(0.0)\n")
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    m = re.search(r'File "([^"]+demo_reciprocal-\d+\.py)", line (\d+)', res.stderr)
    assert m, res.stderr
    lines = Path(m.group(1)).read_text().splitlines()
    assert lines[int(m.group(2)) - 1].strip() == "return 1.0 / x"
