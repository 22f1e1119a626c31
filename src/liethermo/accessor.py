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

    def model(self):
        """The model whose run wrote this dataset (from its stored scene; a file
        without one is read by the registry's rule, :func:`liethermo.models.model_of`)."""
        import sys

        from .models import model_of

        if sys.version_info >= (3, 11):
            import tomllib
        else:  # pragma: no cover
            import tomli as tomllib
        text = self._ds.attrs.get("scene", "")
        try:
            tables = tomllib.loads(text) if isinstance(text, str) else {}
        except tomllib.TOMLDecodeError:
            tables = {}
        return model_of(tables)

    def derived(self) -> xr.Dataset:
        """Every variable a run of the file's scene can write, with
        ``output.variables = "all"``: those the file stores, and those its model
        derives from them (the heavy top: the energies, the entropy and temperature,
        the momenta, the centre of mass, the initial data, from the stored state,
        bit for bit).  A model that derives nothing gives the dataset as it is."""
        derive = getattr(self.model(), "derived", None)
        if derive is None:
            return self._ds
        out = derive(self._ds)
        for name, var in self._ds.data_vars.items():  # what the file holds stays as it is
            if name not in out:
                out[name] = var
        return out

    def __getitem__(self, name: str) -> xr.DataArray:
        """One variable, stored or derived (:meth:`derived`): ``ds.liethermo["kinetic_energy"]``."""
        if name in self._ds.variables:
            return self._ds[name]
        out = self.derived()
        if name not in out.variables:
            raise KeyError(f"{name!r}: neither stored in the dataset nor derived by its model; "
                           f"it has {', '.join(sorted(map(str, out.data_vars)))}")
        return out[name]

    def relative_energy_error(self, convention: str = "node") -> xr.DataArray:
        """The energy error relative to the run's natural energy scale (dimensionless),
        as the file's model defines it.  The top: (E_k − E₀)/E_mech,0 with E_mech,0 =
        K₀ + V₀ + |m g ℓ|, the energy friction can turn into heat; ``convention="node"``:
        node values (every method), ``"paper"``: the variational integrators' step
        velocity with the node values (the paper's figure)."""
        model = self.model()
        reader = getattr(model, "energy_error_of", None)
        if reader is None:
            raise KeyError(f"{model.title or model.name}: its files carry no relative energy error")
        return reader(self._ds, convention)

    def quantiles(self, variable: str | xr.DataArray, q=(0.05, 0.5, 0.95), *,
                  only_ok: bool = False) -> xr.DataArray:
        """Quantiles over the members (e.g. the 5–95 % band and the median of an
        energy error over time); ``only_ok``: over the members that completed.
        A failed member's NaN values count as +inf (they are above every band)."""
        da = self[variable] if isinstance(variable, str) else variable
        if only_ok:
            da = da.where(self.ok, drop=True)
        da = da.fillna(np.inf)
        return da.quantile(list(q), dim="member", method="inverted_cdf")
