"""What a run's summary and ``--check`` print: each figure says what it
measures, and it measures that."""

from __future__ import annotations

import time

import liethermo
from liethermo.top import simulate


def test_the_summarys_wall_time_leaves_out_compiling(monkeypatch):
    """A first run compiles its kernels inside the first chunk; the summary's
    wall time is the simulating and writing, the compiling is reported apart
    (here a compiling made to take 2 s longer)."""
    liethermo.run("spherical_top", {"integrator.steps": 10}, compare=False)  # whatever else a first run loads
    real = simulate._ensure_compiled

    def slow_compile(fn, args):
        time.sleep(1.0)
        return real(fn, args) + 1.0

    monkeypatch.setattr(simulate, "_ensure_compiled", slow_compile)
    ds = liethermo.run("spherical_top", {"integrator.steps": 10}, compare=False)
    summary = ds.attrs["summary"]
    wall = float(summary.split("wall time ")[1].split(" s")[0])
    compiled = float(summary.split("compiled or loaded in ")[1].split(" s")[0])
    assert compiled >= 2.0  # the kernel and the VI's start
    assert wall < 1.5, summary
    assert "not compiling" in summary


def test_the_gpu_extra_installs_cupy_for_numba_cudas_cuda_and_the_refusal_says_so(monkeypatch):
    """The fluid on a GPU needs CuPy: the ``gpu`` extra brings the wheel of
    numba-cuda's CUDA major version, and a refusal names that route."""
    import re
    import sys
    from pathlib import Path

    import pytest

    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib
    from liethermo.zeitlin import xpstep

    root = Path(__file__).resolve().parents[1]
    gpu = tomllib.loads((root / "pyproject.toml").read_text())["project"]["optional-dependencies"]["gpu"]
    cuda = {m.group(1) for d in gpu if (m := re.match(r"numba-cuda\[cu(\d+)\]", d))}
    cupy = [d for d in gpu if d.startswith("cupy-cuda")]
    assert len(cuda) == 1 and len(cupy) == 1
    assert cupy[0].startswith(f"cupy-cuda{cuda.pop()}x[ctk]")
    assert cupy[0].split(">=")[0] == xpstep.CUPY_WHEEL
    monkeypatch.setitem(sys.modules, "cupy", None)  # as where CuPy is not installed
    with pytest.raises(RuntimeError) as err:
        xpstep.namespace("gpu")
    assert "pip install 'liethermo[gpu]'" in str(err.value) and xpstep.CUPY_WHEEL in str(err.value)
    assert xpstep.CUPY_WHEEL in (root / "docs" / "api.md").read_text(encoding="utf-8")


def test_check_prints_every_estimate_then_lists_every_problem(tmp_path, capsys, monkeypatch):
    """Too little disk and too little memory: --check still prints the
    estimates, then one line per problem, and exits 2; it writes nothing."""
    import collections

    from liethermo import preflight
    from liethermo.cli import main

    usage = collections.namedtuple("usage", "total used free")
    monkeypatch.setattr(preflight.shutil, "disk_usage", lambda p: usage(10**6, 10**6 - 1000, 1000))
    monkeypatch.setattr(preflight, "available_memory", lambda: 10**6)
    rc = main(["run", "paper", "-o", str(tmp_path / "p.nc"), "--check", "--set", "ensemble.members=2000",
               "--set", "integrator.steps=20", "--set", "output.compare=[]"])
    cap = capsys.readouterr()
    assert rc == 2
    assert cap.out.startswith("scene 'paper' is valid: 1 output file(s), about ")
    assert "vi: about" in cap.out and "of kernel time on this machine" in cap.out
    errors = [line for line in cap.err.splitlines() if line.startswith("liethermo: error: ")]
    assert len(errors) == 2, cap.err
    assert "would need about" in errors[0] and "free" in errors[0]
    assert errors[1].startswith("liethermo: error: a run would need about ") and "of memory" in errors[1]
    assert list(tmp_path.iterdir()) == []
    # the run itself is refused at the first problem, before any work
    assert main(["run", "paper", "-o", str(tmp_path / "p.nc"), "--set", "ensemble.members=2000",
                 "--set", "integrator.steps=20", "--set", "output.compare=[]"]) == 2
    assert capsys.readouterr().err.count("liethermo: error: ") == 1 and list(tmp_path.iterdir()) == []


def test_check_gives_one_memory_figure_in_its_header_and_its_method_line(tmp_path, capsys):
    """A fluid's --check: the header's "at most about" memory is the figure
    of the method's own line (one way of counting, not two)."""
    import re

    from liethermo.cli import main

    assert main(["run", "zeitlin_decay", "-o", str(tmp_path / "z.nc"), "--check", "--set", "zeitlin.N=48",
                 "--set", "output.compare=[]", "--set", "integrator.steps=20", "--set", "output.every=10"]) == 0
    out = capsys.readouterr().out
    header = re.search(r"at most about (\S+ \w+) of memory \(member chunks", out).group(1)
    in_all = re.search(r"in all: about .* at most about (\S+ \w+) of memory", out).group(1)
    assert header == in_all, out


def test_an_unknown_flag_or_a_missing_argument_is_one_line(capsys):
    import pytest

    from liethermo.cli import main

    for argv, says in ((["run", "paper", "--frob"], "unrecognized arguments: --frob"),
                       (["run"], "the following arguments are required: SCENE"),
                       (["study", "convergence", "--nope"], "unrecognized arguments: --nope")):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert len(err.splitlines()) == 1 and says in err and "usage" not in err, err


def test_a_study_name_resolves_to_the_shipped_study_file(tmp_path, monkeypatch):
    from pathlib import Path

    import pytest

    from liethermo.studies.common import StudyError
    from liethermo.studies.runner import load_study

    shipped = Path(__file__).resolve().parents[1] / "studies" / "convergence.toml"
    monkeypatch.chdir(tmp_path)  # no studies/ here
    for name in ("convergence", "convergence.toml"):
        assert Path(load_study(name)["_source"]).resolve() == shipped
    (tmp_path / "studies").mkdir()  # one of the user's own, of the same name, comes first
    (tmp_path / "studies" / "convergence.toml").write_text(shipped.read_text())
    assert Path(load_study("convergence")["_source"]).resolve() == tmp_path / "studies" / "convergence.toml"
    with pytest.raises(StudyError, match=r"no such study file: convergnce \(nor a study's name: .*convergence"):
        load_study("convergnce")


def test_a_misspelt_base_scene_is_reported_as_typed(capsys):
    from liethermo.cli import main

    assert main(["study", "studies/long_drift.toml", "--scene", "zeitlin_dcay"]) == 2
    err = capsys.readouterr().err
    assert "scene file 'zeitlin_dcay': not found, and not a built-in scene" in err and "studies/" not in err


def test_the_readme_names_the_reduced_studys_folder():
    from pathlib import Path

    from liethermo.studies.runner import default_outdir

    readme = " ".join((Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8").split())
    study = {"study": {"kind": "convergence", "name": "convergence"}}
    reduced = default_outdir(study, True).as_posix().replace("convergence", "<study>")
    assert f"`{reduced}/` with `--reduced`" in readme


def test_drift_findings_call_no_variational_method_the_baseline():
    """The README's baselines are the Runge–Kutta methods; the energy-drift and
    long-drift findings compare with the study's first method, and say so."""
    from types import SimpleNamespace

    import numpy as np
    import xarray as xr

    from liethermo.studies import energy_drift, long_drift

    methods, n = ["vi", "vi4", "rk2", "rk4"], 12
    rng = np.random.default_rng(0)
    scale = np.array([1e-3, 1e-4, 1e-1, 1e-2])[:, None]
    err = scale * (1.0 + 0.1 * rng.random((4, n)))  # vi4 < vi < rk4 < rk2 on every member
    ctx = SimpleNamespace(methods=methods, sweep_keys=["integrator.h"])
    ds = xr.Dataset({"max_relative_energy_error": (("scheme", energy_drift.H, "member"), err[:, None, :]),
                     "median_max_relative_energy_error": (("scheme", energy_drift.H), np.median(err, axis=1)[:, None])},
                    coords={"scheme": methods, energy_drift.H: [0.1], "member": np.arange(n)})
    lines = energy_drift.findings(ds, ctx)
    assert len(lines) == 1 and "vi, the first of the study's methods," in lines[0], lines
    ctx = SimpleNamespace(methods=methods, sweep_keys=[], opt={"t_end": 100.0})
    dims = ("scheme", "dissipation", "member")
    ds = xr.Dataset({"status": (dims, np.zeros((4, 1, n), np.int8)),
                     "drift_measurable": (dims, np.zeros((4, 1, n), np.int8)),
                     "drift_rate": (dims, err[:, None, :] * 1e-3),
                     "max_relative_energy_error": (dims, err[:, None, :]),
                     "failed_members": (("scheme", "dissipation"), np.zeros((4, 1), int))},
                    coords={"scheme": methods, "dissipation": [1.0], "member": np.arange(n)})
    lines += long_drift.findings(ds, ctx)
    assert len(lines) == 2
    for line in lines:
        assert "baseline" not in line, line


def test_the_readme_says_which_fluid_scene_is_viscous():
    from pathlib import Path

    from liethermo import load_scene

    readme = " ".join((Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8").split())
    for name in ("zeitlin_decay", "zeitlin_ideal"):
        viscous = load_scene(name)["fluid"]["kinematic_viscosity"] > 0
        assert f"`liethermo run {name}` ({'viscous' if viscous else 'inviscid'}" in readme, name


def test_a_fluid_runs_summary_counts_its_members_by_status_and_names_its_time(tmp_path):
    from liethermo.zeitlin import run as zr

    small = {"zeitlin.N": 12, "ensemble.members": 3, "integrator.steps": 4, "output.every": 2,
             "output.compare": [], "output.figures": False, "output.member_chunk": 2}
    for ds, by_runner in ((liethermo.run("zeitlin_decay", small, output=tmp_path / "z.nc"), True),  # two chunks
                          (zr.simulate(liethermo.load_scene("zeitlin_decay", small)), False)):  # the array-level one
        lines = ds.attrs["summary"].splitlines()
        assert "  status   ok: 3, fixed_point_not_converged: 0, non_finite: 0" in lines, lines
        assert any(line.startswith("  stepping ") and "compiling" in line and "not the basis" in line
                   for line in lines), lines
        assert "kernels" not in lines[0]
        # a run's wall time, which --check estimates as "the run in all"
        assert any(line.startswith("  wall time ") and "(the run:" in line for line in lines) == by_runner, lines
    rk4 = zr.simulate(liethermo.load_scene("zeitlin_decay", {**small, "integrator.method": "rk4"}))
    assert "  status   ok: 3, non_finite: 0" in rk4.attrs["summary"].splitlines()


def test_a_chunks_summary_figures_from_member_slices_equal_those_of_the_whole_chunk(monkeypatch):
    """The summary's figures of a chunk computed over member slices on several threads
    (``label_chunk``) are those of the whole chunk: counts, maxima and finding spans,
    with failed members among them (rk2 at a large step), for the paper top (the
    Lagrange top's exact Ω₃ and the heating) and a spherical top (its exact solution).
    The negative control: a slice alone gives other figures."""
    import numba
    import numpy as np

    from liethermo import load_scene
    from liethermo.top import model as tm
    from liethermo.top.dataset import chunk_labels
    from liethermo.top.initial import initial_conditions
    from liethermo.top.resolve import resolve

    import pytest

    from liethermo.threads import ThreadCounts, pools

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("needs two kernel threads")
    monkeypatch.setattr(tm, "STATS_SLICE_MEMBERS", 100)
    merged = []
    real_merge = tm.ChunkStats.merge
    monkeypatch.setattr(tm.ChunkStats, "merge",
                        lambda self, other: merged.append(other.members) or real_merge(self, other))
    with pools(ThreadCounts(blas=1, kernel=2)):  # as a run on two cores sets them
        _sliced_equals_whole(tm, load_scene, chunk_labels, initial_conditions, resolve, np)
    assert merged == [300, 300, 300]  # every chunk was summarised in two slices of 300 members


def _sliced_equals_whole(tm, load_scene, chunk_labels, initial_conditions, resolve, np):
    cases = [("paper", {"integrator.method": "rk2", "integrator.h": 0.12}),
             ("paper", {"integrator.method": "split"}),
             ("spherical_top", {"integrator.method": "vi"})]
    for name, over in cases:
        sc = load_scene(name, {"ensemble.members": 600, "integrator.steps": 40, "output.every": 20, **over})
        om0, R0 = initial_conditions(sc, 0, 600)
        traj = resolve(sc).simulate(om0, R0)
        if over.get("integrator.h") == 0.12:  # some members blow up, some do not
            assert 0 < np.count_nonzero(traj.status) < 600
        whole = tm._labelled_stats(traj, chunk_labels(traj, omega0=om0, R0=R0)).to_dict()
        ds, sliced = tm.label_chunk(sc, traj, om0, R0)
        assert sliced.to_dict() == whole, name
        assert sliced.findings and ds.sizes["member"] == 600
        part = traj.take(slice(0, 300))
        alone = tm._labelled_stats(part, chunk_labels(part, omega0=om0[:300], R0=R0[:300])).to_dict()
        assert alone != whole


def _adversarial(rng, shape):
    """Values over the whole double range, with ±0, NaN, ±inf, the largest and the subnormal."""
    import numpy as np

    x = rng.standard_normal(shape) * np.exp(rng.uniform(-340, 340, shape))
    flat = x.reshape(-1)
    idx = rng.integers(0, flat.size, flat.size // 8)
    flat[idx] = rng.choice([0.0, -0.0, np.nan, np.inf, -np.inf, 1.7e308, -1.7e308, 5e-324, -5e-324], idx.size)
    return x


def test_the_labellings_dot_products_are_numpys_bits_in_one_compiled_pass(monkeypatch):
    """dot3 (the energies K = ½ΣIΩΩ, V = Σ g Γ and the norms |Γ|) gives np.sum(a*b[*c], axis=-1)
    bit for bit, on every shape the labelling passes (member parameters broadcast over the stored
    times, one vector per member), and runs the compiled pass for them; summing in another order
    gives other bits on the same values (the comparison can fail)."""
    import numpy as np

    from liethermo.top.kernels import reductions
    from liethermo.top.kernels.terms import dot3, norm3

    calls = []
    real = reductions.dot3_rows

    class Spy:
        overloads = real.overloads  # compiled: dot3 takes this path

        def __call__(self, *args):
            calls.append(args[0].shape)
            return real(*args)

    monkeypatch.setattr(reductions, "dot3_rows", Spy())
    rng = np.random.default_rng(3)
    n = 4000
    cases = [((n, 1, 3), (n, 5, 3), (n, 5, 3)), ((n, 3), (n, 3), (n, 3)), ((n, 5, 3), (n, 5, 3), None),
             ((3,), (n, 3), None), ((1, 3), (n, 2, 3), None), ((n, 2, 3), (n, 2, 3), (n, 2, 3))]
    for sa, sb, sc in cases:
        a, b = _adversarial(rng, sa), _adversarial(rng, sb)
        c = None if sc is None else _adversarial(rng, sc)
        with np.errstate(all="ignore"):
            want = np.sum(a * b if c is None else a * b * c, axis=-1)
            got = dot3(a, b, c)
        assert got.shape == want.shape
        assert np.array_equal(got.view(np.int64), want.view(np.int64)), (sa, sb, sc)
    x = _adversarial(rng, (n, 2, 3))
    with np.errstate(all="ignore"):
        assert np.array_equal(norm3(x).view(np.int64), np.linalg.norm(x, axis=-1).view(np.int64))
        p = x * x
        other = (p[..., 1] + p[..., 2]) + p[..., 0]
        assert not np.array_equal(other.view(np.int64), np.sum(p, axis=-1).view(np.int64))
    assert len(calls) == len(cases) + 1  # every case above ran compiled


def test_the_summarys_energy_figures_in_one_compiled_pass_are_those_of_numpys_arrays(monkeypatch):
    """The energy figures (max |E_k − E_0|, max relative, at t = 0, members beyond the divergence
    bound) and the |Γ| defect from the compiled passes equal those numpy gives from the
    labelled arrays, on adversarial values (NaN, ±inf, ±0, a zero energy scale) and on whole
    chunks of several physics (the coupled top's entropy-dependent inertia, the splitting's
    heat, the flat spin's double bracket).  Summing the error in another order gives other
    figures on the same values (the comparison can fail)."""
    import numpy as np

    from liethermo import load_scene
    from liethermo.top import model as tm
    from liethermo.top.dataset import chunk_labels
    from liethermo.top.kernels.reductions import energy_error_figures, unit_norm_defect
    from liethermo.top.resolve import resolve
    from liethermo.top.initial import initial_conditions

    def numpy_figures(K, V, dU, K0, V0, scale, order=0):
        e = ((K - K0[:, None]) + (V - V0[:, None])) + dU if order == 0 else (K - K0[:, None]) + (
            (V - V0[:, None]) + dU)
        ee = np.abs(e)
        rel = ee / np.abs(scale)[:, None]
        worst = np.fmax.reduce(rel, axis=1, initial=0.0)
        return [tm._nanmax(ee), tm._nanmax(rel), tm._nanmax(rel[:, :1]),
                float(np.count_nonzero(worst > tm.DIVERGED_REL_ENERGY))]

    def same(got, want):
        return all((np.isnan(w) and (np.isnan(g) or g == -np.inf)) or g == w for g, w in zip(got, want))

    rng = np.random.default_rng(11)
    n, T = 3000, 3
    parts = [_adversarial(rng, (n, T)) for _ in range(3)] + [_adversarial(rng, (n,)) for _ in range(3)]
    parts[-1][:50] = 0.0  # no energy to lose: 0/0
    with np.errstate(all="ignore"):
        out = np.empty(4)
        energy_error_figures(*parts, float(tm.DIVERGED_REL_ENERGY), out)
        assert same(out, numpy_figures(*parts)), (out, numpy_figures(*parts))
        mild = [rng.standard_normal((n, T)) for _ in range(3)] + [rng.standard_normal(n) for _ in range(3)]
        energy_error_figures(*mild, float(tm.DIVERGED_REL_ENERGY), out)
        assert same(out, numpy_figures(*mild))
        tie = [np.array([[1.0]]), np.array([[2.0 ** -53]]), np.array([[2.0 ** -53]]), np.zeros(1), np.zeros(1),
               np.ones(1)]  # (1 + u) + u rounds to 1, 1 + (u + u) does not
        energy_error_figures(*tie, float(tm.DIVERGED_REL_ENERGY), out)
        assert same(out, numpy_figures(*tie)) and not same(out, numpy_figures(*tie, order=1))
        G = _adversarial(rng, (n, T, 3))
        g = np.empty(1)
        unit_norm_defect(G, g)
        want = tm._nanmax(np.abs(np.linalg.norm(G, axis=-1) - 1.0))
        assert g[0] == want or (np.isnan(want) and g[0] == -np.inf)
        unit_norm_defect(G[:, ::2], g)  # a strided view
        assert g[0] == tm._nanmax(np.abs(np.linalg.norm(G[:, ::2], axis=-1) - 1.0))

    passes = []
    real = tm._energy_figures_compiled
    monkeypatch.setattr(tm, "_energy_figures_compiled", lambda *a: passes.append(1) or real(*a))
    for name, over in [("paper", {"integrator.method": "split"}), ("coupled_egg", {}), ("flat_spin", {}),
                       ("paper", {"integrator.method": "vi"})]:
        sc = load_scene(name, {"ensemble.members": 400, "integrator.steps": 30, "output.every": 10, **over})
        om0, R0 = initial_conditions(sc, 0, 400)
        traj = resolve(sc).simulate(om0, R0)
        compiled = tm._labelled_stats(traj, chunk_labels(traj, omega0=om0, R0=R0)).to_dict()
        with monkeypatch.context() as m:
            m.setattr(tm, "_compiled_figures", lambda ds: False)
            plain = tm._labelled_stats(traj, chunk_labels(traj, omega0=om0, R0=R0)).to_dict()
        assert compiled == plain, name
    assert len(passes) == 4  # every chunk above took the compiled pass


def test_the_summarys_maxima_and_spans_take_one_pass_where_the_values_allow_and_agree_with_the_masked_ones():
    """_nanmax and _span (the largest finite value; [min, max] of the finite ones) and the
    findings' maximum over the stored times give what numpy's masked reductions give, bit for bit
    (the sign of a zero too), on values with NaN, ±inf, ±0, none finite, and none at all."""
    import numpy as np

    from liethermo.top.findings import _max_over_t, _span
    from liethermo.top.model import _nanmax

    def masked_max(a):
        m = float(np.max(a, where=np.isfinite(a), initial=-np.inf))
        return m if m != -np.inf else float("nan")

    def masked_span(a):
        f = np.isfinite(a)
        lo = float(np.min(a, where=f, initial=np.inf))
        return [lo, float(np.max(a, where=f, initial=-np.inf))] if lo != np.inf else None

    def same(x, y):
        return np.array_equal(np.asarray(x, dtype=float).view(np.int64), np.asarray(y, dtype=float).view(np.int64))

    rng = np.random.default_rng(5)
    arrays = [_adversarial(rng, (500, 3)), rng.standard_normal((500, 2)), np.abs(rng.standard_normal(400)),
              np.array([-0.0, 0.0]), np.array([0.0, -0.0]), np.array([-0.0]), np.array([np.nan, np.inf]),
              np.array([-np.inf, 1.0]), np.array([np.inf, 2.0]), np.array([np.nan, 3.0, -1.0]), np.zeros(0),
              np.array([-5.0, -0.0])]
    with np.errstate(all="ignore"):
        for a in arrays:
            got, want = _nanmax(a), masked_max(a)
            assert same(got, want) or (np.isnan(got) and np.isnan(want)), (a, got, want)
            s, w = _span(a), masked_span(a)
            assert (s is None and w is None) or same(s, w), (a, s, w)
        for x in (np.abs(_adversarial(rng, (300, 2))), np.abs(rng.standard_normal((300, 5))),
                  np.abs(_adversarial(rng, (300, 1))), np.abs(_adversarial(rng, (300, 12)))):
            got, want = _max_over_t(x), np.max(x, axis=1)
            assert np.array_equal(got, want, equal_nan=True)


def test_the_omega3_finding_in_one_compiled_pass_is_numpys_and_its_decay_is_worked_out_once_per_row():
    """The Lagrange top's Ω₃ error span from the compiled pass equals numpy's
    ``_span(max_t |W − W₀ e^{−C₃t/I₃}| / |Ω₀|)`` on adversarial values (NaN, ±inf, ±0, a zero
    norm), strided and broadcast views; the decay computed on one shared row and broadcast has the
    bits of the decay computed per member; the parameter facts of members that share one row are
    those worked out per member, and a row of other values gets its own."""
    import numpy as np

    from liethermo import load_scene
    from liethermo.top import findings as tf
    from liethermo.top.kernels.reductions import decay_error_span
    from liethermo.top.physics import physics_of_scene

    rng = np.random.default_rng(5)
    n, T = 4000, 3

    def numpy_span(W, W0, E, scale):
        return tf._span(tf._max_over_t(np.abs(W - W0[:, None] * E)) / scale)

    def compiled_span(W, W0, E, scale):
        out = np.empty(3)
        decay_error_span(W, W0, E, scale, out)
        return [float(out[0]), float(out[1])] if out[2] > 0 else None

    with np.errstate(all="ignore"):
        W, E = _adversarial(rng, (n, T)), _adversarial(rng, (n, T))
        W0, scale = _adversarial(rng, (n,)), np.abs(_adversarial(rng, (n,)))
        scale[:40] = 0.0
        assert compiled_span(W, W0, E, scale) == numpy_span(W, W0, E, scale)
        big = _adversarial(rng, (n, 2 * T, 3))  # strided views, as the state's Ω₃ column
        row = np.broadcast_to(rng.uniform(0.1, 1.0, (1, 2 * T)), (n, 2 * T))
        args = (big[:, :, 2], big[::1, 0, 1], row, np.abs(big[:, 1, 0]))
        assert compiled_span(*args) == numpy_span(*args)
        nan = np.full((3, T), np.nan)
        assert compiled_span(nan, np.ones(3), nan, np.ones(3)) is None is numpy_span(nan, np.ones(3), nan, np.ones(3))
        # the largest difference can sit at any time; with t = 0 alone the span is another one (can fail)
        W, E, W0, scale = rng.standard_normal((n, T)), rng.uniform(0, 1, (n, T)), rng.standard_normal(n), np.ones(n)
        assert compiled_span(W, W0, E, scale) == numpy_span(W, W0, E, scale) != numpy_span(W[:, :1], W0, E[:, :1],
                                                                                         scale)

    t = np.array([0.0, 0.01, 7.3, 1000.0, 12345.678])
    for c, inertia in zip(rng.uniform(1e-6, 10.0, 200), rng.uniform(1e-3, 100.0, 200)):
        shared = tf._decay(np.broadcast_to(c, (50,)), np.broadcast_to(inertia, (50,)), t)
        each = np.exp(-(np.full(50, c) / np.full(50, inertia))[:, None] * t[None, :])
        assert shared.shape == each.shape and shared.strides[0] == 0
        assert np.array_equal(shared.view(np.int64), each.view(np.int64))

    sc = load_scene("paper", {"ensemble.members": 64})
    phys = physics_of_scene(sc, 64)
    assert phys.uniform
    tf._ROW_FACTS.clear()
    for _ in range(2):  # worked out, then found
        got, want = tf._parameter_facts(phys), tf._facts(phys.take(np.arange(64)))
        assert got.keys() == want.keys() and all(np.array_equal(got[k], want[k]) for k in want)
    assert len(tf._ROW_FACTS) == 1
    other = load_scene("spherical_top", {"ensemble.members": 64})
    got = tf._parameter_facts(physics_of_scene(other, 64))
    assert len(tf._ROW_FACTS) == 2 and bool(got["spherical"].all()) and not bool(tf._parameter_facts(phys)["spherical"].any())
