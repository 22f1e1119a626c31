"""Models: what the run layer asks of every simulated system.

A model is a package that describes one system (the heavy top, the Zeitlin
fluid, …) to the run layer with one object, registered once::

    from liethermo.models import register
    register(MyModel())

(a package's model module is listed in ``liethermo.models.MODEL_MODULES``, so that
it registers on first need).  The runner (member chunks, streaming writes,
journal, lock, resume, stop signals), the preflight checks, Dask runs, the
command line (``run``, ``keys``, ``--check``), the Python API and the study
kinds then reach the model only through :class:`Model`; none of them names a
model.

The required part (:class:`Model`) is small: the model's own scene sections
(its :class:`liethermo.scene.SceneModel`, made with
:func:`liethermo.scene.declare_scene`, which adds the keys every run reads),
its methods, its initial conditions, one member chunk run into a labelled
dataset with its mergeable :class:`Stats`, and the file's setup (global
attributes and an empty :class:`Summary`).  Two capabilities are optional and
declared as protocols a model opts into by implementing them:

* :class:`Estimates` — disk, memory and time of a run before it starts
  (``--check``, the preflight's disk and memory checks);
* :class:`StudySupport` — what the generic studies compare between methods
  (:class:`StudyDefaults` holds the usual defaults; a model adds its
  ``study_state``).

Member ``i``'s values must depend on the scene and ``i`` only, not on the
chunk it is computed in: that is what makes a resumed or a Dask run give the
same file as an uninterrupted one.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable


@dataclass(frozen=True)
class MethodInfo:
    """One method of a model: its order, the laws it keeps to round-off and
    one line on how it steps."""

    name: str
    order: int
    laws: tuple[str, ...]
    description: str

    @staticmethod
    def table(order: dict, laws: dict, description: dict) -> dict[str, "MethodInfo"]:
        """``{method: MethodInfo}`` from a model's tables of orders, laws and descriptions
        (keyed by method, in the order of ``order``)."""
        return {m: MethodInfo(m, order[m], laws[m], description[m]) for m in order}


# ----------------------------------------------------------------------------- stats and summaries


@runtime_checkable
class Stats(Protocol):
    """What a member chunk adds to its run's summary: merged over chunks (in any
    order, also across Dask workers), written to the journal as JSON and read back."""

    kernel_time: float  # seconds

    def merge(self, other: "Stats") -> "Stats":
        """Add ``other``'s figures to these; returns self."""

    def to_dict(self) -> dict:
        """JSON-serialisable; the model's ``stats_from_dict`` reads it back."""


@runtime_checkable
class Summary(Protocol):
    """What a run did, for the report the command line prints."""

    scene_name: str
    method: str
    members: int
    steps: int
    h: float  # s
    wall_time: float  # s
    resumed_members: int
    path: Any  # the written file, or None

    def finish(self, stats: Stats) -> "Summary":
        """Fill in the figures of the merged stats of every chunk; returns self."""

    def lines(self) -> list[str]:
        """The report, one fact a line."""


@dataclass
class BaseStats:
    """A :class:`Stats` of dataclass fields: numbers add up on :meth:`merge`
    unless the field's metadata names another rule (``field(default=0.0,
    metadata={"merge": max})``)."""

    members: int = 0
    kernel_time: float = 0.0

    def merge(self, other: "BaseStats") -> "BaseStats":
        for f in dataclasses.fields(self):
            rule = f.metadata.get("merge", lambda a, b: a + b)
            setattr(self, f.name, rule(getattr(self, f.name), getattr(other, f.name)))
        return self

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "BaseStats":
        return cls(**d)


@dataclass
class BaseSummary:
    """A :class:`Summary` that reports the run's size, times and file; a model
    adds its own lines by overriding :meth:`body`."""

    scene_name: str
    method: str
    members: int
    steps: int
    h: float
    wall_time: float = 0.0
    resumed_members: int = 0
    path: Any = None
    stats: Any = None

    def finish(self, stats) -> "BaseSummary":
        self.stats = stats
        return self

    def body(self) -> list[str]:
        """The model's own lines (after the first)."""
        return []

    def lines(self) -> list[str]:
        k = getattr(self.stats, "kernel_time", float("nan"))
        out = [f"scene {self.scene_name!r}, method {self.method}: {self.members} member(s) x {self.steps} "
               f"steps, h = {self.h:g} s",
               f"  wall time {self.wall_time:.3g} s (simulating and writing), kernels {k:.3g} s"]
        out += self.body()
        return out + closing_lines(self.resumed_members, self.path)


def wall_line(seconds: float) -> str:
    """The summary's line on the run's wall time: what ``--check`` estimates as "the run in all"."""
    return f"  wall time {seconds:.3g} s (the run: simulating, labelling and writing; not start-up or figures)"


def closing_lines(resumed_members: int, path, resumed_note: str = "") -> list[str]:
    """A summary's last lines: the members a resumed run took from the interrupted one
    (``resumed_note``: what that means for the figures above) and the file written."""
    out = []
    if resumed_members:
        out.append(f"  resumed: members 0-{resumed_members - 1} came from the interrupted run"
                   + (f" ({resumed_note})" if resumed_note else ""))
    if path is not None:
        out.append(f"  wrote {path}")
    return out


def basic_setup(scene, history: str | None, title: str, summary=BaseSummary, **attrs) -> tuple[dict, Any]:
    """``(global attributes, empty summary)`` of a model's file: CF conventions,
    ``title``, the scene's TOML text, when and how it was made, and ``attrs``."""
    from . import cf

    itg = scene["integrator"]
    created = cf.timestamp()
    glob = {"Conventions": cf.CONVENTIONS, "title": title, "scene": scene.to_toml(), "created": created,
            "history": cf.history_entry(history or "liethermo", created), **attrs}
    return glob, summary(scene.name, itg["method"], int(scene["ensemble"]["members"]), int(itg["steps"]),
                         float(itg["h"]))


# ----------------------------------------------------------------------------- the required part


class Model:
    """The required part of every model (subclass it).  The run layer reads the
    keys of :data:`liethermo.scene.RUN_KEYS` of every model's scenes; a scene
    reads like TOML tables (``scene["integrator"]["h"]``) and has ``name``,
    ``to_toml()`` and ``with_overrides({"section.key": value})``."""

    #: the model's name (files record it in their ``model`` attribute where they have one)
    name: str = ""
    #: how the command line's help names the model, e.g. "the heavy top"
    title: str = ""
    #: one sentence for the command line's description
    description: str = ""
    #: the scene side (:class:`liethermo.scene.SceneModel`; may be a property that
    #: imports it on first use)
    scene_model: Any = None
    #: the table whose presence marks a scene's tables as this model's (a light test,
    #: for the command line's help); None: ``scene_model.marks``
    scene_table: str | None = None
    #: the model's own study kinds, ``{kind: module}`` (the generic kinds of
    #: :data:`liethermo.studies.GENERIC_KINDS` run on every model with :class:`StudySupport`)
    study_kinds: dict = {}
    #: the scene keys that make a run store less (named when an output does not fit on its disk)
    store_less: str = "output.every"
    #: scene keys (section, key) that do not change what a run writes: an output made
    #: with other values of them is the same run's (replaced, resumed)
    not_in_results: frozenset = frozenset({("output", "figures"), ("output", "compare"),
                                           ("output", "member_chunk"), ("ensemble", "device")})
    #: True where a member's last bits depend on the batch it is computed in (BLAS
    #: products over the chunk): Dask tasks are then the scene's member chunks, and
    #: ``output.member_chunk`` is part of the results
    chunk_sets_bits: bool = False
    #: the model's :class:`Stats` (a :class:`BaseStats` subclass, or any class with
    #: the protocol and a ``from_dict`` class method)
    stats_type: type = BaseStats

    # ---------------------------------------------------------- scenes
    def owns(self, scene) -> bool:
        """Whether ``scene`` (a loaded scene or its tables) is one of this model's."""
        if isinstance(scene, dict):
            return self.scene_table in scene if self.scene_table else bool(self.scene_model.marks(scene))
        return isinstance(scene, self.scene_model.scene_class)

    def keys(self) -> tuple:
        """The scene keys (:class:`liethermo.scene.Key`): unit, default, rule, meaning."""
        return tuple(self.scene_model.keys)

    def methods(self) -> dict[str, MethodInfo]:
        raise NotImplementedError

    def initial_conditions(self, scene, lo: int, hi: int):
        """The initial state of members ``lo:hi`` (depends on (scene, member) only)."""
        raise NotImplementedError

    # ---------------------------------------------------------- a run
    def setup(self, scene, history: str | None) -> tuple[dict, Summary]:
        """``(global attributes of the output, empty summary)`` of a resolved scene
        (:func:`basic_setup` makes both)."""
        raise NotImplementedError

    def new_stats(self) -> Stats:
        return self.stats_type()

    def stats_from_dict(self, d: dict) -> Stats:
        return self.stats_type.from_dict(d)

    def run_chunk(self, scene, lo: int, hi: int, *, progress_cb=None, kernel: str | None = None,
                  threads: int | None = None):
        """Members ``lo:hi``: ``(labelled dataset with a leading member dimension, stats)``.
        ``progress_cb(n)`` gets the member-steps just done."""
        raise NotImplementedError

    def thread_counts(self, scene, cores: int):
        """The threads a run of ``scene`` uses on ``cores`` usable cores
        (:class:`liethermo.threads.ThreadCounts`): by default the model's own
        kernels on every core and numpy's BLAS on one (a model whose work is
        not BLAS products gains nothing from a BLAS pool, and a pool beside
        busy kernels spins).  A count may change speed only, never a result."""
        from .threads import ThreadCounts

        return ThreadCounts(blas=1, kernel=max(1, int(cores)))

    def warm(self, scene, methods: list[str], progress: bool | None):
        """Before the first run of ``methods``: what can be made ready (kernels
        compiled in another process, bases built); returns a process to join
        or terminate, or None."""
        return None

    def figures(self, outputs: dict[str, Path], folder: Path, stem: str) -> list[Path]:
        """Draw the figures of written outputs ``{method: path}`` (the scene's
        own method first) into ``folder`` as ``<stem>_*.png``, from the files alone."""
        return []

    def check_parameters(self, scene) -> None:
        """Refuse (``PreflightError``) what valid keys still make impossible for the kernels."""

    def long_run(self, scene) -> bool:
        """Whether the command line times the run before it starts (and says so if it is long)."""
        return False


# ----------------------------------------------------------------------------- optional capabilities


@runtime_checkable
class Estimates(Protocol):
    """A model that can say, before a run, what it will take (``--check``, and the
    preflight's disk and memory checks; without it those are skipped, and said so)."""

    def estimate(self, scene):
        """Disk and memory of a run: a :class:`liethermo.preflight.Estimate`."""

    def estimate_time(self, scene):
        """An object with ``seconds``, ``line()`` (the run's time on this machine)
        and ``warnings()`` (lines for stderr: a run of hours, or near the memory);
        optionally ``cautions()``, the warnings a long run also prints before it
        starts (a probe that says its members will stop)."""


@runtime_checkable
class StudySupport(Protocol):
    """What the generic studies (convergence, energy_drift, long_drift,
    work_precision) compare between a model's methods.  A generic study refuses,
    in one line, a model without it."""

    #: scene overrides that make a run store what :meth:`study_state` reads
    study_outputs: dict

    def study_state(self, ds) -> dict:
        """The state a study compares between methods, from a run's dataset:
        ``{name: (array (member, t, ...), units, long name, scale)}``; an error is
        the norm over the trailing axes of a difference, and ``scale`` the size
        it is measured against (None: the largest value of the reference)."""

    def method_overrides(self, label: str) -> dict: ...
    def method_details(self, label: str) -> dict: ...
    def method_order(self, label: str) -> int: ...
    def relative_energy_error(self, ds): ...
    def energy_conventions(self, ds) -> dict: ...
    def dissipation_overrides(self, scene, factor: float) -> dict: ...
    def kernel_for(self, scene) -> str | None: ...
    def run_with_laws(self, scene, *, kernel: str | None = None, threads: int | None = None): ...


class StudyDefaults:
    """The usual answers of :class:`StudySupport` (a model mixes this in and adds
    :meth:`study_state` and what it answers otherwise)."""

    study_outputs: dict = {}
    #: the names :meth:`energy_conventions` may return
    energy_convention_names: tuple[str, ...] = ()
    #: ``ode(scene, lo, hi)``: members ``lo:hi`` as a continuous system for scipy's
    #: ``solve_ivp``, ``(y0 (members, n), [f(t, y) per member], state)`` where
    #: ``state(y)`` gives :meth:`study_state`'s variables at one time (those it can);
    #: None: the model has no continuous right-hand side (studies skip scipy)
    ode = None

    def method_overrides(self, label: str) -> dict:
        """Scene overrides that make a scene run the method ``label`` (a name, or a
        model's richer label such as ``"vi:node:explicit"``)."""
        if label not in self.methods():
            raise ValueError(f"{label!r} is not a method of {self.title or self.name} "
                             f"({', '.join(self.methods())})")
        return {"integrator.method": label}

    def method_details(self, label: str) -> dict:
        """``{choice: value}`` of a method label beyond its name (a table's columns)."""
        return {}

    def method_order(self, label: str) -> int:
        """The order the method ``label`` declares on this model's output values."""
        return self.methods()[label].order

    def relative_energy_error(self, ds):
        """(member, t) the energy error of a run relative to its natural scale (1)."""
        return None

    def energy_conventions(self, ds) -> dict:
        """Other readings of the relative energy error that a run's dataset
        records besides :meth:`relative_energy_error`: ``{name: (member, t)
        array}`` ({} when none, or not for this run's method)."""
        return {}

    def dissipation_overrides(self, scene, factor: float) -> dict:
        """Scene overrides that multiply every dissipative coefficient of
        ``scene`` by ``factor`` ({}: the scene has nothing to scale)."""
        return {}

    def kernel_for(self, scene) -> str | None:
        """The kernel :meth:`run_chunk` picks for all of ``scene``'s members (passed
        back as ``kernel=``, shorter runs of the same ensemble time the same loop)."""
        return None

    def run_with_laws(self, scene, *, kernel: str | None = None, threads: int | None = None):
        """Every member of ``scene`` run as :meth:`run_chunk` runs them, and the
        defects of the exact laws (besides energy) of the continuous motion:
        ``(dataset, stats, {name: (per-member max defect, units, long name)})``,
        NaN where the law does not hold for the member's physics or cannot be
        checked on the stored steps."""
        ds, st = self.run_chunk(scene, 0, int(scene["ensemble"]["members"]), kernel=kernel, threads=threads)
        return ds, st, {}


def study_support(model: Model, what: str) -> Model:
    """``model`` if it offers :class:`StudySupport`, else a one-line ``ValueError``
    saying that ``what`` (a study) needs it."""
    if not isinstance(model, StudySupport):
        raise ValueError(f"{what} compares methods by their states, errors and energies, which "
                         f"{model.title or model.name} does not offer (its model has no study support)")
    return model


_MODELS: dict[str, Model] = {}


def register(model: Model) -> Model:
    """Make ``model`` known to the run layer and its scenes to :mod:`liethermo.scene`."""
    _MODELS[model.name] = model
    return model


def unregister(name: str) -> None:
    """Forget a registered model (tests register models of their own)."""
    _MODELS.pop(name, None)


#: the modules that register the built-in models, imported on first need (when a
#: scene is loaded); each is light and registers one model
MODEL_MODULES = ("liethermo.top.model", "liethermo.zeitlin.model", "liethermo.torus.model")


def models() -> list[Model]:
    """Every registered model, once the modules of :data:`MODEL_MODULES` have registered theirs."""
    import importlib

    for name in MODEL_MODULES:
        importlib.import_module(name)
    return list(_MODELS.values())


def get_model(name: str) -> Model:
    for m in models():
        if m.name == name:
            return m
    raise KeyError(f"no model named {name!r}: known models {', '.join(m.name for m in models())}")


#: The model of a scene that no registered model's table marks.  Every scene
#: file and every stored scene text written before scenes named their model is
#: the heavy top's, so they all read, and resume, as the top's.  This is the one
#: place that rule is written.
UNMARKED_SCENES_MODEL = "top"


def model_of(scene) -> Model:
    """The model whose scene ``scene`` (a loaded scene or its tables) is: the
    registered model that owns it, else :data:`UNMARKED_SCENES_MODEL`'s."""
    ms = models()
    for m in ms:
        if m.name != UNMARKED_SCENES_MODEL and m.owns(scene):
            return m
    return get_model(UNMARKED_SCENES_MODEL)


def study_kinds() -> dict[str, str]:
    """``{study kind: module}`` of the registered models' own kinds."""
    return {k: mod for m in models() for k, mod in m.study_kinds.items()}
