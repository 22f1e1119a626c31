"""Every kind of netCDF file liethermo writes passes the IOOS compliance-checker.

The checker runs at the CF version each file declares (``Conventions``) on a
small run (4 members x 20 steps, VI and RK2), a Dask run (combined file, kept
chunk files and ``--no-combine`` chunk files) and a reduced study; any error,
any check that raises and any warning that docs/netcdf.md does not justify
fails the test.  The other study kinds are checked by their own test modules
(test_studies_core, test_studies_extra), on the files their fixtures write.
The encoding is derived from dtypes, dims and units, so a dataset with
variables the project does not have yet must come out just as clean.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import netCDF4
import numpy as np
import pytest
import xarray as xr

from cfcheck import assert_cf_clean, cf_report
from liethermo import cf
from liethermo.cli import main
from liethermo.io import ChunkedWriter
from liethermo.runner import run_scene
from liethermo.studies.common import write_netcdf_atomic

pytest.importorskip("compliance_checker")

STUDIES = Path(__file__).resolve().parents[1] / "studies"
SMALL = ["--set", "ensemble.members=4", "--set", "integrator.steps=20", "--set", "output.figures=false",
         "--no-progress"]


def _history_command(path) -> str:
    """The command of the file's one-line history, after its UTC timestamp."""
    with netCDF4.Dataset(path) as nc:
        stamp, _, command = nc.getncattr("history").partition(": ")
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00", stamp), stamp
    return command


@pytest.fixture(scope="module")
def small_run(tmp_path_factory) -> tuple[list[Path], list[str]]:
    out = tmp_path_factory.mktemp("run") / "paper.nc"
    argv = ["run", "paper", "-o", str(out), *SMALL]
    assert main(argv) == 0
    return [out, out.with_name("paper_rk2.nc")], argv


def test_small_run_files_are_cf_clean(small_run):
    files, argv = small_run
    for path in files:
        r = assert_cf_clean(path)
        assert r.conventions == cf.CONVENTIONS
        assert not r.warnings, r.warnings
        assert _history_command(path) == shlex.join(["liethermo", *[a for a in argv if a != "--no-progress"]])  # not what made the data


def test_plain_xarray_reads_a_run_as_the_api_returns_it(small_run):
    """A collaborator without liethermo: plain ``xr.open_dataset`` with warnings
    as errors gives float seconds, plots with the base dependencies, and the
    file itself says how to select a component by its label."""
    import warnings

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from liethermo import api

    files, _ = small_run
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with xr.open_dataset(files[0]) as ds:
            assert ds["t"].dtype == np.float64 and float(ds["t"][-1]) == pytest.approx(2.0)
            ds["omega"].isel(member=0, axis=2).plot()
            plt.close("all")
            hint = ds["axis_label"].attrs["comment"]
            expr = hint.split(": ", 1)[1]
            z = eval(expr.replace("sel(axis_label='x')", "sel(axis_label='z')"), {"ds": ds})
            with api.open_dataset(files[0]) as mine:
                np.testing.assert_array_equal(z["omega"].values, mine["omega"].sel(axis="z").values)
                np.testing.assert_array_equal(ds["t"].values, mine["t"].values)


def test_dask_files_are_cf_clean(tmp_path):
    distributed = pytest.importorskip("distributed")
    from liethermo import distributed as ld

    # one worker thread: HDF5 (under netCDF4) must not write from two threads at once
    with distributed.Client(processes=False, n_workers=1, threads_per_worker=1,
                            dashboard_address=None) as client:
        out = tmp_path / "dask.nc"
        # combined file, chunk files kept
        _, summ = ld.run_scene_dask("paper", out, address=client, task_members=3, keep_parts=True,
                                    overrides=["ensemble.members=7", "integrator.steps=20"],
                                    progress=False)
        assert summ.tasks == 3
        # --no-combine from the command line: chunk files and index.json only
        nc_out = tmp_path / "nocombine.nc"
        argv = ["run", "paper", "-o", str(nc_out), *SMALL, "--set", "output.compare=[]",
                "--dask", client.scheduler.address, "--no-combine"]
        assert main(argv) == 0
    assert not nc_out.exists()
    parts = sorted(ld.parts_dir(out).glob("part-*.nc"))
    nocombine = sorted(ld.parts_dir(nc_out).glob("part-*.nc"))
    assert len(parts) == 3 and nocombine
    # chunk files differ only in their members: the first of each set stands for the others
    for path in (out, parts[0], nocombine[0]):
        assert_cf_clean(path)
    assert _history_command(out).startswith("liethermo.distributed.run_scene_dask('paper', ")
    assert _history_command(parts[0]) == _history_command(out)
    assert _history_command(nocombine[0]) == shlex.join(["liethermo", *[a for a in argv if a != "--no-progress"]])  # not what made the data
    # the combined file reads back with the kept parts' members, in order
    with cf.open_dataset(out) as ds:
        np.testing.assert_array_equal(ds["member"].values, np.arange(7))
        assert list(ds["axis"].values) == ["x", "y", "z"]


def test_reduced_study_file_is_cf_clean_and_its_cache_claims_nothing(tmp_path):
    argv = ["study", str(STUDIES / "energy_drift.toml"), "--reduced", "-o", str(tmp_path), "--no-progress"]
    assert main(argv) == 0
    r = assert_cf_clean(tmp_path / "energy_drift.nc")
    assert not r.warnings
    assert _history_command(tmp_path / "energy_drift.nc") == shlex.join(["liethermo", *[a for a in argv if a != "--no-progress"]])  # not what made the data
    points = sorted((tmp_path / "points").glob("*.nc"))
    assert points
    for p in points:  # the resume cache is an internal format: no CF claim
        with netCDF4.Dataset(p) as nc:
            assert "Conventions" not in nc.ncattrs()


def test_checker_reports_what_the_old_format_got_wrong(tmp_path):
    """The helper sees errors: int64 under CF-1.8, time in plain 's', a string
    coordinate variable (the checker's monotonicity check raises on it)."""
    path = tmp_path / "old.nc"
    with netCDF4.Dataset(path, "w") as nc:
        nc.setncatts({"Conventions": "CF-1.8", "title": "t", "history": "h"})
        nc.createDimension("time", 3)
        nc.createDimension("axis", 3)
        t = nc.createVariable("time", "f8", ("time",))
        t[:] = [0.0, 0.1, 0.2]
        t.setncatts({"units": "s", "standard_name": "time", "long_name": "time"})
        k = nc.createVariable("step", "i8", ("time",))
        k[:] = [0, 1, 2]
        k.setncatts({"units": "1", "long_name": "step"})
        a = nc.createVariable("axis", str, ("axis",))
        a[:] = np.array(["x", "y", "z"], dtype=object)
        a.long_name = "axis"
    r = cf_report(path)
    text = " ".join(m for _, m in r.errors)
    assert "int64" in text and "since" in text
    assert "check_coordinate_variables_strict_monotonicity" in r.exceptions
    with pytest.raises(AssertionError):
        assert_cf_clean(path)


# ----------------------------------------------------------------------------- the encoding itself

def _future_dataset(n: int = 5, offset: int = 0) -> xr.Dataset:
    """Variables of kinds the project does not have yet: int and float, with and
    without member/t, a boolean, a string coordinate, and a coordinate that
    claims to be a calendar time (``time``), which CF encodes as one."""
    rng = np.random.default_rng(offset)
    t = np.arange(4) * 0.25
    ds = xr.Dataset(
        {
            "omega_step": (("member", "t", "axis"), rng.normal(size=(n, 4, 3)),
                           {"units": "rad s-1", "long_name": "a vector series"}),
            "energy_error_paper": (("member", "t"), rng.normal(size=(n, 4)).astype(np.float32),
                                   {"units": "J", "long_name": "a float32 series"}),
            "friction_coefficients": (("mode",), np.array([1.0, 2.0]), {"units": "N m s", "long_name": "per mode"}),
            "counts": (("member", "mode"), rng.integers(0, 2**40, size=(n, 2)), {"units": "1", "long_name": "int64"}),
            "small_counts": (("member",), np.arange(n, dtype=np.uint16), {"units": "1", "long_name": "uint16"}),
            "converged": (("member",), np.arange(n) % 2 == 0, {"units": "1", "long_name": "a boolean"}),
            "heat_capacity": ((), 3.5, {"units": "J K-1", "long_name": "a scalar per kelvin"}),
            "level": ((), np.int64(3), {"units": "1", "long_name": "a scalar int"}),
            "clock_drift": (("time",), np.array([0.0, 1e-3]), {"units": "s", "long_name": "a series in time"}),
        },
        coords={
            "member": ("member", np.arange(offset, offset + n), {"units": "1", "long_name": "ensemble member"}),
            "t": ("t", t, {"units": "s", "long_name": "time since the start of the run"}),
            "time": ("time", [0.0, 3600.0], {"units": "s", "long_name": "wall-clock time",
                                            "standard_name": "time"}),
            "axis": ("axis", ["x", "y", "z"], {"long_name": "body-frame axis"}),
            "mode": ("mode", ["slow", "fast"], {"long_name": "mode"}),
        },
        attrs={"title": "future variables", "Conventions": "CF-1.8"},
    )
    return ds


def test_new_variables_of_any_kind_come_out_clean_from_both_writers(tmp_path):
    full = _future_dataset(6)
    # chunked writer (runs, Dask parts): two member chunks
    chunked = tmp_path / "chunked.nc"
    with ChunkedWriter(chunked, 6, full.attrs, history="my_api_call(42)") as w:
        w.write(full.isel(member=slice(0, 4)), 0)
        w.write(full.isel(member=slice(4, 6)), 4)
    # xarray writer (studies)
    whole = write_netcdf_atomic(full, tmp_path / "whole.nc", history="my_api_call(43)")
    for path, call in ((chunked, "my_api_call(42)"), (whole, "my_api_call(43)")):
        r = assert_cf_clean(path)
        assert not r.warnings, r.warnings
        assert r.conventions == cf.CONVENTIONS  # replaces what the dataset said
        assert _history_command(path) == call
        with netCDF4.Dataset(path) as nc:
            assert nc["time"].units == cf.TIME_UNITS and nc["time"].calendar == cf.TIME_CALENDAR
            assert nc["counts"].dtype == np.int64 and nc["small_counts"].dtype == np.uint16
            assert nc["converged"].dtype == np.int8
            assert "axis" not in nc.variables and "mode" not in nc.variables
            assert nc["mode_label"].dimensions == ("mode",)
            assert set(nc["counts"].coordinates.split()) == {"mode_label"}
            assert set(nc["omega_step"].coordinates.split()) == {"axis_label"}
            assert nc["heat_capacity"].units_metadata == "temperature: difference"
            assert "_FillValue" not in nc["time"].ncattrs()
            assert nc["t"].units == "s" and "standard_name" not in nc["t"].ncattrs()
            assert "set_xindex('axis_label')" in nc["axis_label"].comment
        back = cf.load_dataset(path)
        assert list(back["axis"].values) == ["x", "y", "z"] and list(back["mode"].values) == ["slow", "fast"]
        np.testing.assert_array_equal(back["time"].values, full["time"].values)  # seconds, not dates
        np.testing.assert_array_equal(back["t"].values, full["t"].values)
        assert "comment" not in back["axis"].attrs  # the plain-xarray hint is not needed once decoded
        for name in full.data_vars:
            a, b = back[name].values, full[name].values
            assert a.shape == b.shape and np.array_equal(a, b.astype(a.dtype)), name
            if b.dtype.kind != "b":
                assert a.dtype == b.dtype, name
        assert back["counts"].sel(mode="fast").dims == ("member",)


def test_encoding_is_idempotent_and_leaves_the_input_alone():
    ds = _future_dataset()
    before = {k: dict(v.attrs) for k, v in ds.variables.items()}
    once = cf.encode(ds, history="x")
    twice = cf.encode(once)
    assert {k: v.attrs for k, v in ds.variables.items()} == before
    assert list(ds["axis"].values) == ["x", "y", "z"]
    assert set(once.variables) == set(twice.variables)
    for k in once.variables:
        assert once[k].attrs == twice[k].attrs, k
    assert twice.attrs["history"] == once.attrs["history"]
    with pytest.raises(ValueError, match="axis_label"):
        cf.encode(ds.assign(axis_label=("axis", [1, 2, 3])))


def test_history_default_names_the_api_call(tmp_path):
    out = tmp_path / "api.nc"
    run_scene("paper", out, overrides=["ensemble.members=2", "integrator.steps=5", "output.compare=[]"],
              progress=False)
    assert _history_command(out) == ("liethermo.runner.run_scene('paper', " + repr(str(out))
                                     + ", overrides=['ensemble.members=2', 'integrator.steps=5', "
                                       "'output.compare=[]'])")
    run_scene("paper", out, overrides=["ensemble.members=2", "integrator.steps=5"], progress=False,
              history="my_notebook: run the paper scene")
    assert _history_command(out) == "my_notebook: run the paper scene"


def test_every_printed_time_selects_its_time(tmp_path, monkeypatch):
    """t holds the decimal times k h (0.3, not 3 x 0.1 = 0.30000000000000004), so
    ``ds.sel(t=...)`` with a time as printed finds every one of the paper scene's 301
    times in its file, and a Zeitlin run's too; docs/netcdf.md's plain-xarray block runs
    on that file and labels the relative energy error as a ratio, not in J."""
    from decimal import Decimal

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from liethermo.scene import load_scene
    from liethermo.zeitlin.run import simulate

    monkeypatch.chdir(tmp_path)
    out = tmp_path / "data" / "runs" / "paper_vi.nc"
    assert main(["run", "paper", "--set", "output.compare=[]", "--set", "output.figures=false",
                 "--no-progress"]) == 0
    doc = (Path(__file__).resolve().parents[1] / "docs" / "netcdf.md").read_text()
    block = re.search(r"## Opening a file.*?```python\n(.*?)```", doc, re.S).group(1)
    ns: dict = {}
    exec(compile(block, "docs/netcdf.md", "exec"), ns)
    assert plt.gca().get_ylabel() == "(E_k - E_0)/E_mech,0 [1]"
    plt.close("all")
    ns["ds"].close()
    ds = cf.load_dataset(out)
    printed = [float(Decimal(k) * Decimal("0.1")) for k in range(301)]  # 0, 0.1, ..., 30 as typed
    assert ds.sizes["t"] == 301
    assert [float(ds.sel(t=t)["t"]) for t in printed] == printed
    assert ds.sel(t=0.3)["step"].item() == 3 and np.array_equal(ds["step"].values, np.arange(301))
    assert cf.decimal_times([3, 7], 0.1).tolist() == [0.3, 0.7] and 3 * 0.1 != 0.3  # what it fixes
    assert cf.decimal_times([3], 2.5e-05)[0] == 7.5e-05 and cf.decimal_times([2], 0.5)[0] == 1.0
    z = simulate(load_scene("zeitlin_decay", {"zeitlin.N": 4, "initial.lmax": 3, "initial.m": 2, "ensemble.members": 1,
                                              "integrator.steps": 60, "output.every": 3,
                                              "integrator.method": "rk4"}), progress=False)
    zt = [float(Decimal(j) * Decimal("0.03")) for j in range(21)]
    assert [float(z.sel(t=t)["t"]) for t in zt] == zt
