"""Golden check: are the outputs of every built-in scene unchanged?

    PYTHONPATH=src python tools/golden.py record DIR     # before a change
    PYTHONPATH=src python tools/golden.py compare DIR    # after it: exit 1 on any difference
    PYTHONPATH=src python tools/golden.py files A B      # two netCDF files, or two folders of them

``record`` runs every built-in scene (``src/liethermo/scenes/*.toml``) small
(a few members, a few hundred steps, a small N for a fluid), under every
method **of the scene's own model** (the registry's ``model_of`` says which
model a scene is), and, where a model has several ensemble loops (the heavy
top's ``simple``, ``fast`` and ``auto``), under each of them.  It writes each
case's data variables and coordinates to ``DIR/<scene>__<method>__<kernel>.npz``
(attributes to a JSON beside it).  ``compare`` runs the same cases again and
prints, per case, ``identical`` or **every** differing variable with its
largest absolute and relative difference.  NaNs compare equal to NaNs in
the same places.  Attributes are compared only with ``--attrs``.

``--files`` (with ``record`` and ``compare``): the cases are written as
netCDF files through the run layer (``DIR/files/<case>.nc``) and compared as
files: every variable's values bit for bit, its type, dimensions, chunking,
filters and attributes, and the global attributes but those that record when
and how a run was made.  ``files A B`` compares two written files (or every
``*.nc`` of two folders) the same way, for changes that must write the same
file another way (a pipeline, a chunking, a resume).

``--allow PATTERN`` (repeatable, or ``--allow-file FILE`` with one pattern a
line) names variables that moved on purpose: ``NAME`` matches that variable
in every case, ``CASE_GLOB:NAME`` in the cases matching the glob
(``zeitlin_ideal__*:vorticity_real``); NAME may be a glob too and matches the
variable's name with or without its ``data:``/``coord:`` prefix; a file's global
attribute is ``global:NAME`` (``--allow global:scene``), its dimensions ``file:dimensions``.  An allowed
difference is printed (``moved, allowed``) and does not fail the check.

Every case stores every variable its model can write (``output.variables = "all"``).
``--derived`` (with ``compare --files``): each case of a model that derives
variables (the heavy top) runs a second time with its scene's default
variables, and the values ``ds.liethermo.derived()`` gives from that file are
compared with the recorded file's (``derived:NAME`` in the report).

``--only SUBSTRING`` keeps the cases whose name contains it (repeatable);
``list`` prints the cases with their model.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("NUMBA_OPT", "2")  # as the console script: the kernels it caches are the ones runs load

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "src" / "liethermo" / "scenes"


@dataclass(frozen=True)
class ModelCases:
    """How golden runs one model's scenes: small sizes, its ensemble loops, the
    variants of its integrator on named scenes, and methods that cost more per step."""

    size: dict
    #: the ensemble loops (the ``kernel=`` of ``run_scene``); ("-",): the model picks
    kernels: tuple[str, ...] = ("-",)
    #: methods run with the first kernel only
    one_kernel: frozenset = frozenset()
    #: {scene: ((method, {key: value}), ...)}; each variant runs with the first two kernels
    variants: dict = field(default_factory=dict)
    #: {method: steps} for methods that cost more per step
    steps: dict = field(default_factory=dict)


#: every case stores every variable its model can write (``output.variables = "all"``), so
#: that a compare judges every value, derived ones included
_COMMON = {"output.compare": [], "output.figures": False, "output.variables": ["all"]}
#: per model (by its registered name); a model not named here runs with DEFAULT
MODELS = {
    "top": ModelCases(
        size={"ensemble.members": 5, "integrator.steps": 200, "output.every": 10, **_COMMON},
        kernels=("simple", "fast", "auto"), one_kernel=frozenset({"reference"}),
        variants={
            "paper": (("vi", {"integrator.start": "legendre"}), ("vi", {"integrator.start": "staggered"}),
                      ("vi", {"integrator.friction": "endpoint"}), ("vi", {"integrator.entropy": "symmetric"}),
                      ("vi4", {"integrator.composition": "triple_jump"}),
                      ("split4", {"integrator.composition": "triple_jump"})),
            "coupled_egg": (("vi", {"integrator.start": "node"}), ("vi", {"integrator.start": "staggered"}),
                            ("vi", {"integrator.entropy": "explicit"}), ("vi", {"integrator.friction": "endpoint"})),
        }),
    "zeitlin": ModelCases(
        size={"zeitlin.N": 8, "ensemble.members": 2, "integrator.steps": 100, "output.every": 10,
              "initial.lmax": 4, **_COMMON},
        steps={"reference": 20}),
    "torus": ModelCases(
        size={"torus.N": 9, "ensemble.members": 2, "integrator.steps": 40, "output.every": 10,
              "initial.kmax": 3, "output.vorticity": True, "output.entropy_field": True, **_COMMON},
        steps={"reference": 10}),
}
#: a model golden has no entry for: its scenes as they are, shortened
DEFAULT = ModelCases(size={"ensemble.members": 2, "integrator.steps": 50, "output.every": 10, **_COMMON},
                     steps={"reference": 10})


@dataclass(frozen=True)
class Case:
    name: str
    scene: str
    model: str
    method: str  # may carry variants after dots: "vi.start=staggered"
    kernel: str  # "-": the model's own choice


def _variant_name(method: str, extra: dict) -> str:
    return method + "".join(f".{k.split('.')[-1]}={v}" for k, v in extra.items())


def _scene_paths() -> list[Path]:
    return sorted(SCENES.glob("*.toml"))


def cases(scene_paths=None) -> list[Case]:
    """Every case: each scene of ``scene_paths`` (the built-in scenes) under each method
    of its own model (the registry decides), each ensemble loop and variant."""
    import tomllib

    from liethermo.models import model_of

    out = []
    for path in scene_paths if scene_paths is not None else _scene_paths():
        name = Path(path).stem
        model = model_of(tomllib.loads(Path(path).read_text()))
        mc = MODELS.get(model.name, DEFAULT)
        for m in model.methods():
            for k in mc.kernels[:1] if m in mc.one_kernel else mc.kernels:
                out.append(Case(f"{name}__{m}__{k}", str(path), model.name, m, k))
        for m, extra in mc.variants.get(name, ()):
            v = _variant_name(m, extra)
            for k in mc.kernels[:2]:
                out.append(Case(f"{name}__{v}__{k}", str(path), model.name, v, k))
    return out


def _scene(case: Case):
    """The case's loaded scene: small, its method and variants."""
    import liethermo

    mc = MODELS.get(case.model, DEFAULT)
    method, *variants = case.method.split(".")
    ov = dict(mc.size, **{"integrator.method": method})
    if method in mc.steps:
        ov["integrator.steps"] = mc.steps[method]
    ov.update({f"integrator.{v.split('=')[0]}": v.split("=")[1] for v in variants})
    path = Path(case.scene)
    scene = path.stem if path.parent == SCENES else path
    return liethermo.load_scene(scene, ov)


def run_case(case: Case, out: Path | None = None, default_variables: bool = False):
    """The in-memory dataset of one case, or (``out``) its file written through the run layer;
    ``default_variables``: with the scene's default variables instead of every one."""
    from liethermo.runner import run_scene

    kernel = None if case.kernel == "-" else case.kernel
    scene = _scene(case)
    if default_variables:
        scene = scene.with_overrides({"output.variables": []})
    ds, _ = run_scene(scene, out, kernel=kernel, progress=False, history="golden")
    return ds


def _derives(model: str) -> bool:
    from liethermo.models import get_model

    return hasattr(get_model(model), "derived")


def derived_differences(recorded: Path, case: Case, tmp: Path) -> list[tuple[str, str]]:
    """``[(variable, what differs)]`` between the values of a recorded file and those
    the accessor derives (``ds.liethermo.derived()``) from the file the case writes
    with its scene's default variables; the variables neither derived nor recorded
    are not compared."""
    import liethermo

    out = tmp / f"{case.name}.default.nc"
    run_case(case, out, default_variables=True)
    with liethermo.open_dataset(out) as small, liethermo.open_dataset(recorded) as full:
        derived = small.load().liethermo.derived()
        old = {n: np.asarray(full[n].values) for n in full.variables if n in derived.variables}
        new = {n: np.asarray(derived[n].values) for n in old}
        missing = [(n, f"{n}: recorded, not derived") for n in full.data_vars if n not in derived.variables]
    out.unlink()
    return missing + array_differences(old, new)


def _refusal(case: Case, out: Path | None = None):
    """(dataset, None), or (None, the one-line message) when the scene refuses the method."""
    from liethermo.scene import SceneError

    try:
        return run_case(case, out), None
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


def _plain(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    return v


def _attrs(ds) -> dict:
    a = {"": {k: _plain(v) for k, v in ds.attrs.items() if not _varies(k)}}
    for n in list(ds.coords) + list(ds.data_vars):
        a[str(n)] = {k: _plain(v) for k, v in ds[n].attrs.items()}
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
    if n == 0:  # equal values, other bits: the sign of a zero
        return f"{name}: the sign of {int(np.count_nonzero(np.signbit(a.real) != np.signbit(b.real)))} zeros"
    return (f"{name}: max abs diff {d.max(initial=0.0):.3e}, max rel diff {rel.max(initial=0.0):.3e} "
            f"({n} of {a.size} values differ)")


def array_differences(old: dict, new: dict) -> list[tuple[str, str]]:
    """``[(variable, what differs)]`` over every variable of two ``{name: array}``."""
    out = [(k, f"{k}: missing") for k in sorted(set(old) - set(new))]
    out += [(k, f"{k}: new") for k in sorted(set(new) - set(old))]
    out += [(k, _difference(k, old[k], new[k])) for k in sorted(set(old) & set(new)) if not _same(old[k], new[k])]
    return out


def attr_differences(oa: dict, na: dict) -> list[tuple[str, str]]:
    """``[(variable, which attributes differ)]``; the dataset's own as ``""``."""
    oa = dict(oa, **{"": {k: v for k, v in oa.get("", {}).items() if not _varies(k)}})
    na = dict(na, **{"": {k: v for k, v in na.get("", {}).items() if not _varies(k)}})
    out = []
    for var in sorted(set(oa) | set(na)):
        o, n = oa.get(var) or {}, na.get(var) or {}
        keys = sorted(k for k in set(o) | set(n) if o.get(k) != n.get(k))
        if keys:
            out.append((var, f"attributes of {var or 'the dataset'}: {', '.join(keys)}"))
    return out


# ----------------------------------------------------------------------------- netCDF files

#: global attributes of a file that record when, where and how it was made
FILE_RUN_ATTRS = ("created", "history", "date_created", "python", "software_version")


def file_differences(a: Path, b: Path) -> list[tuple[str, str]]:
    """``[(variable, what differs)]`` between two netCDF files: dimensions, every
    variable's type, dimensions, chunking, filters, attributes and values bit
    for bit, and the global attributes but :data:`FILE_RUN_ATTRS` and those
    ending in ``_seconds``/``_time``.  ``""`` stands for the file itself."""
    import netCDF4

    out: list[tuple[str, str]] = []
    with netCDF4.Dataset(a) as x, netCDF4.Dataset(b) as y:
        dx = {k: len(d) for k, d in x.dimensions.items()}
        dy = {k: len(d) for k, d in y.dimensions.items()}
        if dx != dy:
            out.append(("file:dimensions", f"dimensions {dx} -> {dy}"))
        gx = {k: str(x.getncattr(k)) for k in x.ncattrs() if k not in FILE_RUN_ATTRS and not _varies(k)}
        gy = {k: str(y.getncattr(k)) for k in y.ncattrs() if k not in FILE_RUN_ATTRS and not _varies(k)}
        keys = sorted(k for k in set(gx) | set(gy) if gx.get(k) != gy.get(k))
        out += [(f"global:{k}", f"global attribute {k}") for k in keys]
        out += [(n, f"{n}: missing") for n in x.variables if n not in y.variables]
        out += [(n, f"{n}: new") for n in y.variables if n not in x.variables]
        for n in x.variables:
            if n not in y.variables:
                continue
            va, vb = x.variables[n], y.variables[n]
            va.set_auto_maskandscale(False)
            vb.set_auto_maskandscale(False)
            what = []
            for label, get in (("type", lambda v: str(v.dtype)), ("dimensions", lambda v: v.dimensions),
                               ("chunking", lambda v: v.chunking()), ("filters", lambda v: v.filters())):
                if get(va) != get(vb):
                    what.append(f"{label} {get(va)} -> {get(vb)}")
            at = lambda v: {k: str(v.getncattr(k)) for k in v.ncattrs()}  # noqa: E731
            ka, kb = at(va), at(vb)
            bad = sorted(k for k in set(ka) | set(kb) if ka.get(k) != kb.get(k))
            if bad:
                what.append(f"attributes {', '.join(bad)}")
            da, db = np.asarray(va[...]), np.asarray(vb[...])
            if not _same(da, db):
                what.append(_difference("values", da, db))
            if what:
                out.append((n, f"{n}: " + "; ".join(what)))
    return out


# ----------------------------------------------------------------------------- the allow-list


def allowed(case: str, variable: str, patterns: list[str]) -> bool:
    """Whether ``variable`` of ``case`` moved on purpose (see the module's ``--allow``)."""
    bare = variable.split(":", 1)[1] if variable.startswith(("data:", "coord:")) else variable
    for p in patterns:
        where, name = "", p
        if ":" in p and not p.startswith(("data:", "coord:", "global:", "file:")):
            where, name = p.split(":", 1)
        if where and not fnmatch.fnmatchcase(case, where):
            continue
        if fnmatch.fnmatchcase(variable, name) or fnmatch.fnmatchcase(bare, name):
            return True
    return False


def _report(case: str, diffs: list[tuple[str, str]], patterns: list[str]) -> bool:
    """Print a case's verdict and every difference; True when it fails."""
    moved = [m for v, m in diffs if allowed(case, v, patterns)]
    bad = [m for v, m in diffs if not allowed(case, v, patterns)]
    if not bad and not moved:
        print(f"{case}: identical", flush=True)
    elif not bad:
        print(f"{case}: identical but {len(moved)} allowed move{'s' if len(moved) > 1 else ''}", flush=True)
    else:
        print(f"{case}: DIFFERS in {len(bad)} variable{'s' if len(bad) > 1 else ''}", flush=True)
    for m in bad:
        print(f"    {m}", flush=True)
    for m in moved:
        print(f"    moved, allowed: {m}", flush=True)
    return bool(bad)


# ----------------------------------------------------------------------------- record and compare


def record(folder: Path, only: list[str], files: bool = False) -> int:
    folder.mkdir(parents=True, exist_ok=True)
    if files:
        (folder / "files").mkdir(exist_ok=True)
    for c in _selected(only):
        t0 = time.perf_counter()
        nc = folder / "files" / f"{c.name}.nc"
        if files and nc.exists():
            nc.unlink()
        ds, refused = _refusal(c, nc if files else None)
        if refused is not None:
            (folder / f"{c.name}.refused.txt").write_text(refused + "\n")
            print(f"{c.name}: refused ({refused})", flush=True)
            continue
        if not files:
            np.savez(folder / f"{c.name}.npz", **_arrays(ds))
            (folder / f"{c.name}.attrs.json").write_text(json.dumps(_attrs(ds), indent=1, sort_keys=True))
        print(f"{c.name}: recorded ({time.perf_counter() - t0:.1f} s)", flush=True)
    return 0


def compare(folder: Path, only: list[str], attrs: bool, patterns: list[str], files: bool = False,
            derived: bool = False) -> int:
    bad = 0
    sel = _selected(only)
    with tempfile.TemporaryDirectory(prefix="golden.") as tmp:
        for c in sel:
            refused_path = folder / f"{c.name}.refused.txt"
            recorded = folder / "files" / f"{c.name}.nc" if files else folder / f"{c.name}.npz"
            out = Path(tmp) / f"{c.name}.nc" if files else None
            if refused_path.exists():
                _, refused = _refusal(c, out)
                same = refused is not None and refused == refused_path.read_text().strip()
                print(f"{c.name}: " + ("identical (refused as recorded)" if same else
                                       f"DIFFERS: recorded a refusal, now {refused or 'runs'}"), flush=True)
                bad += not same
                continue
            if not recorded.exists():
                print(f"{c.name}: not recorded in {folder}", flush=True)
                bad += 1
                continue
            ds, refused = _refusal(c, out)
            if refused is not None:
                print(f"{c.name}: DIFFERS: refused now ({refused})", flush=True)
                bad += 1
                continue
            if files:
                diffs = file_differences(recorded, out)
                out.unlink()
                if derived and _derives(c.model):
                    diffs += [(f"derived:{v}", f"derived {m}") for v, m in derived_differences(recorded, c, Path(tmp))]
            else:
                with np.load(recorded) as f:
                    old = {k: f[k] for k in f.files}
                diffs = array_differences(old, _arrays(ds))
                if attrs:
                    diffs += attr_differences(json.loads((folder / f"{c.name}.attrs.json").read_text()), _attrs(ds))
            bad += _report(c.name, diffs, patterns)
    n = len(sel)
    print(f"{n - bad} of {n} cases identical" + (f", {bad} differ" if bad else ""))
    return 1 if bad else 0


def compare_files(a: Path, b: Path, patterns: list[str]) -> int:
    """Two netCDF files, or the ``*.nc`` of two folders by name."""
    if a.is_dir() and b.is_dir():
        names = sorted({p.name for p in a.glob("*.nc")} | {p.name for p in b.glob("*.nc")})
        pairs = [(n, a / n, b / n) for n in names]
    else:
        pairs = [(a.name, a, b)]
    bad = 0
    for name, x, y in pairs:
        if not (x.is_file() and y.is_file()):
            print(f"{name}: only in {x.parent if x.is_file() else y.parent}")
            bad += 1
            continue
        bad += _report(name, file_differences(x, y), patterns)
    print(f"{len(pairs) - bad} of {len(pairs)} files identical" + (f", {bad} differ" if bad else ""))
    return 1 if bad else 0


def _selected(only: list[str]) -> list[Case]:
    return [c for c in cases() if not only or any(s in c.name for s in only)]


def _patterns(a) -> list[str]:
    pats = list(a.allow)
    for f in a.allow_file:
        pats += [ln.strip() for ln in Path(f).read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    return pats


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("action", choices=("record", "compare", "list", "files"))
    p.add_argument("folder", type=Path, nargs="?", help="the record's folder (files: the first file or folder)")
    p.add_argument("other", type=Path, nargs="?", help="files: the second file or folder")
    p.add_argument("--only", action="append", default=[], metavar="SUBSTRING",
                   help="keep the cases whose name contains it (repeatable)")
    p.add_argument("--attrs", action="store_true", help="compare attributes too")
    p.add_argument("--files", action="store_true", help="record and compare written netCDF files")
    p.add_argument("--derived", action="store_true",
                   help="compare --files: also run each case of a model that derives variables with its "
                        "default variables and compare what ds.liethermo.derived() gives with the record")
    p.add_argument("--allow", action="append", default=[], metavar="[CASE_GLOB:]NAME",
                   help="a variable that moved on purpose (repeatable)")
    p.add_argument("--allow-file", action="append", default=[], metavar="FILE",
                   help="a file of --allow patterns, one a line (# comments)")
    a = p.parse_args(argv)
    if a.action == "list":
        for c in _selected(a.only):
            print(f"{c.name}  ({c.model})")
        return 0
    if a.folder is None:
        p.error(f"{a.action} needs a folder")
    if a.action == "files":
        if a.other is None:
            p.error("files needs two files or two folders")
        return compare_files(a.folder, a.other, _patterns(a))
    if a.action == "record":
        return record(a.folder, a.only, a.files)
    return compare(a.folder, a.only, a.attrs, _patterns(a), a.files, a.derived)


if __name__ == "__main__":
    sys.exit(main())
