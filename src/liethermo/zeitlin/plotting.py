"""Figures of a Zeitlin run: the vorticity on the sphere, energy into heat,
the energy spectrum over time, the Casimirs' drift per method.

An ensemble is drawn as its median over the members and a band
(:mod:`liethermo.bands`: 5–95 % quantiles, or the range of fewer than 20
members) over the members that completed; one member is drawn as it is.
Each method keeps its colour and line style (:data:`STYLE`) in every panel,
and legends sit beside the panels, clear of the data."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..bands import completed, ensemble_band, legend_beside, sample_times, save, series
from . import kernels as zk


def vorticity_on_grid(W: np.ndarray, n_lat: int = 90, n_lon: int = 180):
    """ω(θ, φ) = Σ_lm ω_lm Y_lm on a longitude–latitude grid, the field whose
    matrix is W (kernels: W = i√(N/4π) Σ ω_lm T_lm).  Returns (lon, lat, ω) in
    radians, radians, s⁻¹; W is one (N, N) matrix."""
    b = zk.basis(W.shape[-1])
    C = zk.to_modes(W[None], b)[0]
    lat = np.linspace(-np.pi / 2, np.pi / 2, n_lat)
    lon = np.linspace(-np.pi, np.pi, n_lon)
    Y0 = _harmonics_at_zero_longitude(b.N, n_lat)  # (modes, n_lat): Y_l^m(θ, 0), real
    # F_m(θ) = Σ_l ω_lm Y_l^m(θ, 0); ω = F_0 + 2 Σ_{m≥1} Re(F_m(θ) e^{imφ})
    F = np.zeros((b.N, n_lat), dtype=complex)
    for d in range(b.N):
        sl = slice(b.offset[d], b.offset[d + 1])
        F[d] = C[sl] @ Y0[sl]
    phase = np.exp(1j * np.outer(np.arange(b.N), lon))  # (N, n_lon)
    om = (F[0].real[:, None] * np.ones(n_lon)[None, :]
          + 2.0 * (F[1:].T @ phase[1:]).real)
    return lon, lat, om


_Y0_CACHE: dict = {}


def _harmonics_at_zero_longitude(N: int, n_lat: int) -> np.ndarray:
    from scipy.special import sph_harm_y

    key = (N, n_lat)
    if key not in _Y0_CACHE:
        b = zk.basis(N)
        theta = np.pi / 2 - np.linspace(-np.pi / 2, np.pi / 2, n_lat)
        _Y0_CACHE[key] = sph_harm_y(b.ell.astype(int)[:, None], b.order[:, None], theta[None, :], 0.0).real
    return _Y0_CACHE[key]


#: Colour and line of each method in every panel; the later methods are drawn
#: over the earlier ones, dashed and marked, so coinciding curves both show.
STYLE = {"split": dict(color="C0", ls="-", lw=2.2),
         "split4": dict(color="C4", ls="-", lw=1.6),
         "split6": dict(color="C5", ls="-.", lw=1.4),
         "rk4": dict(color="C3", ls="--", lw=1.3, marker="o", ms=3.5, markevery=0.08, mfc="none"),
         "reference": dict(color="k", ls=":", lw=1.2)}
_SUB = str.maketrans("²⁴", "₂₄")
FLOOR = 1e-17  # relative drifts at or below round-off are drawn here on the log axes


def style(method: str) -> dict:
    return STYLE.get(method, dict(color="0.3", ls="-", lw=1.2))


def spectrum_lines(ax, ls, t, spec, count: int, ok: np.ndarray | None = None) -> None:
    """E_l (``spec``: times × degrees, or members × times × degrees with
    ``ok`` the members that completed) at ``count`` times of the run, one line
    each from dark to light, on log axes: an ensemble's median with its band;
    degrees at round-off level are left out."""
    import matplotlib.pyplot as plt

    cmap = plt.get_cmap("viridis")
    idx = sample_times(spec.shape[-2], count)
    ens = spec.ndim == 3 and spec.shape[0] > 1
    spec = spec if spec.ndim == 3 else spec[None]
    top = np.nanmax(spec)
    for n, i in enumerate(idx):
        c = cmap(n / max(len(idx) - 1, 1))
        if ens:
            band = ensemble_band(spec[:, i], np.arange(spec.shape[0]) if ok is None else ok)
            keep = band.hi > 1e-14 * top
            ax.fill_between(ls[keep], band.lo[keep], band.hi[keep], color=c, alpha=0.15, lw=0)
            e = band.median
        else:
            e = spec[0, i]
        e = np.where(e > 1e-14 * top, e, np.nan)
        ax.loglog(ls, e, color=c, label=f"t = {t[i]:g} s")
    if ens:
        ax.fill_between([], [], [], color="0.5", alpha=0.3, lw=0, label=f"band: {band.label}")


def draw(datasets: dict, W_member0: np.ndarray | None, folder, stem: str) -> list[Path]:
    """The figures of a run: ``datasets`` {method: Dataset}, the first the
    scene's own; ``W_member0`` (times, N, N) of its member 0 for the maps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    first = next(iter(datasets))
    ds = datasets[first]
    t = ds["t"].values
    N = int(ds.attrs["N"])

    if W_member0 is not None:
        idx = sample_times(len(t), 4)
        fields = [vorticity_on_grid(W_member0[i]) for i in idx]
        vmax = max(np.abs(f[2]).max() for f in fields)
        fig = plt.figure(figsize=(3.6 * len(idx) + 0.8, 2.8), layout="constrained")
        for j, (i, (lon, lat, om)) in enumerate(zip(idx, fields)):
            ax = fig.add_subplot(1, len(idx), j + 1, projection="mollweide")
            im = ax.pcolormesh(lon, lat, om, cmap="RdBu_r", vmin=-vmax, vmax=vmax, shading="auto")
            ax.set_xticklabels([])
            ax.set_yticklabels([])
            ax.grid(True, lw=0.3, alpha=0.5)
            ax.set_title(f"t = {t[i]:g} s", fontsize=9)
        fig.colorbar(im, ax=fig.axes, shrink=0.7, label="vorticity ω (s⁻¹)")
        fig.suptitle(f"vorticity of member 0 ({first}, N = {N}), Mollweide projection", fontsize=10)
        out.append(save(fig, folder / f"{stem}_vorticity.png"))

    ok = completed(ds)
    M = ds.sizes["member"]
    whose = "" if M == 1 else f", median of {M} members" if len(ok) == M else f", median of {len(ok)} of {M} members"
    fig, ax = plt.subplots(figsize=(7.6, 4.0), layout="constrained")
    H, q = ds["energy"].values, ds["heat"].values
    series(ax, t, H, ok, "kinetic energy H", color="C0", lw=2.2)
    series(ax, t, q, ok, "heat q = U − U₀", color="C1", lw=2.2)
    # H + q over the others, dashed with wide gaps: where q = 0 (no viscosity) it lies on H,
    # which shows between the dashes; its median only (its band would cover H's)
    tot = np.nanmedian((H + q)[ok], axis=0) if len(ok) else np.full(len(t), np.nan)
    ax.plot(t, tot, color="k", ls=(0, (4, 4)), lw=1.2, zorder=4,
            label="H + q (conserved)" + (": median" if M > 1 else ""))
    ax.set_xlabel("time t (s)")
    ax.set_ylabel(f"energy (J){whose}")
    ax.set_title(f"energy into heat ({first}, ν = {_nu(ds)} s⁻¹, N = {N})")
    legend_beside(ax)
    out.append(save(fig, folder / f"{stem}_energy_heat.png"))

    fig, ax = plt.subplots(figsize=(7.6, 4.0), layout="constrained")
    ls = ds["l"].values
    spectrum_lines(ax, ls, t, ds["energy_spectrum"].values, 6, ok)
    ax.set_xlabel("degree l")
    ax.set_ylabel(f"energy spectrum E_l (J){whose}")
    ax.set_title(f"energy spectrum over time ({first}, N = {N})")
    legend_beside(ax)
    out.append(save(fig, folder / f"{stem}_spectrum.png"))

    # one panel per quantity, each method in its colour and style in every panel
    fig, axes = plt.subplots(1, 3, figsize=(14.5, 3.9), layout="constrained", sharex=True)
    for m, d in datasets.items():
        tm = d["t"].values[1:]
        okm = completed(d)
        for ax, k in zip(axes[:2], (2, 4)):
            v = np.abs(d["casimir_drift"].sel(k=k).values[:, 1:])
            series(ax, tm, v, okm, m, floor=FLOOR, **style(m))
        e = np.abs(d["energy_error"].values[:, 1:])
        series(axes[2], tm, e, okm, m, floor=FLOOR, **style(m))
    what = "drift" if _nu(ds) == "0" else "change (viscosity dissipates it)"
    for ax, k, ylabel in ((axes[0], "²", "|C₂(t) − C₂(0)| / C₂(0)"),
                          (axes[1], "⁴", "|C₄(t) − C₄(0)| / C₂(0)²")):
        ax.set_title(f"Casimir C{k.translate(_SUB)} ∝ tr(−iW){k}: {what}", fontsize=10)
        ax.set_ylabel(ylabel)
    axes[2].set_title("total energy error", fontsize=10)
    axes[2].set_ylabel("|H + q − H(0)| / H(0)")
    for a in axes:
        a.set_yscale("log")
        a.set_xlabel("time t (s)")
    members = next(iter(datasets.values())).sizes["member"]
    fig.suptitle(f"relative drifts, {'member 0' if members == 1 else f'{members} members'} "
                 f"(values at or below {FLOOR:g} drawn at {FLOOR:g})", fontsize=10)
    legend_beside(axes[2])
    out.append(save(fig, folder / f"{stem}_casimirs.png"))
    return out


def _nu(ds) -> str:
    import tomllib

    return f"{tomllib.loads(ds.attrs['scene'])['fluid']['kinematic_viscosity']:g}"
