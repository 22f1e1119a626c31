"""Whether this process can run the ensemble kernels on a CUDA device.

:func:`gpu_available` answers without raising and without compiling
anything, so that a run asked for ``device="gpu"`` is refused before any work
with the reason in one line.  numba-cuda is an optional dependency (the
``gpu`` extra); its simulator (``NUMBA_ENABLE_CUDASIM=1``, set before numba-cuda
is imported) counts as a device: the kernels then run as Python, one thread at
a time, which is what the tests use.

The fluids (on the sphere and on the torus) run on a GPU through an array
namespace: :func:`namespace` gives CuPy for ``"gpu"`` (numpy for ``"cpu-xp"``,
the same steps on the host), :func:`to_host` and :func:`synchronize` move and
wait for its arrays, and :func:`device_refusal` is the one-line reason a
fluid scene's ``ensemble.device = "gpu"`` cannot run (CuPy or a device
missing, or a method that runs on the CPU only).
"""

from __future__ import annotations

import importlib.util

import numpy as np

#: the device names :func:`liethermo.top.simulate.simulate` takes
DEVICES = ("cpu", "gpu")

#: the backends of the fluids' steps: the CPU's own kernels, the array-namespace
#: steps with numpy (``cpu-xp``) or with CuPy (``gpu``)
BACKENDS = ("cpu", "cpu-xp", "gpu")

#: the CuPy wheel of the ``gpu`` extra: the same CUDA major version as numba-cuda's ``cu13``,
#: with its ``ctk`` extra (the CUDA libraries from pip)
CUPY_WHEEL = "cupy-cuda13x[ctk]"


def namespace(backend: str):
    """The array module of a backend: numpy for ``cpu-xp``, CuPy for ``gpu``
    (refused in one line where CuPy or a CUDA device is missing)."""
    if backend == "cpu-xp":
        return np
    if backend == "gpu":
        try:
            import cupy
        except ImportError as e:
            raise RuntimeError(f"backend 'gpu' needs CuPy, which does not import here ({e}); install it "
                               f"with pip install 'liethermo[gpu]' (CuPy for CUDA 13: {CUPY_WHEEL})") from None
        try:
            n = cupy.cuda.runtime.getDeviceCount()
        except Exception as e:  # no driver, no runtime
            raise RuntimeError(f"backend 'gpu': no usable CUDA device ({e})") from None
        if n < 1:
            raise RuntimeError("backend 'gpu': no CUDA device on this machine")
        return cupy
    raise ValueError(f"backend must be one of {', '.join(BACKENDS[1:])} for the array-namespace steps, "
                     f"not {backend!r}")


def to_host(a) -> np.ndarray:
    """A numpy copy (or view) of an xp array."""
    get = getattr(a, "get", None)
    return get() if callable(get) else np.asarray(a)


def synchronize(xp) -> None:
    """Wait for the device (nothing to wait for with numpy)."""
    cuda = getattr(xp, "cuda", None)
    if cuda is not None:
        cuda.Device().synchronize()


def device_refusal(scene, xp_methods: tuple[str, ...]) -> str | None:
    """Why a fluid scene's ``ensemble.device`` cannot run here, in one line,
    or None: with ``"gpu"``, CuPy or a CUDA device missing (:func:`namespace`),
    or ``integrator.method`` or a method of ``output.compare`` not among
    ``xp_methods`` (the methods the array-namespace steps run; the others run
    on the CPU only)."""
    if scene["ensemble"]["device"] != "gpu":
        return None
    try:
        namespace("gpu")
    except RuntimeError as exc:
        return f"scene key 'ensemble.device': \"gpu\" cannot run here: {exc}"
    runs = ", ".join(xp_methods[:-1]) + " and " + xp_methods[-1]
    for key, method in [("ensemble.device", scene["integrator"]["method"])] + [
            ("output.compare", m) for m in scene["output"]["compare"]]:
        if method not in xp_methods:
            return f"scene key '{key}': the {method} method runs on the CPU only (\"gpu\" runs {runs})"
    return None


def gpu_available() -> tuple[bool, str]:
    """(True, the device's name) or (False, why not: numba-cuda missing, no
    CUDA driver, no device)."""
    if importlib.util.find_spec("numba_cuda") is None:
        return False, "numba-cuda is not installed (pip install 'liethermo[gpu]')"
    import numba

    if numba.config.ENABLE_CUDASIM:
        return True, "numba-cuda simulator (NUMBA_ENABLE_CUDASIM=1)"
    try:
        from numba import cuda
        from numba.cuda.cudadrv.driver import driver

        count = driver.get_device_count()
    except Exception as exc:  # noqa: BLE001 - CudaSupportError, a broken install, ...
        msg = " ".join(str(exc).replace("Error at driver init:", "").split()).rstrip(" :")
        return False, f"no usable CUDA driver ({msg or type(exc).__name__})"
    if count < 1:
        return False, "no CUDA device (the driver sees none)"
    try:
        dev = cuda.get_current_device()
        name = dev.name.decode() if isinstance(dev.name, bytes) else str(dev.name)
        return True, f"{name} (compute capability {dev.compute_capability[0]}.{dev.compute_capability[1]})"
    except Exception as exc:  # noqa: BLE001
        return False, f"the CUDA device cannot be opened ({' '.join(str(exc).split())})"


def device_memory() -> tuple[int, int] | None:
    """(free, total) bytes of the current CUDA device, or None."""
    ok, _ = gpu_available()
    if ok:
        try:
            from numba import cuda

            free, total = cuda.current_context().get_memory_info()
            return int(free), int(total)
        except Exception:  # noqa: BLE001 - the simulator, a device that went away
            pass
    try:  # CuPy, which the fluid's steps use
        import cupy

        free, total = cupy.cuda.runtime.memGetInfo()
        return int(free), int(total)
    except Exception:  # noqa: BLE001 - not installed, no driver, no device
        return None


def require_gpu() -> str:
    """The device's name, or RuntimeError with the one-line reason."""
    ok, why = gpu_available()
    if not ok:
        raise RuntimeError(f"device='gpu' cannot run here: {why}")
    return why


__all__ = ["BACKENDS", "CUPY_WHEEL", "DEVICES", "device_memory", "device_refusal", "gpu_available", "namespace",
           "require_gpu", "synchronize", "to_host"]
