"""Whether this process can run the ensemble kernels on a CUDA device.

:func:`gpu_available` answers without raising and without compiling
anything, so that a run asked for ``device="gpu"`` is refused before any work
with the reason in one line.  numba-cuda is an optional dependency (the
``gpu`` extra); its simulator (``NUMBA_ENABLE_CUDASIM=1``, set before numba-cuda
is imported) counts as a device: the kernels then run as Python, one thread at
a time, which is what the tests use.
"""

from __future__ import annotations

import importlib.util

#: the device names :func:`liethermo.top.simulate.simulate` takes
DEVICES = ("cpu", "gpu")


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


__all__ = ["DEVICES", "device_memory", "gpu_available", "require_gpu"]
