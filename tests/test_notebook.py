"""studies/explore.ipynb runs top to bottom on a reduced energy-drift study.

The notebook opens the study's netCDF with plain xarray (path from
``LIETHERMO_STUDY_NC``), redraws the band figure and prints whether the VI's
median energy error stays bounded at h = 0.1 s; the test checks that line.
"""

from __future__ import annotations

from pathlib import Path

import nbformat
from nbclient import NotebookClient

from liethermo.studies import get_study
from liethermo.studies.runner import load_study

ROOT = Path(__file__).resolve().parents[1]


def test_explore_notebook_reproduces_the_energy_figure(tmp_path, monkeypatch):
    study = load_study(ROOT / "studies" / "energy_drift.toml")
    get_study("energy_drift").run(study, tmp_path, reduced=True, progress=False)
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
    assert not any("liethermo" in c.source for c in nb.cells if c.cell_type == "code" and "import" in c.source
                   and "import liethermo" in c.source)
