"""A study of one's own: the relative energy error at t_end, per method and step h.

Runs on every model with study support (the top, the fluid):
``liethermo study examples/studies/final_error.toml``.  The study file names
this module as its kind, ``kind = "mystudies.final_error"``; the package sits
beside the study file, whose folder is put on the import path.
"""

import numpy as np
import xarray as xr

from liethermo.studies.common import dim_name
from liethermo.studies.framework import Figure, Option, Stage, Study, Table, Verdict, first_point, run_scene

H = dim_name("integrator.h")


def final_error(ctx, coords) -> xr.Dataset:
    """One (point, method): the ensemble's |relative energy error| at t_end."""
    h = float(coords["point"]["integrator.h"])
    steps = round(ctx.opt["t_end"] / h)
    ds, st = run_scene(ctx.scene(coords["point"]), coords["scheme"], h=h, steps=steps, every=steps)
    err = np.abs(ctx.model.relative_energy_error(ds)[:, -1])
    return xr.Dataset({"final_error": ("member", err), "kernel_time": ((), st.kernel_time)})


def tables(ds, ctx):
    rows = [{"method": m, "h (s)": float(h), "median final error": float(ds["median_error"].sel({"scheme": m, H: h}))}
            for m in ctx.methods for h in ds[H].values]
    return [Table("final_error", "Median |relative energy error| at t_end", rows)]


def verdicts(ds, ctx):
    e = ds["median_error"]
    finer = bool((e.isel({H: -1}) <= e.isel({H: 0})).all())
    return [Verdict("a smaller step gives a smaller final error, for every method",
                    f"{float(e.isel({H: 0}).max()):.2e} at the largest h, {float(e.isel({H: -1}).max()):.2e} "
                    "at the smallest", "median over members, every method", finer)]


STUDY = Study(
    kind="final_error", title="Energy error at t_end",
    description="median |relative energy error| at t_end per method and h",
    options=(Option("t_end", 2.0, "number>0", "s", "simulated time"),),
    stages=(Stage("runs", final_error, over=("point", "scheme")),),
    quantities={"final_error": ("1", "|relative energy error| at t_end"),
                "median_error": ("1", "median over members of the final error"),
                "kernel_time": ("s", "kernel time of the point's ensemble"), H: ("s", "time step h")},
    derive=lambda ds, ctx: ds.assign(median_error=ds["final_error"].median("member")),
    tables=tables, verdicts=verdicts,
    figures=(Figure("final_error", x=H, y=("median_error",), logx=True, logy=True, title="Energy error at t_end",
                    select=lambda ds, ctx: first_point(ds, ctx, keep=(H,)),
                    claim="the final error falls with h at each method's order"),),
    report="Scene `{scene}`: the relative energy error at t_end = {opt[t_end]} s, median over the members.",
)
