"""Legibility of a matplotlib figure at its saved size, from the text extents.

:func:`layout_problems` draws the figure at a given dpi and lists what a
reader would stumble over:

* two tick labels of one axis that overlap (``3×10⁻³4×10⁻³``);
* a title, axis label, tick label, colorbar label, suptitle or legend that
  overlaps another one (a panel title on the axis label of the row above);
* any of them over the plotting area of another axes (a y label over the
  panel to its left);
* any of them reaching outside the canvas (an axis label cut off).

Only tick labels inside the axis' view interval count (those are the ones
drawn); text inside the axes (annotations, cell numbers) is the figure's
content, not its furniture, and is not checked.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

TOL = 0.5  # px: boxes that merely touch do not overlap

#: resolved path -> layout engine class name (None: explicit margins) of every
#: figure the test session saved and checked (filled by conftest.legible_figures)
SAVED_FIGURES: dict[str, str | None] = {}
#: file names of the study figures the session checked with :func:`readability_problems`
STUDY_FIGURES_CHECKED: set[str] = set()


def _overlap(a, b) -> bool:
    return (min(a.x1, b.x1) - max(a.x0, b.x0) > TOL) and (min(a.y1, b.y1) - max(a.y0, b.y0) > TOL)


def _drawn_ticklabels(axis) -> list:
    # compare in the axis' scale (log axes: in decades), where the view is an interval
    scale = axis.get_transform()
    with np.errstate(invalid="ignore", divide="ignore"):
        lo, hi = sorted(scale.transform(np.asarray(axis.get_view_interval(), float).reshape(-1, 1)).ravel())
    eps = 1e-9 * (hi - lo)
    out = []
    for ticks in (axis.get_major_ticks(), axis.get_minor_ticks()):
        for tick in ticks:
            loc = tick.get_loc()
            if loc is None:
                continue
            with np.errstate(invalid="ignore", divide="ignore"):
                x = float(scale.transform(np.array([[float(loc)]])).ravel()[0])
            if not (np.isfinite(x) and lo - eps <= x <= hi + eps):
                continue
            for label in (tick.label1, tick.label2):
                if label.get_visible() and label.get_text().strip():
                    out.append(label)
    return out


def _axes_texts(ax) -> list[tuple[str, object]]:
    name = ax.get_label() or ax.get_title().split("\n")[0] or f"axes@{id(ax):x}"
    items = []
    for key, axis in ax._axis_map.items():
        if not axis.get_visible():
            continue
        for t in _drawn_ticklabels(axis):
            items.append((f"{name}: {key} tick label {t.get_text()!r}", t))
        lab = axis.label
        if lab.get_visible() and lab.get_text().strip():
            items.append((f"{name}: {key} label {lab.get_text()!r}", lab))
    for t in (ax.title, ax._left_title, ax._right_title):
        if t.get_visible() and t.get_text().strip():
            items.append((f"{name}: title {t.get_text()!r}", t))
    leg = ax.get_legend()
    if leg is not None and leg.get_visible():
        items.append((f"{name}: legend", leg))
    return items


def figure_texts(fig) -> list[tuple[str, object, object]]:
    """``(description, artist, owning axes or None)`` of the figure's furniture."""
    items = []
    for t in fig.texts:
        if t.get_visible() and t.get_text().strip():
            items.append((f"figure text {t.get_text()!r}", t, None))
    for leg in fig.legends:
        items.append(("figure legend", leg, None))
    for ax in fig.axes:
        if ax.get_visible():
            items += [(d, a, ax) for d, a in _axes_texts(ax)]
    return items


def layout_problems(fig, dpi: float | None = None) -> list[str]:
    """What overlaps or leaves the canvas when ``fig`` is drawn at ``dpi``
    (default: the figure's own)."""
    old = fig.get_dpi()
    if dpi is not None and dpi != "figure":
        fig.set_dpi(float(dpi))
    try:
        fig.draw_without_rendering()
        renderer = fig.canvas.get_renderer()
        items = [(desc, owner, art.get_window_extent(renderer)) for desc, art, owner in figure_texts(fig)]
        areas = [(ax, ax.bbox.frozen()) for ax in fig.axes if ax.get_visible()]
        W, H = fig.bbox.width, fig.bbox.height
    finally:
        fig.set_dpi(old)
    problems = []
    for desc, owner, bb in items:
        if bb.x0 < -TOL or bb.y0 < -TOL or bb.x1 > W + TOL or bb.y1 > H + TOL:
            problems.append(f"outside the canvas: {desc} {np.round(bb.extents, 1).tolist()} "
                            f"(canvas {W:.0f}x{H:.0f} px)")
        for ax, area in areas:
            if ax is not owner and _overlap(bb, area):
                problems.append(f"over another panel: {desc} / axes {ax.get_title().split(chr(10))[0]!r}")
    for (da, _, ba), (db, _, bb) in combinations(items, 2):
        if _overlap(ba, bb):
            problems.append(f"overlap: {da} / {db}")
    return problems


def readability_problems(fig, dpi: float | None = None) -> list[str]:
    """What a reader of a study figure misses, with :func:`layout_problems`:
    a title (the figure's suptitle), and at least two non-empty tick labels
    drawn on every visible axis of every visible axes (a colorbar: its long
    axis) — a log axis spanning less than a decade with its minor labels
    blanked has none."""
    fig.draw_without_rendering()
    problems = list(layout_problems(fig, dpi))
    sup = fig._suptitle
    if sup is None or not sup.get_visible() or not sup.get_text().strip():
        problems.append("no title")
    for ax in fig.axes:
        if not ax.get_visible() or not ax.axison:
            continue
        name = ax.get_label() or ax.get_title().split("\n")[0] or f"axes@{id(ax):x}"
        keys = [k for k, axis in ax._axis_map.items() if axis.get_visible()]
        if ax.get_label() == "<colorbar>":  # only the long axis carries ticks
            keys = ["y"] if ax.bbox.height >= ax.bbox.width else ["x"]
        for key in keys:
            n = len(_drawn_ticklabels(ax._axis_map[key]))
            if n < 2:
                problems.append(f"{name}: {key} axis has {n} tick label(s)")
    return problems
