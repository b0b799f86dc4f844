"""The LLVM IR the Numba engine's product kernels are built of
(:mod:`tpnet_ref.engines.numba_products`' row kernel, :mod:`tpnet_ref.engines.numba_tiles`'
tiles): vectors of float lanes and their fused multiply-add, weights of fewer bits widened to
float32 in registers, row pointers, the operands' checks; and which tiles this CPU's registers
hold (:data:`TILE_PLAN`).
"""
from __future__ import annotations

from types import SimpleNamespace

from ..extras import require

numba = require("numba", "metrics", "the Numba inference engine (engine='numba')")
from llvmlite import ir  # noqa: E402
from numba import types  # noqa: E402
from numba.core import cgutils  # noqa: E402

#: bytes of the vectors the weights' columns are padded to (a 64-byte vector: one AVX-512
#: register, two AVX2 ones)
VECTOR_BYTES = 64


def wide_registers() -> bool:
    """Whether the CPU Numba compiles for has 32 vector registers of 64 bytes (AVX-512), as
    its target's features say: ``NUMBA_CPU_FEATURES`` where set; none where only
    ``NUMBA_CPU_NAME`` is (a generic target); else the host's."""
    from numba.core import config
    feats = config.CPU_FEATURES
    if not feats and not config.CPU_NAME:
        from llvmlite import binding as llvm
        feats = llvm.get_host_cpu_features().flatten()
    return "+avx512f" in (feats or "").split(",")


#: the register tiles of the engine's products on this CPU: ``"wide"`` (64-byte vectors; 4 x 4
#: and 8 x 2 tiles) with AVX-512's 32 registers, ``"narrow"`` (32-byte vectors; 4 x 2 tiles)
#: with AVX2's 16, where the wide tiles spill their sums to the stack. Either plan gives every
#: sum the same chain of multiply-adds, so the same bits (``tests/test_engines_numba.py``); the
#: narrow one runs the per-point layers 1.1-2.7x faster on an AVX2 CPU
#: (``bench/probes/tile_plans.py``)
TILE_PLAN = "wide" if wide_registers() else "narrow"
NARROW = TILE_PLAN == "narrow"


#: weights of fewer bits the float32 kernels read (:mod:`tpnet_ref.engines.numba_quant`): int8
#: (symmetric, a float32 scale per output column applied after the sum) and bf16 (stored as
#: its uint16 bits), each widened to float32 in registers
CODES = (types.int8, types.uint16)


def widen(builder, ptr, wdtype, welt, lanes, vty, size):
    """One vector of ``lanes`` weights at ``ptr`` as float32 lanes ``vty``: float weights
    loaded as they are; int8 sign-extended and converted (exact: |q| <= 127); bf16 bits
    shifted into a float32's high half (exact)."""
    if wdtype not in CODES:
        return builder.load(builder.bitcast(ptr, vty.as_pointer()), align=size)
    raw = builder.load(builder.bitcast(ptr, ir.VectorType(welt, lanes).as_pointer()),
                       align=wdtype.bitwidth // 8)
    if wdtype == types.int8:
        return builder.sitofp(raw, vty)
    i32 = ir.VectorType(ir.IntType(32), lanes)
    wide = builder.shl(builder.zext(raw, i32), ir.Constant(i32, [16] * lanes))
    return builder.bitcast(wide, vty)


def widen_planes(builder, ptr, lanes, vty, fma):
    """One vector of bf16 weights in two planes, ``lanes`` pairs (hi, lo) of uint16 at ``ptr``
    (one 32-bit load each: hi the low half, lo the high half), as float32 lanes
    ``fma(lo, 2^-8, hi)``: one rounding of a sum that float32 holds exactly
    (:mod:`tpnet_ref.weights.quantize` makes and checks the planes so), the weights in
    ``model.params`` bit for bit."""
    i32 = ir.VectorType(ir.IntType(32), lanes)
    bits = builder.load(builder.bitcast(ptr, i32.as_pointer()), align=4)
    hi = builder.bitcast(builder.shl(bits, ir.Constant(i32, [16] * lanes)), vty)
    lo = builder.bitcast(builder.and_(bits, ir.Constant(i32, [-65536] * lanes)), vty)
    return builder.call(fma, [lo, ir.Constant(vty, [2.0 ** -8] * lanes), hi])


def operands_ok(x, w, out, act) -> bool:
    """Whether a kernel's typed operands fit it: 2-D arrays, ``x`` and ``out`` of one float
    dtype, ``w`` C-contiguous of that dtype or (float32 ``x``) of :data:`CODES`, ``act`` an
    array."""
    return (isinstance(x, types.Array) and isinstance(w, types.Array)
            and isinstance(out, types.Array) and x.ndim == w.ndim == out.ndim == 2
            and x.dtype == out.dtype and w.layout == "C"
            and (w.dtype == x.dtype or (x.dtype == types.float32 and w.dtype in CODES))
            and isinstance(x.dtype, types.Float) and isinstance(act, types.Array))


def vectors(context, builder, dtype, vbytes=VECTOR_BYTES):
    """The codegen's common values for float ``dtype``: a namespace of ``elt`` (its LLVM type),
    ``size`` (bytes), ``lanes`` (per vector of ``vbytes`` bytes), ``vty`` (the vector type),
    ``intp``, ``fma`` (``llvm.fma`` on vectors), ``undef`` and ``splat`` (a broadcast's
    operands)."""
    elt = context.get_value_type(dtype)
    size = dtype.bitwidth // 8
    lanes = vbytes // size
    vty = ir.VectorType(elt, lanes)
    return SimpleNamespace(
        elt=elt, size=size, lanes=lanes, vty=vty, intp=context.get_value_type(types.intp),
        fma=cgutils.get_or_insert_function(builder.module, ir.FunctionType(vty, [vty] * 3),
                                           f"llvm.fma.v{lanes}f{size * 8}"),
        undef=ir.Constant(vty, ir.Undefined),
        splat=ir.Constant(ir.VectorType(ir.IntType(32), lanes), [0] * lanes))


def row_ptr(builder, arr, row, elt):
    """Element pointer of ``arr[row, 0]`` (a 2-D array's struct; byte strides)."""
    stride = builder.extract_value(arr.strides, 0)
    p = builder.gep(builder.bitcast(arr.data, ir.IntType(8).as_pointer()),
                    [builder.mul(row, stride)])
    return builder.bitcast(p, elt.as_pointer())


def by_planes(builder, wdtype, wa, xa, intp, emit):
    """``emit(planes)``: once with False for float or int8 weights; for bf16 codes behind a
    branch on whether ``w`` has twice ``x``'s rows (two planes: ``emit(True)``) or not."""
    if wdtype != types.uint16:
        emit(False)
        return
    two = builder.icmp_unsigned("==", builder.extract_value(wa.shape, 0), builder.mul(
        builder.extract_value(xa.shape, 1), ir.Constant(intp, 2)))
    with builder.if_else(two) as (then, other):
        with then:
            emit(True)
        with other:
            emit(False)


__all__ = ["VECTOR_BYTES", "TILE_PLAN", "NARROW", "CODES", "wide_registers", "widen",
           "widen_planes", "operands_ok", "vectors", "row_ptr", "by_planes"]
