"""The ensemble kernels on CUDA (numba-cuda): one thread per member.

The device kernel is the member loop of :func:`.simple.advance_members`,
compiled for the GPU: a thread loads its member's state, takes ``every`` ×
``n_out`` steps with the step the stepper's type selects (:mod:`.steppers`,
the same ``advance_member`` and term generics as the CPU kernels
call; numba-cuda compiles ``@njit`` functions, ``@overload``\\ s and
``@intrinsic``\\ s of the generic target for the device), keeps the state in
registers across steps and writes only the kept outputs.  Nothing here names
a term or a method: a term added to :mod:`.terms` runs on the GPU as it is.

Device arrays (flat, member index fastest, so that the threads of a warp
touch consecutive addresses):

* ``Y``     (n·N,)              state, column c of member m at ``c·N + m``
* ``P``     (nparam·N,) or (nparam,)  per-member parameters (column-major),
                                or the one row of a shared model
* ``OUT``   (n_out·n·N,)        output j of member m: ``j·n·N + c·N + m``
* ``ISTAT`` (N, NISTAT) int64 and ``FSTAT`` (N, NFSTAT) float64, as on the
  CPU (:mod:`.simple`), passed as their transposed (column-major) views.

Status, failing step, Newton statistics, steps done and max |h|·|Ω| have the
meaning they have on the CPU; a failed member stops, its state stays at the
start of the failing step and the outputs it did not reach are NaN (the CPU
layer's pre-filled NaN).

Arithmetic: NVVM fuses a multiply and an add into one FMA on its own unless
told not to (its ``-fma=1`` default, which numba-cuda keeps with ``fastmath``
off: it emits ``mul.f64``/``add.f64``, which the assembler may fuse);
:func:`exact_arithmetic` switches that off while the kernel compiles (PTX
``mul.rn``/``add.rn``), so that the device rounds where the CPU kernels round
and fuses only where they call :func:`._jit.fma` (``llvm.fma.f64``, one
``fma.rn.f64``).  Division and ``sqrt`` are IEEE on both (``div.rn``,
``sqrt.rn``); the few calls of ``math.exp``/``math.log1p`` (the internal
energy beyond its polynomials' range) are libdevice's on the device, within
an ulp of the C library's.  So the device should reproduce the CPU's
straightforward kernel bit for bit except where those calls differ; the
tests (numba-cuda's simulator, which runs the CPU-compiled functions) ask
for agreement to 1e-12.

The kernel closes over the stepper and the model (whose values it does not
use: the parameters come from ``P``): :func:`kernel_for` makes and keeps one
kernel per stepper and model type.  :data:`THREADS_PER_BLOCK` is read at each
launch (a benchmark may change it).  The reference (DOP853) method stays on
the CPU.

Importing this module needs numba-cuda; :func:`liethermo.gpu.gpu_available`
says whether a device can run it, without raising.
"""

from __future__ import annotations

import contextlib
import math
import time
import warnings

import numba
import numpy as np

if not hasattr(np, "row_stack"):
    # numba-cuda (0.30) registers an overload of np.row_stack when it first
    # compiles, which NumPy 2.5 removed (it was an alias of vstack)
    np.row_stack = np.vstack

from numba import cuda  # noqa: E402
from numba.core.errors import NumbaPerformanceWarning  # noqa: E402

from ._jit import lane
from .gen import unflatten
from .layout import IS_STATUS, STATUS_OK
from .simple import advance_member

#: threads per block of the device kernel
THREADS_PER_BLOCK = 128


@lane
def run_member(stepper, template, Y, P, pmember, pstride, m, N, n, h, every, n_out, OUT, ISTAT,
               FSTAT):
    """Member m (of N, state size n): ``every`` × ``n_out`` steps, its output
    j into ``OUT`` at ``j·n·N + m`` (stride N); its parameters from ``P`` at
    ``m·pmember`` (stride ``pstride``).  The outputs it does not produce (a
    member that failed, before or during the call) are NaN, as the CPU
    layer's pre-filled outputs are."""
    jdone = 0
    if ISTAT[m, IS_STATUS] == STATUS_OK:
        md = unflatten(template, P, m * pmember, pstride)
        jdone = advance_member(stepper, md, Y, m, N, OUT, h, every, n_out, ISTAT, FSTAT, m, n, N)
    for j in range(jdone, n_out):
        for c in range(n):
            OUT[j * n * N + c * N + m] = math.nan


@lane
def _host_array(a):
    """The array a kernel argument is inside numba-cuda's simulator (its
    numpy array, which the CPU-compiled lane functions take); on a device
    the argument itself."""
    return a


#: what a thread runs: :func:`run_member`; in the simulator the same function
#: compiled for the CPU (and cached, like the CPU kernels), since a thread
#: there is Python calling compiled code
_member_body = run_member

if numba.config.ENABLE_CUDASIM:
    from ._jit import jit

    def _host_array(a):  # noqa: F811
        return np.asarray(a._item._ary) if hasattr(a, "_item") else a

    _member_body = jit(nogil=True)(getattr(run_member, "py_func", run_member))  # plain under NUMBA_DISABLE_JIT


@contextlib.contextmanager
def exact_arithmetic():
    """While this context is active, NVVM compiles without contracting
    ``a·b + c`` into FMAs (``-fma=0``); explicit ``llvm.fma.f64`` calls stay
    fused.  A numba-cuda without the hook compiles as it does by default."""
    try:
        from numba.cuda.cudadrv import nvvm
    except ImportError:
        yield
        return
    original = getattr(nvvm, "compile_ir", None)
    if original is None:
        yield
        return

    def compile_ir(llvmir, **options):
        options.setdefault("fma", False)
        return original(llvmir, **options)

    nvvm.compile_ir = compile_ir
    try:
        yield
    finally:
        nvvm.compile_ir = original


def make_kernel(stepper, template):
    """The device kernel for a stepper and a model type: ``kernel[blocks,
    threads](Y, P, pmember, pstride, N, n, h, every, n_out, OUT, ISTAT, FSTAT)``
    advances every member m < N (one thread each)."""

    @cuda.jit
    def advance_members_cuda(Y, P, pmember, pstride, N, n, h, every, n_out, OUT, ISTAT, FSTAT):
        m = cuda.grid(1)
        if m < N:
            _member_body(stepper, template, _host_array(Y), _host_array(P), pmember, pstride, m, N, n,
                       h, every, n_out, _host_array(OUT), _host_array(ISTAT), _host_array(FSTAT))

    return advance_members_cuda


_KERNELS: dict = {}


def kernel_for(stepper, template):
    """The device kernel of :func:`make_kernel`, compiled once per stepper
    value and numba type of the model (its values are not compiled in)."""
    key = (numba.typeof(stepper), stepper, numba.typeof(template))  # markers: equal tuples, other types
    kern = _KERNELS.get(key)
    if kern is None:
        kern = _KERNELS[key] = make_kernel(stepper, template)
    return kern


#: the device buffer of a chunk's outputs holds at most this many bytes ...
from .layout import OUT_BYTES  # noqa: E402
#: ... and a kernel call takes at most this many member-steps (seconds on an
#: H100), so that progress is reported and a stop acted on between calls
CALL_MEMBER_STEPS = 2**34


def outputs_per_call(N: int, n: int, n_out: int, every: int = 1) -> int:
    """Outputs per kernel call when the caller does not say: as many as fit
    in :data:`OUT_BYTES` and :data:`CALL_MEMBER_STEPS` (at least one)."""
    N = max(1, N)
    return max(1, min(n_out, OUT_BYTES // max(1, 8 * n * N),
                      CALL_MEMBER_STEPS // (N * max(1, every))))


def _event():
    try:
        return cuda.event(timing=True)
    except Exception:  # noqa: BLE001 - a simulator without events: time on the host
        return None


def advance_on_device(stepper, model, shared, Y, P, h, every, n_out, states, ISTAT, FSTAT,
                      out_per_call, progress=None, compile_only=False):
    """Run the chunk loop of an ensemble on the device: ``n_out`` outputs of
    ``every`` steps, ``out_per_call`` outputs per kernel call.

    ``Y`` (N, n), ``P`` (N, nparam), ``ISTAT``, ``FSTAT`` as for
    :func:`.simple.advance_members` (``Y``, ``ISTAT`` and ``FSTAT`` are
    updated in place at the end); ``states`` (N, ≥ n_out + 1, n) receives
    output j in ``states[:, 1 + j]`` (outputs a failed member did not reach
    are NaN).  The state, parameters and statistics go to the device once;
    each call's outputs come back after it.  ``progress(steps)`` after every
    call.  Returns (kernel seconds, compile seconds): the kernels alone,
    summed over the calls (CUDA events), and numba-cuda compiling the kernel."""
    N, n = Y.shape
    kern = kernel_for(stepper, model)
    if shared is not None:
        Pd, pmember, pstride = np.ascontiguousarray(P[0]), 0, 1
    else:
        Pd, pmember, pstride = np.ascontiguousarray(P.T).ravel(), 1, N
    if Pd.size == 0:
        Pd = np.zeros(1)
    cap = max(1, min(int(out_per_call), n_out))
    dY = cuda.to_device(np.ascontiguousarray(Y.T).ravel())
    dP = cuda.to_device(Pd)
    dIS = cuda.to_device(np.asfortranarray(ISTAT))
    dFS = cuda.to_device(np.asfortranarray(FSTAT))
    dOUT = cuda.device_array(cap * n * N)
    ints = (int(pmember), int(pstride), int(N), int(n))

    def args(nj):
        return (dY, dP) + ints + (float(h), int(every), int(nj), dOUT, dIS, dFS)

    t0 = time.perf_counter()
    if hasattr(kern, "compile"):  # not in the simulator
        with exact_arithmetic():
            kern.compile(tuple(numba.typeof(a) for a in args(cap)))
    compile_seconds = time.perf_counter() - t0
    if compile_only:
        return 0.0, compile_seconds
    tpb = int(THREADS_PER_BLOCK)
    try:
        host = cuda.pinned_array(cap * n * N)
    except Exception:  # noqa: BLE001 - the simulator
        host = np.empty(cap * n * N)
    with exact_arithmetic():  # should a launch compile again (another signature)
        kernel_seconds = _launch_calls(kern, tpb, args, cap, n, N, n_out, every, dOUT, host,
                                       states, progress)
    Y[:] = dY.copy_to_host().reshape(n, N).T
    ISTAT[:] = dIS.copy_to_host()
    FSTAT[:] = dFS.copy_to_host()
    return kernel_seconds, compile_seconds


def _launch_calls(kern, tpb, args, cap, n, N, n_out, every, dOUT, host, states, progress):
    """The kernel calls of :func:`advance_on_device`; their kernel seconds."""
    blocks = -(-N // tpb)
    kernel_seconds = 0.0
    j = 0
    while j < n_out:
        nj = min(cap, n_out - j)
        start, end = _event(), _event()
        tc = time.perf_counter()
        if start is not None:
            start.record()
        with warnings.catch_warnings():  # a small ensemble fills few SMs, as its user knows
            warnings.simplefilter("ignore", NumbaPerformanceWarning)
            kern[blocks, tpb](*args(nj))
        if end is not None:
            end.record()
            end.synchronize()
            kernel_seconds += cuda.event_elapsed_time(start, end) * 1e-3
        else:
            cuda.synchronize()
            kernel_seconds += time.perf_counter() - tc
        size = nj * n * N
        dOUT[:size].copy_to_host(host[:size])
        states[:, 1 + j:1 + j + nj] = host[:size].reshape(nj, n, N).transpose(2, 0, 1)
        j += nj
        if progress is not None:
            progress(nj * every)
    return kernel_seconds


__all__ = ["CALL_MEMBER_STEPS", "OUT_BYTES", "THREADS_PER_BLOCK", "advance_on_device",
           "exact_arithmetic", "kernel_for", "make_kernel", "outputs_per_call", "run_member"]
