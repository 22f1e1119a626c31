"""The torus fluid's studies, reduced: the generic convergence study on torus_decay, the
resolution against the pseudo-spectral solution, and the warm patch's relaxation to the
rest state that energy conservation predicts."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from liethermo.cf import open_dataset
from liethermo.cli import main

STUDIES = Path(__file__).resolve().parents[1] / "studies"


def _run(tmp_path, name, *extra):
    out = tmp_path / name
    assert main(["study", str(STUDIES / f"{name}.toml"), "--reduced", "-o", str(out), "--no-progress", *extra]) == 0
    return out


def test_convergence_on_the_torus_gives_the_declared_orders(tmp_path):
    out = _run(tmp_path, "convergence", "--scene", "torus_decay")
    text = (out / "report.md").read_text()
    assert "cmp" in text and "magmp" in text and "rk4" in text
    assert "| FAILS |" not in text


def test_resolution_against_the_continuum(tmp_path):
    out = _run(tmp_path, "torus_resolution")
    with open_dataset(out / "torus_resolution.nc") as ds:
        e = ds["error"].values
        assert np.isclose(e[1], 8.39e-2, rtol=0.02) and np.isclose(e[2], 2.18e-2, rtol=0.02)  # N = 15, 31
        assert ds["order"].values[-1] >= 1.8
    assert "| FAILS |" not in (out / "report.md").read_text()


def test_the_warm_patch_relaxes_to_the_predicted_rest_state(tmp_path):
    from liethermo.torus.studies.torus_convection import predicted_end

    out = _run(tmp_path, "torus_convection")
    text = (out / "report.md").read_text()
    assert "| FAILS |" not in text and "decaying transient" in text
    with open_dataset(out / "torus_convection.nc") as ds:
        end = ds.isel(t=-1)
        assert abs(float(end["entropy"] - end["predicted_entropy"])) < 1e-3 * float(end["predicted_entropy"])
        assert abs(0.5 * float(end["theta_min"] + end["theta_max"]) - float(end["predicted_theta"])) < 1e-3
    # negative control: the predicted rest state of a larger energy is warmer
    a, b = predicted_end(10.0, 9, 1.0, 1.0, 0.2), predicted_end(20.0, 9, 1.0, 1.0, 0.2)
    assert b["theta"] > a["theta"] and b["S_tot"] > a["S_tot"]
