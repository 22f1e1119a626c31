"""A user's initial vorticity: spherical-harmonic coefficients from a file,
or a function on the sphere projected onto the basis.

The coefficients ω_lm (s⁻¹) of ω = Σ ω_lm Y_lm are those of
:func:`liethermo.zeitlin.vorticity_coefficients`: orthonormal complex
spherical harmonics with the Condon–Shortley phase (scipy's ``sph_harm_y``),
m ≥ 0 only (ω is real: ω_l,−m = (−1)^m conj(ω_lm)).  A file holds them as a
triangle C[l, m] (0 ≤ m ≤ l ≤ L, zero above the diagonal) of shape
(L + 1, L + 1) — one field for every member — or (members, L + 1, L + 1):

* ``.npy``: that complex array;
* ``.npz``: the complex array ``initial_vorticity`` (optionally ``units``, which must read ``s-1``);
* ``.nc``: the variables ``initial_vorticity_real`` and ``initial_vorticity_imag``
  with dims ``([member,] degree, order)`` and ``units = "s-1"`` — the variables a
  run from a file stores, so such an output is an input file too.

:func:`write_initial` writes such a file from coefficients or from a function
``f(lon, lat)`` (radians → s⁻¹) projected by :func:`project`.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from ..inputfile import SUFFIXES, foreign, npz_arrays, read_checked
from ..scene import SceneError

#: units a file may give its coefficients in (all mean s⁻¹)
UNITS = ("s-1", "1/s", "s^-1", "s**-1")
#: a field's l = 0 part (its mean) may be this much of its largest coefficient: round-off
MEAN_TOL = 1e-10

_CACHE: dict[tuple[str, str], np.ndarray] = {}


def _units_ok(u) -> bool:
    return str(u).strip() in UNITS


def _parse(key: str, path: str, data: bytes) -> np.ndarray:
    """The coefficient triangle(s) of a file's bytes, unchecked but for its layout."""
    suffix = Path(path).suffix
    try:
        if suffix == ".npy":
            C = np.load(io.BytesIO(data), allow_pickle=False)
        elif suffix == ".npz":
            C, = npz_arrays(key, path, data, "initial_vorticity", (), UNITS, "the coefficients must be in s-1")
        else:
            import netCDF4

            with netCDF4.Dataset("initial", memory=data) as nc:
                names = ("initial_vorticity_real", "initial_vorticity_imag")
                missing = [n for n in names if n not in nc.variables]
                if missing:
                    raise SceneError(key, f"{path}: a netCDF file must hold the variables {' and '.join(names)} "
                                     f"(missing {', '.join(missing)})", show_value=False)
                parts = []
                for n in names:
                    v = nc.variables[n]
                    v.set_auto_mask(False)
                    u = getattr(v, "units", None)
                    if u is None or not _units_ok(u):
                        raise SceneError(key, f"{path}: variable {n} has units {u!r}; the coefficients "
                                         "must be in s-1 (units = \"s-1\")", show_value=False)
                    if tuple(v.dimensions[-2:]) != ("degree", "order"):
                        raise SceneError(key, f"{path}: variable {n} must have dims ([member,] degree, order), "
                                         f"not {v.dimensions}", show_value=False)
                    parts.append(np.asarray(v[...], dtype=np.float64))
                C = parts[0] + 1j * parts[1]
    except SceneError:
        raise
    except Exception as exc:  # a damaged or foreign file
        raise foreign(key, path, exc) from None
    return C


def check_triangle(key: str, what: str, C, N: int) -> np.ndarray:
    """Coefficient triangle(s) checked (shape, numbers, finite, a real field
    of zero mean within the degrees of su(N)), as (fields, N, N) complex."""
    C = np.asarray(C)
    if C.dtype.kind not in "biufc" or C.dtype.kind == "b":
        raise SceneError(key, f"{what}: the coefficients must be numbers (got dtype {C.dtype})", show_value=False)
    if C.ndim not in (2, 3) or C.shape[-1] != C.shape[-2] or C.shape[-1] < 1:
        raise SceneError(key, f"{what}: the coefficients must be a triangle C[l, m] of shape (L+1, L+1) "
                         f"or (members, L+1, L+1), not {C.shape}", show_value=False)
    if not np.isfinite(C).all():
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(C))[0])
        where = (f"member {bad[0]}'s " if C.ndim == 3 else "") + f"C[{bad[-2]}, {bad[-1]}]"
        raise SceneError(key, f"{what}: the coefficients must be finite ({where} is {C[bad]})", show_value=False)
    C = np.asarray(C, dtype=np.complex128).reshape((-1,) + C.shape[-2:])
    L = C.shape[-1] - 1
    upper = np.triu(np.ones((L + 1, L + 1), dtype=bool), 1)  # m > l: no such harmonic
    if np.any(C[:, upper] != 0):
        raise SceneError(key, f"{what}: C[l, m] with m > l must be 0 (there is no such harmonic)",
                         show_value=False)
    scale = float(np.abs(C).max(initial=0.0))
    if scale == 0.0:
        raise SceneError(key, f"{what}: the field is zero everywhere", show_value=False)
    if np.abs(C[:, :, 0].imag).max() > 1e-12 * scale:
        raise SceneError(key, f"{what}: C[l, 0] must be real (ω is a real field: ω_l0 = conj(ω_l0))",
                         show_value=False)
    if np.abs(C[:, 0, 0]).max() > MEAN_TOL * scale:
        raise SceneError(key, f"{what}: the l = 0 coefficient (the field's mean, {C[0, 0, 0].real:.3g} s-1 "
                         "× √(4π)) must be 0: a vorticity on the sphere has zero mean", show_value=False)
    if L > N - 1:
        if np.any(C[:, N:, :] != 0):
            raise SceneError(key, f"{what}: the field has degrees up to l = {L}, but zeitlin.N = {N} holds "
                             f"l ≤ {N - 1}: raise zeitlin.N to at least {L + 1} or drop those degrees",
                             show_value=False)
        C = C[:, :N, :N]
    out = np.zeros((C.shape[0], N, N), dtype=np.complex128)
    out[:, :C.shape[1], :C.shape[2]] = C
    out[:, :, 0] = out[:, :, 0].real
    out[:, 0, 0] = 0.0
    return out


def read_field(key: str, path: str, N: int, sha256: str = "") -> tuple[np.ndarray, str]:
    """(coefficient triangles (fields, N, N), sha256 of the file) of
    ``initial.file``; with ``sha256`` given, the file must still have it."""
    data, digest = read_checked(key, path, sha256)
    cached = _CACHE.get((str(Path(path).resolve()), digest + f":{N}"))
    if cached is not None:
        return cached, digest
    C = check_triangle(key, str(path), _parse(key, str(path), data), N)
    _CACHE.clear()  # one file at a time: a large ensemble's fields are not kept twice
    _CACHE[(str(Path(path).resolve()), digest + f":{N}")] = C
    return C, digest


def triangle_to_modes(C: np.ndarray, N: int) -> np.ndarray:
    """Triangles (fields, N, N) → packed modes (fields, K) of :mod:`.kernels`."""
    from . import kernels as zk

    b = zk.basis(N)
    return C[:, b.ell.astype(int), b.order]


def modes_to_triangle(C: np.ndarray, N: int) -> np.ndarray:
    """Packed modes (..., K) → triangles (..., N, N)."""
    from . import kernels as zk

    b = zk.basis(N)
    out = np.zeros(C.shape[:-1] + (N, N), dtype=np.complex128)
    out[..., b.ell.astype(int), b.order] = C
    return out


def project(f, N: int, *, oversample: int = 2) -> np.ndarray:
    """The coefficient triangle C[l, m] (N, N), s⁻¹, of the vorticity
    ``f(lon, lat)`` (longitude in [−π, π), latitude in [−π/2, π/2], radians;
    ω in s⁻¹; called once with two broadcastable grids), projected onto the
    degrees l ≤ N − 1: Gauss–Legendre quadrature in latitude and the FFT in
    longitude, on ``oversample`` × (N, 2N) points.  Exact to round-off for a
    field of degrees below N; its mean (l = 0) is set to 0 only if it is at
    round-off (else :func:`check_triangle` refuses it)."""
    from scipy.special import sph_harm_y

    if not (isinstance(N, (int, np.integer)) and N >= 2):
        raise ValueError(f"N must be an integer of at least 2, not {N!r}")
    N = int(N)
    n_lat = oversample * N
    n_lon = 2 * oversample * N
    x, w = np.polynomial.legendre.leggauss(n_lat)  # x = cos θ = sin(lat)
    lat = np.arcsin(x)
    lon = -np.pi + 2 * np.pi * np.arange(n_lon) / n_lon
    values = np.asarray(f(lon[None, :], lat[:, None]), dtype=np.float64)
    values = np.broadcast_to(values, (n_lat, n_lon))
    if not np.isfinite(values).all():
        raise SceneError("initial.file", "the function's values must be finite on the quadrature grid",
                         show_value=False)
    # F_m(θ_i) = ∫ f e^{−imφ} dφ; the grid starts at φ = −π: e^{−im(−π)} = (−1)^m
    F = np.fft.rfft(values, axis=1)[:, :N] * (2 * np.pi / n_lon)
    F *= (-1.0) ** np.arange(N)[None, :]
    theta = np.arccos(x)
    C = np.zeros((N, N), dtype=np.complex128)
    ls = np.arange(N)
    for m in range(N):
        Y = sph_harm_y(ls[m:, None], m, theta[None, :], 0.0).real  # (l, i): Y_lm(θ, 0), real
        C[m:, m] = Y @ (w * F[:, m])
    C[:, 0] = C[:, 0].real
    if abs(C[0, 0]) <= MEAN_TOL * np.abs(C).max(initial=0.0):
        C[0, 0] = 0.0
    return C


def write_initial(path, field, N: int | None = None) -> Path:
    """Write an initial vorticity for ``initial.kind = "file"``: ``field`` is
    coefficient triangle(s) C[l, m] (s⁻¹; (L+1, L+1) or (members, L+1, L+1))
    or a function ``f(lon, lat)`` projected with :func:`project` onto the
    degrees l ≤ N − 1 (``N`` required then).  The format follows the suffix
    (``.nc``, ``.npz``, ``.npy``); the file is checked as a run checks it.
    Returns the path."""
    path = Path(path)
    if path.suffix not in SUFFIXES:
        raise ValueError(f"{path}: the file must end in {', '.join(SUFFIXES)}")
    if callable(field):
        if N is None:
            raise ValueError("a function is projected onto the degrees l ≤ N − 1: pass N")
        arr = check_triangle("initial.file", "the projected function", project(field, N), N)[0]
    else:
        given = np.asarray(field)
        arr = check_triangle("initial.file", "the coefficients", given, given.shape[-1] if given.ndim else 1)
        if given.ndim == 2:
            arr = arr[0]
    one = arr.ndim == 2
    if path.suffix == ".npy":
        np.save(path, arr)
    elif path.suffix == ".npz":
        with open(path, "wb") as fh:
            np.savez(fh, initial_vorticity=arr, units=np.array("s-1"))
    else:
        import xarray as xr

        dims = ("degree", "order") if one else ("member", "degree", "order")
        attrs = {"units": "s-1", "comment": "C[l, m]: coefficient ω_lm of ω = Σ ω_lm Y_lm, m ≥ 0 (scipy's "
                 "sph_harm_y, Condon–Shortley phase); zero for m > l"}
        L1 = arr.shape[-1]
        xr.Dataset({"initial_vorticity_real": (dims, arr.real, {**attrs, "long_name": "initial vorticity "
                                                                "coefficient, real part"}),
                    "initial_vorticity_imag": (dims, arr.imag, {**attrs, "long_name": "initial vorticity "
                                                                "coefficient, imag. part"})},
                   coords={"degree": ("degree", np.arange(L1), {"long_name": "degree l"}),
                           "order": ("order", np.arange(L1), {"long_name": "order m"})}).to_netcdf(path)
    return path
