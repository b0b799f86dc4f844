"""The Numba engine's product kernels: ``x @ w`` reading only the weight rows that a non-zero
input multiplies, each output one chain of fused multiply-adds
(:mod:`tpnet_ref.engines.numba_engine` says why and how); shared by the prediction network's
kernels (:mod:`tpnet_ref.engines.numba_lstm`) and the feature extractor's
(:mod:`tpnet_ref.engines.numba_features`). Two ways to compute the same chains: the row kernel
(:func:`product`: weight rows streamed side by side, sums loaded and stored once per chain of
:data:`CHAIN` rows; a window's products, which read each weight once) and the tile kernel
(:func:`tiled_product`, :func:`product_rows`: a few rows by a few vectors of columns whose sums
stay in registers for the whole chain; the per-point layers and batches, which reuse each
weight across rows). numba's cache keys a compiled kernel to its own
file's time stamp: after editing this file, delete the other two modules' cached kernels
(``tpnet_ref/engines/__pycache__/numba_*``), which inline these.

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
_VECTOR_BYTES = 64


def padded_columns(n: int, dtype: Any) -> int:
    """``n`` columns rounded up to whole vectors of ``dtype`` (64 bytes)."""
    lanes = _VECTOR_BYTES // np.dtype(dtype).itemsize
    return -(-n // lanes) * lanes


def pad_columns(w: np.ndarray, dtype: Any) -> np.ndarray:
    """``w (C, N)`` or ``(N,)`` with zero columns appended up to :func:`padded_columns`, in
    ``dtype``, C-contiguous."""
    n = w.shape[-1]
    out = np.zeros(w.shape[:-1] + (padded_columns(n, dtype),), dtype=dtype)
    out[..., :n] = w
    return out


# ------------------------------------------------------------------ the product kernel

#: weights of fewer bits the float32 kernels read (:mod:`tpnet_ref.engines.numba_quant`): int8
#: (symmetric, a float32 scale per output column applied after the sum) and bf16 (stored as
#: its uint16 bits), each widened to float32 in registers
_CODES = (types.int8, types.uint16)


def _widen(builder, ptr, wdtype, welt, lanes, vty, size):
    """One vector of ``lanes`` weights at ``ptr`` as float32 lanes ``vty``: float weights
    loaded as they are; int8 sign-extended and converted (exact: |q| <= 127); bf16 bits
    shifted into a float32's high half (exact)."""
    if wdtype not in _CODES:
        return builder.load(builder.bitcast(ptr, vty.as_pointer()), align=size)
    raw = builder.load(builder.bitcast(ptr, ir.VectorType(welt, lanes).as_pointer()),
                       align=wdtype.bitwidth // 8)
    if wdtype == types.int8:
        return builder.sitofp(raw, vty)
    i32 = ir.VectorType(ir.IntType(32), lanes)
    wide = builder.shl(builder.zext(raw, i32), ir.Constant(i32, [16] * lanes))
    return builder.bitcast(wide, vty)


def _widen_planes(builder, ptr, lanes, vty, fma):
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


def _columns(builder, k, first, count):
    """``count`` vectors of columns from vector ``first`` in one :func:`_row_kernel` call
    (``k``: the call's values): the weights widened, each row's accumulators loaded, the chains
    interleaved (independent sums, so the multiply-adds overlap), the sums stored."""
    offs = [builder.mul(builder.add(first, ir.Constant(k.intp, u)), ir.Constant(k.intp, k.lanes))
            for u in range(count)]
    ws = [[_widen_planes(builder, builder.gep(wr, [builder.mul(off, k.two)]), k.lanes, k.vty,
                         k.fma) if k.planes else
           _widen(builder, builder.gep(wr, [off]), k.wdtype, k.welt, k.lanes, k.vty, k.size)
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


def _operands_ok(x, w, out, act) -> bool:
    """Whether a kernel's typed operands fit it: 2-D arrays, ``x`` and ``out`` of one float
    dtype, ``w`` C-contiguous of that dtype or (float32 ``x``) of :data:`_CODES`, ``act`` an
    array."""
    return (isinstance(x, types.Array) and isinstance(w, types.Array)
            and isinstance(out, types.Array) and x.ndim == w.ndim == out.ndim == 2
            and x.dtype == out.dtype and w.layout == "C"
            and (w.dtype == x.dtype or (x.dtype == types.float32 and w.dtype in _CODES))
            and isinstance(x.dtype, types.Float) and isinstance(act, types.Array))


def _vectors(context, builder, dtype):
    """The codegen's common values for float ``dtype``: a namespace of ``elt`` (its LLVM type),
    ``size`` (bytes), ``lanes`` (per 64-byte vector), ``vty`` (the vector type), ``intp``,
    ``fma`` (``llvm.fma`` on vectors), ``undef`` and ``splat`` (a broadcast's operands)."""
    elt = context.get_value_type(dtype)
    size = dtype.bitwidth // 8
    lanes = _VECTOR_BYTES // size
    vty = ir.VectorType(elt, lanes)
    return SimpleNamespace(
        elt=elt, size=size, lanes=lanes, vty=vty, intp=context.get_value_type(types.intp),
        fma=cgutils.get_or_insert_function(builder.module, ir.FunctionType(vty, [vty] * 3),
                                           f"llvm.fma.v{lanes}f{size * 8}"),
        undef=ir.Constant(vty, ir.Undefined),
        splat=ir.Constant(ir.VectorType(ir.IntType(32), lanes), [0] * lanes))


def _row_ptr(builder, arr, row, elt):
    """Element pointer of ``arr[row, 0]`` (a 2-D array's struct; byte strides)."""
    stride = builder.extract_value(arr.strides, 0)
    p = builder.gep(builder.bitcast(arr.data, ir.IntType(8).as_pointer()),
                    [builder.mul(row, stride)])
    return builder.bitcast(p, elt.as_pointer())


def _by_planes(builder, wdtype, wa, xa, intp, emit):
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


def _row_kernel(rows: int, chain: int):
    """An intrinsic ``k(x, r0, rstep, w, act, j0, out)``: for the rows ``r = r0 + i * rstep``,
    ``i < rows``, ``out[r, :] = fma(x[r, k_last], w[k_last], ... fma(x[r, k_0], w[k_0], out[r]))``
    over the ``chain`` weight rows ``k = act[j0 .. j0 + chain - 1]`` in that order, every column
    of ``w (C, N)`` (C-contiguous, ``N`` whole 64-byte vectors), ``out`` 2-D with contiguous
    rows. The ``chain`` weight rows are streamed side by side, each sequentially, one vector
    of each per step (two rows or more: :data:`UNROLL` vectors of columns per step, their
    chains interleaved); each accumulator is loaded and stored once per call. bf16 weights of
    twice ``x``'s columns are two planes, each weight a pair (hi, lo) widened into one float32
    (:func:`_widen_planes`; decided once per call, outside the loop)."""

    @intrinsic
    def kernel(typingctx, x, r0, rstep, w, act, j0, out):
        if not _operands_ok(x, w, out, act):
            return None
        sig = types.void(x, r0, rstep, w, act, j0, out)

        def codegen(context, builder, signature, args):
            xt, wt, at, ot = (signature.args[i] for i in (0, 3, 4, 6))
            xa, wa, aa, oa = (context.make_array(t)(context, builder, v) for t, v in
                              ((xt, args[0]), (wt, args[3]), (at, args[4]), (ot, args[6])))
            r0i, rs, j0i = (context.cast(builder, args[i], signature.args[i], types.intp)
                            for i in (1, 2, 5))
            v = _vectors(context, builder, xt.dtype)
            elt, size, lanes, vty, intp, fma = v.elt, v.size, v.lanes, v.vty, v.intp, v.fma
            undef, splat = v.undef, v.splat
            welt = context.get_value_type(wt.dtype)
            i32_0 = ir.Constant(ir.IntType(32), 0)
            ncol = builder.extract_value(wa.shape, 1)

            def row_ptr(arr, row):
                return _row_ptr(builder, arr, row, elt)

            rowi = [builder.add(r0i, builder.mul(rs, ir.Constant(intp, r))) for r in range(rows)]
            xrows = [row_ptr(xa, r) for r in rowi]
            orows = [row_ptr(oa, r) for r in rowi]
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

            _by_planes(builder, wt.dtype, wa, xa, intp, stream)
            return context.get_dummy_value()

        return sig, codegen

    return kernel


_KC = tuple(_row_kernel(r, CHAIN) for r in range(1, GROUP_ROWS + 1))
_K1 = tuple(_row_kernel(r, 1) for r in range(1, GROUP_ROWS + 1))
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


@njit(cache=True, nogil=True)
def project_dir(x, kern, out, steps, bsz):
    """One direction's product ``out = x @ kern`` (no bias) for the ``T*B`` time-major rows of
    ``x``, each window's steps in groups reading only the kernel rows of their non-zero inputs
    (batches of :data:`TILE_BATCH` windows or more: :func:`product_rows`' tiles)."""
    if bsz >= TILE_BATCH:
        product_rows(x[:, :], kern, np.empty(x.shape[1], dtype=np.intp), out)
        return
    grp = groups(steps, bsz, True)
    act = np.empty((grp.shape[0], x.shape[1]), dtype=np.intp)
    ns = np.empty(grp.shape[0], dtype=np.intp)
    active(x[:, :], grp, act, ns)        # [:, :]: every call of product one layout
    product(x[:, :], kern, grp, act, ns, out)


# ------------------------------------------------------------------ the tile kernel

#: the feature extractor's tiles (:func:`tiled_product`): rows of points x vectors of columns
#: whose sums stay in registers over the whole chain (8 x 1 and 8 x 2 for layers of one or two
#: vectors, 4 x 4 and a remainder of 1-3 vectors beside them for wider ones)
TILE_ROWS = 8
#: layers of at least this many vectors of columns read only the weight rows of each 4-row
#: tile's non-zero inputs (narrower ones every row: there, finding them costs what it saves)
TILE_SPARSE_FROM = 4


def _tile_loop(builder, k, planes):
    """The loop of a :func:`_tile_kernel` call (``k``: the call's values): ``k.rows x k.vecs``
    sums in phi nodes, one step per input ``act[j]`` (its weight vectors widened, each row's
    input broadcast), then every sum stored. ``planes``: bf16 pairs, 2N codes per row."""
    intp, vty, lanes, rows, vecs = k.intp, k.vty, k.lanes, k.rows, k.vecs
    two = ir.Constant(intp, 2 if planes else 1)
    wbase = builder.gep(k.wdata, [builder.mul(k.coff, two)])
    pre = builder.basic_block
    loop = builder.append_basic_block("tile.loop")
    after = builder.append_basic_block("tile.after")
    builder.cbranch(builder.icmp_signed(">", k.nk, ir.Constant(intp, 0)), loop, after)
    builder.position_at_end(loop)
    j = builder.phi(intp)
    sums = [[builder.phi(vty) for _ in range(vecs)] for _ in range(rows)]
    kk = builder.load(builder.gep(k.adata, [j]))
    wrow = builder.gep(wbase, [builder.mul(builder.mul(kk, k.ncol), two)])
    wptr = [builder.gep(wrow, [ir.Constant(intp, v * lanes * (2 if planes else 1))])
            for v in range(vecs)]
    wv = [_widen_planes(builder, ptr, lanes, vty, k.fma) if planes else
          _widen(builder, ptr, k.wdtype, k.welt, lanes, vty, k.size) for ptr in wptr]
    new = []
    for r in range(rows):
        xv = builder.shuffle_vector(builder.insert_element(
            k.undef, builder.load(builder.gep(k.xrows[r], [kk])),
            ir.Constant(ir.IntType(32), 0)), k.undef, k.splat)
        new.append([builder.call(k.fma, [xv, wv[v], sums[r][v]]) for v in range(vecs)])
    jn = builder.add(j, ir.Constant(intp, 1))
    end = builder.basic_block
    j.add_incoming(ir.Constant(intp, 0), pre)
    j.add_incoming(jn, end)
    for r in range(rows):
        for v in range(vecs):
            sums[r][v].add_incoming(k.zero, pre)
            sums[r][v].add_incoming(new[r][v], end)
    builder.cbranch(builder.icmp_signed("<", jn, k.nk), loop, after)
    builder.position_at_end(after)
    final = [[builder.phi(vty) for _ in range(vecs)] for _ in range(rows)]
    for r in range(rows):
        for v in range(vecs):
            final[r][v].add_incoming(k.zero, pre)
            final[r][v].add_incoming(new[r][v], end)
    for r in range(rows):
        for v in range(vecs):
            builder.store(final[r][v], builder.bitcast(
                builder.gep(k.orows[r], [ir.Constant(intp, v * lanes)]), vty.as_pointer()),
                align=k.size)


def _tile_kernel(rows: int, vecs: int):
    """An intrinsic ``t(x, r0, w, c0, out, act, n)``: for the rows ``r0 .. r0 + rows - 1`` and
    the vectors of columns ``c0 .. c0 + vecs - 1``, ``out[r] = fma(x[r, k_last], w[k_last],
    ... fma(x[r, k_0], w[k_0], +0))`` over ``k = act[0 .. n-1]`` in that order; the
    ``rows * vecs`` sums are held in registers for the whole chain (phi nodes), the weights
    and ``x`` read once per step, every sum stored once. The same chain as
    :func:`_row_kernel`'s, so the same bits for the same ``k`` (and a ``k`` whose input is 0
    adds ``fma(0, w, s) = s`` exactly); weights of fewer bits widened as there (:func:`_widen`,
    bf16's two planes by :func:`_widen_planes`, decided once per call, outside the loop)."""

    @intrinsic
    def kernel(typingctx, x, r0, w, c0, out, act, n):
        if not _operands_ok(x, w, out, act):
            return None
        sig = types.void(x, r0, w, c0, out, act, n)
        wdtype = w.dtype

        def codegen(context, builder, signature, args):
            xa, wa, oa, aa = (context.make_array(signature.args[i])(context, builder, args[i])
                              for i in (0, 2, 4, 5))
            r0i, c0i, nk = (context.cast(builder, args[i], signature.args[i], types.intp)
                            for i in (1, 3, 6))
            k = _vectors(context, builder, signature.args[0].dtype)
            rowi = [builder.add(r0i, ir.Constant(k.intp, r)) for r in range(rows)]
            k.coff = builder.mul(c0i, ir.Constant(k.intp, k.lanes))
            k.zero = ir.Constant(k.vty, [0.0] * k.lanes)
            k.xrows = [_row_ptr(builder, xa, r, k.elt) for r in rowi]
            k.orows = [builder.gep(_row_ptr(builder, oa, r, k.elt), [k.coff]) for r in rowi]
            k.rows, k.vecs, k.nk, k.wdtype = rows, vecs, nk, wdtype
            k.wdata, k.adata = wa.data, aa.data
            k.ncol = builder.extract_value(wa.shape, 1)
            k.welt = context.get_value_type(wdtype)
            _by_planes(builder, wdtype, wa, xa, k.intp,
                       lambda planes: _tile_loop(builder, k, planes))
            return context.get_dummy_value()

        return sig, codegen

    return kernel


_T81, _T82, _T41, _T42, _T43, _T44 = (_tile_kernel(r, v) for r, v in
                                       ((8, 1), (8, 2), (4, 1), (4, 2), (4, 3), (4, 4)))


@njit(cache=True, nogil=True, inline="always")
def _tile_row(x, r0, w, nvec, out, act, n):
    """:func:`_tile_kernel`'s 4-row tiles across all ``nvec`` vectors of columns."""
    c = 0
    while c + 4 <= nvec:
        _T44(x, r0, w, c, out, act, n)
        c += 4
    rem = nvec - c
    if rem == 3:
        _T43(x, r0, w, c, out, act, n)
    elif rem == 2:
        _T42(x, r0, w, c, out, act, n)
    elif rem == 1:
        _T41(x, r0, w, c, out, act, n)


@njit(cache=True, nogil=True, inline="always")
def _nonzero4(x, r0, act):
    """The columns ``k`` non-zero (or NaN) in some row ``r0 .. r0 + 3`` of ``x``, in increasing
    order, into ``act``; returns how many."""
    n = 0
    for k in range(x.shape[1]):
        for i in range(4):
            if x[r0 + i, k] != 0:
                act[n] = k
                n += 1
                break
    return n


@njit(cache=True, nogil=True)
def tiled_product(x, w, rows, act, out):
    """``out[r] = x[r] @ w`` for the rows ``r < rows`` rounded up to :data:`TILE_ROWS` (``x``
    and ``out`` must have them; rows past ``rows`` are computed from whatever they hold and
    mean nothing), ``w (C, N)`` C-contiguous, N whole 64-byte vectors; ``act``: work array of
    ``C`` indices. Every sum is one chain of fused multiply-adds from +0 over the inputs in
    increasing order (layers of :data:`TILE_SPARSE_FROM` vectors or more: only each 4-row
    tile's non-zero inputs), the chain :func:`product` computes: the same bits."""
    c = x.shape[1]
    nvec = w.shape[1] * x.itemsize // _VECTOR_BYTES
    top = -(-rows // TILE_ROWS) * TILE_ROWS
    if nvec < TILE_SPARSE_FROM:
        for k in range(c):
            act[k] = k
    if nvec == 1 or nvec == 2:
        for r0 in range(0, top, 8):
            if nvec == 1:
                _T81(x, r0, w, 0, out, act, c)
            else:
                _T82(x, r0, w, 0, out, act, c)
        return
    for r0 in range(0, top, 4):
        n = _nonzero4(x, r0, act) if nvec >= TILE_SPARSE_FROM else c
        _tile_row(x, r0, w, nvec, out, act, n)


#: batches of at least this many windows take :func:`product_rows` in the prediction network
#: (tiles of 4 rows across windows; below, each window's steps stream the weight rows together)
TILE_BATCH = 2


@njit(cache=True, nogil=True)
def product_rows(x, w, act, out):
    """``out[r] = x[r] @ w`` for every row of ``x (R, C)``: whole 4-row tiles by
    :func:`_tile_kernel` (each reading only the weight rows of its rows' non-zero inputs, the
    sums in registers), the last ``R % 4`` rows by :func:`product`; every sum the chain
    :func:`product` computes, so the same bits. ``w`` float or codes (as :func:`product`);
    ``act``: work array of ``C`` indices."""
    rows = x.shape[0]
    c = x.shape[1]
    nvec = w.shape[1] * x.itemsize // _VECTOR_BYTES
    full = rows - rows % 4
    for r0 in range(0, full, 4):
        n = _nonzero4(x, r0, act)
        _tile_row(x, r0, w, nvec, out, act, n)
    if full < rows:
        grp = np.empty((1, 3), dtype=np.intp)
        grp[0, 0], grp[0, 1], grp[0, 2] = full, 1, rows - full
        ns = np.empty(1, dtype=np.intp)
        rest = np.empty((1, c), dtype=np.intp)
        active(x, grp, rest, ns)
        product(x, w, grp, rest, ns, out)


__all__ = ["CHAIN", "GROUP_ROWS", "TILE_ROWS", "TILE_SPARSE_FROM", "TILE_BATCH", "tiled_product",
           "product_rows", "padded_columns", "pad_columns", "groups", "active", "product",
           "project_dir"]
