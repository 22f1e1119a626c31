"""The dataset variables every matrix fluid writes about how its members ran
(the fixed point's iterations, each member's status and the step it stopped at),
with the same names, units and words for every geometry."""

from __future__ import annotations

import numpy as np


def run_variables(iterations: np.ndarray, status: np.ndarray, failed_step: np.ndarray, meanings: dict,
                  dims_t=("member", "t")) -> dict:
    """``{name: xarray.Variable}``: ``fixed_point_iterations`` (member, t), ``status`` and
    ``failed_step`` (member); ``meanings``: ``{flag: name}`` of the statuses."""
    import xarray as xr

    flags = sorted(meanings)
    return {
        "fixed_point_iterations": xr.Variable(dims_t, iterations, {
            "units": "1", "long_name": "fixed-point iterations",
            "comment": "mean per step over the output interval (0 for rk4 and the reference)"}),
        "status": xr.Variable(("member",), status, {
            "units": "1", "long_name": "member status", "flag_values": np.array(flags, dtype=np.int8),
            "flag_meanings": " ".join(meanings[k] for k in flags)}),
        "failed_step": xr.Variable(("member",), failed_step, {
            "units": "1", "long_name": "step that failed",
            "comment": "the step at which the member failed (-1: none); the member's later values are NaN"}),
    }


def provenance(scene, history: str | None = None) -> dict:
    """The global attributes that say what made a fluid's file: the scene's TOML, the
    software and Python versions, when, and the command (``history``)."""
    import platform

    from .. import cf
    from ..version import __version__

    created = cf.timestamp()
    return {"scene": scene.to_toml(), "software": f"liethermo {__version__}", "software_version": __version__,
            "python": platform.python_version(), "created": created,
            "history": cf.history_entry(history or f"liethermo {__version__}", created)}
