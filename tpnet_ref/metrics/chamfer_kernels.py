"""Numba kernels for the Chamfer metrics (private; imported lazily by ``tpnet_ref.metrics``).

Every kernel works on float64 points and returns, for each point of one set, the squared
Euclidean distance to its nearest neighbour in the other set and that neighbour's index.
Two exact nearest-neighbour methods:

- brute force, O(N·M) per pair, both directions in one pass (best for small sets);
- a uniform grid (cell list) over the target set, searched ring by ring around the query's
  cell until a lower bound on the distance to every unscanned cell is at least the best
  distance found: expected O(1) per query for bounded-density data.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

# Mean number of target points per grid cell.
_OCCUPANCY = 2.0


@njit(cache=True, fastmath=False)
def _brute_pair(A, B, dA, iA, dB, iB):
    """Nearest neighbours both ways between A (n, 2) and B (m, 2), one pass over all pairs."""
    n = A.shape[0]
    m = B.shape[0]
    for j in range(m):
        dB[j] = np.inf
        iB[j] = 0
    for i in range(n):
        ax = A[i, 0]
        ay = A[i, 1]
        best = np.inf
        bi = 0
        for j in range(m):
            dx = ax - B[j, 0]
            dy = ay - B[j, 1]
            d = dx * dx + dy * dy
            if d < best:
                best = d
                bi = j
            if d < dB[j]:
                dB[j] = d
                iB[j] = i
        dA[i] = best
        iA[i] = bi


@njit(cache=True)
def _brute_pair_dist(A, B, dA, dB):
    """Distances only (no indices): branch-free minima that the compiler vectorizes (~3x faster)."""
    n = A.shape[0]
    m = B.shape[0]
    bx = np.empty(m)
    by = np.empty(m)
    for j in range(m):
        bx[j] = B[j, 0]
        by[j] = B[j, 1]
        dB[j] = np.inf
    for i in range(n):
        ax = A[i, 0]
        ay = A[i, 1]
        best = np.inf
        for j in range(m):
            dx = ax - bx[j]
            dy = ay - by[j]
            d = dx * dx + dy * dy
            best = min(best, d)
            dB[j] = min(dB[j], d)
        dA[i] = best


@njit(parallel=True, cache=True)
def nn_brute(P, Q, ip, iq, dP, iP, dQ, iQ, with_index):
    """Brute force over a batch: pair b is (P[ip[b]], Q[iq[b]]); fills dP, iP (B, N), dQ, iQ (B, M).

    With ``with_index=False`` iP and iQ are left untouched.
    """
    if with_index:
        for b in prange(ip.shape[0]):
            _brute_pair(P[ip[b]], Q[iq[b]], dP[b], iP[b], dQ[b], iQ[b])
    else:
        for b in prange(ip.shape[0]):
            _brute_pair_dist(P[ip[b]], Q[iq[b]], dP[b], dQ[b])


@njit(cache=True)
def nn_brute_serial(P, Q, ip, iq, dP, iP, dQ, iQ, with_index):
    """``nn_brute`` on one thread (small work: no cost of starting the thread pool)."""
    for b in range(ip.shape[0]):
        if with_index:
            _brute_pair(P[ip[b]], Q[iq[b]], dP[b], iP[b], dQ[b], iQ[b])
        else:
            _brute_pair_dist(P[ip[b]], Q[iq[b]], dP[b], dQ[b])


@njit(cache=True)
def grid_build(T):
    """Cell list of T (m, 2): points sorted by row-major cell.

    Returns (xs, ys, idx, start, nx, ny, x0, y0, h, slack, cost): sorted coordinates, their
    original indices, cell c holding sorted points start[c]:start[c+1], the grid shape, origin
    and cell size, an absolute rounding margin for the search bound, and sum(count**2) (a cost
    estimate that is large when points crowd into a few cells).
    """
    m = T.shape[0]
    xmin = np.inf
    xmax = -np.inf
    ymin = np.inf
    ymax = -np.inf
    for k in range(m):
        x = T[k, 0]
        y = T[k, 1]
        xmin = min(xmin, x)
        xmax = max(xmax, x)
        ymin = min(ymin, y)
        ymax = max(ymax, y)
    wx = xmax - xmin
    wy = ymax - ymin
    cells = max(1.0, m / _OCCUPANCY)
    h = math.sqrt(wx * wy / cells)
    h = max(h, max(wx, wy) / cells)  # a thin (or straight) set gets at most `cells` cells
    if not (h > 0.0):
        h = 1.0  # all points coincide (callers keep |coordinates| < 1e150, so h is finite)
    nx = int(min(wx / h, cells)) + 1
    ny = int(min(wy / h, cells)) + 1
    ncell = nx * ny
    cell = np.empty(m, np.int64)
    start = np.zeros(ncell + 1, np.int64)
    for k in range(m):
        cx = min(int((T[k, 0] - xmin) / h), nx - 1)
        cy = min(int((T[k, 1] - ymin) / h), ny - 1)
        c = cy * nx + cx
        cell[k] = c
        start[c + 1] += 1
    cost = 0.0
    for c in range(ncell):
        cost += float(start[c + 1]) * float(start[c + 1])
        start[c + 1] += start[c]
    pos = start[:-1].copy()
    xs = np.empty(m, np.float64)
    ys = np.empty(m, np.float64)
    idx = np.empty(m, np.int64)
    for k in range(m):
        c = cell[k]
        p = pos[c]
        pos[c] = p + 1
        xs[p] = T[k, 0]
        ys[p] = T[k, 1]
        idx[p] = k
    # Cell indices are monotone in each coordinate; rounding can misplace a point across a
    # boundary by a few ulps of the coordinates, so the search bound is reduced by a margin
    # many orders of magnitude larger than that.
    slack = 1e-9 * (abs(xmin) + abs(ymin) + abs(xmax) + abs(ymax) + h)
    return xs, ys, idx, start, nx, ny, xmin, ymin, h, slack, cost


@njit(cache=True, inline="always")
def _rect_d2(qx, qy, x0, x1, y0, y1):
    """Squared distance from (qx, qy) to the rectangle [x0, x1] x [y0, y1]."""
    dx = max(x0 - qx, 0.0, qx - x1)
    dy = max(y0 - qy, 0.0, qy - y1)
    return dx * dx + dy * dy


@njit(cache=True)
def grid_query(qx, qy, xs, ys, idx, start, nx, ny, x0, y0, h, slack):
    """Exact nearest neighbour of (qx, qy) in a grid: (squared distance, original index)."""
    fx = (qx - x0) / h
    fy = (qy - y0) / h
    cx = 0 if fx < 0.0 else (nx - 1 if fx >= nx else int(fx))
    cy = 0 if fy < 0.0 else (ny - 1 if fy >= ny else int(fy))
    gx1 = x0 + nx * h
    gy1 = y0 + ny * h
    margin = slack + 1e-9 * (abs(qx) + abs(qy))
    best = np.inf
    bk = -1
    r = 0
    while True:
        i0 = cx - r
        i1 = cx + r
        j0 = cy - r
        j1 = cy + r
        for j in range(max(j0, 0), min(j1, ny - 1) + 1):
            row = j * nx
            if j == j0 or j == j1:
                ilo = max(i0, 0)
                ihi = min(i1, nx - 1)
                for p in range(start[row + ilo], start[row + ihi + 1]):
                    dx = qx - xs[p]
                    dy = qy - ys[p]
                    d = dx * dx + dy * dy
                    if d < best:
                        best = d
                        bk = p
            else:
                if i0 >= 0:
                    for p in range(start[row + i0], start[row + i0 + 1]):
                        dx = qx - xs[p]
                        dy = qy - ys[p]
                        d = dx * dx + dy * dy
                        if d < best:
                            best = d
                            bk = p
                if i1 < nx:
                    for p in range(start[row + i1], start[row + i1 + 1]):
                        dx = qx - xs[p]
                        dy = qy - ys[p]
                        d = dx * dx + dy * dy
                        if d < best:
                            best = d
                            bk = p
        if i0 <= 0 and j0 <= 0 and i1 >= nx - 1 and j1 >= ny - 1:
            break  # the whole grid has been scanned
        # Lower bound on the distance to every point in a cell outside the scanned block.
        bx0 = x0 + max(i0, 0) * h
        bx1 = x0 + (min(i1, nx - 1) + 1) * h
        by0 = y0 + max(j0, 0) * h
        by1 = y0 + (min(j1, ny - 1) + 1) * h
        lb2 = np.inf
        if i0 > 0:
            lb2 = min(lb2, _rect_d2(qx, qy, x0, bx0, y0, gy1))
        if i1 < nx - 1:
            lb2 = min(lb2, _rect_d2(qx, qy, bx1, gx1, y0, gy1))
        if j0 > 0:
            lb2 = min(lb2, _rect_d2(qx, qy, bx0, bx1, y0, by0))
        if j1 < ny - 1:
            lb2 = min(lb2, _rect_d2(qx, qy, bx0, bx1, by1, gy1))
        lb = math.sqrt(lb2) - margin
        if lb > 0.0 and best <= lb * lb:
            break
        r += 1
    return best, idx[bk]


@njit(cache=True)
def _grid_pair(A, B, dA, iA, dB, iB):
    """Nearest neighbours both ways between A and B with one grid per set (sequential)."""
    ax, ay, aidx, astart, anx, any_, ax0, ay0, ah, aslack, _ = grid_build(A)
    bx, by, bidx, bstart, bnx, bny, bx0, by0, bh, bslack, _ = grid_build(B)
    # Queries run in the other grid's cell order, so that consecutive queries are close.
    for k in range(ax.shape[0]):
        d, j = grid_query(ax[k], ay[k], bx, by, bidx, bstart, bnx, bny, bx0, by0, bh, bslack)
        dA[aidx[k]] = d
        iA[aidx[k]] = j
    for k in range(bx.shape[0]):
        d, j = grid_query(bx[k], by[k], ax, ay, aidx, astart, anx, any_, ax0, ay0, ah, aslack)
        dB[bidx[k]] = d
        iB[bidx[k]] = j


@njit(parallel=True, cache=True)
def nn_grid(P, Q, ip, iq, dP, iP, dQ, iQ):
    """Grid method over a batch, parallel over pairs (same interface as ``nn_brute``)."""
    for b in prange(ip.shape[0]):
        _grid_pair(P[ip[b]], Q[iq[b]], dP[b], iP[b], dQ[b], iQ[b])


@njit(cache=True)
def nn_grid_serial(P, Q, ip, iq, dP, iP, dQ, iQ):
    """``nn_grid`` on one thread."""
    for b in range(ip.shape[0]):
        _grid_pair(P[ip[b]], Q[iq[b]], dP[b], iP[b], dQ[b], iQ[b])


@njit(parallel=True, cache=True)
def grid_query_all(gq, gt, dq, iq):
    """Query every point of grid ``gq`` in grid ``gt``, parallel over query points.

    ``gq`` and ``gt`` are ``grid_build`` results; dq, iq (n,) are filled in original order.
    """
    qx, qy, qidx = gq[0], gq[1], gq[2]
    xs, ys, idx, start, nx, ny, x0, y0, h, slack = (gt[0], gt[1], gt[2], gt[3], gt[4], gt[5],
                                                     gt[6], gt[7], gt[8], gt[9])
    n = qx.shape[0]
    nchunk = max(1, min(n // 256, 4096))
    for c in prange(nchunk):
        lo = c * n // nchunk
        hi = (c + 1) * n // nchunk
        for k in range(lo, hi):
            d, j = grid_query(qx[k], qy[k], xs, ys, idx, start, nx, ny, x0, y0, h, slack)
            dq[qidx[k]] = d
            iq[qidx[k]] = j
