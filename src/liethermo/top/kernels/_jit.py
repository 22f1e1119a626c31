"""All numba options of liethermo in one place.

* ``cache=True`` so that a second process does not recompile (set
  ``LIETHERMO_NUMBA_CACHE=0`` to switch it off, e.g. on a read-only install).
  Numba checks only the timestamp and size of the file that defines a
  cached function, not of the files of the functions it calls (nor of the
  model terms whose overloads it compiled in): after editing e.g. a term
  module, a cached driver would still run the old physics.  :func:`_drop_stale_cache` guards
  against that: at import it hashes every kernel source (and the numba
  version) and, when the hash differs from the one stamped beside the cache,
  deletes the kernels' cache files, so a pull or an edit never runs stale
  machine code;
* ``fastmath`` stays off: the kernels promise round-off-level invariants and
  must propagate NaN/inf, which the no-NaN/no-inf fast-math flags would break;
* ``error_model="numpy"``: a division by zero yields inf/NaN (caught by the
  per-member status logic) instead of raising inside a parallel loop;
* :func:`fma` is the one way the kernels fuse a multiply and an add: an
  explicit, correctly rounded ``a·b + c`` (LLVM's ``llvm.fma.f64``, one
  ``vfmadd`` instruction on x86-64 with FMA, packed in vectorized loops).
  Because it is written out, every kernel that calls the same arithmetic gets
  the same bits — the simple and the fast ensemble kernels share their
  arithmetic through inline functions, and LLVM never contracts on its own
  (``fastmath`` off).

Setting ``NUMBA_DISABLE_JIT=1`` runs every kernel as plain Python (slow, but
useful for debugging and for checking that the jitted code means what it says).
"""

from __future__ import annotations

import functools
import hashlib
import math
import os
import struct
from pathlib import Path

import numba
from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic

from ...numerics.jit import CACHE  # noqa: E402


def _cache_dirs(here: Path) -> list[Path]:
    """Where numba puts the kernel caches of the source folder ``here`` and of
    its subfolders: beside the sources, or under NUMBA_CACHE_DIR in the one
    folder numba names after each source folder (its name plus the SHA-1 of
    its path, as numba's ``_CacheLocator.get_suitable_cache_subpath``
    computes it) — never another project's folder in a shared cache
    directory."""
    folders = [here] + sorted(p for p in here.rglob("*") if p.is_dir() and p.name != "__pycache__"
                              and "__pycache__" not in p.parts)
    if numba.config.CACHE_DIR:
        return [Path(numba.config.CACHE_DIR) / f"{d.name}_{hashlib.sha1(str(d).encode()).hexdigest()}"
                for d in folders]
    return [d / "__pycache__" for d in folders]


def _drop_stale_cache(here: Path | None = None) -> None:
    here = Path(__file__).resolve().parent if here is None else here
    digest = hashlib.sha256(numba.__version__.encode())
    for src in sorted(here.rglob("*.py")):
        digest.update(str(src.relative_to(here)).encode() + b"\0" + src.read_bytes())
    stamp_text = digest.hexdigest()
    for cache in _cache_dirs(here):
        stamp = cache / "liethermo-kernels.sha256"
        try:
            old = stamp.read_text()
        except OSError:
            old = None  # first import beside this cache (numba made it after our import): adopt it
        if old == stamp_text:
            continue
        try:
            if old is not None:
                for f in list(cache.glob("*.nbi")) + list(cache.glob("*.nbc")):
                    f.unlink(missing_ok=True)
            cache.mkdir(parents=True, exist_ok=True)
            tmp = cache / f".liethermo-kernels.{os.getpid()}.tmp"
            tmp.write_text(stamp_text)
            os.replace(tmp, stamp)
        except OSError:  # read-only install: numba then cannot cache either
            pass


if CACHE:
    _drop_stale_cache()

jit = functools.partial(numba.njit, cache=CACHE, fastmath=False, error_model="numpy")
#: a lane function: compiled once per argument types (so ``x is None`` tests on
#: its arguments are decided at compile time) and marked ``alwaysinline`` for
#: LLVM, which inlines it into every caller after linking — so a lane loop
#: built of such calls is one straight-line body that LLVM can vectorize,
#: without numba re-typing the callee's IR at every call site
#: (``inline="always"``), which made generic kernels take minutes to compile
lane = functools.partial(numba.njit, cache=False, fastmath=False, error_model="numpy",
                         forceinline=True, nogil=True)
#: jit options of the ``@overload`` implementations that are lane functions
LANE_OPTIONS = {"forceinline": True, "fastmath": False, "error_model": "numpy", "nogil": True}


@intrinsic
def _align_frame_intrinsic(typingctx):
    """Align the calling function's stack frame to 64 bytes (LLVM ``alignstack``).

    The vectorized sweeps keep tuples and spilled zmm registers on the stack,
    which LLVM addresses with unaligned moves at offsets from a stack pointer
    that the ABI aligns to 16 bytes only; where the frame lands mod 64 (set by
    address-space randomisation, i.e. by the process) decides how many of those
    moves split a cache line.  Measured (Zen 4): RK4 on 64 members of the paper
    scene without viscosity took 0.097 or 0.19 ms of CPU time per simulated
    second, by process; with the frame aligned, 0.097–0.100 in 8 of 8."""
    def codegen(context, builder, signature, args):
        attrs = builder.function.attributes
        attrs.alignstack = 64
        attrs.add("nounwind")  # numba's functions return their errors; llvmlite prints no attribute of an empty set
        return context.get_dummy_value()

    return types.none(), codegen


@intrinsic
def _fma_intrinsic(typingctx, a, b, c):
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        d = ir.DoubleType()
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(d, [d, d, d]),
                                            "llvm.fma.f64")
        a_, b_, c_ = (context.cast(builder, v, t, types.float64)
                      for v, t in zip(args, signature.args))
        return builder.call(fn, [a_, b_, c_])

    return sig, codegen


def fma_exact(a: float, b: float, c: float) -> float:
    """a·b + c rounded once (IEEE 754 fusedMultiplyAdd), in plain Python: the
    exact value from rational arithmetic, rounded by ``float()``.  Used when
    numba's JIT is disabled, so that such a run gives the jitted bits."""
    from fractions import Fraction

    a, b, c = float(a), float(b), float(c)
    if not (math.isfinite(a) and math.isfinite(b) and math.isfinite(c)):
        return a * b + c  # inf/NaN: same result as the fused operation
    exact = Fraction(a) * Fraction(b) + Fraction(c)
    if exact == 0:
        # sign of an exact zero: −0 only when a·b and c are both −0 (or
        # both negative zero-products), as IEEE 754 specifies under rounding to nearest
        prod_neg = (math.copysign(1.0, a) * math.copysign(1.0, b)) < 0
        if a * b == 0 and c == 0:
            return -0.0 if (prod_neg and math.copysign(1.0, c) < 0) else 0.0
        return 0.0
    try:
        return float(exact)
    except OverflowError:
        return math.inf if exact > 0 else -math.inf


#: ``fma(a, b, c)`` = a·b + c with one rounding (see module docstring)
fma = fma_exact if numba.config.DISABLE_JIT else _fma_intrinsic


def _align_frame_py() -> None:
    """Plain Python has no stack frame to align."""


align_frame = _align_frame_py if numba.config.DISABLE_JIT else _align_frame_intrinsic


@intrinsic
def _select_intrinsic(typingctx, cond, a, b):
    sig = types.float64(cond, a, b)  # casts below: a and b may be integers

    def codegen(context, builder, signature, args):
        c_ = context.cast(builder, args[0], signature.args[0], types.boolean)
        a_ = context.cast(builder, args[1], signature.args[1], types.float64)
        b_ = context.cast(builder, args[2], signature.args[2], types.float64)
        return builder.select(c_, a_, b_)

    return sig, codegen


def select_py(cond: bool, a: float, b: float) -> float:
    """``a if cond else b`` (the plain-Python meaning of :func:`select`)."""
    return float(a) if cond else float(b)


#: ``select(c, a, b)`` = ``a if c else b`` as one LLVM ``select`` instruction.
#: Numba lowers ``a if c else b`` to a branch; in a lane loop that stores
#: ``S[p] = n if c else S[p]``, LLVM then sees a conditional store and
#: vectorizes it as a masked store (``vmaskmovpd``), which AMD Zen cores
#: execute as slow microcode.  A select keeps the store unconditional: a
#: blend and a plain store.
select = select_py if numba.config.DISABLE_JIT else _select_intrinsic


def _ld_py(a, i):
    return a[i]


def _st_py(a, i, v):
    a[i] = v


@intrinsic
def _ld_intrinsic(typingctx, arr, idx):
    if not isinstance(arr, types.Array) or arr.ndim != 1 or not isinstance(idx, types.Integer):
        return None
    sig = arr.dtype(arr, idx)

    def codegen(context, builder, signature, args):
        return builder.load(_element_ptr(context, builder, signature, args))

    return sig, codegen


@intrinsic
def _st_intrinsic(typingctx, arr, idx, val):
    if not isinstance(arr, types.Array) or arr.ndim != 1 or not isinstance(idx, types.Integer):
        return None
    sig = types.none(arr, idx, val)

    def codegen(context, builder, signature, args):
        v = context.cast(builder, args[2], signature.args[2], signature.args[0].dtype)
        builder.store(v, _element_ptr(context, builder, signature, args))
        return context.get_dummy_value()

    return sig, codegen


def _element_ptr(context, builder, signature, args):
    aryty = signature.args[0]
    ary = context.make_array(aryty)(context, builder, args[0])
    idx = context.cast(builder, args[1], signature.args[1], types.intp)
    if aryty.layout == "C":
        return builder.gep(ary.data, [idx], inbounds=True)
    stride = cgutils.unpack_tuple(builder, ary.strides, 1)[0]
    addr = builder.add(builder.ptrtoint(ary.data, cgutils.intp_t), builder.mul(idx, stride))
    return builder.inttoptr(addr, ary.data.type)


#: ``ld(a, i)`` = ``a[i]`` and ``st(a, i, v)``: ``a[i] = v`` for a 1-D array and an index
#: the caller knows to be in range: no negative-index wraparound.  The lane loops
#: index their block rows with ``offset + lane``; numba's wraparound test on such
#: an index is a compare and a select per access, which LLVM removes only when it
#: can prove the index non-negative — and when it could not (a lane loop with a
#: few more rows), it left the loop scalar.
ld = _ld_py if numba.config.DISABLE_JIT else _ld_intrinsic
st = _st_py if numba.config.DISABLE_JIT else _st_intrinsic


def _float_bits_py(x) -> int:
    return struct.unpack("<q", struct.pack("<d", float(x)))[0]


def _bits_float_py(i) -> float:
    return struct.unpack("<d", struct.pack("<Q", int(i) & 0xFFFF_FFFF_FFFF_FFFF))[0]


@intrinsic
def _float_bits_intrinsic(typingctx, x):
    if not isinstance(x, types.Float):
        return None
    sig = types.int64(x)

    def codegen(context, builder, signature, args):
        v = context.cast(builder, args[0], signature.args[0], types.float64)
        return builder.bitcast(v, ir.IntType(64))

    return sig, codegen


@intrinsic
def _bits_float_intrinsic(typingctx, i):
    if not isinstance(i, types.Integer):
        return None
    sig = types.float64(i)

    def codegen(context, builder, signature, args):
        v = context.cast(builder, args[0], signature.args[0], types.int64)
        return builder.bitcast(v, ir.DoubleType())

    return sig, codegen


#: ``float_bits(x)``: the IEEE 754 bits of the float64 x as an int64, and
#: ``bits_float(i)``: the float64 whose bits are the int64 i (its low 64 bits in
#: plain Python).  One LLVM ``bitcast`` each — no instruction at all in a
#: vectorized loop, where the lanes already sit in the same register — so
#: that :mod:`.lanemath` can build 2ᵏ from its exponent bits.
float_bits = _float_bits_py if numba.config.DISABLE_JIT else _float_bits_intrinsic
bits_float = _bits_float_py if numba.config.DISABLE_JIT else _bits_float_intrinsic
