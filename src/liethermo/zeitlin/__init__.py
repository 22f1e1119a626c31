"""The thermodynamic Zeitlin fluid on the sphere: the second Lie group (su(N)).

* :mod:`.kernels` — the Laplacian by diagonals, the modes, the exact viscous
  flow and its heat, the isospectral midpoint, the vector field (plain arrays);
* :mod:`.scene` — the scene keys of a fluid (a scene with a ``[zeitlin]`` table);
* :mod:`.run` — initial fields, the methods' steps over a batch, the dataset;
* :mod:`.plotting` — the vorticity on the sphere and the run's figures.

``vorticity_coefficients(ds)`` gives a run's stored vorticity as its
spherical-harmonic coefficients ω_lm (s⁻¹); ``vorticity_on_grid(W)`` its map.
``project(f, N)`` projects a vorticity f(lon, lat) (s⁻¹) onto the basis and
``write_initial(path, field, N)`` writes a file for ``initial.kind = "file"``
(:mod:`.field`).

The model, the scheme and what each method keeps:
docs/model.md, "A second Lie group: the thermodynamic Zeitlin fluid".
"""


def __getattr__(name):
    # the readers of a run's vorticity, imported on first use (they need xarray and scipy)
    if name == "vorticity_coefficients":
        from .run import vorticity_coefficients

        return vorticity_coefficients
    if name in ("project", "write_initial"):
        from . import field

        return getattr(field, name)
    if name == "vorticity_on_grid":
        from .plotting import vorticity_on_grid

        return vorticity_on_grid
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
