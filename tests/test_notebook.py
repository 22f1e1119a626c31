"""studies/explore.ipynb runs top to bottom on a reduced energy-drift study.

The notebook opens the study's netCDF with ``liethermo.open_dataset`` (path
from ``LIETHERMO_STUDY_NC``), redraws the band figure and prints whether the
VI's median energy error stays bounded at h = 0.1 s; the test checks that
line.  Without results it stops with the command that makes them.
"""

from __future__ import annotations

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient
from nbclient.exceptions import CellExecutionError

from liethermo.studies import get_study
from liethermo.studies.runner import load_study

ROOT = Path(__file__).resolve().parents[1]


def test_explore_notebook_reproduces_the_energy_figure(tmp_path, monkeypatch):
    study = load_study(ROOT / "studies" / "energy_drift.toml")
    get_study("energy_drift").STUDY.run(study, tmp_path, reduced=True, progress=False)
    nc = tmp_path / "energy_drift.nc"
    monkeypatch.setenv("LIETHERMO_STUDY_NC", str(nc))
    monkeypatch.setenv("JUPYTER_PLATFORM_DIRS", "1")  # silences jupyter_core's path-migration warning
    nb = nbformat.read(ROOT / "studies" / "explore.ipynb", as_version=4)
    assert nb.metadata["kernelspec"]["name"] == "python3"
    NotebookClient(nb, kernel_name="python3", timeout=180,
                   resources={"metadata": {"path": str(tmp_path)}}).execute()
    assert (tmp_path / "explore_energy_bands.png").is_file()
    text = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []))
    assert "bounded: True" in text
    assert any("liethermo.open_dataset(" in c.source for c in nb.cells if c.cell_type == "code")


def test_explore_notebook_without_results_names_the_command(tmp_path, monkeypatch):
    monkeypatch.setenv("LIETHERMO_STUDY_NC", str(tmp_path / "absent.nc"))
    monkeypatch.setenv("JUPYTER_PLATFORM_DIRS", "1")
    nb = nbformat.read(ROOT / "studies" / "explore.ipynb", as_version=4)
    with pytest.raises(CellExecutionError) as exc:
        NotebookClient(nb, kernel_name="python3", timeout=180,
                       resources={"metadata": {"path": str(tmp_path)}}).execute()
    msg = str(exc.value)
    assert "FileNotFoundError" in msg and "liethermo study studies/energy_drift.toml --reduced" in msg
    assert "StopIteration" not in msg
