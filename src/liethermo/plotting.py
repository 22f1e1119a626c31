"""Figures of a run: what the paper shows, for member 0 of each method.

``scene_figures({method: path.nc}, folder)`` writes four PNGs:

* ``<stem>_center_of_mass.png``: the path ℓRχ of the centre of mass in 3-D;
* ``<stem>_energies.png``: kinetic, potential and internal energy (U − U₀),
  each where the physics moves it (no potential energy panel without a
  gravity torque, no internal energy panel without friction);
* ``<stem>_total_energy.png``: relative total energy (E_k − E₀)/E₀ as in the
  paper (for the variational integrator in the paper's convention: its step
  velocity with the node values), and below |E_k − E₀| on node values (and
  in the paper's convention, dotted) over the initial mechanical energy, on a
  log scale;
* ``<stem>_entropy.png``: entropy over time.

A method whose member failed (e.g. RK2 blowing up) is plotted up to its last
finite value and the failure time is marked; in 3-D its path ends where
|RG| leaves ℓ by 20 % (it is blowing up), and its legend says so.
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
            label = LABEL.get(m, m)
            if stop < len(x):  # say why the curve ends early
                label += (f"\n(drawn to t = {float(t_of(ds)[stop - 1]):g} s: there |R G| leaves l by 20 %, "
                          f"it is blowing up{_failed_at(ds)})")
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

    def shown(ds, name):  # mJ; U from U0
        v = ds[name].values
        return (v - v[0] if name == "internal_energy" else v) * 1e3

    for m, ds in data.items():
        t = t_of(ds).values
        for k, (name, _) in enumerate(panels):
            axes[k].plot(t, shown(ds, name), label=LABEL.get(m, m) if k == 0 else None, **STYLE.get(m, {}))
        _failure_note(ds, axes[0], m)
    for ax, (_, ylabel) in zip(axes, panels):
        ax.set_ylabel(ylabel)
    axes[-1].set_xlabel("time t (s)")
    axes[0].legend(fontsize=8)
    # limits from the methods that completed, so a blow-up does not flatten the rest
    good = [ds for ds in data.values() if int(ds["status"].values) == 0] or list(data.values())
    for ax, (name, _) in zip(axes, panels):
        vals = np.concatenate([shown(ds, name) for ds in good])
        lo, hi = np.nanmin(vals), np.nanmax(vals)
        pad = 0.15 * (hi - lo) + 1e-9
        ax.set_ylim(lo - pad, hi + pad)
    fig.suptitle(f"energies — {title}", fontsize=10)
    files.append(_save(fig, folder / f"{stem}_energies.png", top=0.5, gap=0.3))

    # 3. total energy: the paper's figure (its convention for the VI: the step
    # velocity with the node values, over E_0) on top, the errors over E_mech,0 below;
    # each legend entry names its quantity and its normalisation
    fig, axes = plt.subplots(2, 1, figsize=(7, 6.5), sharex=True)
    E0s, emechs, clipped = [], [], False
    for m, ds in data.items():
        t = t_of(ds).values
        E0 = float(ds["total_energy"].values[0]) - float(ds["energy_error"].values[0])
        paper = "energy_error_paper" in ds
        err_top = ds["energy_error_paper" if paper else "energy_error"].values
        conv = "paper's convention" if paper else "node values"
        if int(ds["status"].values) == 0:
            axes[0].plot(t, err_top / E0, label=f"{LABEL.get(m, m)}, {conv}, / E_0", **STYLE.get(m, {}))
        emech = float(ds["mechanical_energy_initial"].values)
        E0s.append(E0)
        emechs.append(emech)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            err = np.abs(ds["energy_error"].values) / emech
            err_p = np.abs(err_top) / emech
        clipped |= bool(np.any(~(err <= CLIP)))
        err = np.where(err > CLIP, CLIP, err)  # a blow-up is drawn up to the top of the panel
        axes[1].semilogy(t, err, label=f"{LABEL.get(m, m)}, node values, / E_mech,0", **STYLE.get(m, {}))
        if paper:
            axes[1].semilogy(t, np.where(err_p > CLIP, CLIP, err_p),
                             label=f"{LABEL.get(m, m)}, paper's convention, / E_mech,0",
                             **dict(STYLE.get(m, {}), lw=0.8, ls=":"))
        _failure_note(ds, axes[1], m)
    axes[0].axhline(0.0, color="g", lw=0.8, label="exact (E conserved)")
    axes[0].set_ylabel("(E_k - E_0) / E_0")
    axes[0].legend(fontsize=8)
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
                      + (f"; a blow-up is drawn at {CLIP:g}" if clipped else ""), fontsize=9)
    axes[1].legend(fontsize=7)
    fig.suptitle(f"total energy error — {title}", fontsize=10)
    files.append(_save(fig, folder / f"{stem}_total_energy.png", top=0.75, gap=0.5))

    # 4. entropy
    fig, ax = plt.subplots(figsize=(7, 3.8))
    for m, ds in data.items():
        ax.plot(t_of(ds).values, ds["entropy"].values * 1e6, label=LABEL.get(m, m), **STYLE.get(m, {}))
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


def _energy(values) -> str:
    """"4.12e+05 J" (the members' common value), or the range over the methods."""
    lo, hi = min(values), max(values)
    return f"{hi:.3g} J" if np.isclose(lo, hi, rtol=1e-9) else f"{lo:.3g} to {hi:.3g} J"


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
