"""tools/golden.py records a case's arrays, finds them identical on a second
run, and reports the first variable that differs (exit status 1)."""

import importlib.util
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _golden():
    spec = importlib.util.spec_from_file_location("golden", ROOT / "tools" / "golden.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_golden_record_compare_and_a_difference(tmp_path, capsys):
    golden = _golden()
    names = [c[0] for c in golden.cases()]
    assert "paper__vi__fast" in names and "zeitlin_decay__split__-" in names
    case = "zeitlin_decay__split__-"
    assert golden.main(["record", str(tmp_path), "--only", case]) == 0
    assert golden.main(["compare", str(tmp_path), "--only", case, "--attrs"]) == 0
    assert f"{case}: identical" in capsys.readouterr().out

    path = tmp_path / f"{case}.npz"
    with np.load(path) as f:
        arrays = {k: f[k] for k in f.files}
    name = next(k for k in sorted(arrays) if k.startswith("data:") and arrays[k].dtype.kind == "f")
    arrays[name] = arrays[name].copy()
    old = arrays[name].flat[-1]
    arrays[name].flat[-1] = old + max(abs(old), 1.0) * 1e-3 if np.isfinite(old) else 0.0
    np.savez(path, **arrays)
    assert golden.main(["compare", str(tmp_path), "--only", case]) == 1
    out = capsys.readouterr().out
    assert f"{case}: DIFFERS: {name}: max abs diff" in out and "1 of " in out
