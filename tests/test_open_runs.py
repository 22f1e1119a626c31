"""Compared methods as one dataset: ``liethermo.open_runs`` and
``liethermo.run(..., compare=True, combine=True)`` give a Dataset with a
``method`` dimension, variables only some methods have filled with NaN,
opened lazily (dask) from the files."""

from __future__ import annotations

import dask.array as da
import numpy as np
import pytest

import liethermo
from liethermo.scene import SceneError

TOP = {"integrator.steps": 20, "ensemble.members": 5, "output.member_chunk": 2, "output.figures": False,
       "output.variables": "all"}  # the combined files with their derived variables too
FLUID = {"zeitlin.N": 6, "initial.lmax": 4, "integrator.steps": 20, "ensemble.members": 2,
         "output.figures": False, "output.compare": ["rk4"]}


def test_a_compared_run_combined_is_one_lazy_dataset_with_a_method_dimension(tmp_path):
    out = tmp_path / "p.nc"
    ds = liethermo.run("paper", TOP, compare=True, combine=True, output=out)
    assert list(ds["method"].values) == ["vi", "rk2"]
    assert ds["omega"].dims == ("method", "member", "t", "axis")
    assert isinstance(ds["omega"].data, da.Array) and isinstance(ds["energy_error"].data, da.Array)
    assert list(ds["source"].values) == [str(out), str(tmp_path / "p_rk2.nc")]
    assert list(ds["h"].values) == [0.1, 0.1] and ds["h"].attrs["units"] == "s"
    assert list(ds["method_order"].values) == [1, 2]  # the paper's VI starts at the node: first order
    # each method's values are its file's; what only the VI has is NaN for RK2
    for m, path in (("vi", out), ("rk2", tmp_path / "p_rk2.nc")):
        with liethermo.open_dataset(path) as one:
            for v in ("omega", "gamma", "energy_error", "status"):
                np.testing.assert_array_equal(ds[v].sel({"method": m}).values, one[v].values, err_msg=v)
    with liethermo.open_dataset(out) as vi:
        np.testing.assert_array_equal(ds["omega_step"].sel({"method": "vi"}).values, vi["omega_step"].values)
    for v in ("omega_step", "energy_error_paper", "newton_iterations_mean", "newton_iterations_max"):
        assert bool(ds[v].sel({"method": "rk2"}).isnull().all()), v
        assert isinstance(ds[v].data, da.Array), v
    assert ds["newton_iterations_max"].dtype == np.float64  # an integer count with NaN for RK2
    assert "method" not in ds.attrs and "scene" not in ds.attrs  # they differ between the methods
    assert "method vi" in ds.attrs["summary"] and "method rk2" in ds.attrs["summary"]
    # a reduction over members stays lazy until computed
    med = ds["energy_error"].max("member")
    assert isinstance(med.data, da.Array) and med.compute().shape == (2, 21)
    ds.close()

    again = liethermo.open_runs([out, tmp_path / "p_rk2.nc"])
    assert list(again["method"].values) == ["vi", "rk2"]
    np.testing.assert_array_equal(again["total_energy"].values, ds["total_energy"].values)
    labelled = liethermo.open_runs({"a": out, "b": tmp_path / "p_rk2.nc"})
    assert list(labelled["method"].values) == ["a", "b"]
    with pytest.raises(ValueError, match="two runs of method 'vi'"):
        liethermo.open_runs([out, out])
    with pytest.raises(FileNotFoundError, match="no such file"):
        liethermo.open_runs([tmp_path / "none.nc"])
    again.close()
    labelled.close()


def test_a_fluid_compared_run_combined_and_in_memory(tmp_path):
    ds = liethermo.run("zeitlin_decay", FLUID, compare=True, combine=True, output=tmp_path / "z.nc")
    assert list(ds["method"].values) == ["split", "rk4"]
    assert ds["energy"].dims == ("method", "member", "t") and isinstance(ds["energy"].data, da.Array)
    mem = liethermo.run("zeitlin_decay", FLUID, compare=True, combine=True)
    assert isinstance(mem["energy"].data, np.ndarray)
    np.testing.assert_allclose(mem["energy"].values, ds["energy"].values, rtol=1e-14)
    ds.close()


def test_combine_needs_compare():
    with pytest.raises(SceneError, match="combine=True joins the compared methods"):
        liethermo.run("paper", TOP, compare=False, combine=True)


def test_without_dask_the_runs_are_loaded_with_a_warning(tmp_path, monkeypatch):
    import liethermo.combine as lc

    liethermo.run("paper", {**TOP, "integrator.steps": 4}, compare=True, output=tmp_path / "p.nc")
    monkeypatch.setattr(lc, "dask_available", lambda: False)
    with pytest.warns(UserWarning, match=r"dask is not installed: open_runs loads the runs into memory "
                                         r"\(pip install dask to open them lazily\)"):
        ds = liethermo.open_runs([tmp_path / "p.nc", tmp_path / "p_rk2.nc"])
    assert isinstance(ds["omega"].data, np.ndarray) and ds.sizes["method"] == 2
