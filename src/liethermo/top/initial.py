"""Initial conditions of an ensemble, reproducible from ``ensemble.seed``.

* ``ensemble.members = 1``: the scene's own data, exactly (Ω₀ = initial.omega,
  R₀ = initial.R, Γ₀ = R₀ᵀe₃, S = S₀).
* ``initial.file``: Ω₀ (rad s⁻¹) and, if the file has them, the attitudes
  R₀ of every member, read from the file (:func:`read_file`);
* more members: member i's initial condition depends only on (seed, i) — not
  on how the ensemble is chunked or distributed — because members are drawn
  in fixed blocks of :data:`BLOCK` from ``SeedSequence([seed, block])``:
  attitude R uniform on SO(3) (Haar measure: a normalised 4-D Gaussian
  quaternion), spin direction uniform on the sphere, spin magnitude uniform
  in ``spin_range × |initial.omega|``.
"""

from __future__ import annotations

import numpy as np

from .kernels.draws import shaped

BLOCK = 1024


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of unit quaternions (N, 4) in (w, x, y, z) order."""
    w, x, y, z = q.T
    R = np.empty((q.shape[0], 3, 3))
    R[:, 0, 0] = 1 - 2 * (y * y + z * z)
    R[:, 0, 1] = 2 * (x * y - w * z)
    R[:, 0, 2] = 2 * (x * z + w * y)
    R[:, 1, 0] = 2 * (x * y + w * z)
    R[:, 1, 1] = 1 - 2 * (x * x + z * z)
    R[:, 1, 2] = 2 * (y * z - w * x)
    R[:, 2, 0] = 2 * (x * z - w * y)
    R[:, 2, 1] = 2 * (y * z + w * x)
    R[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def _draw_raw(seed: int, block: int, q, d, u, spin_range) -> None:
    """Block ``block``'s draws, in their fixed order, into q (BLOCK, 4), d (BLOCK, 3), u (BLOCK,)."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, block]))
    rng.standard_normal(out=q)
    rng.standard_normal(out=d)
    u[:] = rng.uniform(spin_range[0], spin_range[1], BLOCK)


#: units a file may give Ω₀ in (all mean rad s⁻¹)
OMEGA_UNITS = ("rad s-1", "rad/s", "s-1", "1/s", "rad s^-1")
ATTITUDE_UNITS = ("1", "")

_FILE_CACHE: dict[str, tuple] = {}


def read_file(path: str, sha256: str = "", key: str = "initial.file") -> tuple[np.ndarray, np.ndarray | None, str]:
    """(Ω₀ (members, 3) in rad s⁻¹, attitudes R₀ (members, 3, 3) or None, sha256)
    of a file of initial data, checked (shape, numbers, finite, units, rotations):

    * ``.npy``: the array Ω₀, shape (members, 3);
    * ``.npz``: ``initial_omega`` (members, 3), optionally ``initial_attitude``
      (members, 3, 3) and ``units`` (of Ω₀: ``rad s-1``);
    * ``.nc``: the variables ``initial_omega`` (member, axis) with ``units =
      "rad s-1"`` and optionally ``initial_attitude`` (member, row, col) — those
      every run of the top stores, so its output is such a file too.

    With ``sha256`` given, the file must still have it."""
    import io

    from ..inputfile import foreign, npz_arrays, read_checked, units_ok
    from ..scene import SceneError

    data, digest = read_checked(key, path, sha256)
    if digest in _FILE_CACHE:
        return _FILE_CACHE[digest] + (digest,)
    suffix = path[path.rfind("."):]
    R = None
    try:
        if suffix == ".npy":
            om = np.load(io.BytesIO(data), allow_pickle=False)
        elif suffix == ".npz":
            om, R = npz_arrays(key, path, data, "initial_omega", ("initial_attitude",), OMEGA_UNITS,
                               "Ω₀ must be in rad s-1")
        else:
            import netCDF4

            with netCDF4.Dataset("initial", memory=data) as nc:
                if "initial_omega" not in nc.variables:
                    raise SceneError(key, f"{path}: a netCDF file must hold the variable initial_omega "
                                     "(member, axis)", show_value=False)
                for name, allowed, what in (("initial_omega", OMEGA_UNITS, "rad s-1"),
                                            ("initial_attitude", ATTITUDE_UNITS, "1")):
                    if name in nc.variables:
                        u = getattr(nc.variables[name], "units", None)
                        if u is None or not units_ok(u, allowed):
                            raise SceneError(key, f"{path}: variable {name} has units {u!r}; give it in {what} "
                                             f"(units = \"{what}\")", show_value=False)
                        nc.variables[name].set_auto_mask(False)
                om = np.asarray(nc.variables["initial_omega"][...])
                if "initial_attitude" in nc.variables:
                    R = np.asarray(nc.variables["initial_attitude"][...])
    except SceneError:
        raise
    except Exception as exc:  # a damaged or foreign file
        raise foreign(key, path, exc) from None
    om = _numbers(key, path, "Ω₀", om, (3,))
    if R is not None:
        R = _numbers(key, path, "the attitudes", R, (3, 3))
        if R.shape[0] != om.shape[0]:
            raise SceneError(key, f"{path}: {R.shape[0]} attitudes for {om.shape[0]} Ω₀: give one per member",
                             show_value=False)
        dev = np.abs(np.einsum("mji,mjk->mik", R, R) - np.eye(3)).max(axis=(1, 2))
        det = np.linalg.det(R)
        bad = np.flatnonzero((dev > 1e-12) | (np.abs(det - 1.0) > 1e-12))
        if bad.size:
            raise SceneError(key, f"{path}: attitude {bad[0]} is not a rotation matrix (RᵀR = I to 1e-12, "
                             f"det R = +1; |RᵀR − I| = {dev[bad[0]]:.1e}, det R = {det[bad[0]]:.6g})",
                             show_value=False)
    _FILE_CACHE.clear()
    _FILE_CACHE[digest] = (om, R)
    return om, R, digest


def _numbers(key, path, what, a, shape) -> np.ndarray:
    from ..scene import SceneError

    a = np.asarray(a)
    if a.dtype.kind not in "iuf":
        raise SceneError(key, f"{path}: {what} must be real numbers (got dtype {a.dtype})", show_value=False)
    if a.ndim != 1 + len(shape) or a.shape[1:] != shape or a.shape[0] < 1:
        want = ", ".join(["members"] + [str(n) for n in shape])
        raise SceneError(key, f"{path}: {what} must have shape ({want}), not {a.shape}", show_value=False)
    a = a.astype(np.float64)
    if not np.isfinite(a).all():
        m = int(np.argwhere(~np.isfinite(a))[0][0])
        raise SceneError(key, f"{path}: {what} must be finite (member {m} is not)", show_value=False)
    return a


def file_members(scene: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """(Ω₀, R₀) of every member of a scene with ``initial.file`` (None without)."""
    path = scene["initial"]["file"]
    if not path:
        return None
    om, R, _ = read_file(path, scene["initial"]["sha256"])
    if R is None:
        R = np.repeat(np.asarray(scene["initial"]["R"], dtype=np.float64)[None], om.shape[0], 0)
    return om, R


def check_file(scene: dict) -> None:
    """The scene rules of ``initial.file`` (a cross rule: it needs ensemble.members);
    fills in ``initial.sha256``."""
    from ..scene import SceneError

    ini = scene["initial"]
    if not ini["file"]:
        if ini["sha256"]:
            raise SceneError("initial.sha256", "is read only with initial.file", ini["sha256"])
        return
    om, _, digest = read_file(ini["file"], ini["sha256"])
    members = scene["ensemble"]["members"]
    if om.shape[0] != members:
        raise SceneError("ensemble.members", f"must equal the {om.shape[0]} members of initial.file "
                         f"{ini['file']}", members)
    ini["sha256"] = digest


def max_spin(scene: dict) -> float:
    """The largest |Ω(0)| (rad s⁻¹) any member of the scene's ensemble can
    start with: |initial.omega|, times ``ensemble.spin_range``[1] when the
    members are drawn (more than one); with ``initial.file``, the file's largest."""
    given = file_members(scene)
    if given is not None:
        return float(np.linalg.norm(given[0], axis=1).max())
    w = float(np.linalg.norm(np.asarray(scene["initial"]["omega"], dtype=np.float64)))
    if int(scene["ensemble"]["members"]) > 1:
        w *= float(scene["ensemble"]["spin_range"][1])
    return w


def heat_bound(scene: dict, phys) -> float:
    """An upper bound (J) of the heat any member of the scene's ensemble can
    produce: its initial mechanical energy above rest, at most
    ½ I_max (s_hi |Ω(0)|)² + (max V − min V) with s_hi = ``ensemble.spin_range``[1]
    (1 for a single member).  The same for every member chunk of a run, so
    the kernels' model (see :func:`liethermo.top.physics.build_model`) and with
    it every member's bits do not depend on how the ensemble is split.
    ``phys``: the scene's physics (any number of members)."""
    from .physics import potential_span

    w = max_spin(scene)
    span = float(np.max(potential_span(phys), initial=0.0))
    return 0.5 * float(np.max(phys.inertia, initial=0.0)) * w * w + span


def initial_conditions(scene: dict, start: int = 0, stop: int | None = None):
    """Initial Ω (N, 3) and R (N, 3, 3) of members ``start:stop``."""
    members = int(scene["ensemble"]["members"])
    stop = members if stop is None else stop
    given = file_members(scene)
    if given is not None:
        return given[0][start:stop].copy(), given[1][start:stop].copy()
    omega0 = np.asarray(scene["initial"]["omega"], dtype=np.float64)
    R0 = np.asarray(scene["initial"]["R"], dtype=np.float64)
    n = stop - start
    if members == 1:
        return np.repeat(omega0[None], n, 0), np.repeat(R0[None], n, 0)
    seed = int(scene["ensemble"]["seed"])
    sr = scene["ensemble"]["spin_range"]
    w = np.linalg.norm(omega0)
    b0, b1 = start // BLOCK, (stop - 1) // BLOCK + 1
    nb = b1 - b0
    q, d, u = np.empty((nb * BLOCK, 4)), np.empty((nb * BLOCK, 3)), np.empty(nb * BLOCK)
    for k in range(nb):  # one generator per block: a member's draws do not depend on the chunking
        rows = slice(k * BLOCK, (k + 1) * BLOCK)
        _draw_raw(seed, b0 + k, q[rows], d[rows], u[rows], sr)
    keep = slice(start - b0 * BLOCK, stop - b0 * BLOCK)
    return shaped(q[keep], d[keep], u[keep], w)  # normalised, scaled and turned into rotations
