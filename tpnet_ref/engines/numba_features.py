"""The Numba engine's feature extractor: each frame's points through the per-point MLP (the
products by :func:`tpnet_ref.engines.numba_products.product`), their max, the global layer;
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
    out           the global features (F, k)
    zero          0 in the model's dtype
    dst, src, n   _max_into's rows and length
"""
from __future__ import annotations

import numpy as np

from ..extras import require

numba = require("numba", "metrics", "the Numba inference engine (engine='numba')")
from numba import njit, prange  # noqa: E402

from .numba_products import GROUP_ROWS, active, groups, product  # noqa: E402

#: points of a frame that go through the per-point layers together (their activations stay in
#: cache; a frame's max is taken over its chunks, exact whatever the cut)
FEATURE_CHUNK = 64


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
    """The work arrays of :func:`_pool_points` (two activation blocks, the active columns of
    each row group and their counts), made once per call of a kernel below, not per frame."""
    cmax = c0
    for li in range(len(ws)):
        cmax = max(cmax, ws[li].shape[1])
    a = np.empty((FEATURE_CHUNK, cmax), dtype=dt)
    b = np.empty((FEATURE_CHUNK, cmax), dtype=dt)
    act = np.empty(((FEATURE_CHUNK + GROUP_ROWS - 1) // GROUP_ROWS, cmax), dtype=np.intp)
    ns = np.empty(act.shape[0], dtype=np.intp)
    return a, b, act, ns


@njit(cache=True, nogil=True, error_model="numpy")
def _pool_points(pts, p0, p1, w0, b0, ws, bs, zero, pool, a, b, act, ns):
    """The max over the points ``pts[p0:p1]`` of the per-point MLP's last products (before its
    bias and ReLU) into ``pool (1, C)`` (NaN kept: once NaN, NaN stays). The first layer
    ``w0 (dim, C0)`` directly; every later one (``ws``, ``bs``) by :func:`product`, reading
    only the weight rows of each group of points' non-zero inputs, ReLU after each but the
    last. Points go through in chunks of :data:`FEATURE_CHUNK`; each point's numbers do not
    depend on the others, and a max does not depend on the order, so neither does ``pool``.
    ``a, b, act, ns``: :func:`_scratch`'s work arrays."""
    nl = len(ws)
    c0 = w0.shape[1]
    dim = w0.shape[0]
    chunk = FEATURE_CHUNK
    cl = ws[nl - 1].shape[1]
    for q0 in range(p0, p1, chunk):
        r = min(chunk, p1 - q0)
        for i in range(r):
            for j in range(c0):
                v = zero
                for d in range(dim):
                    v += pts[q0 + i, d] * w0[d, j]
                v += b0[j]
                a[i, j] = zero if v < zero else v
        grp = groups(r, 1, False)
        cur, nxt, cin = a, b, c0
        for li in range(nl):
            cw = ws[li].shape[1]
            xi = cur[:r, :cin]
            yo = nxt[:r, :cw]
            active(xi, grp, act, ns)
            product(xi, ws[li], grp, act, ns, yo)
            if li < nl - 1:
                bb = bs[li]
                for i in range(r):
                    for j in range(cw):
                        v = yo[i, j] + bb[j]
                        yo[i, j] = zero if v < zero else v
            cur, nxt, cin = nxt, cur, cw
        i0 = 0
        if q0 == p0:
            for j in range(cl):               # a loop, not a slice copy (as in _recur_dir)
                pool[0, j] = cur[0, j]
            i0 = 1
        for i in range(i0, r):
            _max_into(pool[0], cur[i], cl)


@njit(cache=True, nogil=True, error_model="numpy")
def _finish_frame(pool, bl, gw, gb, zero, out, f, one_row, act, ns, g):
    """``out[f] = relu(relu(pool + bl) @ gw + gb)``: the MLP's last bias and ReLU after the max
    (as :func:`tpnet_ref.engines.layers.mlp_max`: the same numbers), then the global layer.
    ``one_row, act, ns, g``: :func:`_global_scratch`'s work arrays."""
    cl = pool.shape[1]
    for j in range(cl):
        v = pool[0, j] + bl[j]
        pool[0, j] = zero if v < zero else v
    active(pool[:, :], one_row, act, ns)
    product(pool[:, :], gw, one_row, act, ns, g[:, :])
    for j in range(gw.shape[1]):
        v = g[0, j] + gb[j]
        out[f, j] = zero if v < zero else v


@njit(cache=True, nogil=True, inline="always")
def _global_scratch(cl, gw, dt):
    """The work arrays of :func:`_finish_frame`, made once per call of a kernel below."""
    return (groups(1, 1, False), np.empty((1, cl), dtype=np.intp), np.empty(1, dtype=np.intp),
            np.empty((1, gw.shape[1]), dtype=dt))


@njit(cache=True, nogil=True, error_model="numpy")
def frame_range(pts, starts, counts, f0, f1, w0, b0, ws, bs, gw, gb, zero, out):
    """The global feature of frames ``f0 .. f1-1`` into ``out[f]``: frame ``f`` is the points
    ``pts[starts[f] : starts[f] + counts[f]]`` (model coordinates, canonical order)."""
    nl = len(ws)
    cl = ws[nl - 1].shape[1]
    pool = np.empty((1, cl), dtype=pts.dtype)
    a, b, act, ns = _scratch(ws, w0.shape[1], pts.dtype)
    one_row, gact, gns, g = _global_scratch(cl, gw, pts.dtype)
    for f in range(f0, f1):
        _pool_points(pts, starts[f], starts[f] + counts[f], w0, b0, ws, bs, zero, pool,
                     a, b, act, ns)
        _finish_frame(pool, bs[nl - 1], gw, gb, zero, out, f, one_row, gact, gns, g)


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
    pools = np.empty((2, 1, cl), dtype=pts.dtype)
    for h in prange(2):
        a, b, act, ns = _scratch(ws, w0.shape[1], pts.dtype)
        if h == 0:
            _pool_points(pts, starts[0], mid, w0, b0, ws, bs, zero, pools[0], a, b, act, ns)
        else:
            _pool_points(pts, mid, starts[0] + n, w0, b0, ws, bs, zero, pools[1], a, b, act,
                         ns)
    _max_into(pools[0, 0], pools[1, 0], pools.shape[2])
    one_row, gact, gns, g = _global_scratch(cl, gw, pts.dtype)
    _finish_frame(pools[0], bs[nl - 1], gw, gb, zero, out, 0, one_row, gact, gns, g)


__all__ = ["FEATURE_CHUNK", "frame_range", "features_parallel"]
