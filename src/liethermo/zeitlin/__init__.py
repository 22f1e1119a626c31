"""The thermodynamic Zeitlin fluid on the sphere: the second Lie group (su(N)).

* :mod:`.kernels` — the Laplacian by diagonals, the modes, the exact viscous
  flow and its heat, the isospectral midpoint, the vector field (plain arrays);
* :mod:`.scene` — the scene keys of a fluid (a scene with a ``[zeitlin]`` table);
* :mod:`.run` — initial fields, the methods' steps over a batch, the dataset;
* :mod:`.plotting` — the vorticity on the sphere and the run's figures.

The model, the scheme and what each method keeps:
docs/model.md, "A second Lie group: the thermodynamic Zeitlin fluid".
"""
