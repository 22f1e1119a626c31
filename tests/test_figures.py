"""Figures are legible at their saved size.

conftest.legible_figures checks every figure any test saves with
tests/layout.py; here the check itself is shown to catch the defects the
figures had (colliding log tick labels, panel titles on the axis labels of the
row above, y labels over the neighbouring panel, an x label cut off), and a
run's four figures are drawn, including a failed RK2 member's note, and
checked.
"""

from __future__ import annotations


import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from layout import SAVED_FIGURES, layout_problems  # noqa: E402
from liethermo.plotting import scene_figures  # noqa: E402
from liethermo.runner import run_scene  # noqa: E402


@pytest.fixture
def figure():
    figs = []

    def make(*args, **kwargs):
        fig, axes = plt.subplots(*args, **kwargs)
        figs.append(fig)
        return fig, axes

    yield make
    for f in figs:
        plt.close(f)


def test_check_catches_colliding_log_tick_labels(figure):
    hs = 0.05 / 2.0 ** np.arange(5)  # the reduced convergence study's steps
    fig, axes = figure(2, 2, figsize=(10, 8), layout="constrained")
    for ax in axes.ravel():
        ax.loglog(hs, hs**2, "o-")
    problems = layout_problems(fig, 110)
    assert any("x tick label" in p and p.count("tick label") == 2 for p in problems), problems
    for ax in axes.ravel():  # what the convergence figure does now
        ax.set_xticks(hs, [f"{h:.3g}" for h in hs])
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    assert layout_problems(fig, 110) == []


def test_check_catches_titles_on_labels_and_labels_over_panels(figure):
    fig, axes = figure(2, 4, figsize=(14.4, 6.6))  # the stability map's grid, no layout engine
    for ax in axes.ravel():
        ax.set_title("vi:endpoint: log10 error (max over run)", fontsize=9)
        ax.set_xlabel("h|Omega_0| (rad)")
        ax.set_ylabel("kappa = c h / I_min")
    problems = layout_problems(fig, 110)
    assert any("title" in p and "x label" in p for p in problems), problems
    assert any(p.startswith("over another panel") and "y label" in p for p in problems), problems
    fig.set_layout_engine("constrained")
    assert layout_problems(fig, 110) == []


def test_check_catches_a_label_cut_off(figure):
    fig, ax = figure(figsize=(7, 3.8))
    ax.plot([0, 1], [0, 1])
    ax.set_xlabel("time t (s)")
    fig.subplots_adjust(bottom=0.08)  # the entropy figure's old margin
    problems = layout_problems(fig, 120)
    assert any(p.startswith("outside the canvas") and "x label" in p for p in problems), problems


def test_run_figures_are_legible(tmp_path):
    """The four figures of a run where RK2 fails (paper h, 160 steps) pass the
    check at 120 dpi; explicit margins, no layout engine (drawing speed)."""
    outputs = {}
    for method in ("vi", "rk2"):
        outputs[method] = tmp_path / f"r_{method}.nc"
        with np.errstate(over="ignore", invalid="ignore"):
            run_scene("paper", outputs[method], progress=False,
                      overrides=["integrator.steps=160", f"integrator.method='{method}'"])
    from liethermo import cf

    with cf.open_dataset(outputs["rk2"]) as rk2:
        assert int(rk2["status"][0]) != 0  # the failure note is drawn
    files = scene_figures(outputs, tmp_path, stem="r")
    assert [f.name for f in files] == ["r_center_of_mass.png", "r_energies.png", "r_total_energy.png",
                                       "r_entropy.png"]
    for f in files:  # saved through the conftest check
        assert str(f.resolve()) in SAVED_FIGURES


@pytest.mark.parametrize("scene, over", [
    ("paper", {"integrator.steps": 4, "output.compare": []}),
    ("zeitlin_ideal", {"zeitlin.N": 8, "initial.lmax": 5, "integrator.steps": 4, "output.every": 2,
                       "output.vorticity": True, "output.compare": []}),
])
def test_plain_xarray_labels_fit_on_one_line(scene, over):
    """xarray's automatic axis label "long_name [units]" wraps past 30
    characters (and a wrapped x label is cut off at the figure's edge): every
    variable's label fits on one line, and a variable whose detail moved out
    of its long_name keeps it in ``comment``."""
    from xarray.plot.utils import label_from_attrs

    import liethermo

    ds = liethermo.run(scene, over)
    for name, v in ds.variables.items():
        label = label_from_attrs(v)
        assert "\n" not in label and len(label) <= 30, (name, label)
    assert ds["t"].attrs["long_name"] == "time t" and "since the start of the run" in ds["t"].attrs["comment"]
    assert "t = 0" in ds["entropy" if scene == "zeitlin_ideal" else "energy_error"].attrs["comment"]


def test_model_term_parameters_label_on_one_line():
    """The terms' parameters become dataset variables (friction, expansion,
    drag): their labels fit on one line too, and their formulas are kept."""
    from liethermo.kernels.terms import registry

    for term in registry():
        for prm in term.parameters:
            if prm.shape is not None and prm.variable_name:
                assert len(f"{prm.long_name} [{prm.unit}]") <= 30, prm
                assert prm.comment, prm
