"""Checks made before any kernel compiles or simulates.

:func:`prepare_run` decides where each method's output goes
(:func:`output_paths`), and refuses, with one line, what would fail later or
lose a result:

* an output path that is a folder, or a folder that does not take files
  (a probe file is created and removed);
* an output that another live process is writing (:class:`~liethermo.faults.OutputLock`);
* an existing output made from another scene (unless ``force``): a run never
  silently replaces another experiment's file; the first differing scene key
  is named.  Rerunning the same scene replaces its file;
* ``resume`` from an interrupted run of another scene (the first differing
  key is named) or another liethermo version;
* an output that does not fit on its disk, or a member chunk that does not
  fit in the memory left (:func:`estimate`).

Then it removes what interrupted or killed runs of the same outputs left
(temporaries of dead processes, and without ``resume`` their partial files)
and says so in one line.
"""

from __future__ import annotations

import os
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .faults import Busy, OutputLock, folder_leftovers, human_bytes, leftovers, remove_files
from .models import model_of

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

DEFAULT_DIR = Path("data") / "runs"


#: how the remedies a refusal names are spelled on the command line and in Python
CLI_WORDS = {"force": "pass --force to replace it", "elsewhere": "or -o to write elsewhere",
             "fresh": "rerun without --resume to start over"}
PYTHON_WORDS = {"force": "pass force=True to replace it", "elsewhere": "or another output= to write elsewhere",
                "fresh": "run with resume=False to start over"}


class PreflightError(Exception):
    """A run refused before any work: the message is one line.  A message
    that names a remedy is a template with ``{force}``, ``{elsewhere}`` or
    ``{fresh}``: ``str()`` spells them as on the command line,
    :meth:`in_words` with another spelling (``PYTHON_WORDS`` for the API)."""

    def __init__(self, message: str, *, template: str | None = None):
        self.template = template
        super().__init__(template.format(**CLI_WORDS) if template is not None else message)

    @classmethod
    def remedy(cls, text: str, *remedies: str, sep: str = ": ") -> "PreflightError":
        """``text`` (taken literally), then ``sep`` and the named remedies."""
        literal = text.replace("{", "{{").replace("}", "}}")
        return cls("", template=literal + sep + ", ".join("{%s}" % r for r in remedies))

    def in_words(self, words: dict) -> str:
        return self.template.format(**words) if self.template is not None else str(self)


# ---------------------------------------------------------------- names
def output_paths(scene: dict, output: str | os.PathLike | None) -> dict[str, Path]:
    """``{method: path}`` for the scene's method and its ``output.compare`` methods.

    Without ``output``: ``data/runs/<scene>_<method>.nc`` for every method.
    With ``output``: that path for the scene's method, ``<stem>_<method>.nc``
    next to it for the others.
    """
    method = scene["integrator"]["method"]
    methods = [method] + [m for m in scene["output"]["compare"] if m != method]
    methods = list(dict.fromkeys(methods))
    name = scene["scene"]["name"]
    if output is None:
        return {m: DEFAULT_DIR / f"{name}_{m}.nc" for m in methods}
    out = Path(output)
    paths = {method: out}
    for m in methods[1:]:
        paths[m] = out.with_name(f"{out.stem}_{m}{out.suffix}")
    return paths


def method_scene(scene, method: str):
    """The scene with ``integrator.method = method``."""
    return scene.with_overrides({"integrator.method": method})


# ---------------------------------------------------------------- scene identity
def _fmt(v) -> str:
    return repr(v) if isinstance(v, str) else str(v).replace("'", '"')


#: keys that do not change what a run computes or writes into its file
NOT_IN_RESULTS = {("output", "figures"), ("output", "compare"), ("output", "member_chunk")}


def scene_difference(old_toml: str, new_toml: str, ignore=NOT_IN_RESULTS) -> str | None:
    """The first key in which two resolved scenes (TOML texts) differ, as
    ``"section.key (A there, B here)"``; None if they are equal but for keys
    that do not change the results (``ignore``, default :data:`NOT_IN_RESULTS`:
    figures, the other methods compared, the member chunk; a model's own:
    :attr:`liethermo.models.Model.not_in_results`)."""
    if old_toml == new_toml:
        return None
    try:
        old = tomllib.loads(old_toml)
    except tomllib.TOMLDecodeError:
        return "the scene (unreadable)"
    new = tomllib.loads(new_toml)
    missing = object()
    for section in list(new) + [s for s in old if s not in new]:
        a, b = old.get(section, {}), new.get(section, {})
        if not isinstance(a, dict) or not isinstance(b, dict):
            if a != b:
                return section
            continue
        for key in list(b) + [k for k in a if k not in b]:
            if (section, key) in ignore:
                continue
            va, vb = a.get(key, missing), b.get(key, missing)
            if va != vb and not (isinstance(va, float) and isinstance(vb, float) and np.isnan(va) and np.isnan(vb)):
                there = "absent" if va is missing else _fmt(va)
                here = "absent" if vb is missing else _fmt(vb)
                return f"{section}.{key} ({there} there, {here} here)"
    return None


def _short_hashes(diff: str) -> str:
    """``initial.sha256 ('<64 hex>' there, '<64 hex>' here)`` → ``<12 hex>…<12 hex> there, …``."""
    import re

    return re.sub(r"['\"]([0-9a-f]{12})[0-9a-f]{40}([0-9a-f]{12})['\"]", r"\1…\2",
                  diff[len("initial.sha256 ("):-1])


def file_scene(path: Path) -> str | None:
    """The resolved scene stored in a liethermo output (None: not one)."""
    import netCDF4

    try:
        with netCDF4.Dataset(path, "r") as nc:
            s = nc.getncattr("scene")
            return s if isinstance(s, str) else None
    except (OSError, RuntimeError, AttributeError, KeyError, ValueError):
        return None


# ---------------------------------------------------------------- sizes
@dataclass
class Estimate:
    """Bytes per member in the output file and in memory while its chunk is computed."""

    file_per_member: int
    memory_per_member: int
    members: int
    member_chunk: int

    #: per variable with a member dimension: (bytes per member, members per disk chunk or 0)
    layout: list = field(default_factory=list)
    #: memory a run needs once whatever its chunk (e.g. a basis the steps share)
    fixed_memory: int = 0
    #: GPU memory of one member chunk (bytes; 0 for a run on the CPU)
    device_memory: int = 0
    #: the names of the per-member variables the file stores (``output.variables``), where the model says
    variables: tuple = ()

    @property
    def file_bytes(self) -> int:
        """The file's size: every variable's values, its last disk chunk
        stored whole (HDF5 does), and the header (names, attributes, index)."""
        total = 0
        for per, disk in self.layout:
            n = -(-self.members // disk) * disk if disk else self.members
            total += n * per
        return total + FILE_OVERHEAD

    @property
    def chunk_members(self) -> int:
        return min(self.members, self.member_chunk)

    @property
    def chunk_memory(self) -> int:
        return self.chunk_members * self.memory_per_member

    @property
    def writer_memory(self) -> int:
        """The netCDF writer's chunk cache: two disk chunks per variable."""
        return sum(2 * min(disk, self.members) * per for per, disk in self.layout if disk)

    @property
    def memory(self) -> int:
        """What a run needs at most: a member chunk, the writer and the program."""
        return self.chunk_memory + self.writer_memory + self.fixed_memory + BASE_MEMORY


#: Bytes of a file besides the values (measured: 74 kB for the paper scene).
FILE_OVERHEAD = 96 * 1024
#: What a run needs besides its member chunk (Python, numba, xarray, netCDF).
BASE_MEMORY = 300 * 2**20


def estimate(scene) -> Estimate:
    """Output size and chunk memory of a resolved scene (its model's estimate; no kernel
    runs).  A model without :class:`liethermo.models.Estimates` gets an estimate of
    nothing but the file's header: the disk and memory checks then pass, unchecked."""
    from .models import Estimates

    model = model_of(scene)
    if isinstance(model, Estimates):
        return model.estimate(scene)
    return Estimate(0, 0, int(scene["ensemble"]["members"]), int(scene["output"]["member_chunk"]))


def check_parameters(scene) -> None:
    """What valid keys still make impossible for the kernels (the scene's model says), as a PreflightError."""
    model_of(scene).check_parameters(scene)


def available_memory() -> int | None:
    """Bytes of memory this process may still use: the least of the system's
    available memory and its control group's limit (batch schedulers set one)."""
    vals = []
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                vals.append(int(line.split()[1]) * 1024)
    except (OSError, ValueError, IndexError):
        pass
    for limit, usage in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                         ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                          "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        try:
            lim = Path(limit).read_text().strip()
            if lim != "max" and int(lim) < 2**60:
                vals.append(int(lim) - int(Path(usage).read_text().strip()))
                break
        except (OSError, ValueError):
            continue
    return max(0, min(vals)) if vals else None


# ---------------------------------------------------------------- the run plan
@dataclass
class Output:
    method: str
    path: Path
    scene: dict
    skip: bool = False  # complete already (resume)


@dataclass
class RunPlan:
    outputs: list[Output]
    locks: list[OutputLock] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # lines for stderr
    estimate: Estimate | None = None
    disk_need: int = 0
    disk_free: int | None = None
    memory_available: int | None = None
    device_free: int | None = None  # bytes free on the GPU of a run there
    resume_sources: dict = field(default_factory=dict)  # {path: ResumeSource}
    created: list = field(default_factory=list)  # folders made for the outputs
    #: the memory of the outputs' most demanding run (bytes)
    memory_need: int = 0
    #: what would refuse the run (disk, memory, GPU memory), when a check lists them
    problems: list = field(default_factory=list)

    def remove_created(self) -> None:
        """Remove the folders made for the outputs, if still empty (a check-only run)."""
        for d in reversed(self.created):
            try:
                d.rmdir()
            except OSError:
                pass

    def release(self) -> None:
        for lock in self.locks:
            lock.release()
        self.locks = []

    def check_line(self) -> str:
        e = self.estimate
        n = len([o for o in self.outputs if not o.skip])
        mem = human_bytes(self.memory_need or e.memory)
        free = f", {human_bytes(self.disk_free)} free" if self.disk_free is not None else ""
        avail = f", {human_bytes(self.memory_available)} available" if self.memory_available is not None else ""
        gpu = ""
        if e.device_memory:
            have = f", {human_bytes(self.device_free)} free" if self.device_free is not None else ""
            gpu = f"; about {human_bytes(e.device_memory)} of GPU memory{have}"
        stored = (f" ({human_bytes(e.file_per_member)} per member in {len(e.variables)} variables: "
                  f"{', '.join(e.variables)})" if e.variables else "")
        return (f"{n} output file(s), about {human_bytes(self.disk_need)} on disk{stored}{free}; "
                f"at most about {mem} of memory (member chunks of {e.chunk_members}){avail}{gpu}")


def _first_existing(p: Path) -> Path:
    p = p.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _check_folder(path: Path, created: list[Path]) -> None:
    """The output's folder exists (created if needed) and takes new files."""
    parent = path.parent
    missing = []
    q = parent.absolute()
    while not q.exists() and q != q.parent:
        missing.append(q)
        q = q.parent
    if q.exists() and not q.is_dir():
        raise PreflightError(f"cannot write {path}: {q} is not a folder")
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PreflightError(f"cannot write {path}: cannot create the folder {parent} "
                             f"({exc.strerror or exc})") from None
    created += reversed(missing)
    probe = parent / f".{path.name}.{os.getpid()}.probe"
    try:
        fd = os.open(probe, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666)
    except OSError as exc:
        raise PreflightError(f"cannot write {path}: the folder {parent} does not take new files "
                             f"({exc.strerror or exc})") from None
    os.close(fd)
    probe.unlink()


def prepare_run(scene: dict, output=None, *, force: bool = False, resume: bool = False,
                dask: bool = False, combine: bool = True, check_memory: bool = True, clean: bool = True,
                warn_conflicts: bool = False, list_problems: bool = False) -> RunPlan:
    """Every check before a run; returns the plan (holding the output locks:
    call ``plan.release()`` when done).  Raises :class:`PreflightError`.
    ``clean=False``: leave what earlier runs left (a check only).
    ``warn_conflicts``: an existing output that the run would refuse to
    replace is a warning in ``plan.notes`` instead of an error (a check
    that still estimates the run).  ``list_problems``: what the disk, the
    memory or the GPU memory would refuse goes into ``plan.problems``, all of
    it, instead of raising at the first (a check that prints every estimate)."""
    from .io import journal_path, partial_path, parts_dir, resume_sources
    from .scene import scene_to_toml

    check_parameters(scene)
    ignore = model_of(scene).not_in_results
    outs = [Output(m, p, method_scene(scene, m)) for m, p in output_paths(scene, output).items()]
    plan = RunPlan(outs)
    created = plan.created
    try:
        for o in outs:
            if o.path.suffix != ".nc":
                raise PreflightError(f"output {o.path}: the output file must end in .nc")
            if o.path.is_dir():
                raise PreflightError(f"cannot write {o.path}: it is a folder")
            _check_folder(o.path, created)
        for o in outs:
            try:
                plan.locks.append(OutputLock(o.path).acquire())
            except Busy as exc:
                raise PreflightError(str(exc)) from None
            except OSError as exc:
                raise PreflightError(f"cannot write {o.path}: {exc.strerror or exc}") from None
        for o in outs:
            toml = scene_to_toml(o.scene)
            if (dask and not combine) or not (o.path.exists() or o.path.is_symlink()):
                continue
            old = file_scene(o.path)
            if old is not None and scene_difference(old, toml, ignore) is None:
                o.skip = resume  # a rerun replaces it; a resume has nothing left to do
                if resume:
                    plan.notes.append(f"liethermo: {o.path} is complete for this scene: kept")
                continue
            if force:
                continue
            what = ("is not a liethermo output" if old is None
                    else f"holds a run of another scene, differing in {scene_difference(old, toml, ignore)}")
            refusal = PreflightError.remedy(f"{o.path} exists and {what}", "force", "elsewhere")
            if not warn_conflicts:
                raise refusal
            plan.notes.append(f"liethermo: warning: the run would be refused: {refusal}")
        chosen = {}
        if resume and not dask:
            for o in outs:
                if o.skip:
                    continue
                src = resume_sources(o.path)
                if not src:
                    continue
                j = src[0].journal
                from .version import __version__

                if j.version != __version__:
                    raise PreflightError.remedy(f"cannot resume {o.path}: its partial run was made by "
                                                f"liethermo {j.version}, this is {__version__}", "fresh", sep="; ")
                diff = scene_difference(j.scene_toml, scene_to_toml(o.scene), ignore)
                if diff is not None and diff.startswith("initial.sha256 "):
                    raise PreflightError.remedy(f"cannot resume {o.path}: initial.file "
                                                f"{o.scene['initial']['file']} has changed since the interrupted "
                                                f"run (sha256 {_short_hashes(diff)})", "fresh", sep="; ")
                if diff is not None:
                    raise PreflightError.remedy(f"cannot resume {o.path}: the scene differs from the "
                                                f"interrupted run's in {diff}", "fresh", sep="; ")
                chosen[o.path] = src[0]
        _check_sizes(plan, scene, dask=dask, combine=combine, check_memory=check_memory and not dask,
                     problems=plan.problems if list_problems else None)
    except BaseException:
        plan.release()
        plan.remove_created()
        raise
    plan.resume_sources = chosen
    if not clean:
        return plan
    # what earlier runs of these outputs left: removed, but for the resume sources
    stale: list[Path] = []
    where: list[str] = []
    for o in outs:
        keep = set()
        if o.path in chosen:
            keep = {chosen[o.path].data, chosen[o.path].journal_file}
        cands = list(leftovers(o.path))
        pj = journal_path(partial_path(o.path))
        cands += [p for p in (pj.with_name(pj.name + ".new"),) if p.exists()]  # a journal cut short
        if not resume or dask:
            cands += [p for p in (partial_path(o.path), pj) if p.exists()]
        if dask:
            cands += folder_leftovers(parts_dir(o.path))
        mine = [p for p in cands if p not in keep]
        if mine:
            stale += mine
            where.append(str(o.path))
    n, size = remove_files(stale)
    if n:
        plan.notes.append(f"liethermo: removed {n} file{'s' if n != 1 else ''} ({human_bytes(size)}) "
                          f"left by interrupted or killed runs of {' and '.join(where)}")
    return plan


def _check_sizes(plan: RunPlan, scene: dict, *, dask: bool, combine: bool, check_memory: bool,
                 problems: list | None = None) -> None:
    """Disk, GPU memory and memory for the outputs still to run; each shortage
    raises, or with ``problems`` is appended to it (and the checks go on)."""

    def refuse(message: str) -> None:
        if problems is None:
            raise PreflightError(message)
        problems.append(message)

    todo = [o for o in plan.outputs if not o.skip]
    if not todo:
        plan.estimate = estimate(scene)
        return
    ests = {o.method: estimate(o.scene) for o in todo}
    plan.estimate = ests[todo[0].method]
    plan.memory_need = max(e.memory for e in ests.values())
    # disk: every output, on its own filesystem (parts and the combined file both, with Dask)
    need: dict[int, list] = {}
    for o in todo:
        root = _first_existing(o.path.parent)
        dev = os.stat(root).st_dev
        b = ests[o.method].file_bytes * (2 if dask and combine else 1)
        ent = need.setdefault(dev, [o.path.parent, 0, []])
        ent[1] += b
        ent[2].append(o)
    plan.disk_need = sum(v[1] for v in need.values())
    for root, b, os_ in need.values():
        free = shutil.disk_usage(root).free
        plan.disk_free = free if plan.disk_free is None else min(plan.disk_free, free)
        if b > free:
            e = ests[os_[0].method]
            names = " and ".join(str(o.path) for o in os_)
            refuse(
                f"{names} would need about {human_bytes(b)} ({e.members} members x "
                f"{human_bytes(e.file_per_member)}{' x 2 for the Dask parts' if dask and combine else ''}) "
                f"but the disk of {root} has {human_bytes(free)} free; run fewer members (ensemble.members) "
                f"or store less ({model_of(scene).store_less})")
    gpu = max(ests.values(), key=lambda e: e.device_memory)
    if gpu.device_memory:
        from .gpu import device_memory

        dm = device_memory()
        plan.device_free = None if dm is None else dm[0]
        if dm is not None and gpu.device_memory > dm[0]:
            fit = max(1, int(gpu.chunk_members * dm[0] / gpu.device_memory) // 2)
            refuse(
                f"a member chunk of {gpu.chunk_members} members would need about "
                f"{human_bytes(gpu.device_memory)} of GPU memory but {human_bytes(dm[0])} are free; "
                f"lower output.member_chunk (to about {fit})")
    if not check_memory:
        return
    avail = available_memory()
    plan.memory_available = avail
    worst = max(ests.values(), key=lambda e: e.memory)
    if avail is not None and worst.memory > avail:
        fixed = worst.memory - worst.chunk_memory
        fit = max(0, (avail - fixed) // max(1, worst.memory_per_member))
        hint = (f"lower output.member_chunk to at most {fit}" if fit >= 1
                else "store fewer output times (output.every) or integrate fewer steps")
        refuse(
            f"a run would need about {human_bytes(worst.memory)} of memory (a member chunk of "
            f"{worst.chunk_members} members x {human_bytes(worst.memory_per_member)}, plus "
            f"{human_bytes(fixed)} for the program and its file buffers) but {human_bytes(avail)} "
            f"are available; {hint}")
