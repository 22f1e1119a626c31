"""Golden check: are the datasets of every built-in scene unchanged?

    PYTHONPATH=src python tools/golden.py record DIR     # before a change
    PYTHONPATH=src python tools/golden.py compare DIR    # after it: exit 1 on any difference

``record`` runs every built-in scene (``src/liethermo/scenes/*.toml``) of
both models, small (a few members, a few hundred steps, a small N for the
fluid), under every method its model offers and, for the heavy top, every
ensemble loop (``simple``, ``fast`` and ``auto``), and writes each case's
data variables and coordinates to ``DIR/<scene>__<method>__<kernel>.npz``
(attributes to a JSON beside it).  ``compare`` runs the same cases again and
prints, per case, ``identical`` or the first differing variable with its
largest absolute and relative difference.  NaNs compare equal to NaNs in
the same places.  Attributes are compared only with ``--attrs`` (a renamed
scene key changes the stored scene text, not the numbers).

``--only SUBSTRING`` keeps the cases whose name contains it (repeatable);
``--list`` prints the cases.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("NUMBA_OPT", "2")  # as the console script: the kernels it caches are the ones runs load

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "src" / "liethermo" / "scenes"

TOP_METHODS = ("vi", "vi4", "vi6", "split", "split4", "split6", "rk2", "rk4", "reference")
TOP_KERNELS = ("simple", "fast", "auto")
#: small enough that every case takes well under a second once compiled
TOP_SIZE = {"ensemble.members": 5, "integrator.steps": 200, "output.every": 10,
            "output.compare": [], "output.figures": False}
FLUID_SIZE = {"zeitlin.N": 8, "ensemble.members": 2, "integrator.steps": 100, "output.every": 10,
              "output.compare": [], "output.figures": False, "initial.lmax": 4}
#: the integrator's variants, on the scenes named: (method, {key: value})
TOP_VARIANTS = {
    "paper": (("vi", {"integrator.start": "legendre"}), ("vi", {"integrator.start": "staggered"}),
              ("vi", {"integrator.friction": "endpoint"}), ("vi", {"integrator.entropy": "symmetric"}),
              ("vi4", {"integrator.composition": "triple_jump"}),
              ("split4", {"integrator.composition": "triple_jump"})),
    "coupled_egg": (("vi", {"integrator.start": "node"}), ("vi", {"integrator.start": "staggered"}),
                    ("vi", {"integrator.entropy": "explicit"}), ("vi", {"integrator.friction": "endpoint"})),
}
#: the reference (DOP853) and the compositions of order 6 cost more per step
FLUID_STEPS = {"reference": 20}


def _fluid_methods() -> tuple[str, ...]:
    try:
        from liethermo.zeitlin.scene import METHODS
        return tuple(METHODS)
    except ImportError:
        return ("split", "split4", "split6", "rk4", "reference")


def _variant_name(method: str, extra: dict) -> str:
    return method + "".join(f".{k.split('.')[-1]}={v}" for k, v in extra.items())


def cases() -> list[tuple[str, str, str, str]]:
    """(case name, scene name, method, kernel) of every case, fluid kernels "-";
    a method may carry variants after dots ("vi.start=staggered")."""
    import tomllib

    out = []
    for path in sorted(SCENES.glob("*.toml")):
        tables = tomllib.loads(path.read_text())
        name = path.stem
        if "zeitlin" in tables:
            for m in _fluid_methods():
                out.append((f"{name}__{m}__-", name, m, "-"))
        else:
            for m in TOP_METHODS:
                for k in TOP_KERNELS:
                    if m == "reference" and k != "simple":
                        continue  # the reference has one ensemble loop
                    out.append((f"{name}__{m}__{k}", name, m, k))
            for m, extra in TOP_VARIANTS.get(name, ()):
                for k in ("simple", "fast"):
                    v = _variant_name(m, extra)
                    out.append((f"{name}__{v}__{k}", name, v, k))
    return out


def _fluid_overrides(scene: str, method: str) -> dict:
    ov = dict(FLUID_SIZE)
    ov["integrator.method"] = method
    if method in FLUID_STEPS:
        ov["integrator.steps"] = FLUID_STEPS[method]
    return ov


def run_case(scene: str, method: str, kernel: str):
    """The in-memory dataset of one case."""
    import liethermo

    if kernel == "-":
        return liethermo.run(scene, _fluid_overrides(scene, method), compare=False, figures=False)
    from liethermo.runner import run_scene

    method, *variants = method.split(".")
    extra = {f"integrator.{v.split('=')[0]}": v.split("=")[1] for v in variants}
    sc = liethermo.load_scene(scene, dict(TOP_SIZE, **{"integrator.method": method}, **extra))
    ds, _ = run_scene(sc, kernel=kernel, progress=False, history="golden")
    return ds


def _refusal(scene: str, method: str, kernel: str):
    """(dataset, None), or (None, the one-line message) when the scene refuses the method."""
    from liethermo.scene import SceneError

    try:
        return run_case(scene, method, kernel), None
    except SceneError as exc:
        return None, str(exc).splitlines()[0]


def _arrays(ds) -> dict[str, np.ndarray]:
    """Data variables and coordinates, named ``data:NAME`` / ``coord:NAME``."""
    out = {}
    for kind, group in (("coord", ds.coords), ("data", ds.data_vars)):
        for n in sorted(group):
            out[f"{kind}:{n}"] = np.asarray(group[n].values)
    return out


#: dataset attributes that change from run to run (times, the machine, the command)
RUN_ATTRS = ("history", "summary", "created", "date_created", "python", "software_version")


def _varies(name: str) -> bool:
    return name in RUN_ATTRS or name.endswith(("_seconds", "_time"))


def _attrs(ds) -> dict:
    def plain(v):
        if isinstance(v, np.ndarray):
            return v.tolist()
        if isinstance(v, np.generic):
            return v.item()
        return v
    a = {"": {k: plain(v) for k, v in ds.attrs.items() if not _varies(k)}}
    for n in list(ds.coords) + list(ds.data_vars):
        a[str(n)] = {k: plain(v) for k, v in ds[n].attrs.items()}
    return json.loads(json.dumps(a, default=str))


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    if a.dtype.kind in "fc":
        return a.tobytes() == b.tobytes() or bool(np.array_equal(a, b, equal_nan=True)
                                                  and np.array_equal(np.signbit(a.real), np.signbit(b.real)))
    return bool(np.array_equal(a, b))


def _difference(name: str, a: np.ndarray, b: np.ndarray) -> str:
    if a.shape != b.shape:
        return f"{name}: shape {a.shape} -> {b.shape}"
    if a.dtype != b.dtype:
        return f"{name}: dtype {a.dtype} -> {b.dtype}"
    if a.dtype.kind not in "fciu":
        n = int(np.count_nonzero(a != b))
        return f"{name}: {n} of {a.size} values differ"
    a64, b64 = a.astype(np.complex128 if a.dtype.kind == "c" else np.float64), \
        b.astype(np.complex128 if b.dtype.kind == "c" else np.float64)
    nan_a, nan_b = np.isnan(a64), np.isnan(b64)
    if (nan_a != nan_b).any():
        return f"{name}: NaN in different places ({int(np.count_nonzero(nan_a != nan_b))} values)"
    both = ~nan_a
    d = np.abs(a64[both] - b64[both])
    scale = np.abs(a64[both])
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(scale > 0, d / scale, np.where(d > 0, np.inf, 0.0))
    n = int(np.count_nonzero(d)) if d.size else 0
    return (f"{name}: max abs diff {d.max(initial=0.0):.3e}, max rel diff {rel.max(initial=0.0):.3e} "
            f"({n} of {a.size} values differ)")


def record(folder: Path, only: list[str]) -> int:
    folder.mkdir(parents=True, exist_ok=True)
    for case, scene, method, kernel in _selected(only):
        t0 = time.perf_counter()
        ds, refused = _refusal(scene, method, kernel)
        if refused is not None:
            (folder / f"{case}.refused.txt").write_text(refused + "\n")
            print(f"{case}: refused ({refused})", flush=True)
            continue
        np.savez(folder / f"{case}.npz", **_arrays(ds))
        (folder / f"{case}.attrs.json").write_text(json.dumps(_attrs(ds), indent=1, sort_keys=True))
        print(f"{case}: recorded ({time.perf_counter() - t0:.1f} s)", flush=True)
    return 0


def compare(folder: Path, only: list[str], attrs: bool) -> int:
    bad = 0
    for case, scene, method, kernel in _selected(only):
        path = folder / f"{case}.npz"
        refused_path = folder / f"{case}.refused.txt"
        if refused_path.exists():
            _, refused = _refusal(scene, method, kernel)
            same = refused is not None and refused == refused_path.read_text().strip()
            print(f"{case}: " + ("identical (refused as recorded)" if same else
                                 f"DIFFERS: recorded a refusal, now {refused or 'runs'}"), flush=True)
            bad += not same
            continue
        if not path.exists():
            print(f"{case}: not recorded in {folder}", flush=True)
            bad += 1
            continue
        ds, refused = _refusal(scene, method, kernel)
        if refused is not None:
            print(f"{case}: DIFFERS: refused now ({refused})", flush=True)
            bad += 1
            continue
        new = _arrays(ds)
        with np.load(path) as f:
            old = {k: f[k] for k in f.files}
        msg = None
        for k in sorted(set(old) - set(new)):
            msg = f"{k} missing"
            break
        if msg is None:
            for k in sorted(set(new) - set(old)):
                msg = f"{k} new"
                break
        if msg is None:
            for k in sorted(old):
                if not _same(old[k], new[k]):
                    msg = _difference(k, old[k], new[k])
                    break
        if msg is None and attrs:
            apath = folder / f"{case}.attrs.json"
            oa, na = json.loads(apath.read_text()), _attrs(ds)
            oa[""] = {k: v for k, v in oa.get("", {}).items() if not _varies(k)}
            if oa != na:
                for var in sorted(set(oa) | set(na)):
                    if oa.get(var) != na.get(var):
                        o, n = oa.get(var) or {}, na.get(var) or {}
                        keys = sorted(k for k in set(o) | set(n) if o.get(k) != n.get(k))
                        msg = f"attributes of {var or 'the dataset'!s}: {', '.join(keys)}"
                        break
        print(f"{case}: " + ("identical" if msg is None else f"DIFFERS: {msg}"), flush=True)
        bad += msg is not None
    n = len(_selected(only))
    print(f"{n - bad} of {n} cases identical" + (f", {bad} differ" if bad else ""))
    return 1 if bad else 0


def _selected(only: list[str]):
    return [c for c in cases() if not only or any(s in c[0] for s in only)]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("action", choices=("record", "compare", "list"))
    p.add_argument("folder", type=Path, nargs="?")
    p.add_argument("--only", action="append", default=[], metavar="SUBSTRING",
                   help="keep the cases whose name contains it (repeatable)")
    p.add_argument("--attrs", action="store_true", help="compare attributes too")
    a = p.parse_args(argv)
    if a.action == "list":
        for c in _selected(a.only):
            print(c[0])
        return 0
    if a.folder is None:
        p.error(f"{a.action} needs a folder")
    if a.action == "record":
        return record(a.folder, a.only)
    return compare(a.folder, a.only, a.attrs)


if __name__ == "__main__":
    sys.exit(main())
