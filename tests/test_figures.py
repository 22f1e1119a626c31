"""Figures are legible at their saved size.

conftest.legible_figures checks every figure any test saves with
tests/layout.py; here the check itself is shown to catch the defects the
figures had (colliding log tick labels, panel titles on the axis labels of the
row above, y labels over the neighbouring panel, an x label cut off), and a
run's four figures are drawn, including a failed RK2 member's note, and
checked.
"""

from __future__ import annotations


from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from layout import SAVED_FIGURES, layout_problems  # noqa: E402
from liethermo.top.plotting import scene_figures  # noqa: E402
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

    ds = liethermo.run(scene, over).liethermo.derived()  # the stored variables and the derived ones
    for name, v in ds.variables.items():
        label = label_from_attrs(v)
        assert "\n" not in label and len(label) <= 30, (name, label)
    assert ds["t"].attrs["long_name"] == "time t" and "since the start of the run" in ds["t"].attrs["comment"]
    assert "t = 0" in ds["entropy" if scene == "zeitlin_ideal" else "energy_error"].attrs["comment"]


def test_model_term_parameters_label_on_one_line():
    """The terms' parameters become dataset variables (friction, expansion,
    drag): their labels fit on one line too, and their formulas are kept."""
    from liethermo.top.kernels.terms import registry

    for term in registry():
        for prm in term.parameters:
            if prm.shape is not None and prm.variable_name:
                assert len(f"{prm.long_name} [{prm.unit}]") <= 30, prm
                assert prm.comment, prm


# ----------------------------------------------------------------------------- what the figures show


def _captured(monkeypatch, module, name):
    """Figures that ``module.name`` (its save function) saves, kept for inspection."""
    figs = {}
    original = getattr(module, name)

    def keep(fig, path, *args, **kwargs):
        figs[Path(path).name] = fig
        return original(fig, path, *args, **kwargs)

    monkeypatch.setattr(module, name, keep)
    return figs


def _bands(ax):
    from matplotlib.collections import PolyCollection

    return [c for c in ax.collections if isinstance(c, PolyCollection) and len(c.get_paths())]


def _legend_clear_of_data(fig):
    """Every legend of a 2-D axes lies outside the data area of every axes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    renderer = FigureCanvasAgg(fig).get_renderer()  # the saved figure was closed: a canvas again
    fig.draw(renderer)
    for ax in fig.axes:
        leg = ax.get_legend()
        if leg is None:
            continue
        box = leg.get_window_extent(renderer)
        for other in fig.axes:
            area = other.get_window_extent(renderer)
            assert not box.overlaps(area), (leg.get_texts()[0].get_text(), other.get_title())


def _coinciding_lines_both_show(ax):
    """Where two lines of a panel lie on each other, the one on top is dashed
    or marked and differs in colour or style, so the one below shows."""
    lines = sorted([ln for ln in ax.get_lines() if len(ln.get_xdata())], key=lambda ln: ln.get_zorder())
    for i, low in enumerate(lines):
        for high in lines[i + 1:]:
            y0, y1 = np.asarray(low.get_ydata(), float), np.asarray(high.get_ydata(), float)
            if y0.shape != y1.shape or not np.allclose(y0, y1, rtol=1e-2, equal_nan=True):
                continue
            see_through = high.get_linestyle() not in ("-", "solid") or high.get_marker() not in ("", "None", None)
            distinct = (low.get_color(), low.get_linestyle()) != (high.get_color(), high.get_linestyle())
            assert see_through and distinct, (low.get_label(), high.get_label())


@pytest.fixture(scope="module")
def top_ensemble(tmp_path_factory):
    """A 24-member paper run (VI and RK2, 60 steps) and a one-member one."""
    d = tmp_path_factory.mktemp("ens")
    paths = {}
    for members in (24, 1):
        for method in ("vi", "rk2"):
            paths[members, method] = d / f"m{members}_{method}.nc"
            with np.errstate(over="ignore", invalid="ignore"):
                run_scene("paper", paths[members, method], progress=False,
                          overrides=["integrator.steps=60", f"integrator.method='{method}'",
                                     f"ensemble.members={members}"])
    return d, paths


@pytest.mark.parametrize("members", [24, 1])
def test_run_figures_show_the_ensemble_as_median_and_band(top_ensemble, monkeypatch, members):
    from liethermo.top import plotting

    d, paths = top_ensemble
    figs = _captured(monkeypatch, plotting, "_save")
    plotting.scene_figures({m: paths[members, m] for m in ("vi", "rk2")}, d / f"fig{members}", stem="e")
    for name in ("e_energies.png", "e_entropy.png", "e_total_energy.png"):
        fig = figs[name]
        _legend_clear_of_data(fig)
        for ax in fig.axes:
            _coinciding_lines_both_show(ax)
            texts = [t.get_text() for t in ax.get_legend().get_texts()] if ax.get_legend() else []
            if members == 1:
                assert not _bands(ax), name  # a single member looks as it did: its lines
            elif texts:  # the first panel of each figure carries the legend
                assert len(_bands(ax)) >= 2, name  # one band per method
                assert any("5–95 % of" in t and "24 members" in t.replace("\n", " ") for t in texts), texts
                assert any("median" in t for t in texts), texts
    energies = figs["e_energies.png"]
    if members > 1:  # member 0 over the band, in the method's colour
        labels = [ln.get_label() for ln in energies.axes[0].get_lines()]
        assert "variational integrator: member 0" in labels
        assert "24 members" in energies.texts[0].get_text()  # the suptitle says what is drawn
    else:
        assert "member 0" in energies.texts[0].get_text()
    # the same colour for a method in every figure
    for name in ("e_energies.png", "e_entropy.png"):
        vi = [ln for ln in figs[name].axes[0].get_lines() if ln.get_label().startswith("variational")]
        assert vi and all(ln.get_color() == "C0" for ln in vi)


def test_center_of_mass_plot_has_equal_scales_and_explains_its_marks(top_ensemble, monkeypatch):
    from liethermo.top import plotting

    d, paths = top_ensemble
    figs = _captured(monkeypatch, plotting, "_save")
    plotting.scene_figures({m: paths[24, m] for m in ("vi", "rk2")}, d / "com", stem="c")
    fig = figs["c_center_of_mass.png"]
    ax = next(a for a in fig.axes if a.name == "3d")
    spans = [np.diff(lim)[0] for lim in (ax.get_xlim(), ax.get_ylim(), ax.get_zlim())]
    assert np.allclose(spans, spans[0], rtol=1e-9)  # equal data ranges ...
    assert np.allclose(ax.get_box_aspect(), ax.get_box_aspect()[0])  # ... in a cube: equal scales
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any(t.startswith("start") for t in labels), labels  # the dot is named
    assert len(ax.collections) == 1  # one start marker, not one per method on top of each other
    title = fig.texts[0].get_text()
    assert "l R chi" not in title and "ℓRχ" in title and "R: attitude" in title and "member 0 of 24" in title
    assert all(a.get_xlabel().endswith("(mm)") for a in [ax])


@pytest.mark.parametrize("scene", ["zeitlin_decay", "zeitlin_ideal"])
def test_fluid_figures_show_every_method_and_quantity(tmp_path, monkeypatch, scene):
    """Split and RK4 coincide where viscosity dominates the Casimirs' change
    (decay) and H coincides with H + q where nothing is dissipated (ideal):
    each legend entry's line still shows, a method keeps its colour in every
    panel, and a 3-member ensemble is drawn as bands."""
    import liethermo
    from liethermo.zeitlin import plotting as zp

    over = {"zeitlin.N": 8, "initial.lmax": 5, "integrator.steps": 40, "output.every": 4,
            "ensemble.members": 3}
    out = liethermo.run(scene, over, compare=True)
    figs = _captured(monkeypatch, zp, "save")
    zp.draw(out, None, tmp_path, "z")
    cas = figs["z_casimirs.png"]
    colors = {}
    for ax in cas.axes:
        assert ax.get_yscale() == "log"
        assert len(_bands(ax)) == 2  # one band per method
        _coinciding_lines_both_show(ax)
        for ln in ax.get_lines():
            colors.setdefault(ln.get_label().split(":")[0], set()).add(ln.get_color())
    assert set(colors) == {"split", "rk4"} and all(len(c) == 1 for c in colors.values()), colors
    assert colors["split"] != colors["rk4"]
    heat = figs["z_energy_heat.png"].axes[0]
    total = next(ln for ln in heat.get_lines() if ln.get_label().startswith("H + q"))
    H = next(ln for ln in heat.get_lines() if ln.get_label().startswith("kinetic energy H"))
    assert total.get_zorder() > H.get_zorder() and total.get_linestyle() != "-"
    _coinciding_lines_both_show(heat)
    for name in ("z_casimirs.png", "z_energy_heat.png", "z_spectrum.png"):
        _legend_clear_of_data(figs[name])
        assert all("(s)" in a.get_xlabel() or a.get_xlabel() == "degree l" for a in figs[name].axes)
    assert "range of 3 members" in " ".join(t.get_text() for t in heat.get_legend().get_texts())
