"""The Numba engine's row kernel: ``x @ w`` reading only the weight rows that a non-zero
input multiplies, each output one chain of fused multiply-adds
(:mod:`tpnet_ref.engines.numba_engine` says why and how). :func:`product` streams weight rows
side by side, the sums loaded and stored once per chain of :data:`CHAIN` rows: a window's
products, which read each weight once. The tile kernels (:mod:`tpnet_ref.engines.numba_tiles`)
compute the same chains for the products that reuse each weight across rows; both are built of
:mod:`tpnet_ref.engines.numba_codegen`'s IR. numba's cache keys a compiled kernel to its own
file's time stamp: after editing this file, delete the cached kernels that inline these
(``tpnet_ref/engines/__pycache__/numba_*``).

Argument names (every kernel below; rows are time-major where there are steps, row t*B + b)::

    x             the input rows (R, C), the left operand
    w, kern       a weight matrix (C, N), C-contiguous, N whole 64-byte vectors (kern: one
                  direction's input kernel); bf16 in two planes: (2C, N) against an x of C
                  columns, weight row k's N pairs (hi, lo) interleaved in rows 2k and 2k+1
    out           the result rows (R, N)
    grp           row groups (G, 3): first row, stride between its rows, number of rows
    r0, rs, g     one group's first row, stride and number of rows (rstep: rs)
    act, ns       per group, the input columns non-zero in some row of the group, in increasing
                  order (G, C), and how many of them there are (G,)
    j, j0         where in a group's act a chain of weight rows starts
    steps, bsz    T steps of B windows (R = T*B)
    per_window    group each window's steps together (else runs of consecutive rows)
"""
from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np

from ..extras import require

numba = require("numba", "metrics", "the Numba inference engine (engine='numba')")
from llvmlite import ir  # noqa: E402
from numba import njit, types  # noqa: E402
from numba.core import cgutils  # noqa: E402
from numba.extending import intrinsic  # noqa: E402

from .numba_codegen import (NARROW, VECTOR_BYTES, by_planes, operands_ok, row_ptr,  # noqa: E402
                            vectors, widen, widen_planes)

#: weight rows each call of the product kernel streams together (a chain of this many fused
#: multiply-adds per accumulator load and store; 8 rows read side by side, each sequentially)
CHAIN = 8
#: input rows that share each weight row read (one window's m = 4 steps at B = 1); the
#: kernels below are instantiated for 1 .. 4 rows
GROUP_ROWS = 4
#: vectors of columns each step of a multi-row kernel's loop computes together, their
#: chains interleaved (independent sums: the multiply-adds overlap; 1.2-1.5x on the feature
#: extractor's products, the same bits)
UNROLL = 2


def padded_columns(n: int, dtype: Any) -> int:
    """``n`` columns rounded up to whole vectors of ``dtype`` (64 bytes)."""
    lanes = VECTOR_BYTES // np.dtype(dtype).itemsize
    return -(-n // lanes) * lanes


def pad_columns(w: np.ndarray, dtype: Any) -> np.ndarray:
    """``w (C, N)`` or ``(N,)`` with zero columns appended up to :func:`padded_columns`, in
    ``dtype``, C-contiguous."""
    n = w.shape[-1]
    out = np.zeros(w.shape[:-1] + (padded_columns(n, dtype),), dtype=dtype)
    out[..., :n] = w
    return out


# ------------------------------------------------------------------ the product kernel

def _columns(builder, k, first, count):
    """``count`` vectors of columns from vector ``first`` in one :func:`_row_kernel` call
    (``k``: the call's values): the weights widened, each row's accumulators loaded, the chains
    interleaved (independent sums, so the multiply-adds overlap), the sums stored."""
    offs = [builder.mul(builder.add(first, ir.Constant(k.intp, u)), ir.Constant(k.intp, k.lanes))
            for u in range(count)]
    ws = [[widen_planes(builder, builder.gep(wr, [builder.mul(off, k.two)]), k.lanes, k.vty,
                         k.fma) if k.planes else
           widen(builder, builder.gep(wr, [off]), k.wdtype, k.welt, k.lanes, k.vty, k.size)
           for wr in k.wrows] for off in offs]
    ptrs = [[builder.bitcast(builder.gep(k.orows[r], [off]), k.vty.as_pointer()) for off in offs]
            for r in range(k.rows)]
    accs = [[builder.load(p, align=k.size) for p in pr] for pr in ptrs]
    for q in range(k.chain):
        for r in range(k.rows):
            for u in range(count):
                accs[r][u] = builder.call(k.fma, [k.avs[r][q], ws[u][q], accs[r][u]])
    for r in range(k.rows):
        for u in range(count):
            builder.store(accs[r][u], ptrs[r][u], align=k.size)


def _stream(builder, k, nvec):
    """The loop of a :func:`_row_kernel` call over its ``nvec`` vectors of columns: one row, a
    vector at a time (its weight loads dominate; pairs measured no faster); more rows,
    :data:`UNROLL` vectors a step (:func:`_columns`), then an odd last one."""
    unroll = UNROLL if k.rows > 1 else 1
    nstep = builder.udiv(nvec, ir.Constant(k.intp, unroll))
    with cgutils.for_range(builder, nstep) as loop:
        _columns(builder, k, builder.mul(loop.index, ir.Constant(k.intp, unroll)), unroll)
    if unroll > 1:
        done = builder.mul(nstep, ir.Constant(k.intp, unroll))
        with cgutils.for_range(builder, builder.sub(nvec, done)) as loop:
            _columns(builder, k, builder.add(done, loop.index), 1)


def _row_kernel(rows: int, chain: int, vbytes: int = VECTOR_BYTES):
    """An intrinsic ``k(x, r0, rstep, w, act, j0, out)``: for the rows ``r = r0 + i * rstep``,
    ``i < rows``, ``out[r, :] = fma(x[r, k_last], w[k_last], ... fma(x[r, k_0], w[k_0], out[r]))``
    over the ``chain`` weight rows ``k = act[j0 .. j0 + chain - 1]`` in that order, every column
    of ``w (C, N)`` (C-contiguous, ``N`` whole 64-byte vectors), ``out`` 2-D with contiguous
    rows. The ``chain`` weight rows are streamed side by side, each sequentially, one vector
    of each per step (two rows or more: :data:`UNROLL` vectors of columns per step, their
    chains interleaved); each accumulator is loaded and stored once per call. bf16 weights of
    twice ``x``'s columns are two planes, each weight a pair (hi, lo) widened into one float32
    (:func:`widen_planes`; decided once per call, outside the loop)."""

    @intrinsic
    def kernel(typingctx, x, r0, rstep, w, act, j0, out):
        if not operands_ok(x, w, out, act):
            return None
        sig = types.void(x, r0, rstep, w, act, j0, out)

        def codegen(context, builder, signature, args):
            xt, wt, at, ot = (signature.args[i] for i in (0, 3, 4, 6))
            xa, wa, aa, oa = (context.make_array(t)(context, builder, v) for t, v in
                              ((xt, args[0]), (wt, args[3]), (at, args[4]), (ot, args[6])))
            r0i, rs, j0i = (context.cast(builder, args[i], signature.args[i], types.intp)
                            for i in (1, 2, 5))
            v = vectors(context, builder, xt.dtype, vbytes)
            elt, size, lanes, vty, intp, fma = v.elt, v.size, v.lanes, v.vty, v.intp, v.fma
            undef, splat = v.undef, v.splat
            welt = context.get_value_type(wt.dtype)
            i32_0 = ir.Constant(ir.IntType(32), 0)
            ncol = builder.extract_value(wa.shape, 1)

            rowi = [builder.add(r0i, builder.mul(rs, ir.Constant(intp, r))) for r in range(rows)]
            xrows = [row_ptr(builder, xa, r, elt) for r in rowi]
            orows = [row_ptr(builder, oa, r, elt) for r in rowi]
            ks = [builder.load(builder.gep(aa.data, [builder.add(j0i, ir.Constant(intp, q))]))
                  for q in range(chain)]
            avs = [[builder.shuffle_vector(builder.insert_element(
                undef, builder.load(builder.gep(xr, [k])), i32_0), undef, splat) for k in ks]
                for xr in xrows]
            nvec = builder.udiv(ncol, ir.Constant(intp, lanes))

            def stream(planes):               # the loop; planes: bf16 pairs, 2N per row
                two = ir.Constant(intp, 2 if planes else 1)
                wrows = [builder.gep(wa.data, [builder.mul(builder.mul(k, ncol), two)])
                         for k in ks]
                _stream(builder, SimpleNamespace(
                    rows=rows, chain=chain, planes=planes, two=two, wrows=wrows, orows=orows,
                    avs=avs, wdtype=wt.dtype, welt=welt, lanes=lanes, vty=vty, size=size,
                    fma=fma, intp=intp), nvec)

            by_planes(builder, wt.dtype, wa, xa, intp, stream)
            return context.get_dummy_value()

        return sig, codegen

    return kernel


#: the row kernels' vectors: 64 bytes where the CPU has 32 registers of them, 32 bytes (one
#: AVX2 register) otherwise, where the interleaved chains of 64-byte vectors spill (the same
#: sums either way: each column's chain is its own)
_ROW_BYTES = 32 if NARROW else VECTOR_BYTES
_KC = tuple(_row_kernel(r, CHAIN, _ROW_BYTES) for r in range(1, GROUP_ROWS + 1))
_K1 = tuple(_row_kernel(r, 1, _ROW_BYTES) for r in range(1, GROUP_ROWS + 1))
_KC1, _KC2, _KC3, _KC4 = _KC
_K11, _K12, _K13, _K14 = _K1


@njit(cache=True, nogil=True, inline="always")
def groups(steps, bsz, per_window):
    """Row groups ``(first, stride, count)`` of ``T*B`` time-major rows (row ``t*B + b``):
    ``per_window``: each window's steps, up to ``GROUP_ROWS`` at a time (a window's steps
    share most of their non-zero inputs); else runs of up to ``GROUP_ROWS`` consecutive rows."""
    if per_window:
        chunks = -(-steps // GROUP_ROWS)
        grp = np.empty((bsz * chunks, 3), dtype=np.intp)
        for b in range(bsz):
            for ci in range(chunks):
                t0 = ci * GROUP_ROWS
                g = b * chunks + ci
                grp[g, 0] = t0 * bsz + b
                grp[g, 1] = bsz
                grp[g, 2] = min(GROUP_ROWS, steps - t0)
    else:
        rows = steps * bsz
        grp = np.empty((-(-rows // GROUP_ROWS), 3), dtype=np.intp)
        for gi in range(grp.shape[0]):
            grp[gi, 0] = gi * GROUP_ROWS
            grp[gi, 1] = 1
            grp[gi, 2] = min(GROUP_ROWS, rows - gi * GROUP_ROWS)
    return grp


@njit(cache=True, nogil=True, inline="always")
def active(x, grp, act, ns):
    """For each row group ``(first, stride, count)`` of ``x (R, C)``, the columns ``k``
    non-zero (or NaN) in some row of the group, in increasing order, into ``act[group]``, and
    how many into ``ns[group]``."""
    for gi in range(grp.shape[0]):
        r0, rs, g = grp[gi, 0], grp[gi, 1], grp[gi, 2]
        a = act[gi]
        n = 0
        for k in range(x.shape[1]):
            for i in range(g):
                if x[r0 + i * rs, k] != 0:
                    a[n] = k
                    n += 1
                    break
        ns[gi] = n


@njit(cache=True, nogil=True, inline="always")
def _chain(x, r0, rs, g, w, act, j, out):
    """:func:`_row_kernel`'s ``CHAIN`` rows ``act[j ..]`` for a group of ``g`` rows."""
    if g == 4:
        _KC4(x, r0, rs, w, act, j, out)
    elif g == 3:
        _KC3(x, r0, rs, w, act, j, out)
    elif g == 2:
        _KC2(x, r0, rs, w, act, j, out)
    else:
        _KC1(x, r0, rs, w, act, j, out)


@njit(cache=True, nogil=True, inline="always")
def _single(x, r0, rs, g, w, act, j, out):
    """:func:`_row_kernel`'s single row ``act[j]`` for a group of ``g`` rows."""
    if g == 4:
        _K14(x, r0, rs, w, act, j, out)
    elif g == 3:
        _K13(x, r0, rs, w, act, j, out)
    elif g == 2:
        _K12(x, r0, rs, w, act, j, out)
    else:
        _K11(x, r0, rs, w, act, j, out)


@njit(cache=True, nogil=True)
def product(x, w, grp, act, ns, out):
    """``out[r] = x[r] @ w`` for every row of ``x (R, C)`` in the groups ``grp``,
    ``w (C, N)``, ``out (R, N)``: each group streams the weight rows of its own non-zero inputs
    (:func:`active`'s ``act``, ``ns``), ``CHAIN`` at a time, in increasing order, every
    column's sum one chain of fused multiply-adds from +0."""
    for gi in range(grp.shape[0]):
        r0, rs, g = grp[gi, 0], grp[gi, 1], grp[gi, 2]
        for i in range(g):
            out[r0 + i * rs, :] = 0
        a, n = act[gi], ns[gi]
        j = 0
        while j + CHAIN <= n:
            _chain(x, r0, rs, g, w, a, j, out)
            j += CHAIN
        while j < n:
            _single(x, r0, rs, g, w, a, j, out)
            j += 1


__all__ = ["CHAIN", "GROUP_ROWS", "padded_columns", "pad_columns", "groups", "active", "product"]
