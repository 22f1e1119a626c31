"""The ``ds.liethermo`` accessor of xarray datasets (registered on import).

Kept apart from :mod:`liethermo.api` so that registering it costs only
xarray: ``import liethermo`` registers it as soon as xarray is imported
(see :mod:`liethermo`), without loading the kernels.
"""

from __future__ import annotations

import numpy as np
import xarray as xr


@xr.register_dataset_accessor("liethermo")
class LiethermoAccessor:
    """``ds.liethermo``: the quantities analysts of a run dataset compute again and again."""

    def __init__(self, ds: xr.Dataset):
        self._ds = ds

    @property
    def ok(self) -> xr.DataArray:
        """Members that completed every step (status ok)."""
        return self._ds["status"] == 0

    @property
    def failed(self) -> xr.DataArray:
        """Members that failed (Newton did not converge, or the state overflowed)."""
        return self._ds["status"] != 0

    def status_counts(self) -> dict[str, int]:
        """Members per status meaning."""
        st = self._ds["status"]
        meanings = str(st.attrs.get("flag_meanings", "ok newton_not_converged non_finite")).split()
        values = np.asarray(st.attrs.get("flag_values", range(len(meanings)))).tolist()
        return {m: int((st == v).sum()) for m, v in zip(meanings, values)}

    def relative_energy_error(self, convention: str = "node") -> xr.DataArray:
        """(E_k − E₀)/E_mech,0 (dimensionless) with E_mech,0 = K₀ + V₀ + |m g ℓ|, the
        energy friction can turn into heat.  ``convention="node"``: node values
        (every method); ``"paper"``: the variational integrators' step velocity
        with the node values (the paper's figure)."""
        name = {"node": "energy_error", "paper": "energy_error_paper"}.get(convention)
        if name is None:
            raise ValueError(f"convention must be 'node' or 'paper', got {convention!r}")
        if name not in self._ds:
            raise KeyError(f"{name}: this dataset has no energy error in the {convention} convention "
                           "(it exists for the variational integrators only)")
        rel = self._ds[name] / self._ds["mechanical_energy_initial"]
        rel.attrs = {"units": "1", "long_name": f"relative total energy error ({convention} values)"}
        return rel

    def quantiles(self, variable: str | xr.DataArray, q=(0.05, 0.5, 0.95), *,
                  only_ok: bool = False) -> xr.DataArray:
        """Quantiles over the members (e.g. the 5–95 % band and the median of an
        energy error over time); ``only_ok``: over the members that completed.
        A failed member's NaN values count as +inf (they are above every band)."""
        da = self._ds[variable] if isinstance(variable, str) else variable
        if only_ok:
            da = da.where(self.ok, drop=True)
        da = da.fillna(np.inf)
        return da.quantile(list(q), dim="member", method="inverted_cdf")
