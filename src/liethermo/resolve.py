"""A scene resolved once for its run: what every part of the run reads.

``resolve(scene)`` derives, once per scene and process, the physics (every
member of a scene shares its parameters, so one member's, repeated for a
chunk), the method, the model terms the run compiles and the heat bound
that fixes the kernels' model for every chunk.  The runner (its summary and
every member chunk, here or in a Dask task), the time probe, preflight's
checks and estimates, and the process that warms the kernel cache all read
it instead of resolving the scene again.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

from .methods import Method, get_method
from .physics import Physics, build_model, physics_of_scene
from .scene import Scene, load_scene


@dataclass(frozen=True, eq=False)
class ResolvedRun:
    scene: Scene
    method: Method
    physics: Physics                # one member
    terms: tuple[str, ...]          # the model terms the run compiles
    heat_bound: float               # J: the most heat any member can make

    def physics_for(self, members: int) -> Physics:
        """The physics of ``members`` members (all share the scene's parameters)."""
        return self.physics if members == 1 else self.physics.repeat(members)

    def simulate_options(self, kernel: str = "auto") -> dict:
        """The keywords of :func:`liethermo.simulate.simulate` that the scene fixes
        for every part of its run: the integrator's variants and Newton settings,
        the attitude, the ensemble loop (chosen on the full chunk size, so every
        chunk uses the same one) and the heat bound (the same kernel model for
        every chunk)."""
        from .simulate import kernel_for

        integ, outp = self.scene["integrator"], self.scene["output"]
        chunk = min(int(self.scene["ensemble"]["members"]), int(outp["member_chunk"]))
        return dict(friction=integ["friction"], start=integ["start"], entropy=integ["entropy"],
                    composition=integ["composition"],
                    attitude=bool(outp["attitude"]), newton_tol=float(integ["newton_tol"]),
                    newton_maxiter=int(integ["newton_maxiter"]),
                    kernel=kernel_for(integ["method"], chunk, int(integ["steps"]), kernel),
                    heat_bound=self.heat_bound)


def resolve(scene) -> ResolvedRun:
    """The resolved run of a scene (a :class:`~liethermo.scene.Scene`, or tables
    that validate to one); computed once per scene and process."""
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    return _resolve(scene)


@functools.lru_cache(maxsize=16)
def _resolve(scene: Scene) -> ResolvedRun:
    from .initial import heat_bound

    phys = physics_of_scene(scene, 1)
    terms = tuple(build_model(phys, bool(scene["output"]["attitude"])).terms())
    return ResolvedRun(scene, get_method(scene["integrator"]["method"]), phys, terms, heat_bound(scene, phys))
