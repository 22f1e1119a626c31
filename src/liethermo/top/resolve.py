"""A scene resolved once for its run: what every part of the run reads.

``resolve(scene)`` derives, once per scene and process, the physics (every
member of a scene shares its parameters, so one member's, repeated for a
chunk), the method choice (:class:`~liethermo.top.methods.MethodChoice`: the
method with the start, friction, entropy update and composition it really
runs), the step, the kernels' model of one member (the model terms the run
compiles) and the heat bound that fixes that model for every chunk.  The
runner (its summary and every member chunk, here or in a Dask task), the
time probe, preflight's checks and estimates, and the process that warms
the kernel cache all read it instead of resolving the scene again.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from .methods import Method, MethodChoice
from .physics import KernelModel, Physics, build_model, physics_of_scene
from ..scene import load_scene
from .scene import Scene


@dataclass(frozen=True, eq=False)
class ResolvedRun:
    scene: Scene
    choice: MethodChoice
    h: float                        # s
    steps: int
    every: int
    physics: Physics                # one member
    model: KernelModel              # the kernels' model of one member (with the heat bound)
    heat_bound: float               # J: the most heat any member can make

    @property
    def method(self) -> Method:
        return self.choice.method

    @property
    def terms(self) -> tuple[str, ...]:
        """The model terms the run compiles."""
        return tuple(self.model.terms())

    @property
    def attitude(self) -> bool:
        return bool(self.scene["output"]["attitude"])

    @property
    def members(self) -> int:
        return int(self.scene["ensemble"]["members"])

    def physics_for(self, members: int) -> Physics:
        """The physics of ``members`` members (all share the scene's parameters): the same
        object for every chunk of that size, so its kernel model is built once."""
        return self.physics if members == 1 else _repeated(self, int(members))

    def kernel(self, kernel: str = "auto") -> str:
        """The ensemble loop every chunk of the run uses ("fast" or "simple"),
        chosen on the full chunk size."""
        from .simulate import kernel_for

        chunk = min(self.members, int(self.scene["output"]["member_chunk"]))
        return kernel_for(self.choice.name, chunk, self.steps, kernel)

    def simulate_options(self, kernel: str = "auto") -> dict:
        """The keywords of :func:`liethermo.top.simulate.simulate`, besides the
        method choice, that the scene fixes for every part of its run: the
        Newton settings, the attitude, the ensemble loop (:meth:`kernel`), the
        heat bound (the same kernel model for every chunk) and the device."""
        integ = self.scene["integrator"]
        return dict(attitude=self.attitude, newton_tol=float(integ["newton_tol"]),
                    newton_maxiter=int(integ["newton_maxiter"]), kernel=self.kernel(kernel),
                    heat_bound=self.heat_bound, device=self.scene["ensemble"]["device"])

    def simulate(self, omega0: np.ndarray, R0: np.ndarray, *, steps: int | None = None,
                 every: int | None = None, kernel: str = "auto", physics: Physics | None = None, **kw):
        """:func:`liethermo.top.simulate.simulate` of the members with these initial
        conditions (as many as ``omega0`` has rows), the run's whole length
        unless ``steps`` (and ``every``) say otherwise.  ``physics``: the
        members' own parameters (one row per member, e.g. a study's map of
        frictions) instead of the scene's; ``kw`` (``heat_bound``, ``threads``,
        ``chunk_steps``, …) replace the scene's :meth:`simulate_options`."""
        from .simulate import simulate

        n = len(omega0)
        if physics is not None and physics.n != n:
            raise ValueError(f"physics: {physics.n} members for {n} initial conditions")
        return simulate(self.physics_for(n) if physics is None else physics, omega0, R0, self.h,
                        self.steps if steps is None else steps, self.choice,
                        every=self.every if every is None else every, **{**self.simulate_options(kernel), **kw})


def resolve(scene) -> ResolvedRun:
    """The resolved run of a scene (a :class:`~liethermo.scene.Scene`, or tables
    that validate to one); computed once per scene and process."""
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    return _resolve(scene)


@functools.lru_cache(maxsize=4)
def _repeated(run: ResolvedRun, members: int) -> Physics:
    return run.physics.repeat(members)


@functools.lru_cache(maxsize=16)
def _resolve(scene: Scene) -> ResolvedRun:
    from .initial import heat_bound

    phys = physics_of_scene(scene, 1)
    bound = heat_bound(scene, phys)
    integ = scene["integrator"]
    return ResolvedRun(scene, MethodChoice.from_scene(scene), float(integ["h"]), int(integ["steps"]),
                       int(scene["output"]["every"]), phys,
                       build_model(phys, bool(scene["output"]["attitude"]), heat=bound), bound)
