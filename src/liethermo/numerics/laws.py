"""The names of the discrete laws a method may keep to round-off, shared by
every model's method declarations (:class:`liethermo.models.MethodInfo`)."""

#: Laws a method may satisfy exactly (to round-off).
LAW_UNIT_GAMMA = "unit_gamma"  # | |Γ_k| − 1 | at round-off
LAW_ROTATION = "rotation"  # R_kᵀR_k = I at round-off (attitude)
LAW_ENTROPY_MONOTONE = "entropy_monotone"  # S_{k+1} ≥ S_k (positive steps)
LAW_KELVIN_NOETHER = "kelvin_noether"  # the discrete Kelvin–Noether law (docs/model.md)
LAW_CASIMIR = "casimir"  # |μ| constant under double-bracket friction without torques
LAW_VERTICAL_MOMENTUM = "vertical_momentum"  # Γ·μ constant without friction (gravity's symmetry)
