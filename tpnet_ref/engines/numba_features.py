"""The Numba engine's feature extractor: each frame's points through the per-point MLP (the
products by :func:`tpnet_ref.engines.numba_tiles.tiled_product`), their max, the global layer;
:class:`tpnet_ref.engines.numba_engine.NumbaFeatures` calls them.

Argument names (every kernel below)::

    pts           the frames' points (P, dim), frame after frame, model coordinates, each frame
                  in canonical order
    starts, counts  each frame's first point and number of points (F,)
    f0, f1        the frames f0 .. f1-1 to compute; f: one frame's row of out
    p0, p1        the points p0 .. p1-1 of one frame (or of half of one)
    w0, b0        the first per-point layer (dim, C0), (C0,)
    ws, bs        the later per-point layers' weights and biases (tuples; each weight's rows
                  padded to the previous layer's padded width)
    bl            the last per-point layer's bias, added after the max
    gw, gb        the global layer
    pool          the running max over a frame's points (1, C)
    pools, nf     frames' maxes (a row each), nf of them
    out           the global features (F, k)
    zero          0 in the model's dtype
    dst, src, n   _max_into's rows and length
"""
from __future__ import annotations

import numpy as np

from ..extras import require

numba = require("numba", "metrics", "the Numba inference engine (engine='numba')")
from numba import njit, prange  # noqa: E402

from .numba_tiles import TILE_ROWS, tiled_product  # noqa: E402

#: points of a frame that go through the per-point layers together (their activations stay in
#: cache; a frame's max is taken over its chunks, exact whatever the cut); a multiple of
#: :data:`tpnet_ref.engines.numba_tiles.TILE_ROWS`
FEATURE_CHUNK = 64
assert FEATURE_CHUNK % TILE_ROWS == 0


@njit(cache=True, nogil=True, inline="always")
def _max_into(dst, src, n):
    """``dst[j] = max(dst[j], src[j])`` for ``j < n``, NaN kept (once NaN, NaN stays);
    branch-free, so it vectorises."""
    for j in range(n):
        v = src[j]
        p = dst[j]
        dst[j] = v if (v > p) | (v != v) else p


@njit(cache=True, nogil=True, inline="always")
def _scratch(ws, c0, dt):
    """The work arrays of :func:`_pool_points` (two activation blocks; the inputs a tile
    reads), made once per call of a kernel below, not per frame."""
    cmax = c0
    for li in range(len(ws)):
        cmax = max(cmax, ws[li].shape[1])
    a = np.empty((FEATURE_CHUNK, cmax), dtype=dt)
    b = np.empty((FEATURE_CHUNK, cmax), dtype=dt)
    act = np.empty(cmax, dtype=np.intp)
    return a, b, act


@njit(cache=True, nogil=True, error_model="numpy")
def _pool_points(pts, p0, p1, w0, b0, ws, bs, zero, pool, a, b, act):
    """The max over the points ``pts[p0:p1]`` of the per-point MLP's last products (before its
    bias and ReLU) into ``pool (1, C)`` (NaN kept: once NaN, NaN stays). The first layer
    ``w0 (dim, C0)`` directly; every later one (``ws``, ``bs``) by :func:`tiled_product`
    (tiles of points whose sums stay in registers; wide layers read only the weight rows of
    each tile's non-zero inputs), ReLU after each but the last. Points go through in chunks of
    :data:`FEATURE_CHUNK`; each point's numbers do not depend on the others, and a max does not
    depend on the order, so neither does ``pool``. ``a, b, act``: :func:`_scratch`'s work
    arrays."""
    nl = len(ws)
    c0 = w0.shape[1]
    dim = w0.shape[0]
    chunk = FEATURE_CHUNK
    cl = ws[nl - 1].shape[1]
    for q0 in range(p0, p1, chunk):
        r = min(chunk, p1 - q0)
        top = -(-r // TILE_ROWS) * TILE_ROWS      # the tiles' rows: past r, a point of zeros
        for i in range(r):
            for j in range(c0):
                v = zero
                for d in range(dim):
                    v += pts[q0 + i, d] * w0[d, j]
                v += b0[j]
                a[i, j] = zero if v < zero else v
        for i in range(r, top):
            for j in range(c0):
                a[i, j] = zero
        cur, nxt, cin = a, b, c0
        for li in range(nl):
            cw = ws[li].shape[1]
            tiled_product(cur[:, :cin], ws[li], r, act, nxt[:, :cw])
            if li < nl - 1:
                bb = bs[li]
                for i in range(top):          # nxt itself, not a slice: contiguous, vectorises
                    for j in range(cw):
                        v = nxt[i, j] + bb[j]
                        nxt[i, j] = zero if v < zero else v
            cur, nxt, cin = nxt, cur, cw
        i0 = 0
        if q0 == p0:
            for j in range(cl):               # a loop, not a slice copy (as in _recur_dir)
                pool[0, j] = cur[0, j]
            i0 = 1
        for i in range(i0, r):
            _max_into(pool[0], cur[i], cl)


@njit(cache=True, nogil=True, error_model="numpy")
def _finish_frames(pools, nf, bl, gw, gb, zero, out, f0, act, g):
    """``out[f0 + i] = relu(relu(pools[i] + bl) @ gw + gb)`` for ``i < nf``: the MLP's last
    bias and ReLU after the max (as :func:`tpnet_ref.engines.layers.mlp_max`: the same numbers),
    then the global layer, the frames together in tiles (:func:`tiled_product`; ``pools`` and
    ``g`` have ``nf`` rows rounded up to whole tiles, those past ``nf`` made zeros here).
    ``act``: the inputs a tile reads."""
    cl = pools.shape[1]
    top = -(-nf // TILE_ROWS) * TILE_ROWS
    for i in range(top):
        for j in range(cl):
            v = pools[i, j] + bl[j] if i < nf else zero
            pools[i, j] = zero if v < zero else v
    tiled_product(pools, gw, nf, act, g)
    for i in range(nf):
        for j in range(gw.shape[1]):
            v = g[i, j] + gb[j]
            out[f0 + i, j] = zero if v < zero else v


@njit(cache=True, nogil=True, error_model="numpy")
def frame_range(pts, starts, counts, f0, f1, w0, b0, ws, bs, gw, gb, zero, out):
    """The global feature of frames ``f0 .. f1-1`` into ``out[f]``: frame ``f`` is the points
    ``pts[starts[f] : starts[f] + counts[f]]`` (model coordinates, canonical order)."""
    nl = len(ws)
    cl = ws[nl - 1].shape[1]
    top = -(-(f1 - f0) // TILE_ROWS) * TILE_ROWS
    pools = np.empty((top, cl), dtype=pts.dtype)
    g = np.empty((top, gw.shape[1]), dtype=pts.dtype)
    a, b, act = _scratch(ws, w0.shape[1], pts.dtype)
    for f in range(f0, f1):
        _pool_points(pts, starts[f], starts[f] + counts[f], w0, b0, ws, bs, zero,
                     pools[f - f0:f - f0 + 1], a, b, act)
    _finish_frames(pools, f1 - f0, bs[nl - 1], gw, gb, zero, out, f0, act, g)


@njit(cache=True, nogil=True, parallel=True)
def features_parallel(pts, starts, counts, w0, b0, ws, bs, gw, gb, zero, out):
    """:func:`frame_range` of every frame on two threads: two frames or more, in two halves; one
    frame (a rollout's new frame), its points in two halves, whose maxes are then combined
    (exact: a max of the same numbers, NaN kept)."""
    nf = counts.shape[0]
    if nf > 1:
        half = (nf + 1) // 2
        for h in prange(2):
            frame_range(pts, starts, counts, h * half, min(nf, (h + 1) * half), w0, b0, ws,
                         bs, gw, gb, zero, out)
        return
    nl = len(ws)
    n = counts[0]
    mid = starts[0] + (n + 1) // 2
    cl = ws[nl - 1].shape[1]
    pools = np.empty((2, TILE_ROWS, cl), dtype=pts.dtype)
    for h in prange(2):
        a, b, act = _scratch(ws, w0.shape[1], pts.dtype)
        if h == 0:
            _pool_points(pts, starts[0], mid, w0, b0, ws, bs, zero, pools[0, 0:1], a, b, act)
        else:
            _pool_points(pts, mid, starts[0] + n, w0, b0, ws, bs, zero, pools[1, 0:1], a, b,
                         act)
    _max_into(pools[0, 0], pools[1, 0], cl)
    g = np.empty((TILE_ROWS, gw.shape[1]), dtype=pts.dtype)
    # np.int64, not constants: a literal type would compile the callees once more
    _finish_frames(pools[0], np.int64(1), bs[nl - 1], gw, gb, zero, out, np.int64(0),
                   np.empty(cl, dtype=np.intp), g)


__all__ = ["FEATURE_CHUNK", "frame_range", "features_parallel"]
