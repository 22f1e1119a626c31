"""Figures of a run: what the paper shows, for one member or for an ensemble.

``scene_figures({method: path.nc}, folder)`` writes four PNGs:

* ``<stem>_center_of_mass.png``: the path ℓRχ of member 0's centre of mass
  in 3-D, on equal axis scales, its start marked;
* ``<stem>_energies.png``: kinetic, potential and internal energy (U − U₀),
  each where the physics moves it (no potential energy panel without a
  gravity torque, no internal energy panel without friction);
* ``<stem>_total_energy.png``: relative total energy (E_k − E₀)/E₀ as in the
  paper (for the variational integrator in the paper's convention: its step
  velocity with the node values), and below |E_k − E₀| on node values (and
  in the paper's convention, dotted) over the initial mechanical energy, on a
  log scale;
* ``<stem>_entropy.png``: entropy over time.

A run of one member draws that member.  An ensemble is drawn as its median
over the members and a band (:mod:`liethermo.bands`: 5–95 % quantiles, or
the range of fewer than 20 members), over the members that completed, with
member 0 as a thin line over them in the energies and the entropy; legends
say which band and over how many members.  Each method keeps its colour in
every figure, and legends sit beside the panels, clear of the data.

A method whose member failed (e.g. RK2 blowing up) is plotted up to its last
finite value and the failure time is marked; in 3-D its path ends where
|RG| leaves ℓ by 20 % (it is blowing up), and its legend says so.
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .. import cf  # noqa: E402
from ..bands import MAX_BAND_MEMBERS, Band, draw_band, member_band  # noqa: E402

STYLE = {"vi": dict(color="C0", lw=1.6), "rk2": dict(color="C3", lw=1.2, ls="--"),
         "rk4": dict(color="C2", lw=1.2, ls="-."), "reference": dict(color="k", lw=0.8, ls=":")}
CLIP = 1e3  # relative energy errors above this are drawn at the top of the log panel
LABEL = {"vi": "variational integrator", "rk2": "RK2 (explicit midpoint)", "rk4": "RK4",
         "reference": "reference (DOP853)"}
MEMBER0 = dict(lw=0.6, alpha=0.9)  # member 0 drawn over an ensemble's band
SCALE = {"kinetic_energy": 1e3, "potential_energy": 1e3, "internal_energy": 1e3, "entropy": 1e6}


def _style(method: str) -> dict:
    return STYLE.get(method, {})


def _color(method: str):
    return _style(method).get("color", "k")


def _failure_note(ds, ax, method, who=""):
    st = int(ds["status"].values)
    if st != 0:
        k = int(ds["failed_at_step"].values)
        t = k * float(ds.attrs["h"])
        meaning = ds["status"].attrs["flag_meanings"].split()[st]
        ax.axvline(t, color=_color(method), lw=0.8, alpha=0.6)
        # on a white box above the curves: the failing method's own curve runs through here
        ax.annotate(f"{method.upper()}{who}: {meaning}\nat t = {t:g} s", xy=(t, 0.5),
                    xycoords=("data", "axes fraction"),
                    fontsize=8, ha="right", va="center", rotation=90, zorder=5, color=_color(method),
                    bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="none", alpha=0.85))


def t_of(ds):
    """The time coordinate (s) of a run's dataset, whatever its name."""
    return ds[ds["kinetic_energy"].dims[-1]]


def _failed_at(ds) -> str:
    """", failed (its status) at t = ... s" for a member that failed, else ""."""
    st = int(ds["status"].values)
    if st == 0:
        return ""
    meaning = ds["status"].attrs["flag_meanings"].split()[st].replace("_", " ")
    return f"; {meaning} at t = {int(ds['failed_at_step'].values) * float(ds.attrs['h']):g} s"


def _shown(name: str, v: np.ndarray) -> np.ndarray:
    """A variable as drawn: energies in mJ (U from U₀), entropy in µJ/K."""
    v = v - v[..., :1] if name == "internal_energy" else v
    return v * SCALE[name]


@dataclass
class Ensemble:
    """What the figures draw of a method's ensemble: bands by quantity, and
    the per-member normalisations that the titles quote."""

    members: int
    failed: int
    bands: dict = field(default_factory=dict)  # name -> Band
    E0: np.ndarray | None = None
    emech: np.ndarray | None = None


def _paper_convention(ds) -> bool:
    """Whether to draw a run's energy in the paper's convention: a variational
    integrator's own step velocity, not a composition's (vi4, vi6), whose
    ``omega_step`` is a substep's velocity."""
    from .methods import METHODS

    m = METHODS.get(ds.attrs.get("method"))
    return "energy_error_paper" in ds and not (m is not None and m.composed)


def _start_words(ds) -> str:
    """Why a variational integrator's energy error is not 0 at t = 0 (its start), or ""."""
    first = {"node": "Omega(0)", "staggered": "Omega(h/2)"}.get(ds.attrs.get("start"))
    if first is None or "energy_error_paper" not in ds:
        return ""
    return (f"start \"{ds.attrs['start']}\" takes {first} as the first step velocity, "
            "so the node momentum at t = 0 is not I Omega(0) (docs/model.md, Starts)")


def _ensemble(full) -> Ensemble:
    """The bands of a run's ensemble (more than one member), over the members
    that completed among the first :data:`MAX_BAND_MEMBERS`; each variable is
    derived (:meth:`liethermo.accessor.LiethermoAccessor.derived`) from their stored state."""
    n = full.sizes["member"]
    k = min(n, MAX_BAND_MEMBERS)
    status = full["status"].values
    failed = int(np.count_nonzero(status != 0))
    ok = np.flatnonzero(status[:k] == 0)
    ens = Ensemble(n, failed)
    if ok.size == 0:
        return ens
    why = " ".join(w for w in ("that completed" if failed else "",
                               f"(among the first {k})" if k < n else "") if w)
    part = full.isel(member=slice(0, k)).liethermo.derived()  # the energies from the stored state

    def get(name):  # a contiguous read, then the members that completed
        return np.asarray(part[name].values, dtype=np.float64)[ok]

    for name in SCALE:
        if name in part:
            ens.bands[name] = member_band(_shown(name, get(name)), of=n, why=why)
    ee = get("energy_error")
    ens.E0 = get("total_energy")[:, 0] - ee[:, 0]
    ens.emech = get("mechanical_energy_initial")
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        paper = get("energy_error_paper") if _paper_convention(part) else None
        ens.bands["relative_top"] = member_band((ee if paper is None else paper) / ens.E0[:, None], of=n, why=why)
        ens.bands["abs_node"] = member_band(np.abs(ee) / ens.emech[:, None], of=n, why=why)
        if paper is not None:
            ens.bands["abs_paper"] = member_band(np.abs(paper) / ens.emech[:, None], of=n, why=why)
    return ens


def _failed_words(ens: Ensemble) -> str:
    return f"; {ens.failed} of {ens.members} members failed, not in the band" if ens.failed else ""


def _clipped(band: Band) -> Band:
    """A band of relative errors with values above :data:`CLIP` (a blow-up) drawn at CLIP."""
    def c(v):
        return np.where(~(v <= CLIP), CLIP, v)

    return Band(c(band.median), c(band.lo), c(band.hi), band.members, band.label)


def legend_beside(ax, width: int = 44, **kwargs):
    """The axes' legend to the right of its panel, top-aligned, so that it
    covers no data; entries wrap at ``width`` characters."""
    kwargs.setdefault("fontsize", 8)
    handles, labels = ax.get_legend_handles_labels()
    labels = ["\n".join(textwrap.wrap(label, width, subsequent_indent="  ")) for label in labels]
    return ax.legend(handles, labels, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, **kwargs)


def scene_figures(outputs: dict, folder, stem: str = "run", member: int = 0) -> list[Path]:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    data, ensembles = {}, {}
    for m, p in outputs.items():  # one member read from each file, and the ensemble's bands
        with cf.open_dataset(p) as full:  # the derived variables (energies, centre of mass) through the accessor
            data[m] = full.isel(member=[member]).load().liethermo.derived().isel(member=0)
            if full.sizes["member"] > 1:
                ensembles[m] = _ensemble(full)
    first = next(iter(data.values()))
    h = float(first.attrs["h"])
    n_members = max((e.members for e in ensembles.values()), default=1)
    title = (f"{stem}: h = {h:g} s, member {member}" if not ensembles
             else f"{stem}: h = {h:g} s, {n_members} members")
    who = f" member {member}" if ensembles else ""  # whose failure a note marks
    files = []

    # 1. centre of mass in 3-D: member 0's path (an ensemble has no useful 3-D band)
    if all("center_of_mass" in ds for ds in data.values()):
        files.append(_center_of_mass(data, folder, stem, h, member, n_members))

    # 2. energies: a panel for each energy the run's physics moves (no potential energy
    # without a gravity torque, no internal energy without friction)
    def moves(name):
        return any(name in ds and np.any(ds[name].values != 0.0) for ds in data.values())

    def changes(name):
        def changed(v):
            return np.any((v != v[..., :1]) & np.isfinite(v))

        return any(name in ds and changed(ds[name].values) for ds in data.values())

    panels = [("kinetic_energy", "kinetic K (mJ)")]
    if moves("potential_energy"):
        panels.append(("potential_energy", "potential V (mJ)"))
    if changes("internal_energy"):
        panels.append(("internal_energy", "internal U - U0 (mJ)"))
    n = len(panels)
    fig, axes = plt.subplots(n, 1, figsize=(7, 1.1 + 0.3 * (n - 1) + 1.95 * n), sharex=True, squeeze=False)
    axes = axes[:, 0]

    def series(ax, m, t, name, values, label, member_line=True):
        """Member ``values`` alone, or the ensemble's band and median with it as a thin
        line.  Returns what sets the y limits: the band and median, and the member's
        values if it completed (a blow-up would flatten the rest)."""
        keep = [values] if int(data[m]["status"].values) == 0 else []
        ens = ensembles.get(m)
        band = ens.bands.get(name) if ens is not None else None
        if band is None:
            if label and ens is not None:  # no member completed: member 0 alone
                label = f"{label}: member {member} (all {ens.members} members failed)"
            ax.plot(t, values, label=label, **_style(m))
            return keep
        st = _style(m)
        draw_band(ax, t, band, color=st.get("color", "k"), label=label,
                  median_label=f"{label}: median" + _failed_words(ens) if label else None,
                  lw=st.get("lw", 1.2), ls=st.get("ls", "-"))
        if member_line:
            ax.plot(t, values, color=st.get("color", "k"), ls=st.get("ls", "-"), zorder=3,
                    label=f"{LABEL.get(m, m)}: member {member}" if label else None, **MEMBER0)
        return [band.lo, band.hi, band.median] + (keep if member_line else [])

    limits = {name: [] for name, _ in panels}
    for m, ds in data.items():
        t = t_of(ds).values
        for k, (name, _) in enumerate(panels):
            limits[name].extend(series(axes[k], m, t, name, _shown(name, ds[name].values),
                                       LABEL.get(m, m) if k == 0 else None))
        _failure_note(ds, axes[0], m, who)
    for ax, (_, ylabel) in zip(axes, panels):
        ax.set_ylabel(ylabel)
    axes[-1].set_xlabel("time t (s)")
    legend_beside(axes[0])
    # limits from the methods that completed, so a blow-up does not flatten the rest
    for ax, (name, _) in zip(axes, panels):
        lo, hi = _finite_range(limits[name] or [_shown(name, ds[name].values) for ds in data.values()])
        pad = 0.15 * (hi - lo) + 1e-9
        ax.set_ylim(lo - pad, hi + pad)
    fig.suptitle(f"energies — {title}", fontsize=10)
    files.append(_save(fig, folder / f"{stem}_energies.png", top=0.5, gap=0.3))

    # 3. total energy: the paper's figure (its convention for the VI: the step
    # velocity with the node values, over E_0) on top, the errors over E_mech,0 below;
    # each legend entry names its quantity and its normalisation
    fig, axes = plt.subplots(2, 1, figsize=(7, 6.5), sharex=True)
    E0s, emechs, clipped, at_start = [], [], False, []
    for m, ds in data.items():
        t = t_of(ds).values
        ens = ensembles.get(m)
        paper = _paper_convention(ds)
        why = _start_words(ds)
        if why:  # the start's own error, drawn at t = 0, said where it is seen
            with np.errstate(divide="ignore", invalid="ignore"):
                e0 = (float(np.nanmedian(ens.bands["abs_node"].median[:1])) if ens is not None and ens.bands
                      else abs(float(ds["energy_error"].values[0])) / float(ds["mechanical_energy_initial"].values))
            if np.isfinite(e0) and e0 > 1e-12:
                at_start.append(f"{LABEL.get(m, m)}: {e0:.2g} at t = 0{' (median)' if ens is not None else ''}: {why}")
        conv = "paper's convention" if paper else "node values"
        name = LABEL.get(m, m)
        if ens is not None and ens.bands:
            E0s.extend(ens.E0)
            emechs.extend(ens.emech)
            st = _style(m)
            kw = dict(color=st.get("color", "k"), lw=st.get("lw", 1.2), ls=st.get("ls", "-"))
            top = ens.bands["relative_top"]
            draw_band(axes[0], t, top, label=f"{name}, {conv}, / E_0",
                      median_label=f"{name}, {conv}, / E_0: median" + _failed_words(ens), **kw)
            node = ens.bands["abs_node"]
            clipped |= bool(np.any(~(node.hi <= CLIP)))
            draw_band(axes[1], t, _clipped(node), label=f"{name}, node values, / E_mech,0",
                      median_label=f"{name}, node values, / E_mech,0: median", **kw)
            if "abs_paper" in ens.bands:
                pb = ens.bands["abs_paper"]
                axes[1].plot(t, _clipped(pb).median, color=kw["color"], lw=0.8, ls=":", zorder=2,
                             label=f"{name}, paper's convention, / E_mech,0: median")
            continue
        E0 = float(ds["total_energy"].values[0]) - float(ds["energy_error"].values[0])
        err_top = ds["energy_error_paper" if paper else "energy_error"].values
        if int(ds["status"].values) == 0:
            axes[0].plot(t, err_top / E0, label=f"{name}, {conv}, / E_0", **_style(m))
        emech = float(ds["mechanical_energy_initial"].values)
        E0s.append(E0)
        emechs.append(emech)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            err = np.abs(ds["energy_error"].values) / emech
            err_p = np.abs(err_top) / emech
        clipped |= bool(np.any(~(err <= CLIP)))
        err = np.where(err > CLIP, CLIP, err)  # a blow-up is drawn up to the top of the panel
        axes[1].semilogy(t, err, label=f"{name}, node values, / E_mech,0", **_style(m))
        if paper:
            axes[1].semilogy(t, np.where(err_p > CLIP, CLIP, err_p),
                             label=f"{name}, paper's convention, / E_mech,0",
                             **dict(_style(m), lw=0.8, ls=":"))
        _failure_note(ds, axes[1], m)
    axes[1].set_yscale("log")
    axes[0].axhline(0.0, color="g", lw=0.8, label="exact (E conserved)")
    axes[0].set_ylabel("(E_k - E_0) / E_0")
    legend_beside(axes[0])
    axes[0].set_title(f"as in the paper: over E_0 = K_0 + V_0 + U_0 = {_energy(E0s)} (runs that completed)",
                      fontsize=9)
    if clipped:
        axes[1].set_ylim(top=CLIP)
    # plain "1e-3" tick labels: matplotlib's default 10^k labels go through mathtext,
    # whose parser takes ~0.3 s to build on first use (a tenth of a warm run)
    axes[1].yaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(_log_label))
    axes[1].set_ylabel("|E_k - E_0| / E_mech,0")
    axes[1].set_xlabel("time t (s)")
    axes[1].set_title(f"over E_mech,0 = K_0 + V_0 + |m g l| = {_energy(emechs)}"
                      + (f"; a blow-up is drawn at {CLIP:g}" if clipped else "")
                      + "".join("\n" + "\n".join(textwrap.wrap(w, 100)) for w in at_start), fontsize=8 if at_start else 9)
    legend_beside(axes[1], fontsize=7)
    fig.suptitle(f"total energy error — {title}", fontsize=10)
    lines = sum(len(textwrap.wrap(w, 100)) for w in at_start)
    files.append(_save(fig, folder / f"{stem}_total_energy.png", top=0.75, gap=0.5 + 0.16 * lines))

    # 4. entropy
    fig, ax = plt.subplots(figsize=(7, 3.8))
    drawn = []
    for m, ds in data.items():
        drawn.extend(series(ax, m, t_of(ds).values, "entropy", _shown("entropy", ds["entropy"].values),
                            LABEL.get(m, m)))
        _failure_note(ds, ax, m, who)
    # limits from the methods that completed, as for the energies: a blow-up's entropy
    # (RK2 at the paper's h reaches ~1e9 uJ/K) would flatten the other curves
    lo, hi = _finite_range(drawn or [_shown("entropy", ds["entropy"].values) for ds in data.values()])
    pad = 0.08 * (hi - lo) + 1e-9
    ax.set_ylim(lo - pad, hi + pad)
    ax.set_xlabel("time t (s)")
    ax.set_ylabel("entropy S (uJ/K)")
    legend_beside(ax)
    ax.set_title(f"entropy — {title}", fontsize=10)
    files.append(_save(fig, folder / f"{stem}_entropy.png", top=0.4))
    return files


def _center_of_mass(data: dict, folder: Path, stem: str, h: float, member: int, n_members: int) -> Path:
    """Member ``member``'s centre of mass ℓRχ in 3-D (mm), on equal axis scales."""
    fig = plt.figure(figsize=(6.4, 6.4))
    ax = fig.add_axes((0.0, 0.14, 0.92, 0.72), projection="3d")  # placed below, under the legend's height
    pts, ell = [], None
    for m, ds in data.items():
        x = ds["center_of_mass"].values * 1e3
        # |RG| = l exactly; a method that loses orthogonality (RK2 near its blow-up) is
        # drawn only up to the first point where |RG| departs from l by 20 %
        with np.errstate(over="ignore", invalid="ignore"):
            r = np.sqrt(np.sum(x * x, axis=1))
            bad = ~np.isfinite(r) | (np.abs(r - r[0]) > 0.2 * r[0])
        ell = ell or float(r[0])
        stop = int(np.argmax(bad)) if bad.any() else len(x)
        label = LABEL.get(m, m)
        if stop < len(x):  # say why the curve ends early
            label += (f" (drawn to t = {float(t_of(ds)[stop - 1]):g} s: there |R G| leaves ℓ by 20 %,"
                      f"\nit is blowing up{_failed_at(ds)})")
        x = x[:stop]
        pts.append(x)
        ax.plot(x[:, 0], x[:, 1], x[:, 2], label=label, **_style(m))
    x0 = pts[0][0]
    ax.scatter(*x0, color="k", s=18, depthshade=False, zorder=5, label="start (t = 0), every method")
    # equal scales: every axis spans the largest of the three data ranges, and the box is a cube
    allp = np.concatenate(pts)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    half = 0.5 * float(np.max(hi - lo)) or 1.0
    for set_lim, mid in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), 0.5 * (lo + hi)):
        set_lim(mid - half, mid + half)
    ax.set_box_aspect((1.0, 1.0, 1.0))
    # labels clear of the tick labels (which take more room with 5-character values)
    ax.set_xlabel("x (mm)", labelpad=14)
    ax.set_ylabel("y (mm)", labelpad=16)
    ax.set_zlabel("z, up (mm)", labelpad=14)
    whose = f"member {member}" + (f" of {n_members}" if n_members > 1 else "")
    fig.suptitle(f"centre of mass ℓRχ relative to the fixed point (mm), {whose}\n"
                 f"R: attitude; ℓχ: fixed point to centre of mass in the body frame, ℓ = {ell:.3g} mm\n"
                 f"{stem}: h = {h:g} s", fontsize=9, y=0.99, va="top")
    # the legend below the axes, clear of the path: the figure grows by its height
    leg = fig.legend(*ax.get_legend_handles_labels(), loc="lower center", bbox_to_anchor=(0.5, 0.0),
                     fontsize=8, frameon=False)
    # (+0.7 in: the 3-D x and y labels reach below the axes box)
    below = leg.get_window_extent(fig.canvas.get_renderer()).height / fig.dpi + 0.7
    axes_h, above = 4.6, 0.8  # inches: the 3-D box, the title over it
    H = below + axes_h + above
    fig.set_size_inches(6.4, H)
    ax.set_position((0.0, below / H, 0.92, axes_h / H))
    return _save(fig, folder / f"{stem}_center_of_mass.png")


def _finite_range(arrays) -> tuple[float, float]:
    """Smallest and largest finite value of ``arrays`` ((0, 1) if none is finite)."""
    v = np.concatenate([np.ravel(a) for a in arrays])
    v = v[np.isfinite(v)]
    return (float(v.min()), float(v.max())) if v.size else (0.0, 1.0)


def _energy(values) -> str:
    """"4.12e+05 J" (the members' common value), or the range over the methods."""
    lo, hi = min(values), max(values)
    if np.isclose(lo, hi, rtol=1e-9):
        return f"{hi:.3g} J"
    d = next((d for d in range(3, 10) if f"{lo:.{d}g}" != f"{hi:.{d}g}"), 10)  # digits that tell them apart
    return f"{lo:.{d}g} to {hi:.{d}g} J"


def _log_label(value, _pos=None) -> str:
    """Tick label of a log axis: "1e-3" at powers of ten."""
    if not value > 0:
        return ""
    k = round(float(np.log10(value)))
    return f"1e{k}" if np.isclose(value, 10.0 ** k, rtol=1e-9) else ""


def _save(fig, path: Path, *, left=0.95, right=0.2, bottom=0.6, top=0.45, gap=0.45) -> Path:
    """Save at 120 dpi with fixed margins, in inches (so they hold whatever the
    figure's size): ``left`` for the y tick labels and label, ``bottom`` for the
    x ones, ``top`` for the titles, ``gap`` between stacked panels (their titles
    or x tick labels); the figure widens by the widest legend beside a panel
    (:func:`legend_beside`).  Fixed margins instead of tight_layout, which measures
    every text and took ~0.2 s more for the four figures of a warm
    `liethermo run paper` (2 cores)."""
    if not any(getattr(ax, "name", "") == "3d" for ax in fig.axes):
        legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
        if legends:  # legends beside the panels (legend_beside): the figure widens by the widest
            renderer = fig.canvas.get_renderer()
            extra = max(leg.get_window_extent(renderer).width for leg in legends) / fig.dpi + 0.2
            w, h = fig.get_size_inches()
            fig.set_size_inches(w + extra, h)
            right += extra
        w, h = fig.get_size_inches()
        rows = fig.axes[0].get_subplotspec().get_gridspec().nrows
        axes_h = (h - top - bottom - (rows - 1) * gap) / rows
        fig.subplots_adjust(left=left / w, right=1 - right / w, bottom=bottom / h, top=1 - top / h,
                            hspace=gap / axes_h)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
