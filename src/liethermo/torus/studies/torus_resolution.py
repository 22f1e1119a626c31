"""Resolution of the torus fluid against the continuum: the vorticity
ω₀ = cos x + cos y + 0.6 cos 2x + 0.2 cos 3x + 0.3 sin(x + 2y) at N = 15 … 127, run to
t_end, against a dealiased pseudo-spectral solution (:mod:`liethermo.torus.pseudospectral`,
which shares no code with the sine bracket).  The error is the relative L² error of the
modes |m_i| ≤ M; its order in 1/N between successive N."""

from __future__ import annotations

import math

import numpy as np
import xarray as xr

from ...studies.common import StudyError, dim_name
from ...studies.framework import Figure, Option, Stage, Study, Table, Verdict

SWEEP_KEY = "torus.N"
DIM = dim_name(SWEEP_KEY)


def _Ns(ctx):  # noqa: N802
    return [int(p[SWEEP_KEY]) for p in ctx.points]


def _check(ctx):
    Ns = (ctx.study.get("sweep") or {}).get(SWEEP_KEY)
    if list(ctx.study.get("sweep") or {}) != [SWEEP_KEY] or not isinstance(Ns, list) or len(Ns) < 2 \
            or Ns != sorted(set(Ns)) or any(n % 2 == 0 or n < 7 for n in Ns):
        raise StudyError(f"sweep: a torus_resolution study sweeps {SWEEP_KEY!r} over at least two odd N ≥ 7, "
                         f"increasing, got {Ns!r}")


def reference(ctx, coords) -> xr.Dataset:
    from ..pseudospectral import PseudoSpectral, section7_modes

    n = int(ctx.opt["reference_n"])
    ps = PseudoSpectral(n, float(ctx.opt["nu"]))
    w = ps.run(ps.from_modes(section7_modes(7)), float(ctx.opt["t_end"]), float(ctx.opt["reference_dt"]))
    M = math.ceil(n / 3) - 1  # the modes the 2/3 rule keeps: |k| < n/3
    f = ps.to_modes(w, 2 * M + 1)
    return xr.Dataset({"reference_real": (("kx", "ky"), f.real), "reference_imag": (("kx", "ky"), f.imag)})


def resolve(ctx, coords, reference) -> xr.Dataset:
    import time

    from threadpoolctl import threadpool_limits

    from .. import kernels as tk
    from .. import step as ts
    from ..pseudospectral import section7_modes

    N = int(coords["point"][SWEEP_KEY])
    b = tk.basis(N)
    W = tk.from_modes(section7_modes(N)[None], b)
    h = float(ctx.opt["h"])
    steps = round(float(ctx.opt["t_end"]) / h)
    t0 = time.perf_counter()
    with threadpool_limits(1):
        Ws, *_ = ts.integrate(W, np.zeros_like(W), th=tk.Thermo(nu=float(ctx.opt["nu"])), b=b,
                              method=ctx.opt["method"], h=h, steps=steps, every=steps)
    cost = (time.perf_counter() - t0) / steps
    fN = tk.to_modes(Ws[:, -1], b)[0]
    R = reference["reference_real"].values + 1j * reference["reference_imag"].values
    NR = R.shape[-1]
    ks = tk.wave_numbers(N)
    kept = np.abs(ks) <= (NR - 1) // 2  # modes beyond the reference's are zero there
    fr = np.zeros((N, N), complex)
    fr[np.ix_(kept, kept)] = R[np.ix_(ks[kept] % NR, ks[kept] % NR)]
    err = float(np.linalg.norm(fN - fr) / np.linalg.norm(fr))
    low = np.abs(ks) <= 5
    sel = np.ix_(low, low)
    err5 = float(np.linalg.norm(fN[sel] - fr[sel]) / np.linalg.norm(fr[sel]))
    return xr.Dataset({"error": err, "error_low": err5, "cost_per_step": cost})


QUANTITIES = {
    DIM: ("1", "matrix size N (sweep)"),
    "error": ("1", "relative L² error of the modes |m_i| ≤ M at t_end against the pseudo-spectral solution"),
    "error_low": ("1", "the same over the modes |m_i| ≤ 5"),
    "cost_per_step": ("s", "wall time per step of one member"),
    "order": ("1", "log(e(N_prev)/e(N)) / log(N/N_prev): the order in 1/N"),
}


def derive(ds, ctx):
    Ns = np.array(_Ns(ctx), float)
    e = ds["error"].values
    order = np.concatenate([[np.nan], np.log(e[:-1] / e[1:]) / np.log(Ns[1:] / Ns[:-1])])
    return ds.assign(order=((DIM,), order))


def tables(ds, ctx):
    rows = [{"N": int(n), "relative L² error": float(ds["error"].sel({DIM: n})),
             "error |m_i| ≤ 5": float(ds["error_low"].sel({DIM: n})), "order in 1/N": float(ds["order"].sel({DIM: n})),
             "ms per step": 1e3 * float(ds["cost_per_step"].sel({DIM: n}))} for n in _Ns(ctx)]
    return [Table("resolution", f"Error at t = {ctx.opt['t_end']:g} s against the pseudo-spectral solution", rows)]


def verdicts(ds, ctx):
    o = ds["order"].values[1:]
    Ns = _Ns(ctx)
    from_31 = [v for n, v in zip(Ns[1:], o) if n > 31 or (n == 31)]
    return [Verdict("the error falls at order ≥ 1.8 in 1/N", ", ".join(f"{v:.2f}" for v in o),
                    "every order from N = 31 on ≥ 1.8", bool(all(v >= 1.8 for v in from_31)))]


def findings(ds, ctx):
    return [f"Errors {', '.join(f'{v:.3g}' for v in ds['error'].values)} at N = {', '.join(map(str, _Ns(ctx)))}: "
            f"orders {', '.join(f'{v:.2f}' for v in ds['order'].values[1:])} in 1/N (the truncation of the sine "
            "bracket, ε = 2π/N, is second order)."]


def draw(ds, ctx, fig):
    ax = fig.subplots(1, 1)
    Ns = np.array(_Ns(ctx), float)
    ax.loglog(Ns, ds["error"].values, "o-", label="all modes |m_i| ≤ M")
    ax.loglog(Ns, ds["error_low"].values, "s--", label="modes |m_i| ≤ 5")
    ax.loglog(Ns, ds["error"].values[0] * (Ns[0] / Ns) ** 2, ":", color="0.4", label="slope −2")
    ax.set(xlabel="N", ylabel="relative L² error at t_end (1)", title="convergence in N to the continuum",
           xticks=Ns, xticklabels=[str(int(n)) for n in Ns])
    ax.minorticks_off()
    ax.legend(fontsize=8)
    return [ax]


STUDY = Study(
    kind="torus_resolution", title="torus fluid: convergence in N to the continuum", models=("torus",),
    needs_methods=False, description="The torus fluid at N = 15 ... 127 against a pseudo-spectral solution",
    options=(Option("method", "rk4", "one of cmp|isomp|rk4", "", "the method run"),
             Option("h", 2.5e-3, "number>0", "s", "time step (small: the error in N must dominate)"),
             Option("t_end", 1.0, "number>0", "s", "end time"),
             Option("nu", 0.0, "number>=0", "m2 s-1", "kinematic viscosity ν"),
             Option("reference_n", 192, "int>=3", "1", "the pseudo-spectral grid (modes |k| < n/3 kept)"),
             Option("reference_dt", 2.5e-3, "number>0", "s", "the pseudo-spectral RK4 step")),
    check=_check,
    stages=(Stage("reference", reference, over=(), keep=()),
            Stage("run", resolve, over=("point",), needs=("reference",))),
    quantities=QUANTITIES, derive=derive, tables=tables, verdicts=verdicts, findings=findings,
    facts=lambda ds, ctx: {},
    figures=(Figure("resolution", kind="custom", draw=draw, select=lambda ds, ctx: ds, size=(6.5, 4.4),
                    claim="the error falls as N⁻² against the continuum"),),
    report=("ω₀ = cos x + cos y + 0.6 cos 2x + 0.2 cos 3x + 0.3 sin(x + 2y), {opt[method]} with h = {opt[h]:g} s to "
            "t = {opt[t_end]:g} s, ν = {opt[nu]:g}; reference: pseudo-spectral {opt[reference_n]}², 2/3 rule, RK4 "
            "dt = {opt[reference_dt]:g} s."),
)
