"""The worked examples of docs/extending.md run as documented: a study kind of
one's own from a module beside its study file, and the toy model in at most
100 lines that imports no private name."""

import re
import sys
from pathlib import Path

from liethermo.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_a_study_kind_of_ones_own_runs_from_its_study_file(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sys, "path", list(sys.path))  # the study file's folder joins the path
    monkeypatch.delitem(sys.modules, "mystudies", raising=False)
    monkeypatch.delitem(sys.modules, "mystudies.final_error", raising=False)
    study = ROOT / "examples" / "studies" / "final_error.toml"
    assert main(["study", str(study), "--reduced", "-o", str(tmp_path / "fe"), "--no-progress"]) == 0
    report = (tmp_path / "fe" / "report.md").read_text()
    assert "a smaller step gives a smaller final error, for every method" in report
    assert re.search(r"\| a smaller step gives a smaller final error, for every method \|[^\n]*\| holds \|", report)
    assert (tmp_path / "fe" / "final_error.png").is_file() and (tmp_path / "fe" / "final_error.csv").is_file()
    assert len((ROOT / "examples" / "studies" / "mystudies" / "final_error.py").read_text().splitlines()) <= 60
    capsys.readouterr()


def test_an_unknown_module_kind_is_refused_in_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('[study]\nkind = "nosuchpackage.nostudy"\n')
    assert main(["study", str(bad)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "nosuchpackage.nostudy" in err and "cannot be imported" in err


def test_the_toy_model_is_small_and_public():
    text = (ROOT / "tests" / "toymodel.py").read_text()
    assert len(text.splitlines()) <= 100
    imported = re.findall(r"^from liethermo[\w.]* import (.+)$", text, re.M)
    names = [n.strip() for line in imported for n in line.split(",")]
    assert names and not [n for n in names if n.startswith("_")], names
