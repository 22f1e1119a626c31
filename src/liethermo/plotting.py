"""Figures of a run: what the paper shows, for member 0 of each method.

``scene_figures({method: path.nc}, folder)`` writes four PNGs:

* ``<stem>_center_of_mass.png``: the path ℓRχ of the centre of mass in 3-D;
* ``<stem>_energies.png``: kinetic, potential and internal energy (U − U₀);
* ``<stem>_total_energy.png``: relative total energy (E_k − E₀)/E₀ as in the
  paper (for the variational integrator in the paper's convention: its step
  velocity with the node values), and below |E_k − E₀| on node values (and
  in the paper's convention, dotted) over the initial mechanical energy, on a
  log scale;
* ``<stem>_entropy.png``: entropy over time.

A method whose member failed (e.g. RK2 blowing up) is plotted up to its last
finite value and the failure time is marked.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from . import cf  # noqa: E402

STYLE = {"vi": dict(color="C0", lw=1.6), "rk2": dict(color="C3", lw=1.2, ls="--"),
         "rk4": dict(color="C2", lw=1.2, ls="-."), "reference": dict(color="k", lw=0.8, ls=":")}
CLIP = 1e3  # relative energy errors above this are drawn at the top of the log panel
LABEL = {"vi": "variational integrator", "rk2": "RK2 (explicit midpoint)", "rk4": "RK4",
         "reference": "reference (DOP853)"}


def _failure_note(ds, ax, method):
    st = int(ds["status"].values)
    if st != 0:
        k = int(ds["failed_at_step"].values)
        t = k * float(ds.attrs["h"])
        meaning = ds["status"].attrs["flag_meanings"].split()[st]
        ax.axvline(t, color=STYLE.get(method, {}).get("color", "k"), lw=0.8, alpha=0.6)
        # on a white box above the curves: the failing method's own curve runs through here
        ax.annotate(f"{method.upper()}: {meaning}\nat t = {t:g} s", xy=(t, 0.5), xycoords=("data", "axes fraction"),
                    fontsize=8, ha="right", va="center", rotation=90, zorder=5,
                    color=STYLE.get(method, {}).get("color", "k"),
                    bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="none", alpha=0.85))


def scene_figures(outputs: dict, folder, stem: str = "run", member: int = 0) -> list[Path]:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    data = {}
    for m, p in outputs.items():  # one member read from each file, not the whole ensemble
        with cf.open_dataset(p) as full:
            data[m] = full.isel(member=member).load()
    first = next(iter(data.values()))
    h = float(first.attrs["h"])
    title = f"{stem}: h = {h:g} s, member {member}"
    files = []

    # 1. centre of mass in 3-D
    if all("center_of_mass" in ds for ds in data.values()):
        fig = plt.figure(figsize=(6.4, 5.6))
        ax = fig.add_subplot(projection="3d")
        for m, ds in data.items():
            x = ds["center_of_mass"].values * 1e3
            # |RG| = l exactly; a method that loses orthogonality (RK2 near its blow-up) is
            # drawn only up to the first point where |RG| departs from l by 20 %
            with np.errstate(over="ignore", invalid="ignore"):
                r = np.sqrt(np.sum(x * x, axis=1))
                bad = ~np.isfinite(r) | (np.abs(r - r[0]) > 0.2 * r[0])
            stop = int(np.argmax(bad)) if bad.any() else len(x)
            label = LABEL.get(m, m) + (f" (to t = {float(ds['time'][stop - 1]):g} s)" if stop < len(x) else "")
            x = x[:stop]
            ax.plot(x[:, 0], x[:, 1], x[:, 2], label=label, **STYLE.get(m, {}))
            ax.scatter(*x[0], color=STYLE.get(m, {}).get("color", "k"), s=12)
        # labels clear of the tick labels (which take more room with 5-character values)
        ax.set_xlabel("x (mm)", labelpad=14)
        ax.set_ylabel("y (mm)", labelpad=16)
        ax.set_zlabel("z (mm)", labelpad=14)
        ax.set_title(f"centre of mass l R chi\n{title}", fontsize=10)
        ax.legend(fontsize=8)
        files.append(_save(fig, folder / f"{stem}_center_of_mass.png"))

    # 2. energies
    fig, axes = plt.subplots(3, 1, figsize=(7, 7.5), sharex=True)
    for m, ds in data.items():
        t = ds["time"].values
        axes[0].plot(t, ds["kinetic_energy"].values * 1e3, label=LABEL.get(m, m), **STYLE.get(m, {}))
        axes[1].plot(t, ds["potential_energy"].values * 1e3, **STYLE.get(m, {}))
        dU = ds["internal_energy"].values - ds["internal_energy"].values[0]
        axes[2].plot(t, dU * 1e3, **STYLE.get(m, {}))
        _failure_note(ds, axes[0], m)
    axes[0].set_ylabel("kinetic K (mJ)")
    axes[1].set_ylabel("potential V (mJ)")
    axes[2].set_ylabel("internal U - U0 (mJ)")
    axes[2].set_xlabel("time t (s)")
    axes[0].legend(fontsize=8)
    # limits from the methods that completed, so a blow-up does not flatten the rest
    good = [ds for ds in data.values() if int(ds["status"].values) == 0] or list(data.values())
    for ax, name in zip(axes, ["kinetic_energy", "potential_energy", "internal_energy"]):
        vals = np.concatenate([(ds[name].values - (ds[name].values[0] if name == "internal_energy" else 0)) * 1e3
                               for ds in good])
        lo, hi = np.nanmin(vals), np.nanmax(vals)
        pad = 0.15 * (hi - lo) + 1e-9
        ax.set_ylim(lo - pad, hi + pad)
    fig.suptitle(f"energies — {title}", fontsize=10)
    files.append(_save(fig, folder / f"{stem}_energies.png", top=0.5, gap=0.3))

    # 3. total energy: the paper's figure (its convention for the VI: the step
    # velocity with the node values) on top, the node-value errors below
    fig, axes = plt.subplots(2, 1, figsize=(7, 6.5), sharex=True)
    for m, ds in data.items():
        t = ds["time"].values
        E0 = float(ds["total_energy"].values[0]) - float(ds["energy_error"].values[0])
        paper = "energy_error_paper" in ds
        err_top = ds["energy_error_paper" if paper else "energy_error"].values
        label = LABEL.get(m, m) + (" (paper's convention)" if paper else "")
        if int(ds["status"].values) == 0:
            axes[0].plot(t, err_top / E0, label=label, **STYLE.get(m, {}))
        emech = float(ds["mechanical_energy_initial"].values)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            err = np.abs(ds["energy_error"].values) / emech
            err_p = np.abs(err_top) / emech
        err = np.where(err > CLIP, CLIP, err)  # a blow-up is drawn up to the top of the panel
        axes[1].semilogy(t, err, label=LABEL.get(m, m) + " (node values)", **STYLE.get(m, {}))
        if paper:
            axes[1].semilogy(t, np.where(err_p > CLIP, CLIP, err_p), label=label,
                             **dict(STYLE.get(m, {}), lw=0.8, ls=":"))
        _failure_note(ds, axes[1], m)
    axes[0].axhline(0.0, color="g", lw=0.8, label="exact (E conserved)")
    axes[0].set_ylabel("(E_k - E_0) / E_0")
    axes[0].legend(fontsize=8)
    axes[0].set_title("relative total energy as in the paper (methods that completed)", fontsize=9)
    axes[1].set_ylim(top=CLIP)
    # plain "1e-3" tick labels: matplotlib's default 10^k labels go through mathtext,
    # whose parser takes ~0.3 s to build on first use (a tenth of a warm run)
    axes[1].yaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(_log_label))
    axes[1].set_ylabel("|E_k - E_0| / E_mech,0")
    axes[1].set_xlabel("time t (s)")
    axes[1].set_title("energy error: node values (solid), the paper's convention (dotted)",
                      fontsize=9)
    axes[1].legend(fontsize=7)
    fig.suptitle(f"total energy — {title}", fontsize=10)
    files.append(_save(fig, folder / f"{stem}_total_energy.png", top=0.75, gap=0.5))

    # 4. entropy
    fig, ax = plt.subplots(figsize=(7, 3.8))
    for m, ds in data.items():
        ax.plot(ds["time"].values, ds["entropy"].values * 1e6, label=LABEL.get(m, m), **STYLE.get(m, {}))
        _failure_note(ds, ax, m)
    # limits from the methods that completed, as for the energies: a blow-up's entropy
    # (RK2 at the paper's h reaches ~1e9 uJ/K) would flatten the other curves
    vals = np.concatenate([ds["entropy"].values * 1e6 for ds in good])
    lo, hi = np.nanmin(vals), np.nanmax(vals)
    pad = 0.08 * (hi - lo) + 1e-9
    ax.set_ylim(lo - pad, hi + pad)
    ax.set_xlabel("time t (s)")
    ax.set_ylabel("entropy S (uJ/K)")
    ax.legend(fontsize=8)
    ax.set_title(f"entropy — {title}", fontsize=10)
    files.append(_save(fig, folder / f"{stem}_entropy.png", top=0.4))
    return files


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
    or x tick labels).  Fixed margins instead of tight_layout, which measures
    every text and took ~0.2 s more for the four figures of a warm
    `liethermo run paper` (2 cores)."""
    if not any(getattr(ax, "name", "") == "3d" for ax in fig.axes):
        w, h = fig.get_size_inches()
        rows = fig.axes[0].get_subplotspec().get_gridspec().nrows
        axes_h = (h - top - bottom - (rows - 1) * gap) / rows
        fig.subplots_adjust(left=left / w, right=1 - right / w, bottom=bottom / h, top=1 - top / h,
                            hspace=gap / axes_h)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
