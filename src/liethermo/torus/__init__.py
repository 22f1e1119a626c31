"""Zeitlin's sine-bracket fluid on the torus T², with viscosity, heat conduction
and buoyancy: the third model (a scene with a ``[torus]`` table).

* :mod:`.kernels` — the clock-and-shift basis, the FFT transforms, the bracket,
  the ideal steps (CMP, MagMP), the viscous and conduction steps (plain arrays);
* :mod:`.step` — the Strang splitting and RK4 over a batch, the run loop;
* :mod:`.scene` — the scene keys; :mod:`.run` — initial fields and the dataset;
* :mod:`.plotting` — maps of ω, T and Θ, the energy budget, the animation.

``vorticity_modes(ds)`` gives a run's stored vorticity as its Fourier modes ω_m.
The model, the scheme and what each method keeps:
docs/model.md, "The fluid on the torus".
"""


def __getattr__(name):
    if name == "vorticity_modes":
        from .run import vorticity_modes

        return vorticity_modes
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
