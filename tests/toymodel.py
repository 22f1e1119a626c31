"""A model that exists only in the tests: the scalar decay y' = −k y.

It shows what adding a model takes: this file (its scene keys, its one
method, its chunk, its variables, its summary, its estimates) and one line,
``liethermo.models.register(Toy())``.  The run layer (member chunks,
streaming writes, journal, lock, resume, the command line, the Python API)
is the same for it as for the built-in models.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field

import numpy as np
import tomli_w
import xarray as xr

from liethermo import cf
from liethermo.models import MethodInfo, Model
from liethermo.scene import Key, OtherModel, SceneError, _merge, integer, number, string

KEYS = (
    Key("scene", "name", "toy", "", "a string", "name of the scene", string),
    Key("toy", "rate", 0.5, "s-1", "> 0", "decay rate k of y' = −k y", number(0.0, lo_open=True)),
    Key("initial", "y", 1.0, "1", "finite", "y(0) of member 0; member i starts at y (1 + i/10)", number()),
    Key("integrator", "method", "euler", "", '"euler"', "explicit Euler", string),
    Key("integrator", "h", 0.1, "s", "> 0", "time step", number(0.0, lo_open=True)),
    Key("integrator", "steps", 10, "1", "integer ≥ 1", "number of steps", integer()),
    Key("ensemble", "members", 3, "1", "integer ≥ 1", "members", integer()),
    Key("output", "every", 1, "1", "integer ≥ 1 dividing integrator.steps", "keep every k-th step", integer()),
    Key("output", "compare", [], "", "[]", "no other methods", lambda n, v, s: list(v)),
    Key("output", "figures", False, "", "false", "no figures", lambda n, v, s: bool(v)),
    Key("output", "member_chunk", 2, "1", "integer ≥ 1", "members at a time", integer()),
)
DEFAULTS = {}
for _k in KEYS:
    DEFAULTS.setdefault(_k.section, {})[_k.name] = _k.default


class ToyScene:
    def __init__(self, tables):
        self._t = copy.deepcopy(tables)

    def __getitem__(self, section):
        return dict(self._t[section])

    def __contains__(self, section):
        return section in self._t

    @property
    def name(self):
        return self._t["scene"]["name"]

    def to_dict(self):
        return copy.deepcopy(self._t)

    def to_toml(self):
        return tomli_w.dumps(self._t)

    def with_overrides(self, overrides):
        return load(self._t, "the scene", overrides)


def load(tables, origin, overrides=None, validate=True):
    from liethermo.scene import _overrides_as_tables

    d = copy.deepcopy(DEFAULTS)
    _merge(d, tables, origin, DEFAULTS, " of a toy scene")
    for table, o in _overrides_as_tables(overrides):
        _merge(d, table, o, DEFAULTS, " of a toy scene")
    if not validate:
        return d
    for k in KEYS:
        d[k.section][k.name] = k.check(k.path, d[k.section][k.name], d)
    if d["integrator"]["steps"] % d["output"]["every"]:
        raise SceneError("output.every", f"must divide integrator.steps = {d['integrator']['steps']}",
                         d["output"]["every"])
    return ToyScene(d)


@dataclass
class Stats:
    members: int = 0
    kernel_time: float = 0.0
    y_max: float = 0.0

    def merge(self, o):
        self.members += o.members
        self.kernel_time += o.kernel_time
        self.y_max = max(self.y_max, o.y_max)
        return self

    def to_dict(self):
        return dict(self.__dict__)


@dataclass
class Summary:
    scene_name: str
    method: str
    members: int
    steps: int
    h: float
    wall_time: float = 0.0
    resumed_members: int = 0
    path: object = None
    stats: Stats = field(default_factory=Stats)

    def finish(self, st):
        self.stats = st
        return self

    def lines(self):
        out = [f"toy {self.scene_name!r}: {self.members} member(s) x {self.steps} steps, max |y| {self.stats.y_max:g}"]
        return out + ([f"  wrote {self.path}"] if self.path is not None else [])


class Toy(Model):
    name = "toy"
    title = "the toy decay"
    description = "a scalar decay (tests only)"
    scene_model = OtherModel(name="toy", marks=lambda t: "toy" in t, load=load, scene_class=ToyScene,
                             keys=KEYS, title="a toy decay", intro="A scene with a `[toy]` table.")

    def methods(self):
        return {"euler": MethodInfo("euler", 1, (), "y' = y − h k y")}

    def initial_conditions(self, scene, lo, hi):
        return scene["initial"]["y"] * (1.0 + np.arange(lo, hi) / 10.0)

    def setup(self, scene, history):
        itg = scene["integrator"]
        created = cf.timestamp()
        attrs = {"Conventions": cf.CONVENTIONS, "title": "toy decay", "scene": scene.to_toml(),
                 "created": created, "history": cf.history_entry(history or "toy", created)}
        return attrs, Summary(scene.name, itg["method"], scene["ensemble"]["members"], itg["steps"], itg["h"])

    def new_stats(self):
        return Stats()

    def stats_from_dict(self, d):
        return Stats(**d)

    def run_chunk(self, scene, lo, hi, *, progress_cb=None, kernel=None, threads=None):
        t0 = time.perf_counter()
        h, k = scene["integrator"]["h"], scene["toy"]["rate"]
        steps, every = scene["integrator"]["steps"], scene["output"]["every"]
        y = self.initial_conditions(scene, lo, hi)
        out = [y.copy()]
        for j in range(1, steps + 1):
            y = y - h * k * y
            if j % every == 0:
                out.append(y.copy())
        Y = np.stack(out, axis=1)
        ds = xr.Dataset({"y": (("member", "t"), Y, {"units": "1", "long_name": "y"})},
                        coords={"member": ("member", np.arange(lo, hi), {"units": "1", "long_name": "member"}),
                                "t": ("t", np.arange(Y.shape[1]) * every * h, {"units": "s", "long_name": "time"})})
        return ds, Stats(hi - lo, time.perf_counter() - t0, float(np.abs(Y).max()))

    def estimate(self, scene):
        from liethermo.preflight import Estimate

        T = scene["integrator"]["steps"] // scene["output"]["every"] + 1
        return Estimate(8 * T + 8, 16 * T, scene["ensemble"]["members"], scene["output"]["member_chunk"],
                        [(8 * T, 0), (8, 0)])

    def estimate_time(self, scene):
        class T:
            seconds = 0.0

            def line(self):
                return "  euler: instantaneous"

            def warnings(self):
                return []

        return T()
