"""The thermodynamic Zeitlin fluid on the sphere: operators, flows, orders,
conservation laws, scenes, datasets, the command line."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from scipy.special import sph_harm_y

from liethermo.cli import main
from liethermo.top.methods import COMPOSITION_FACTORS
from liethermo.scene import SceneError, load_scene
from liethermo.zeitlin import kernels as zk
from liethermo.zeitlin import run as zr


def _random_W(N, M, lmax, rng):
    b = zk.basis(N)
    C = np.zeros((M, b.modes), complex)
    sel = (b.ell >= 1) & (b.ell <= lmax)
    C[:, sel] = rng.normal(size=(M, sel.sum())) + 1j * rng.normal(size=(M, sel.sum()))
    W = zk.from_modes(C, b)
    return W / np.sqrt(zk.energy_of_modes(zk.to_modes(W, b), b))[:, None, None]


@pytest.mark.parametrize("N", [3, 8, 17])
def test_laplacian_by_diagonals_is_the_spin_definition_and_inverts(N):
    rng = np.random.default_rng(N)
    b = zk.basis(N)
    A = rng.normal(size=(3, N, N)) + 1j * rng.normal(size=(3, N, N))
    W = A - np.conj(np.swapaxes(A, 1, 2))
    W -= np.trace(W, axis1=1, axis2=2)[:, None, None] * np.eye(N) / N
    dense = np.array([zk.laplacian_dense(w) for w in W])
    assert np.abs(zk.laplacian(W, b) - dense).max() < 1e-13 * N * N * np.abs(W).max()
    P = zk.laplacian_inverse(W, b)
    assert np.abs(zk.laplacian(P, b) - W).max() < 1e-13 * N * np.abs(W).max()
    # the T_lm are orthonormal: ∫ω² dA = Σ weight |ω_lm|² = (4π/N)‖W‖², and W is rebuilt from its ω_lm
    C = zk.to_modes(W, b)
    area = 4 * np.pi / N
    assert np.allclose((np.abs(C) ** 2 * zk.mode_weights(b)).sum(1), area * (np.abs(W) ** 2).sum((1, 2)), rtol=1e-13)
    assert np.allclose(2 * zk.enstrophy(W), area * (np.abs(W) ** 2).sum((1, 2)), rtol=1e-14)
    assert np.abs(zk.from_modes(C, b) - W).max() < 1e-13 * np.abs(W).max()
    # H = −½∫ψω dA = (4π/N)·½⟨W, −P⟩ (⟨A, B⟩ = −tr AB) from the modes, and the spectrum sums to it
    H = area * 0.5 * np.einsum("kij,kji->k", W, P).real
    assert np.allclose(zk.energy_of_modes(C, b), H, rtol=1e-13)
    assert np.allclose(zk.spectrum_of_modes(C, b).sum(-1), H, rtol=1e-13)


def _coherent(N: int, theta: float, phi: float) -> np.ndarray:
    """Spin coherent state |θ, φ⟩ in the basis m_i = s − i (|s⟩ at the north pole)."""
    from math import lgamma

    s = (N - 1) / 2.0
    m = s - np.arange(N)
    k = np.arange(N)
    logc = np.array([0.5 * (lgamma(N) - lgamma(kk + 1) - lgamma(N - kk)) for kk in k])
    amp = np.exp(logc) * np.cos(theta / 2) ** (N - 1 - k) * np.sin(theta / 2) ** k
    return amp * np.exp(-1j * m * phi)


@pytest.mark.parametrize("N", [2, 7, 12])
def test_quantized_harmonics_have_the_spherical_harmonics_as_symbols(N):
    """The coherent-state (Berezin) symbol of each T_lm is a positive multiple
    of Y_lm, the same at every point.  The symbols of the high degrees fall
    super-exponentially with N, so this independent check of the harmonics'
    phases is made where they stand well above round-off (N ≤ 12); the
    rotation test below covers large N."""
    b = zk.basis(N)
    pts = [(0.4, 0.3), (1.3, 2.0), (2.5, -1.1)]
    for d in range(N):
        n = N - d
        V = b.vecs[b.voff[d]:b.voff[d + 1]].reshape(n, n)
        for j, l in enumerate(range(d, N)):
            ratios = []
            for th, ph in pts:
                z = _coherent(N, th, ph)
                sym = np.sum(np.conj(z[:n]) * V[:, j] * z[d:])
                ratios.append(sym / sph_harm_y(l, d, th, ph))
            ratios = np.array(ratios)
            assert np.all(ratios.real > 0) and np.abs(ratios.imag).max() < 1e-10
            assert np.ptp(ratios.real) < 1e-10 * ratios.real.max()


def test_viscous_flow_is_exact_and_its_heat_is_the_energy_lost():
    rng = np.random.default_rng(3)
    N, nu = 9, 0.05
    b = zk.basis(N)
    W = _random_W(N, 3, N - 1, rng)
    W1, q1 = zk.viscous_flow(W, 0.3, nu, b)
    W2, q2 = zk.viscous_flow(W1, 0.2, nu, b)
    W12, q12 = zk.viscous_flow(W, 0.5, nu, b)
    assert np.abs(W2 - W12).max() < 1e-14 * np.abs(W).max()  # a flow: F_s ∘ F_t = F_(s+t)
    assert np.allclose(q1 + q2, q12, rtol=1e-13)
    H = lambda X: zk.energy_of_modes(zk.to_modes(X, b), b)  # noqa: E731
    assert np.allclose(H(W) - H(W12), q12, rtol=1e-12)
    # its generator is ν(Δ + 2)W, and the l = 1 part (angular momentum) is undamped
    eps = 1e-6
    Wp, _ = zk.viscous_flow(W, eps, nu, b)
    Wm, _ = zk.viscous_flow(W, -eps, nu, b)
    assert np.abs((Wp - Wm) / (2 * eps) - nu * (zk.laplacian(W, b) + 2 * W)).max() < 1e-8
    assert np.abs(zk.angular_momentum(W12, b) - zk.angular_momentum(W, b)).max() < 1e-14


def _split_run(W, h, T, nu, b, fac):
    q = np.zeros(W.shape[0])
    D = None
    for _ in range(int(round(T / h))):
        W, q, _, failed, D = zr.split_step(W, q, h, nu, b, fac, 1e-14, 100, D)
        assert not failed.any()
    return W, q


def _reference(W0, T, nu, N):
    b = zk.basis(N)
    Ws = np.empty((W0.shape[0], 2, N, N), complex)
    qs = np.empty((W0.shape[0], 2))
    status = np.zeros(W0.shape[0], np.int8)
    zr.reference_run(W0, np.array([0.0, T]), nu, b, Ws, qs, status, False)
    assert not status.any()
    return Ws[:, 1], qs[:, 1]


def test_orders_2_4_6_against_the_reference():
    """N = 8, ν = 0.01, t = 1, unit energy, l ≤ 5: the observed orders of split,
    split4 (Suzuki) and split6 (Kahan–Li), and the RK4 baseline, on W and q."""
    rng = np.random.default_rng(2)
    N, nu, T = 8, 0.01, 1.0
    b = zk.basis(N)
    W0 = _random_W(N, 2, 5, rng)
    Wr, qr = _reference(W0, T, nu, N)
    cases = {"split": ((1.0,), (0.1, 0.05), 2), "split4": (COMPOSITION_FACTORS[("small_error", 4)], (0.05, 0.025), 4),
             "split6": (COMPOSITION_FACTORS[("small_error", 6)], (0.1, 0.05), 6)}
    for name, (fac, hs, order) in cases.items():
        errs = []
        for h in hs:
            W, q = _split_run(W0, h, T, nu, b, fac)
            errs.append(np.abs(W - Wr).max() / np.abs(Wr).max())
        observed = np.log2(errs[0] / errs[1])
        assert abs(observed - order) < 0.15, (name, errs, observed)
    assert errs[1] > 1e-11  # the order-6 pair is above the reference's own error
    # split4 at h = 0.025 s: an error near 1e-7 on these members
    W, _ = _split_run(W0, 0.025, T, nu, b, COMPOSITION_FACTORS[("small_error", 4)])
    assert 1e-8 < np.abs(W - Wr).max() / np.abs(Wr).max() < 1e-6
    errs = []
    for h in (0.05, 0.025):
        W, q = W0, np.zeros(2)
        for _ in range(int(round(T / h))):
            W, q = zr.rk4_step(W, q, h, nu, b)
        errs.append((np.abs(W - Wr).max() / np.abs(Wr).max(), np.abs(q - qr).max()))
    assert abs(np.log2(errs[0][0] / errs[1][0]) - 4) < 0.2
    assert abs(np.log2(errs[0][1] / errs[1][1]) - 4) < 0.3  # and the heat it integrates alongside


def test_ideal_fluid_keeps_casimirs_and_angular_momentum_over_ten_thousand_steps():
    rng = np.random.default_rng(5)
    N = 8
    b = zk.basis(N)
    W0 = _random_W(N, 2, 5, rng)
    W, q = _split_run(W0, 0.05, 500.0, 0.0, b, (1.0,))
    c0, c1 = zk.casimirs(W0), zk.casimirs(W)
    assert np.abs(c1[:, 0] / c0[:, 0] - 1).max() < 1e-11  # tr W²
    assert np.abs(c1[:, 2] / c0[:, 2] - 1).max() < 1e-11  # tr W⁴
    L0, L1 = zk.angular_momentum(W0, b), zk.angular_momentum(W, b)
    assert np.abs(L1 - L0).max() < 1e-11 * np.linalg.norm(L0, axis=1).max()
    assert np.all(q == 0.0)
    H0, H1 = (zk.energy_of_modes(zk.to_modes(X, b), b) for X in (W0, W))
    assert np.abs(H1 / H0 - 1).max() < 1e-3  # bounded, not kept: the midpoint's energy error


def test_viscous_fluid_conserves_total_energy_to_the_order_and_entropy_never_decreases():
    base = {"zeitlin.N": 10, "fluid.kinematic_viscosity": 0.02, "initial.lmax": 6, "ensemble.members": 3,
            "integrator.steps": 100, "output.every": 1}
    errs = []
    for h in (0.04, 0.02):
        sc = load_scene("zeitlin_decay", {**base, "integrator.h": h, "integrator.steps": int(round(4 / h))})
        ds = zr.simulate(sc, progress=False)
        errs.append(float(np.abs(ds["energy_error"]).max()))
        assert (np.diff(ds["entropy"].values, axis=1) >= 0).all()
        assert float(ds["heat"][:, -1].min()) > 0.1 * float(ds["energy"][:, 0].min())
        L = ds["angular_momentum"].values
        assert np.abs(L - L[:, :1]).max() < 1e-12 * np.abs(L).max()
    assert abs(np.log2(errs[0] / errs[1]) - 2) < 0.2


@pytest.mark.parametrize("method", sorted(zr.METHOD_LAWS))
def test_each_method_keeps_the_laws_it_declares(method):
    """Every law in METHOD_LAWS holds in every output step of a run that could
    break it: entropy at ν = 0.3 s-1 (ν h λ_max = 1.3, within RK4's stability), the
    spectrum at ν = 0, the angular momentum in both."""
    laws = zr.METHOD_LAWS[method]
    base = {"zeitlin.N": 10, "initial.lmax": 7, "ensemble.members": 3, "integrator.method": method,
            "integrator.steps": 40, "output.every": 1, "output.compare": []}
    for nu, h in ((0.3, 0.05), (0.0, 0.05)):
        ds = zr.simulate(load_scene("zeitlin_decay", {**base, "fluid.kinematic_viscosity": nu, "integrator.h": h}),
                         progress=False)
        assert (ds["status"] == 0).all()
        if zr.LAW_ENTROPY_MONOTONE in laws and nu > 0:
            assert (np.diff(ds["entropy"].values, axis=1) >= 0).all()
        if zr.LAW_ISOSPECTRAL in laws and nu == 0:
            assert np.abs(ds["casimir_drift"].values).max() < 1e-12
        if zr.LAW_ANGULAR_MOMENTUM in laws:
            L = ds["angular_momentum"].values
            assert np.abs(L - L[:, :1]).max() < 1e-11 * np.abs(L).max()
    assert (zr.LAW_ENTROPY_MONOTONE in laws) == (method == "split")  # the compositions measure it, rk4 has none


def test_a_member_whose_fixed_point_fails_is_flagged_and_stops():
    sc = load_scene("zeitlin_ideal", {"zeitlin.N": 8, "initial.lmax": 4, "ensemble.members": 2,
                                      "integrator.steps": 10, "output.every": 1, "integrator.max_iter": 2})
    ds = zr.simulate(sc, progress=False)
    assert (ds["status"].values == 1).all() and (ds["failed_step"].values == 1).all()
    assert np.isnan(ds["energy"].values[:, 1:]).all() and np.isfinite(ds["energy"].values[:, 0]).all()


def test_scene_rules_name_the_key():
    with pytest.raises(SceneError, match="initial.lmax.*zeitlin.N"):
        load_scene("zeitlin_decay", {"zeitlin.N": 8, "initial.lmax": 8})
    with pytest.raises(SceneError, match="output.compare"):
        load_scene("zeitlin_decay", {"output.compare": ["vi"]})
    with pytest.raises(SceneError, match="body.radius.*Zeitlin"):
        load_scene("zeitlin_decay", {"body.radius": 1.0})
    with pytest.raises(SceneError, match="zeitlin.N"):
        load_scene("zeitlin_decay", {"zeitlin.N": 2})
    # members are reproducible one by one
    sc = load_scene("zeitlin_decay", {"zeitlin.N": 8, "initial.lmax": 4, "ensemble.members": 3})
    assert np.array_equal(zr.initial_fields(sc)[2:], zr.initial_fields(sc, [2]))


def test_command_line_writes_the_named_variables(tmp_path, capsys):
    out = tmp_path / "z.nc"
    rc = main(["run", "zeitlin_ideal", "-o", str(out), "--no-progress", "--set", "zeitlin.N=8",
               "--set", "initial.lmax=5", "--set", "integrator.steps=20", "--set", "output.every=5",
               "--set", "output.figures=true"])
    assert rc == 0
    for f in ("vorticity", "energy_heat", "spectrum", "casimirs"):
        assert (tmp_path / f"z_{f}.png").stat().st_size > 10_000
    printed = capsys.readouterr().out
    assert "tr W² drift" in printed and str(out) in printed
    ds = xr.open_dataset(out)  # plain xarray
    for v in ("energy", "heat", "entropy", "temperature", "enstrophy"):
        assert ds[v].dims == ("member", "t") and ds[v].attrs["units"]
    assert ds["casimir"].dims == ("member", "t", "k") and list(ds["k"].values) == [2, 3, 4]
    assert ds["angular_momentum"].dims[:2] == ("member", "t") and ds["angular_momentum"].shape[-1] == 3
    assert ds["energy_spectrum"].dims == ("member", "t", "l") and ds.sizes["l"] == 7
    assert ds["vorticity_real"].dims == ("member", "t", "row", "col")
    W = ds["vorticity_real"].values + 1j * ds["vorticity_imag"].values
    assert np.abs(W + np.conj(np.swapaxes(W, -1, -2))).max() == 0.0  # skew-Hermitian
    assert (tmp_path / "z_rk4.nc").exists()
    ds.close()
    # another scene's file is not replaced without --force
    assert main(["run", "zeitlin_decay", "-o", str(out), "--no-progress", "--set", "zeitlin.N=8",
                 "--set", "initial.lmax=5"]) == 2
    assert "--force" in capsys.readouterr().err


# ----------------------------------------------------------------------------- studies (reduced)


def _study(name, tmp_path, scene=None):
    from pathlib import Path

    from liethermo.studies.common import with_scene
    from liethermo.studies.runner import load_study, run_study, validate_study

    study = load_study(Path(__file__).resolve().parents[1] / "studies" / f"{name}.toml")
    study = with_scene(study, scene) if scene else study
    validate_study(study)
    return run_study(study, tmp_path / name, reduced=True, progress=False)


def test_convergence_study_reports_the_orders(tmp_path):
    import pandas as pd

    report = _study("convergence", tmp_path, scene="zeitlin_decay")  # the top's study file on a fluid scene
    df = pd.read_csv(report.parent / "orders.csv").set_index("method")
    for m, order in (("split", 2), ("split4", 4), ("split6", 6), ("rk4", 4)):
        assert abs(df.loc[m, "order vorticity"] - order) < 0.2, (m, df.loc[m, "order vorticity"])
    assert (report.parent / "convergence.png").stat().st_size > 10_000


def test_decay_study_turns_energy_into_heat(tmp_path):
    import pandas as pd

    from liethermo.cf import load_dataset

    report = _study("zeitlin_decay", tmp_path)
    df = pd.read_csv(report.parent / "decay.csv").set_index("viscosity (s-1)")
    assert df.loc[0.0, "heat / H(0) at the end"] == 0.0 and df.loc[0.01, "heat / H(0) at the end"] > 0.3
    assert (df["smallest entropy change per output (J K-1)"] >= 0).all()
    assert (df["angular momentum drift (relative)"] < 1e-11).all()
    ds = load_dataset(report.parent / "zeitlin_decay.nc")
    nu = "fluid_kinematic_viscosity"
    assert ds["energy"].dims == (nu, "member", "t") and ds[nu].attrs["units"] == "s-1"
    # the heat is the energy lost but for the method's energy error, member by member
    H, q = ds["energy"].values, ds["heat"].values
    lost = H[..., :1] - H
    assert np.array_equal(df["max |H + q − H(0)| / H(0)"].values,
                          np.abs(ds["energy_error"].values).max(axis=(1, 2)))
    assert np.allclose(q - lost, ds["energy_error"].values * H[..., :1], rtol=0, atol=1e-14)
    assert "| FAILS |" not in report.read_text()
    for f in ("decay.png", "spectrum.png"):
        assert (report.parent / f).stat().st_size > 10_000


def test_structure_study_compares_at_equal_measured_cost(tmp_path, monkeypatch):
    import pandas as pd

    from liethermo.cf import load_dataset
    from liethermo.zeitlin.studies import zeitlin_structure

    timed, cpu = [], zeitlin_structure._cpu

    def spy(sc, m, h, n, every):  # a timed run stores one sample (the long runs store several)
        if n == every > 1:
            timed.append((m, n))
        return cpu(sc, m, h, n, every)

    monkeypatch.setattr(zeitlin_structure, "_cpu", spy)
    report = _study("zeitlin_structure", tmp_path)
    # the timings (one stored sample) take both sides over the splitting's 100 steps: a run's fixed cost weighs the same
    assert {m for m, _ in timed} == {"split", "rk4"} and {n for _, n in timed} == {100}
    df = pd.read_csv(report.parent / "drift.csv")
    split, rk4 = df[df["method"] == "split"].iloc[0], df[df["method"] == "rk4"].iloc[0]
    assert split["tr W² drift"] < 1e-13 and split["tr W⁴ drift"] < 1e-13  # the spectrum is kept
    assert rk4["tr W² drift"] > 100 * split["tr W² drift"]
    assert rk4["|H + q − H(0)|/H(0)"] < split["|H + q − H(0)|/H(0)"]  # RK4 wins the energy
    # RK4 runs at its calibrated step (rounded to whole steps per sample): its fixed cost per step over the step
    # equals the splitting's whole run's cost per simulated second, timed in one interleaved measurement
    full = load_dataset(report.parent / "zeitlin_structure.nc")
    ds = full.sel(N=12, kinematic_viscosity=0.0, pair="split")
    per = round(5.0 / float(ds["rk4_step"]) / 5)
    assert rk4["h (s)"] == 5.0 / (per * 5) and rk4["steps"] == 5 * per and per > 1
    c = ds["calibrated_cost"]
    assert float(ds["rk4_step"]) == pytest.approx(0.05 * float(c.sel(side="rk4") / c.sel(side="splitting")), rel=1e-12)
    w, text = ds["cost_per_simulated_second"], report.read_text()
    assert (w > 0).all() and f"largest ratio {float(w.max() / w.min()):.2f}" in text
    assert ("(equal_cost_check) | holds" in text) == (float(w.max() / w.min()) <= 1.15)
    assert full["casimir2_drift"].dims == ("N", "kinematic_viscosity", "pair", "side", "t")
    assert (report.parent / "drift.png").stat().st_size > 10_000


def test_resolution_study_shows_one_flow_converging_in_n(tmp_path):
    import pandas as pd

    from liethermo.cf import load_dataset

    report = _study("zeitlin_resolution", tmp_path)
    df = pd.read_csv(report.parent / "resolution.csv")
    nxt = df["Σ|ΔE_l| to the next N / H(0), t end"].values[:-1]
    assert list(df["N"]) == [8, 16, 32] and nxt[1] < 0.5 * nxt[0]
    ds = load_dataset(report.parent / "zeitlin_resolution.nc")
    assert ds["energy_spectrum"].dims == ("zeitlin_N", "member", "t", "l") and ds.sizes["l"] == 31
    assert np.isnan(ds["energy_spectrum"].sel(zeitlin_N=8, l=8)).all()  # N = 8 resolves l ≤ 7 only
    # the differences are those of the spectra in the file, over the degrees N = 8 resolves
    e = ds["energy_spectrum"].isel(t=-1).sel(l=slice(1, 7))
    d = (abs(e.sel(zeitlin_N=8) - e.sel(zeitlin_N=16)).sum("l") / ds["energy"].sel(zeitlin_N=32).isel(t=0)).max()
    assert float(d) == pytest.approx(nxt[0], rel=1e-12)
    assert 0 < float(ds["time_error"]) < 1e-3 * nxt.min()
    assert "| FAILS |" not in report.read_text()
    assert (report.parent / "resolution.png").stat().st_size > 10_000


def test_a_zeitlin_study_refuses_a_top_scene():
    from liethermo.studies.common import StudyError
    from liethermo.studies.runner import validate_study

    with pytest.raises(StudyError, match="runs on a scene of zeitlin"):
        validate_study({"study": {"kind": "zeitlin_decay", "base_scene": "paper"}})


def test_vorticity_map_is_the_field_of_the_harmonic_coefficients():
    """The map's ω = Σ ω_lm Y_lm: ∫ω² dA = (4π/N)‖W‖² (the T_lm are orthonormal),
    and solid-body rotation about z (the l = 1, m = 0 mode) is ∝ sin(latitude)."""
    from liethermo.zeitlin import plotting as zp

    sc = load_scene("zeitlin_ideal", {"zeitlin.N": 9, "initial.lmax": 6, "ensemble.members": 1})
    W = zr.initial_fields(sc)[0]
    lon, lat, om = zp.vorticity_on_grid(W, 1500, 401)
    integral = (om[:, :-1] ** 2 * np.cos(lat)[:, None]).sum() * (lat[1] - lat[0]) * (2 * np.pi / 400)
    assert abs(integral / (4 * np.pi / 9 * (np.abs(W) ** 2).sum()) - 1) < 1e-6
    b = zk.basis(9)
    C = np.zeros((1, b.modes), complex)
    C[0, 1] = 1.0
    _, lat, om = zp.vorticity_on_grid(zk.from_modes(C, b)[0], 31, 8)
    assert np.allclose(om, np.sqrt(3 / (4 * np.pi)) * np.sin(lat)[:, None], atol=1e-14)


def test_a_member_gets_the_same_bits_alone_or_in_a_batch():
    sc = load_scene("zeitlin_decay", {"zeitlin.N": 10, "initial.lmax": 6, "ensemble.members": 5,
                                      "integrator.steps": 20, "output.every": 10, "integrator.method": "split4"})
    W0 = zr.initial_fields(sc)
    whole = zr.integrate(sc, W0, progress=False, keep_vorticity=True).W
    alone = zr.integrate(sc, W0[3:4], progress=False, keep_vorticity=True).W
    assert np.array_equal(whole[3], alone[0])


def test_zeitlin_files_are_cf_clean(tmp_path):
    from cfcheck import assert_cf_clean

    out = tmp_path / "cf.nc"
    assert main(["run", "zeitlin_decay", "-o", str(out), "--no-progress", "--set", "zeitlin.N=6",
                 "--set", "initial.lmax=4", "--set", "integrator.steps=10", "--set", "output.every=5",
                 "--set", "output.vorticity=true",
                 "--set", "output.compare=[]", "--set", "output.figures=false"]) == 0
    assert_cf_clean(out)


def test_python_api_runs_a_zeitlin_scene(tmp_path):
    import liethermo

    over = {"zeitlin.N": 8, "initial.lmax": 5, "integrator.steps": 10, "output.every": 5}
    with pytest.raises(SceneError, match="compare=True"):
        liethermo.run("zeitlin_ideal", over)
    out = liethermo.run("zeitlin_ideal", over, compare=True)
    assert set(out) == {"split", "rk4"} and out["split"]["energy"].dims == ("member", "t")
    ds = liethermo.run("zeitlin_ideal", over, compare=False, output=tmp_path / "z.nc", figures=False)
    assert (tmp_path / "z.nc").exists() and "tr W²" in ds.attrs["summary"]
    from liethermo.zeitlin import vorticity_coefficients

    w = vorticity_coefficients(liethermo.open_dataset(tmp_path / "z.nc"))  # as docs/api.md shows
    assert w.dims == ("member", "t", "mode") and w.attrs["units"] == "s-1"
    L = liethermo.open_dataset(tmp_path / "z.nc")["angular_momentum"].isel(t=0).sel(axis="z").values
    w10 = w.isel(t=0, mode=int(np.flatnonzero((w["l"].values == 1) & (w["m"].values == 0))[0])).values.real
    assert np.allclose(L, np.sqrt(4 * np.pi / 3) * w10, rtol=1e-13)  # L_z = ∫ z ω dA


def test_a_vorticity_that_would_not_fit_in_memory_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    def no_basis(N, *a, **k):  # the basis of su(1024) takes about a minute: it must not be built
        raise AssertionError(f"the basis of su({N}) was built before the run was refused")

    monkeypatch.setattr("liethermo.zeitlin.estimate.build_basis", no_basis)
    out = tmp_path / "big.nc"
    args = ["run", "zeitlin_decay", "-o", str(out), "--set", "zeitlin.N=1024", "--set", "ensemble.members=4096",
            "--set", "output.vorticity=true"]
    assert main(args + ["--check"]) == 2
    assert "output.vorticity" in capsys.readouterr().err
    assert main(args) == 2 and not out.exists()


def test_the_predicted_start_saves_iterations_not_accuracy():
    """The fixed point started from the extrapolated last solutions converges to
    the same step (to the tolerance) in fewer iterations."""
    rng = np.random.default_rng(9)
    N, M, h = 12, 3, 0.01
    b = zk.basis(N)
    W0 = _random_W(N, M, 8, rng)
    runs = {}
    for use in (False, True):
        W, q, D = W0, np.zeros(M), None
        pred = zr.Predictor(1, M, N) if use else None
        its = []
        for _ in range(60):
            W, q, it, failed, D = zr.split_step(W, q, h, 1e-3, b, (1.0,), 1e-14, 100, D, pred, np.arange(M))
            assert not failed.any()
            its.append(it.mean())
        runs[use] = (W, np.mean(its[10:]))
    assert np.abs(runs[True][0] - runs[False][0]).max() < 1e-12 * np.abs(W0).max()
    assert runs[True][1] < runs[False][1] - 1.5


def test_the_compositions_heat_never_fell_where_measured():
    """docs/model.md's measured (not a law) monotone heat of split4 and split6, on a small grid
    (benchmarks/zeitlin_entropy.py runs the full one): no step lowers the heat up to ν h λ_max = 47.6,
    and at 99 split6's fixed point does not converge in its first step (status 1) while split4's does."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from zeitlin_entropy import measure

    for m in ("split4", "split6"):
        for N, nu, h in ((16, 1.0, 0.2), (16, 0.1, 0.05)):
            r = measure(m, N, nu, h, members=2, steps=60)
            assert r["failed"] == 0 and r["compared"] == 120 and r["decreasing"] == 0, (m, N, nu, h, r)
    with np.errstate(all="ignore"), warnings.catch_warnings():  # the failing member's last iterates overflow
        warnings.simplefilter("ignore", RuntimeWarning)
        hot = {m: measure(m, 32, 1.0, 0.1, members=2, steps=5) for m in ("split4", "split6")}
    assert hot["split6"]["status"] == [1] and hot["split6"]["first_failed_step"] == 1
    assert hot["split4"]["failed"] == 0 and hot["split4"]["decreasing"] == 0


def test_the_transposed_eigenvectors_are_made_only_for_the_products_that_use_them():
    """to_modes reads vecs alone: it leaves vecs_t (a second copy of the eigenvectors,
    2.9 GB at N = 1024) unmade; from_modes makes it, and both give their values."""
    from liethermo.zeitlin import kernels as zk

    b = zk.compute_basis(20)
    W = zk.from_modes(np.random.default_rng(3).standard_normal((2, b.modes)) + 0j, zk.compute_basis(20))
    C = zk.to_modes(W, b)
    assert "vecs_t" not in b.__dict__ and "block_views_t" not in b.__dict__
    assert np.allclose(zk.from_modes(C, b), W, rtol=0, atol=1e-12) and "vecs_t" in b.__dict__
