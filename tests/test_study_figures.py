"""Study figures are readable: a title, numbers on every axis, nothing dropped.

conftest.readable_study_figures checks every figure a study draws in the test
session (each study's reduced run, in the module that runs it) with
:func:`layout.readability_problems`: a title, at least two non-empty tick
labels drawn on every axis (matplotlib's own tick objects, in the axis' view),
and no overlapping text boxes (``get_window_extent``).  Here the check is shown
to catch what the figures had (a log axis under a decade whose minor labels
were blanked shows no number; no title), and the framework's drawing is held
to what it promises on small synthetic data: labelled short log axes,
non-finite points marked, stored quantiles drawn as bands, categorical regime
maps with a legend and no colour bar, distinguishable methods.
"""

from __future__ import annotations

import dataclasses

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import xarray as xr  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402

from layout import _drawn_ticklabels, readability_problems  # noqa: E402
from liethermo.studies import framework as fw  # noqa: E402
from liethermo.studies import get_study  # noqa: E402
from liethermo.studies.runner import load_study  # noqa: E402
from liethermo.studies import shipped_studies  # noqa: E402


@pytest.fixture(scope="module")
def conv():
    """The convergence study and its reduced context (its twelve methods), nothing run."""
    study = load_study(shipped_studies()["convergence"])
    S = get_study("convergence").STUDY
    return S, S.context(study, True)


def _labels(axis) -> list[str]:
    axis.figure.draw_without_rendering()
    return [t.get_text() for t in _drawn_ticklabels(axis)]


def test_the_check_catches_a_short_log_axis_without_numbers_and_a_missing_title():
    fig, ax = plt.subplots(figsize=(5, 3.5), layout="constrained")
    ax.semilogy([1, 2, 3], [2e-3, 4e-3, 6e-3])
    ax.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())  # what the framework did
    problems = readability_problems(fig, 120)
    assert "no title" in problems
    assert any(p.endswith("y axis has 0 tick label(s)") for p in problems), problems
    fig.suptitle("a title")
    fw.readable_log_ticks(ax)
    assert readability_problems(fig, 120) == []
    plt.close(fig)


@pytest.mark.parametrize("lo, hi", [(2e-3, 6e-3), (1.02, 1.08), (3e-5, 8e-4), (0.2, 30.0), (1e-9, 1e-2)])
def test_every_log_axis_gets_two_readable_labels(lo, hi):
    fig, ax = plt.subplots(figsize=(4.6, 3.6), layout="constrained")
    ax.loglog([1, 2], [lo, hi])
    ax.set_ylim(lo, hi)
    fig.suptitle("t")
    fw.readable_log_ticks(ax)
    labels = _labels(ax.yaxis)
    assert len(labels) >= 2 and len(set(labels)) == len(labels), labels
    assert readability_problems(fig, 120) == []
    plt.close(fig)


def _errors(ctx, bad: bool = True) -> xr.Dataset:
    h = 0.05 / 2.0 ** np.arange(5)
    q = [0.05, 0.5, 0.95]
    m = ctx.methods[:3]
    e = np.array([[[c * x ** 2 * (1 + 0.3 * (k - 1)) for x in h] for k in range(3)] for c in (1.0, 2.0, 4.0)])
    if bad:
        e[2, :, 0] = np.inf  # a blow-up at the coarsest step
    ds = xr.Dataset({"err": (("scheme", "quantile", "h"), e, {"units": "1", "long_name": "error"})},
                    coords={"scheme": m, "quantile": q, "h": ("h", h, {"units": "s", "long_name": "time step"})})
    return ds


def test_lines_mark_non_finite_points_and_draw_quantile_bands(conv):
    S, ctx = conv
    f = fw.Figure("err", claim="", x="h", y=("err",), band="quantile", logx=True, logy=True)
    fig = fw._draw_lines(f, _errors(ctx), ctx)
    ax = fig.axes[0]
    bands = [c for c in ax.collections if isinstance(c, PolyCollection)]
    assert len(bands) == 3  # one band per method
    marks = [ln for ln in ax.lines if ln.get_marker() == "X"]
    assert len(marks) == 1 and marks[0].get_color() == ctx.color(ctx.methods[2])
    assert np.allclose(marks[0].get_xdata(), 0.05)  # at the step where the run blew up
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "× at the top: no finite value" in legend and any(t.startswith("band: quantile 0.05") for t in legend)
    plt.close(fig)
    fig = fw._draw_lines(f, _errors(ctx, bad=False), ctx)  # negative control: nothing to mark
    assert not [ln for ln in fig.axes[0].lines if ln.get_marker() == "X"]
    plt.close(fig)


def test_draw_figures_titles_every_figure(conv, tmp_path):
    S, ctx = conv
    ctx = dataclasses.replace(ctx, outdir=tmp_path) if dataclasses.is_dataclass(ctx) else ctx
    ctx.outdir = tmp_path
    study = dataclasses.replace(S, figures=(fw.Figure("plain", claim="", x="h", y=("err",), band="quantile"),
                                            fw.Figure("named", claim="", x="h", y=("err",), band="quantile",
                                                      title="errors at {opt[t_end]} s")))
    seen = {}
    save = fw.save_figure

    def keep(fig, path):
        seen[path.name] = fig._suptitle.get_text()
        assert readability_problems(fig, 120) == []
        return save(fig, path)

    fw.save_figure = keep
    try:
        fw.draw_figures(study, ctx, _errors(ctx))
    finally:
        fw.save_figure = save
    assert seen == {"plain.png": "convergence: plain", "named.png": f"errors at {ctx.opt['t_end']} s"}


def test_a_regime_map_has_categorical_colours_and_a_legend(conv):
    S, ctx = conv
    names = ("accurate", "bounded", "unbounded", "newton not converged", "non finite")
    z = np.array([[0, 1, 2], [3, 4, 0], [1, 1, 2]], float)
    z[2, 2] = np.nan
    ds = xr.Dataset({"regime": (("scheme", "a", "b"), np.stack([z, z]), {"units": "1", "long_name": "regime"})},
                    coords={"scheme": ctx.methods[:2], "a": [1.0, 2.0, 3.0], "b": [0.1, 1.0, 10.0]})
    f = fw.Figure("regimes", claim="", kind="heatmap", x="a", hue="b", facet="scheme", y=("regime",),
                  logy=False, categories=names)
    fig = fw._draw_heatmap(f, ds, ctx)
    assert not [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert [t.get_text() for t in fig.legends[0].get_texts()] == list(names) + ["not finite"]
    im = fig.axes[0].images[0]
    colours = {tuple(np.round(im.cmap(im.norm(v)), 3)) for v in range(5)}
    assert len(colours) == 5  # one colour per category
    plt.close(fig)


def test_methods_that_share_a_hue_family_are_told_apart(conv):
    S, ctx = conv  # twelve methods: vi and rk2, vi6 and rk4 were two blues and two browns
    m = ctx.methods
    assert len(m) == 12 and len({ctx.color(x) for x in m}) == 12
    for a, b in (("vi", "rk2"), ("vi6", "rk4")):
        assert (ctx.color(a), fw.method_style(m, a)) != (ctx.color(b), fw.method_style(m, b))
        ca, cb = (np.array(matplotlib.colors.to_rgb(ctx.color(x))) for x in (a, b))
        assert np.abs(ca - cb).sum() > 0.5, (a, b)
