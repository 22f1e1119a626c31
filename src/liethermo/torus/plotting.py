"""Figures of a torus run, from its files alone: maps of the vorticity and the
temperature (and Θ on request) on the periodic square, the energy budget and
S_tot as ensemble bands, and an animation on request."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np

from ..bands import completed, legend_beside, sample_times, save, series
from . import kernels as tk

STYLE = {"cmp": dict(color="C0", ls="-", lw=2.0), "magmp": dict(color="C1", ls="--", lw=1.4),
         "isomp": dict(color="C2", ls="--", lw=1.4), "rk4": dict(color="C3", ls=":", lw=1.3),
         "reference": dict(color="k", ls=":", lw=1.2)}


def style(method: str) -> dict:
    return dict(STYLE.get(method, dict(color="0.3", ls="-", lw=1.2)))


def on_grid(X: np.ndarray) -> np.ndarray:
    """A field's values on the periodic N × N grid (x_j, y_k) = 2π(j, k)/N from its matrix (the inverse transform)."""
    b = tk.basis(X.shape[-1])
    return tk.grid_values(tk.to_modes(X, b), b)


def member0_fields(ds):
    """W and S of member 0 at every kept time: stored, or integrated again from the scene the file stores."""
    if "vorticity_real" in ds and "entropy_density_real" in ds:
        W = ds["vorticity_real"].values[0] + 1j * ds["vorticity_imag"].values[0]
        S = ds["entropy_density_real"].values[0] + 1j * ds["entropy_density_imag"].values[0]
        return W, S
    from ..scene import load_scene
    from .run import initial_fields, integrate

    scene = load_scene(tomllib.loads(ds.attrs["scene"]))
    W0, S0 = initial_fields(scene, np.arange(1))
    traj = integrate(scene, W0, S0, method=ds.attrs["method"], progress=False, keep=(False, False))
    return traj.out.W_first, traj.out.S_first


def _scene_numbers(ds):
    t = tomllib.loads(ds.attrs["scene"])
    th = t.get("thermo", {})
    return float(th.get("areal_heat_capacity", 1.0)), float(th.get("T0", 1.0)), float(th.get("buoyancy", 0.0))


def field_maps(W, S, c, T0, alpha):
    """ω, T = T₀e^{s/c} and Θ on the grid, from the matrices (T and Θ through the matrix functions)."""
    b = tk.basis(W.shape[-1])
    th = tk.Thermo(c=c, T0=T0, alpha=alpha)
    lam, V = np.linalg.eigh(S)
    Tm = tk.func(lam, V, lambda x: T0 * np.exp(x / c))
    Th = Tm - alpha * np.asarray(b.Phi)
    assert th is not None
    return on_grid(W), on_grid(Tm), on_grid(Th)


def map_figure(W, S, times, idx, ds, path, theta: bool):
    import matplotlib.pyplot as plt

    c, T0, alpha = _scene_numbers(ds)
    rows = 3 if theta else 2
    fig, axes = plt.subplots(rows, len(idx), figsize=(3.0 * len(idx), 2.8 * rows), squeeze=False,
                             constrained_layout=True)
    maps = [field_maps(W[i], S[i], c, T0, alpha) for i in idx]
    wmax = max(np.abs(m[0]).max() for m in maps) or 1.0
    tlo, thi = min(m[1].min() for m in maps), max(m[1].max() for m in maps)
    extent = (0, 2 * np.pi, 0, 2 * np.pi)
    for col, (i, (w, T, Th)) in enumerate(zip(idx, maps)):
        im0 = axes[0, col].imshow(w.T, origin="lower", extent=extent, cmap="RdBu_r", vmin=-wmax, vmax=wmax)
        axes[0, col].set_title(f"ω at t = {times[i]:g} s")
        im1 = axes[1, col].imshow(T.T, origin="lower", extent=extent, cmap="inferno", vmin=tlo, vmax=thi)
        axes[1, col].set_title(f"T at t = {times[i]:g} s")
        if theta:
            im2 = axes[2, col].imshow(Th.T, origin="lower", extent=extent, cmap="viridis")
            axes[2, col].set_title(f"Θ at t = {times[i]:g} s")
            fig.colorbar(im2, ax=axes[2, col], label="Θ (K)", shrink=0.8)
        for ax in axes[:, col]:
            ax.set_xlabel("x (m)")
            ax.set_ylabel("y (m)")
    fig.colorbar(im0, ax=axes[0, :].tolist(), label="vorticity ω (s-1)", shrink=0.8)
    fig.colorbar(im1, ax=axes[1, :].tolist(), label="temperature T (K)", shrink=0.8)
    fig.suptitle(f"{ds.attrs.get('method', '')}: member 0 on the torus [0, 2π)², N = {W.shape[-1]}")
    return save(fig, path)


def budget_figure(datasets: dict, path):
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.2), constrained_layout=True)
    colors = {"kinetic_energy": "C0", "internal_energy": "C3", "potential_energy": "C2", "total_energy": "k"}
    for m, ds in datasets.items():
        t = ds["t"].values
        ok = completed(ds)
        if ok.size == 0:
            continue
        dash = "-" if m == next(iter(datasets)) else "--"
        for name, col in colors.items():
            v = ds[name].values - (ds[name].values[:, :1] if name != "kinetic_energy" else 0.0)
            series(a, t, v, ok, f"{m}: {name.replace('_', ' ')}" + ("" if name == "kinetic_energy" else " − t=0"),
                   color=col, ls=dash)
        series(b, t, ds["entropy"].values - ds["entropy"].values[:, :1], ok, f"{m}: S_tot − S_tot(0)",
               **style(m))
    a.set_xlabel("t (s)")
    a.set_ylabel("energy (J)")
    a.set_title("energy budget: kinetic, internal, potential, total")
    legend_beside(a)
    b.set_xlabel("t (s)")
    b.set_ylabel("S_tot − S_tot(0) (J K-1)")
    b.set_title("total entropy (never falls)")
    legend_beside(b)
    return save(fig, path)


def animation(W, S, times, ds, path_stem) -> Path | None:
    """ω and T of member 0 as an animation: GIF (pillow) or MP4 (ffmpeg), whichever writer exists."""
    import matplotlib.pyplot as plt
    from matplotlib import animation as anim

    writer, ext = None, None
    if anim.writers.is_available("pillow"):
        writer, ext = "pillow", "gif"
    elif anim.writers.is_available("ffmpeg"):
        writer, ext = "ffmpeg", "mp4"
    if writer is None:
        print("no animation: matplotlib has neither the pillow nor the ffmpeg writer here")
        return None
    c, T0, alpha = _scene_numbers(ds)
    maps = [field_maps(W[i], S[i], c, T0, alpha) for i in range(len(times))]
    wmax = max(np.abs(m[0]).max() for m in maps) or 1.0
    tlo, thi = min(m[1].min() for m in maps), max(m[1].max() for m in maps)
    fig, (a, b) = plt.subplots(1, 2, figsize=(8, 3.6), constrained_layout=True)
    extent = (0, 2 * np.pi, 0, 2 * np.pi)
    i0 = a.imshow(maps[0][0].T, origin="lower", extent=extent, cmap="RdBu_r", vmin=-wmax, vmax=wmax)
    i1 = b.imshow(maps[0][1].T, origin="lower", extent=extent, cmap="inferno", vmin=tlo, vmax=thi)
    fig.colorbar(i0, ax=a, label="ω (s-1)")
    fig.colorbar(i1, ax=b, label="T (K)")

    def frame(k):
        i0.set_data(maps[k][0].T)
        i1.set_data(maps[k][1].T)
        a.set_title(f"ω, t = {times[k]:g} s")
        b.set_title(f"T, t = {times[k]:g} s")
        return i0, i1

    ani = anim.FuncAnimation(fig, frame, frames=len(times), blit=False)
    out = Path(f"{path_stem}.{ext}")
    ani.save(out, writer=writer, fps=8)
    plt.close(fig)
    return out


def draw(datasets: dict, folder, stem: str) -> list[Path]:
    """The figures of a run, ``datasets`` {method: Dataset}, the scene's own method first."""
    import matplotlib

    matplotlib.use("Agg")
    folder = Path(folder)
    first = next(iter(datasets.values()))
    out = [budget_figure(datasets, folder / f"{stem}_budget.png")]
    W, S = member0_fields(first)
    times = first["t"].values
    if np.isfinite(W).all() and np.isfinite(S).all():
        opts = tomllib.loads(first.attrs["scene"]).get("output", {})
        out.append(map_figure(W, S, times, sample_times(len(times), 4), first, folder / f"{stem}_maps.png",
                              bool(opts.get("theta_map", False))))
        if opts.get("animation", False):
            a = animation(W, S, times, first, folder / f"{stem}_animation")
            if a is not None:
                out.append(a)
    return out
