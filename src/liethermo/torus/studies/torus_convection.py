"""The warm patch of torus_convection rising, mixing and relaxing toward rest, and the end
state energy conservation alone predicts: W = 0, uniform Θ = θ∞, S∞ = c log((θ∞I + αΦ)/T₀),
with θ∞ from H(S∞) = H(0).  The run is a decaying transient (closed system, periodic
"gravity"), never sustained convection.  The entropy produced is checked against the
rate formula Ṡ_tot = (4π²/N)[ν tr(Θ⁻¹W²) + κ tr(Θ⁻¹L′Θ)] integrated over the kept states."""

from __future__ import annotations

import math

import numpy as np
import xarray as xr
from scipy.optimize import brentq

from ...studies.framework import Figure, Option, Stage, Study, Table, Verdict, run_scene


def predicted_end(H0: float, N: int, c: float, T0: float, alpha: float) -> dict:
    """θ∞, S_tot∞ and the stratified T range of the rest state with the energy H0."""
    phi = np.cos(2 * math.pi * np.arange(N) / N)  # the eigenvalues of Φ = ½(h + h†)
    area = 4 * math.pi**2 / N

    def energy(theta):  # U of S = c log((θI + αΦ)/T₀): E(S) = c(θI + αΦ), tr Φ = 0
        return area * (c * N * theta - alpha * c * np.sum(phi * np.log((theta + alpha * phi) / T0)))

    lo = alpha * (1 + 1e-12) + 1e-300
    theta = brentq(lambda x: energy(x) - H0, lo, max(10 * H0 / (4 * math.pi**2 * c), 10 * T0) + 10 * alpha,
                   xtol=1e-15, rtol=1e-15)
    return {"theta": theta, "S_tot": area * c * float(np.sum(np.log((theta + alpha * phi) / T0))),
            "T_min": theta + alpha * float(phi.min()), "T_max": theta + alpha * float(phi.max())}


def relax(ctx, coords) -> xr.Dataset:
    sc = ctx.scene(coords["point"])
    itg = sc["integrator"]
    ds, st = run_scene(sc, ctx.opt["method"], h=itg["h"], steps=itg["steps"], every=sc["output"]["every"])
    from .. import kernels as tk
    from ..run import thermo_of

    th = thermo_of(sc)
    b = tk.basis(int(sc["torus"]["N"]))
    W = ds["vorticity_real"].values[0] + 1j * ds["vorticity_imag"].values[0]
    S = ds["entropy_density_real"].values[0] + 1j * ds["entropy_density_imag"].values[0]
    rate = tk.entropy_rate(W, S, th, b)
    t = ds["t"].values
    produced = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))])
    pred = predicted_end(float(ds["total_energy"].values[0, 0]), b.N, th.c, th.T0, th.alpha)
    out = ds[["kinetic_energy", "internal_energy", "potential_energy", "total_energy", "entropy", "theta_min",
              "theta_max", "temperature_min", "temperature_max"]].isel(member=0, drop=True)
    return out.assign(entropy_rate=("t", rate), entropy_from_rate=("t", out["entropy"].values[0] + produced),
                      predicted_theta=pred["theta"], predicted_entropy=pred["S_tot"],
                      predicted_temperature_min=pred["T_min"], predicted_temperature_max=pred["T_max"],
                      conduction_substeps=st.conduction_substeps, kernel_time=st.kernel_time)


QUANTITIES = {
    "entropy_rate": ("J K-1 s-1", "(4π²/N)[ν tr(Θ⁻¹W²) + κ tr(Θ⁻¹L′Θ)] at the kept states"),
    "entropy_from_rate": ("J K-1", "S_tot(0) + the trapezoid integral of the rate formula"),
    "predicted_theta": ("K", "θ∞ of the rest state with the initial energy"),
    "predicted_entropy": ("J K-1", "S_tot of that rest state (the largest at that energy)"),
    "predicted_temperature_min": ("K", "θ∞ + α min eig Φ: the rest state's coldest T"),
    "predicted_temperature_max": ("K", "θ∞ + α max eig Φ: its warmest T"),
    "conduction_substeps": ("1", "conduction sub-steps of the run"),
    "kernel_time": ("s", "the run's stepping time"),
}


def _end(ds):
    return ds.isel(t=-1)


def tables(ds, ctx):
    e = _end(ds)
    K0 = float(ds["potential_energy"].isel(t=0) - e["potential_energy"])
    rows = [{"quantity": "θ (K): mean of Θ's extremes at t_end vs predicted θ∞",
             "run": 0.5 * float(e["theta_min"] + e["theta_max"]), "predicted": float(e["predicted_theta"])},
            {"quantity": "Θ spread max − min (K) at t_end", "run": float(e["theta_max"] - e["theta_min"]),
             "predicted": 0.0},
            {"quantity": "T min (K) at t_end", "run": float(e["temperature_min"]),
             "predicted": float(e["predicted_temperature_min"])},
            {"quantity": "T max (K) at t_end", "run": float(e["temperature_max"]),
             "predicted": float(e["predicted_temperature_max"])},
            {"quantity": "S_tot (J K-1) at t_end", "run": float(e["entropy"]), "predicted": float(e["predicted_entropy"])},
            {"quantity": "kinetic energy (J) at t_end", "run": float(e["kinetic_energy"]), "predicted": 0.0},
            {"quantity": "potential energy released (J)", "run": K0, "predicted": float("nan")},
            {"quantity": "max |H − H(0)| / H(0)",
             "run": float(abs(ds["total_energy"] - ds["total_energy"].isel(t=0)).max() / ds["total_energy"].isel(t=0)),
             "predicted": 0.0},
            {"quantity": "S_tot(t_end) − S_tot(0): run vs ∫ rate formula dt (J K-1)",
             "run": float(e["entropy"] - ds["entropy"].isel(t=0)),
             "predicted": float(e["entropy_from_rate"] - ds["entropy"].isel(t=0))}]
    return [Table("end_state", "The run's end against the rest state energy conservation predicts", rows)]


def verdicts(ds, ctx):
    e = _end(ds)
    H = ds["total_energy"]
    dH = float(abs(H - H.isel(t=0)).max() / H.isel(t=0))
    dS = ds["entropy"].diff("t")
    gap = float(e["predicted_entropy"] - e["entropy"])
    gap0 = float(e["predicted_entropy"] - ds["entropy"].isel(t=0))
    produced = float(e["entropy"] - ds["entropy"].isel(t=0))
    by_rate = float(e["entropy_from_rate"] - ds["entropy"].isel(t=0))
    return [
        Verdict("the energy is conserved (CMP)", f"{dH:.2g}", "≤ 1e-12", dH <= 1e-12),
        Verdict("the entropy never falls", f"least change between kept times {float(dS.min()):.2g} J K-1",
                "≥ −1e-12 J K-1", float(dS.min()) >= -1e-12),
        Verdict("the entropy approaches the predicted maximum",
                f"{gap:.3g} J K-1 left of {gap0:.3g} at t = 0", "below 10 % of the initial gap", 0 <= gap < 0.1 * gap0),
        Verdict("the entropy produced follows the rate formula",
                f"{produced:.5g} vs {by_rate:.5g} J K-1", "within 2 % (trapezoid on the kept states)",
                abs(produced - by_rate) <= 0.02 * abs(produced)),
        Verdict("Θ stays positive", f"min {float(ds['theta_min'].min()):.4g} K", "> 0",
                float(ds["theta_min"].min()) > 0),
    ]


def findings(ds, ctx):
    e = _end(ds)
    K = ds["kinetic_energy"]
    i = int(np.argmax(K.values))
    return [f"The patch rises: the kinetic energy peaks at {float(K[i]):.3g} J at t = {float(ds['t'][i]):g} s "
            f"(from potential energy) and decays to {float(e['kinetic_energy']):.2g} J at t = {float(ds['t'][-1]):g} s: "
            "a decaying transient (the system is closed and its gravity periodic), never sustained convection.",
            f"Energy conservation alone predicts the rest state θ∞ = {float(e['predicted_theta']):.6g} K with T from "
            f"{float(e['predicted_temperature_min']):.4g} to {float(e['predicted_temperature_max']):.4g} K "
            f"(stratified) and S_tot = {float(e['predicted_entropy']):.6g} J K-1; at the end the run has Θ in "
            f"[{float(e['theta_min']):.6g}, {float(e['theta_max']):.6g}] K, T in [{float(e['temperature_min']):.4g}, "
            f"{float(e['temperature_max']):.4g}] K and S_tot = {float(e['entropy']):.6g} J K-1."]


def draw(ds, ctx, fig):
    a, b = fig.subplots(1, 2)
    t = ds["t"].values
    for v, c in (("kinetic_energy", "C0"), ("internal_energy", "C3"), ("potential_energy", "C2")):
        a.plot(t, ds[v] - (0 if v == "kinetic_energy" else ds[v].isel(t=0)), color=c,
               label=v.replace("_", " ") + ("" if v == "kinetic_energy" else " − t=0"))
    a.set(xlabel="t (s)", ylabel="energy (J)", title="energy: potential → kinetic → heat")
    a.legend(fontsize=8)
    b.plot(t, ds["theta_max"] - ds["theta_min"], color="C1", label="Θ max − min")
    b.plot(t, ds["temperature_max"] - ds["temperature_min"], color="C3", label="T max − min")
    b.axhline(float(ds["predicted_temperature_max"] - ds["predicted_temperature_min"]), color="C3", ls=":",
              label="predicted T max − min at rest")
    b.set(xlabel="t (s)", ylabel="spread (K)", title="Θ becomes uniform, T stratified")
    b.legend(fontsize=8)
    return [a, b]


STUDY = Study(
    kind="torus_convection", title="torus fluid: a warm patch rises and relaxes", models=("torus",),
    needs_methods=False,
    description="The warm patch rises, mixes and relaxes to the rest state energy conservation predicts",
    options=(Option("method", "cmp", "one of cmp|magmp|rk4", "", "the method run"),),
    stages=(Stage("run", relax, over=("point",)),),
    quantities=QUANTITIES, tables=tables, verdicts=verdicts, findings=findings,
    facts=lambda ds, ctx: {"sc": ctx.scene(ctx.points[0])},
    figures=(Figure("relaxation", kind="custom", draw=draw, select=lambda ds, ctx: ds, size=(11.5, 4.2),
                    claim="potential energy becomes kinetic energy and then heat; Θ evens out while T stays "
                          "stratified by 2α"),),
    report=("Scene `{scene}`: N = {sc[torus][N]}, ν = {sc[fluid][kinematic_viscosity]:g} m2 s-1, "
            "κ = {sc[thermo][conductivity]:g} W K-1, α = {sc[thermo][buoyancy]:g} K, {opt[method]}, "
            "{sc[integrator][steps]} steps of h = {sc[integrator][h]:g} s. The rest state is predicted from the "
            "initial energy alone (W = 0, Θ uniform)."),
)
