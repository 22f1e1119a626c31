"""An ensemble in a figure: its median over members and a band around it.

The band is the 5–95 % quantiles of the members at each time
(:data:`QUANTILES`); with fewer than :data:`MIN_FOR_QUANTILES` members,
whose 5 % and 95 % quantiles would be interpolated between the two
extremes, it is their full range.  :func:`member_band` computes it from a
(members, times) array, :func:`draw_band` draws it; the band's label says
which of the two it is and over how many members, so a legend states it.

numpy only: matplotlib is imported by the figures that call this.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Quantiles (fractions) of the band drawn over an ensemble.
QUANTILES = (0.05, 0.95)
#: Below this many members the band is the members' range (min to max).
MIN_FOR_QUANTILES = 20
#: Members read for a band: the first ones of a larger ensemble (members are
#: independent draws, so the first ones are a random sample).
MAX_BAND_MEMBERS = 32768


@dataclass(frozen=True)
class Band:
    """Median, lower and upper edge of an ensemble at each time, and what the band is."""

    median: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    members: int  # members the statistics are over
    label: str  # e.g. "5–95 % of 4096 members"


def band_words(members: int, of: int | None = None, why: str = "") -> str:
    """"5–95 % of 4096 members", or "range of 4 members"; ``of``: the
    ensemble's size when only some members are in the band, ``why`` says which."""
    n = f"{members}" if of is None or of == members else f"{members} of {of}"
    what = (f"{100 * QUANTILES[0]:g}–{100 * QUANTILES[1]:g} % of" if members >= MIN_FOR_QUANTILES
            else "range of")
    return f"{what} {n} members" + (f" {why}" if why else "")


def member_band(values: np.ndarray, of: int | None = None, why: str = "") -> Band:
    """The band of ``values`` (members, times) over its first axis; NaNs
    (a member's values after it failed) are left out at each time."""
    v = np.asarray(values, dtype=np.float64)
    with warnings.catch_warnings():  # a time where every member is NaN: the band is NaN there
        warnings.simplefilter("ignore", RuntimeWarning)
        if v.shape[0] >= MIN_FOR_QUANTILES:
            # nanquantile goes column by column (~20x slower): only where there are NaNs
            quantile = np.nanquantile if np.isnan(v).any() else np.quantile
            lo, med, hi = quantile(v, [QUANTILES[0], 0.5, QUANTILES[1]], axis=0)
        else:
            lo, med, hi = np.nanmin(v, axis=0), np.nanmedian(v, axis=0), np.nanmax(v, axis=0)
    return Band(med, lo, hi, v.shape[0], band_words(v.shape[0], of, why))


def draw_band(ax, x, band: Band, *, color, label: str | None = None, median_label: str | None = None,
              alpha: float = 0.22, zorder: float = 1.0, **median_style):
    """Draw ``band`` on ``ax``: the band filled in ``color`` (legend:
    "``label``: <the band's words>"), and the median over it as a line in
    ``median_style`` (legend: ``median_style``).  Returns (band artist, median line)."""
    poly = ax.fill_between(x, band.lo, band.hi, color=color, alpha=alpha, lw=0, zorder=zorder,
                           label=None if label is None else f"{label}: {band.label}")
    (line,) = ax.plot(x, band.median, color=color, zorder=zorder + 1, label=median_label, **median_style)
    return poly, line


# ----------------------------------------------------------------------------- helpers of every model's figures


def sample_times(n_times: int, count: int) -> np.ndarray:
    """Indices of ``count`` output times spread evenly over a run (first and last included)."""
    return np.unique(np.linspace(0, n_times - 1, count).round().astype(int))


def completed(ds):
    """Members of ``ds`` that completed, as an index array."""
    return np.flatnonzero(ds["status"].values == 0)


def ensemble_band(values: np.ndarray, ok: np.ndarray):
    """The band of ``values`` (members, ...) over the members ``ok`` that
    completed; the words say so when some did not."""
    why = "that completed" if len(ok) < values.shape[0] else ""
    return member_band(values[ok], of=values.shape[0], why=why)


def series(ax, x, values: np.ndarray, ok: np.ndarray, label: str, floor: float | None = None, **line):
    """``values`` (members, times) on ``ax``: one member as a line, an
    ensemble as its median line and band (legend: ``label`` and the band's
    words); ``floor``: values below it drawn at it (log axes)."""
    def f(v):
        return v if floor is None else np.maximum(v, floor)

    if values.shape[0] == 1:
        ax.plot(x, f(values[0]), label=label, **line)
        return
    band = ensemble_band(values, ok)
    color = line.pop("color")
    draw_band(ax, x, Band(f(band.median), f(band.lo), f(band.hi), band.members, band.label), color=color,
              label=label, median_label=f"{label}: median", zorder=line.pop("zorder", 1.0), **line)


def legend_beside(ax, **kwargs):
    """The legend right of the axes (constrained layout makes room): it covers no data."""
    kwargs.setdefault("fontsize", 8)
    return ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, **kwargs)


def save(fig, path) -> Path:
    """Write a figure as PNG (110 dpi, tight) and close it."""
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return Path(path)
