"""Figures of a Zeitlin run: the vorticity on the sphere, energy into heat,
the energy spectrum over time, the Casimirs' drift per method."""

from __future__ import annotations

from pathlib import Path

import numpy as np

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
        ls = b.ell.astype(int)
        ds = np.repeat(np.arange(N), np.arange(N, 0, -1))
        _Y0_CACHE[key] = sph_harm_y(ls[:, None], ds[:, None], theta[None, :], 0.0).real
    return _Y0_CACHE[key]


def sample_times(n_times: int, count: int) -> np.ndarray:
    """Indices of ``count`` output times spread evenly over a run (first and last included)."""
    return np.unique(np.linspace(0, n_times - 1, count).round().astype(int))


def spectrum_lines(ax, ls, t, spec, count: int) -> None:
    """E_l (``spec``: times × degrees) at ``count`` times of the run, one
    line each from dark to light, on log axes; degrees at round-off level are
    left out."""
    import matplotlib.pyplot as plt

    cmap = plt.get_cmap("viridis")
    idx = sample_times(len(t), count)
    for n, i in enumerate(idx):
        e = np.where(spec[i] > 1e-14 * np.nanmax(spec), spec[i], np.nan)
        ax.loglog(ls, e, color=cmap(n / max(len(idx) - 1, 1)), label=f"t = {t[i]:g} s")


def save(fig, path) -> Path:
    """Write a figure as PNG (110 dpi, tight) and close it."""
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return Path(path)


def _mean(da):
    return np.nanmean(da.values, axis=0)


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

    fig, ax = plt.subplots(figsize=(6.4, 4.0), layout="constrained")
    H, q = _mean(ds["energy"]), _mean(ds["heat"])
    ax.plot(t, H, label="kinetic energy H")
    ax.plot(t, q, label="heat q = U − U₀")
    ax.plot(t, H + q, "k--", lw=1, label="H + q")
    ax.set_xlabel("time t (s)")
    ax.set_ylabel("energy (J), member mean")
    ax.set_title(f"energy into heat ({first}, ν = {_nu(ds)} s⁻¹, N = {N})")
    ax.legend()
    out.append(save(fig, folder / f"{stem}_energy_heat.png"))

    fig, ax = plt.subplots(figsize=(6.4, 4.0), layout="constrained")
    spec = _mean(ds["energy_spectrum"])
    ls = ds["l"].values
    spectrum_lines(ax, ls, t, spec, 6)
    ax.set_xlabel("degree l")
    ax.set_ylabel("energy spectrum E_l (J), member mean")
    ax.set_title("energy spectrum over time")
    ax.legend(fontsize=8)
    out.append(save(fig, folder / f"{stem}_spectrum.png"))

    fig, axes = plt.subplots(1, 2, figsize=(10.5, 3.8), layout="constrained")
    for m, d in datasets.items():
        tm = d["t"].values[1:]
        for k, ls_ in ((2, "-"), (4, ":")):
            v = np.nanmax(np.abs(d["casimir_drift"].sel(k=k).values[:, 1:]), axis=0)
            axes[0].semilogy(tm, np.maximum(v, 1e-17), ls_, label=f"{m}: tr W{'²' if k == 2 else '⁴'}")
        e = np.nanmax(np.abs(d["energy_error"].values[:, 1:]), axis=0)
        axes[1].semilogy(tm, np.maximum(e, 1e-17), label=m)
    axes[0].set_title("Casimir drift (max over members)" if _nu(ds) == "0"
                      else "Casimir change (max over members): viscosity dissipates it")
    axes[0].set_ylabel("|C_k(t) − C_k(0)| / C₂(0)^(k/2)")
    axes[1].set_title("total energy error |H + q − H(0)| / H(0)")
    for a in axes:
        a.set_xlabel("time t (s)")
        a.legend(fontsize=8)
    out.append(save(fig, folder / f"{stem}_casimirs.png"))
    return out


def _nu(ds) -> str:
    import tomllib

    return f"{tomllib.loads(ds.attrs['scene'])['fluid']['viscosity']:g}"
