"""The layering contract (``[tool.importlinter]`` in pyproject.toml): the run
layer, the scene base, the registry, the API and command line, the shared
numerics and the studies framework import no model package, and the models
import none of one another.  import-linter reads every import, those inside
functions included; a copy of the package with one forbidden import shows
that the check can fail."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytest.importorskip("importlinter")


def _lint(src: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(src))
    return subprocess.run([sys.executable, "-c", "from importlinter.cli import lint_imports_command; "
                           "lint_imports_command()", "--config", str(ROOT / "pyproject.toml"), "--no-cache"],
                          capture_output=True, text=True, env=env, cwd=ROOT)


def test_the_run_layer_imports_no_model():
    r = _lint(ROOT / "src")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "2 kept, 0 broken" in r.stdout


@pytest.mark.parametrize("module, line", [
    ("studies/framework.py", "    from ..top.methods import METHODS\n"),   # inside a function
    ("runner.py", "from .zeitlin import run as _zr  # noqa\n"),
    ("zeitlin/model.py", "from ..top import physics as _ph  # noqa\n"),
])
def test_a_forbidden_import_breaks_the_contract(tmp_path, module, line):
    src = tmp_path / "src"
    shutil.copytree(ROOT / "src" / "liethermo", src / "liethermo",
                    ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    path = src / "liethermo" / module
    text = path.read_text()
    if line.startswith("    "):
        i = text.index("\ndef ") + 1
        j = text.index("\n", text.index(":\n", i)) + 1  # after the first function's signature
        text = text[:j] + line + text[j:]
    else:
        i = text.index("\nfrom ") + 1
        text = text[:i] + line + text[i:]
    path.write_text(text)
    r = _lint(src)
    assert r.returncode != 0 and "BROKEN" in r.stdout, r.stdout + r.stderr
