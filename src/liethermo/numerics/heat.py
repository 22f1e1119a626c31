"""The thermodynamics of an ideal solid, shared by every model.

A body of constant heat capacity c_v (J K⁻¹) that starts at T₀ (K) and has
absorbed the heat q = U − U₀ (J) has the temperature T = T₀ + q/c_v and the
entropy S − S₀ = c_v log(T/T₀) = c_v log1p(q/(c_v T₀)).  The top's fluid and
the Zeitlin fluid both turn their dissipated energy into heat this way.
"""

from __future__ import annotations

import numpy as np


def entropy_of_heat(q, cv, T0):
    """S − S₀ = c_v log1p(q/(c_v T₀)) in J K⁻¹ (never negative for q ≥ 0)."""
    return cv * np.log1p(q / (cv * T0))


def temperature_of_heat(q, cv, T0):
    """T = T₀ + q/c_v in K."""
    return T0 + q / cv
