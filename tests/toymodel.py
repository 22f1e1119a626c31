"""A model that exists only in the tests: the scalar decay y' = −k y.

It shows what adding a model takes: its own keys, its equation, its
dataset's variables, and one line, ``liethermo.models.register(Toy())``.
The keys every run reads, the scene class, the stats and the summary are
the framework's; the run layer (member chunks, streaming writes, journal,
lock, resume, the command line, the Python API) is the same as for the
built-in models.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import xarray as xr

from liethermo.models import BaseStats, BaseSummary, MethodInfo, Model, basic_setup
from liethermo.scene import Key, declare_scene, number, string

KEYS = (
    Key("scene", "name", "toy", "", "a string", "name of the scene", string),
    Key("toy", "rate", 0.5, "s-1", "> 0", "decay rate k of y' = −k y", number(0.0, lo_open=True)),
    Key("initial", "y", 1.0, "1", "finite", "y(0) of member 0; member i starts at y (1 + i/10)", number()),
)
SCENE = declare_scene("toy", KEYS, methods=("euler",), marks=lambda t: "toy" in t, title="a toy decay",
                      intro="A scene with a `[toy]` table.",
                      defaults={"integrator.steps": 10, "ensemble.members": 3, "output.member_chunk": 2})


@dataclass
class Stats(BaseStats):
    y_max: float = field(default=0.0, metadata={"merge": max})


class Summary(BaseSummary):
    def body(self):
        return [f"  toy: max |y| {self.stats.y_max:g}"]


class Toy(Model):
    name = "toy"
    title = "the toy decay"
    description = "a scalar decay (tests only)"
    scene_model = SCENE
    stats_type = Stats

    def methods(self):
        return {"euler": MethodInfo("euler", 1, (), "y' = y − h k y")}

    def initial_conditions(self, scene, lo, hi):
        return scene["initial"]["y"] * (1.0 + np.arange(lo, hi) / 10.0)

    def setup(self, scene, history):
        return basic_setup(scene, history, "toy decay", summary=Summary)

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
