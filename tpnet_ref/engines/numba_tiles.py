"""The Numba engine's tile kernels: ``x @ w`` for a few rows by a few vectors of columns whose
sums stay in registers for the whole chain (:func:`tiled_product`: the feature extractor's
per-point layers; :func:`product_rows`: the prediction network's products for batches; both
reuse each weight across rows), each sum the chain of fused multiply-adds that
:func:`tpnet_ref.engines.numba_products.product` computes, so the same bits; and
:func:`project_dir`, which of the two a direction's input product takes. The tiles' shape
follows the CPU's registers (:data:`tpnet_ref.engines.numba_codegen.TILE_PLAN`). numba's cache
keys a compiled kernel to its own file's time stamp: after editing this file or the two below
it, delete the cached kernels that inline these (``tpnet_ref/engines/__pycache__/numba_*``).

Argument names as in :mod:`tpnet_ref.engines.numba_products`; ``narrow``: the narrow plan's
tiles (the same sums).
"""
from __future__ import annotations

import numpy as np

from ..extras import require

numba = require("numba", "metrics", "the Numba inference engine (engine='numba')")
from llvmlite import ir  # noqa: E402
from numba import njit, types  # noqa: E402
from numba.extending import intrinsic  # noqa: E402

from .numba_codegen import (NARROW, VECTOR_BYTES, by_planes, operands_ok, row_ptr,  # noqa: E402
                            vectors, widen, widen_planes)
from .numba_products import active, groups, product  # noqa: E402

#: the feature extractor's tiles (:func:`tiled_product`): rows of points x vectors of columns
#: whose sums stay in registers over the whole chain (the wide plan: 8 x 1 and 8 x 2 for layers
#: of one or two 64-byte vectors, 4 x 4 and a remainder of 1-3 vectors beside them for wider
#: ones; the narrow plan: 4 x 2 of 32-byte vectors, and one beside them); rows are computed in
#: multiples of this many
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
    wv = [widen_planes(builder, ptr, lanes, vty, k.fma) if planes else
          widen(builder, ptr, k.wdtype, k.welt, lanes, vty, k.size) for ptr in wptr]
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


def _tile_kernel(rows: int, vecs: int, vbytes: int = VECTOR_BYTES):
    """An intrinsic ``t(x, r0, w, c0, out, act, n)``: for the rows ``r0 .. r0 + rows - 1`` and
    the vectors of columns ``c0 .. c0 + vecs - 1``, ``out[r] = fma(x[r, k_last], w[k_last],
    ... fma(x[r, k_0], w[k_0], +0))`` over ``k = act[0 .. n-1]`` in that order; the
    ``rows * vecs`` sums are held in registers for the whole chain (phi nodes), the weights
    and ``x`` read once per step, every sum stored once. The same chain as
    :func:`_row_kernel`'s, so the same bits for the same ``k`` (and a ``k`` whose input is 0
    adds ``fma(0, w, s) = s`` exactly); weights of fewer bits widened as there (:func:`_widen`,
    bf16's two planes by :func:`widen_planes`, decided once per call, outside the loop)."""

    @intrinsic
    def kernel(typingctx, x, r0, w, c0, out, act, n):
        if not operands_ok(x, w, out, act):
            return None
        sig = types.void(x, r0, w, c0, out, act, n)
        wdtype = w.dtype

        def codegen(context, builder, signature, args):
            xa, wa, oa, aa = (context.make_array(signature.args[i])(context, builder, args[i])
                              for i in (0, 2, 4, 5))
            r0i, c0i, nk = (context.cast(builder, args[i], signature.args[i], types.intp)
                            for i in (1, 3, 6))
            k = vectors(context, builder, signature.args[0].dtype, vbytes)
            rowi = [builder.add(r0i, ir.Constant(k.intp, r)) for r in range(rows)]
            k.coff = builder.mul(c0i, ir.Constant(k.intp, k.lanes))
            k.zero = ir.Constant(k.vty, [0.0] * k.lanes)
            k.xrows = [row_ptr(builder, xa, r, k.elt) for r in rowi]
            k.orows = [builder.gep(row_ptr(builder, oa, r, k.elt), [k.coff]) for r in rowi]
            k.rows, k.vecs, k.nk, k.wdtype = rows, vecs, nk, wdtype
            k.wdata, k.adata = wa.data, aa.data
            k.ncol = builder.extract_value(wa.shape, 1)
            k.welt = context.get_value_type(wdtype)
            by_planes(builder, wdtype, wa, xa, k.intp,
                       lambda planes: _tile_loop(builder, k, planes))
            return context.get_dummy_value()

        return sig, codegen

    return kernel


_T81, _T82, _T41, _T42, _T43, _T44 = (_tile_kernel(r, v) for r, v in
                                       ((8, 1), (8, 2), (4, 1), (4, 2), (4, 3), (4, 4)))


#: the narrow plan's tiles, for CPUs of 16 vector registers (AVX2): 4 rows x 2 vectors of 32
#: bytes keep their 8 sums, 2 weight vectors and 4 broadcasts in registers, where the wide
#: plan's 4 x 4 tile of 64-byte vectors (16 sums of two registers each) spills to the stack
_N41, _N42 = (_tile_kernel(4, v, 32) for v in (1, 2))


@njit(cache=True, nogil=True, inline="always")
def _tile_row_narrow(x, r0, w, nvec, out, act, n):
    """:func:`_tile_kernel`'s 4-row tiles of 32-byte vectors across all ``nvec`` 64-byte
    vectors of columns."""
    nv = 2 * nvec
    c = 0
    while c + 2 <= nv:
        _N42(x, r0, w, c, out, act, n)
        c += 2
    if c < nv:
        _N41(x, r0, w, c, out, act, n)


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
def _tile_row_in(x, r0, w, nvec, out, act, n, narrow):
    """The 4-row tiles of the plan ``narrow`` says (:func:`_tile_row_narrow`, else
    :func:`_tile_row`)."""
    if narrow:
        _tile_row_narrow(x, r0, w, nvec, out, act, n)
    else:
        _tile_row(x, r0, w, nvec, out, act, n)


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
    """:func:`tiled_plan` in this CPU's plan
    (:data:`tpnet_ref.engines.numba_codegen.TILE_PLAN`; the other plan's tiles are not
    compiled here: ``NARROW`` is a constant)."""
    _tiled(x, w, rows, act, out, NARROW)


@njit(cache=True, nogil=True)
def tiled_plan(x, w, rows, act, out, narrow):
    """:func:`tiled_product` in the plan ``narrow`` says (either, for the tests)."""
    _tiled(x, w, rows, act, out, narrow)


@njit(cache=True, nogil=True, inline="always")
def _tiled(x, w, rows, act, out, narrow):
    """``out[r] = x[r] @ w`` for the rows ``r < rows`` rounded up to :data:`TILE_ROWS` (``x``
    and ``out`` must have them; rows past ``rows`` are computed from whatever they hold and
    mean nothing), ``w (C, N)`` C-contiguous, N whole 64-byte vectors; ``act``: work array of
    ``C`` indices. Every sum is one chain of fused multiply-adds from +0 over the inputs in
    increasing order (layers of :data:`TILE_SPARSE_FROM` vectors or more: only each 4-row
    tile's non-zero inputs), the chain :func:`product` computes: the same bits in either plan
    (``narrow``: the narrow plan's tiles, else the wide plan's)."""
    c = x.shape[1]
    nvec = w.shape[1] * x.itemsize // VECTOR_BYTES
    top = -(-rows // TILE_ROWS) * TILE_ROWS
    if nvec < TILE_SPARSE_FROM:
        for k in range(c):
            act[k] = k
    if not narrow and (nvec == 1 or nvec == 2):   # the wide plan's 8-row tiles
        for r0 in range(0, top, 8):
            if nvec == 1:
                _T81(x, r0, w, 0, out, act, c)
            else:
                _T82(x, r0, w, 0, out, act, c)
        return
    for r0 in range(0, top, 4):
        n = _nonzero4(x, r0, act) if nvec >= TILE_SPARSE_FROM else c
        _tile_row_in(x, r0, w, nvec, out, act, n, narrow)


#: batches of at least this many windows take :func:`product_rows` in the prediction network
#: (tiles of 4 rows across windows; below, each window's steps stream the weight rows together)
TILE_BATCH = 2


@njit(cache=True, nogil=True)
def product_rows(x, w, act, out):
    """:func:`rows_plan` in this CPU's plan (only its tiles compiled, as :func:`tiled_product`)."""
    _rows(x, w, act, out, NARROW)


@njit(cache=True, nogil=True)
def rows_plan(x, w, act, out, narrow):
    """:func:`product_rows` in the plan ``narrow`` says (either, for the tests)."""
    _rows(x, w, act, out, narrow)


@njit(cache=True, nogil=True, inline="always")
def _rows(x, w, act, out, narrow):
    """``out[r] = x[r] @ w`` for every row of ``x (R, C)``: whole 4-row tiles by
    :func:`_tile_kernel` (each reading only the weight rows of its rows' non-zero inputs, the
    sums in registers), the last ``R % 4`` rows by :func:`product`; every sum the chain
    :func:`product` computes, so the same bits in either plan. ``w`` float or codes (as
    :func:`product`); ``act``: work array of ``C`` indices."""
    rows = x.shape[0]
    c = x.shape[1]
    nvec = w.shape[1] * x.itemsize // VECTOR_BYTES
    full = rows - rows % 4
    for r0 in range(0, full, 4):
        _tile_row_in(x, r0, w, nvec, out, act, _nonzero4(x, r0, act), narrow)
    if full < rows:
        grp = np.empty((1, 3), dtype=np.intp)
        grp[0, 0], grp[0, 1], grp[0, 2] = full, 1, rows - full
        ns = np.empty(1, dtype=np.intp)
        rest = np.empty((1, c), dtype=np.intp)
        active(x, grp, rest, ns)
        product(x, w, grp, rest, ns, out)


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


__all__ = ["TILE_ROWS", "TILE_SPARSE_FROM", "TILE_BATCH", "tiled_product", "tiled_plan",
           "product_rows", "rows_plan", "project_dir"]
