"""Numba kernels for the Chamfer metrics of 3-D point sets (``tpnet_ref.metrics``, dim = 3).

The 3-D twins of ``chamfer_kernels`` with the same interfaces: for each point of one set, the
squared Euclidean distance to its nearest neighbour in the other set and that neighbour's index,
in float64. Brute force (both directions in one pass, each row of the distance matrix
vectorized) for small sets; for larger ones a uniform 3-D grid (cell list) over the target set:
a query scans the 2 x 2 x 2 cells nearest to it, which is exact when the nearest point found is
no farther than every other cell; otherwise it scans every cell that meets the ball of that
distance. A row of cells (or a cell at a row's end) whose box is no nearer than the best
distance found so far is skipped: it holds no point nearer than that, so skipping never changes
the result. Every geometric bound is lowered by a rounding margin, as in 2-D.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

# Mean number of target points per grid cell.
_OCCUPANCY = 4.0


@njit(cache=True)
def _scratch(m):
    """Work space of ``_brute_rows`` for m target points: (5, m rounded up to 4)."""
    return np.empty((5, (m + 3) // 4 * 4))


@njit(cache=True)
def _brute_rows(A, s, i):
    """Squared distances from A[i] to every point of B into s[4] (a row of the distance matrix),
    and the column minima s[3] lowered to them.

    s holds B's coordinates by axis in s[0], s[1], s[2] (``_fill``); the arithmetic is that of a
    single distance, so the row vectorizes without changing a bit of any value."""
    ax = A[i, 0]
    ay = A[i, 1]
    az = A[i, 2]
    bx, by, bz, db, t = s[0], s[1], s[2], s[3], s[4]
    for j in range(t.shape[0]):
        dx = ax - bx[j]
        dy = ay - by[j]
        dz = az - bz[j]
        d = dx * dx + dy * dy + dz * dz
        t[j] = d
        e = db[j]
        db[j] = d if d < e else e


@njit(cache=True)
def _fill(B, s):
    """B's coordinates by axis into s[0:3], padded to s's width with points at +inf (whose
    squared distances are +inf: they are never a nearest neighbour), s[3] = +inf."""
    m = B.shape[0]
    for j in range(s.shape[1]):
        inside = j < m
        s[0, j] = B[j, 0] if inside else np.inf
        s[1, j] = B[j, 1] if inside else 0.0
        s[2, j] = B[j, 2] if inside else 0.0
        s[3, j] = np.inf


@njit(cache=True)
def _brute_pair(A, B, dA, iA, dB, iB, s):
    """Nearest neighbours both ways between A (n, 3) and B (m, 3), one pass over all pairs."""
    n = A.shape[0]
    m = B.shape[0]
    _fill(B, s)
    t = s[4]
    for j in range(m):
        dB[j] = np.inf
        iB[j] = 0
    for i in range(n):
        _brute_rows(A, s, i)
        best = np.inf
        bi = 0
        for j in range(m):
            d = t[j]
            if d < best:
                best = d
                bi = j
            if d < dB[j]:
                dB[j] = d
                iB[j] = i
        dA[i] = best
        iA[i] = bi


@njit(cache=True)
def _brute_pair_dist(A, B, dA, dB, s):
    """Distances only: each row vectorized, its minimum taken in four independent chains."""
    n = A.shape[0]
    m = B.shape[0]
    _fill(B, s)
    db, t = s[3], s[4]
    for i in range(n):
        _brute_rows(A, s, i)
        b0 = np.inf
        b1 = np.inf
        b2 = np.inf
        b3 = np.inf
        for j in range(0, t.shape[0], 4):
            b0 = min(b0, t[j])
            b1 = min(b1, t[j + 1])
            b2 = min(b2, t[j + 2])
            b3 = min(b3, t[j + 3])
        dA[i] = min(min(b0, b1), min(b2, b3))
    for j in range(m):
        dB[j] = db[j]


@njit(cache=True)
def _brute_block(P, Q, ip, iq, dP, iP, dQ, iQ, with_index, lo, hi):
    """Pairs lo:hi of a batch, with one work space."""
    s = _scratch(Q.shape[1])
    for b in range(lo, hi):
        if with_index:
            _brute_pair(P[ip[b]], Q[iq[b]], dP[b], iP[b], dQ[b], iQ[b], s)
        else:
            _brute_pair_dist(P[ip[b]], Q[iq[b]], dP[b], dQ[b], s)


@njit(parallel=True, cache=True)
def nn_brute(P, Q, ip, iq, dP, iP, dQ, iQ, with_index):
    """Brute force over a batch: pair b is (P[ip[b]], Q[iq[b]]); fills dP, iP (B, N), dQ, iQ (B, M).

    With ``with_index=False`` iP and iQ are left untouched.
    """
    n = ip.shape[0]
    nchunk = min(n, 256)
    for c in prange(nchunk):
        _brute_block(P, Q, ip, iq, dP, iP, dQ, iQ, with_index, c * n // nchunk,
                     (c + 1) * n // nchunk)


@njit(cache=True)
def nn_brute_serial(P, Q, ip, iq, dP, iP, dQ, iQ, with_index):
    """``nn_brute`` on one thread (small work: no cost of starting the thread pool)."""
    _brute_block(P, Q, ip, iq, dP, iP, dQ, iQ, with_index, 0, ip.shape[0])


@njit(cache=True)
def _cell_size(w1, w2, w3, cells):
    """Cell size for extents w1 >= w2 >= w3 and about ``cells`` cells: a volume's cube root, or
    for a flat (or straight) set the cells of its plane (or line), never more than ~8·cells."""
    h = (w1 / cells) ** (1.0 / 3.0) * w2 ** (1.0 / 3.0) * w3 ** (1.0 / 3.0)
    if not (h > 0.0 and w3 >= h):
        h = math.sqrt(w1 / cells) * math.sqrt(w2)
        if not (h > 0.0 and w2 >= h):
            h = w1 / cells
    if not (h > 0.0) or not (h < np.inf):
        h = max(w1, 1.0)  # all points coincide (callers keep |coordinates| < 1e150)
    return h


@njit(cache=True)
def grid_build(T):
    """Cell list of T (m, 3): points sorted by cell, cell c = (cz·ny + cy)·nx + cx.

    Returns (pts, idx, start, nx, ny, nz, x0, y0, z0, h, slack, cost): sorted coordinates
    (m, 3), their original indices, cell c holding sorted points start[c]:start[c+1], the grid
    shape, origin and cell size, an absolute rounding margin for the search bounds, and
    sum(count**2) (a cost estimate that is large when points crowd into a few cells).
    """
    m = T.shape[0]
    xlo, ylo, zlo = T[0, 0], T[0, 1], T[0, 2]
    xhi, yhi, zhi = xlo, ylo, zlo
    for k in range(1, m):
        x, y, z = T[k, 0], T[k, 1], T[k, 2]
        xlo, xhi = min(xlo, x), max(xhi, x)
        ylo, yhi = min(ylo, y), max(yhi, y)
        zlo, zhi = min(zlo, z), max(zhi, z)
    wx, wy, wz = xhi - xlo, yhi - ylo, zhi - zlo
    w2 = max(min(wx, wy), min(max(wx, wy), wz))   # the middle one
    cells = max(1.0, m / _OCCUPANCY)
    h = _cell_size(max(wx, wy, wz), w2, min(wx, wy, wz), cells)
    nx = int(min(wx / h, cells)) + 1
    ny = int(min(wy / h, cells)) + 1
    nz = int(min(wz / h, cells)) + 1
    ncell = nx * ny * nz
    cell = np.empty(m, np.int64)
    start = np.zeros(ncell + 1, np.int64)
    for k in range(m):
        cx = min(int((T[k, 0] - xlo) / h), nx - 1)
        cy = min(int((T[k, 1] - ylo) / h), ny - 1)
        cz = min(int((T[k, 2] - zlo) / h), nz - 1)
        c = (cz * ny + cy) * nx + cx
        cell[k] = c
        start[c + 1] += 1
    cost = 0.0
    for c in range(ncell):
        cost += float(start[c + 1]) * float(start[c + 1])
        start[c + 1] += start[c]
    pos = start[:-1].copy()
    pts = np.empty((m, 3), np.float64)
    idx = np.empty(m, np.int64)
    for k in range(m):
        c = cell[k]
        p = pos[c]
        pos[c] = p + 1
        pts[p, 0] = T[k, 0]
        pts[p, 1] = T[k, 1]
        pts[p, 2] = T[k, 2]
        idx[p] = k
    # Cell indices are monotone in each coordinate; rounding can misplace a point across a
    # boundary by a few ulps of the coordinates, so every bound is reduced by this margin.
    slack = 1e-9 * (abs(xlo) + abs(ylo) + abs(zlo) + abs(xhi) + abs(yhi) + abs(zhi) + h)
    return pts, idx, start, nx, ny, nz, xlo, ylo, zlo, h, slack, cost


@njit(cache=True)
def _gap2(q, a, b, margin):
    """Squared distance from q to the interval [a, b], less ``margin`` before squaring."""
    g = max(a - q, q - b, margin) - margin
    return g * g


@njit(cache=True, inline="always")
def _scan(qx, qy, qz, pts, p0, p1, best, bk):
    """The nearest of sorted points p0:p1 if nearer than ``best``: (best, its position)."""
    for p in range(p0, p1):
        dx = qx - pts[p, 0]
        dy = qy - pts[p, 1]
        dz = qz - pts[p, 2]
        d = dx * dx + dy * dy + dz * dz
        if d < best:
            best = d
            bk = p
    return best, bk


@njit(cache=True)
def _clamp_cell(f, n):
    return 0 if f < 0.0 else (n - 1 if f >= n else int(f))


@njit(cache=True)
def _scan_box(qx, qy, qz, pts, start, nx, ny, x0, y0, z0, h, margin, box, skip, best, bk):
    """Scan the cells of ``box`` (i0, i1, j0, j1, k0, k1, inclusive) row by row, the middle
    layer and row first, skipping every row, and every cell at a row's ends, whose lower bound
    is at least ``best``, and the block ``skip`` (scanned already; same layout as ``box``)."""
    i0, i1, j0, j1, k0, k1 = box
    sa, sb, ja, jb, ka, kb = skip
    cx, cy, cz = (i0 + i1) // 2, (j0 + j1) // 2, (k0 + k1) // 2
    for kk in range(k0 - 1, k1 + 1):   # first layer cz (when in the box), then the others
        k = cz if kk == k0 - 1 else kk
        if (kk == k0 - 1) != (k == cz) or k < k0 or k > k1:
            continue
        gz = _gap2(qz, z0 + k * h, z0 + (k + 1) * h, margin)
        if gz >= best:
            continue
        for jj in range(j0 - 1, j1 + 1):
            j = cy if jj == j0 - 1 else jj
            if (jj == j0 - 1) != (j == cy) or j < j0 or j > j1:
                continue
            gyz = _gap2(qy, y0 + j * h, y0 + (j + 1) * h, margin) + gz
            if gyz >= best:
                continue   # no point of this row is nearer than best
            a, b = i0, i1
            while a <= b and gyz + _gap2(qx, x0 + a * h, x0 + (a + 1) * h, margin) >= best:
                a += 1
            while b > a and gyz + _gap2(qx, x0 + b * h, x0 + (b + 1) * h, margin) >= best:
                b -= 1
            if a > b:
                continue
            row = (k * ny + j) * nx
            if ka <= k <= kb and ja <= j <= jb:   # around the cells already scanned
                best, bk = _scan(qx, qy, qz, pts, start[row + max(a, sb + 1)],
                                 start[row + max(b, sb) + 1], best, bk)
                b = min(b, sa - 1)
            best, bk = _scan(qx, qy, qz, pts, start[row + a], start[row + max(b, a - 1) + 1],
                             best, bk)
    return best, bk


@njit(cache=True)
def _half(f, c, n, q, o, h):
    """Along one axis, the two cells nearest to q (cell c and its neighbour on q's side, within
    0..n-1) and q's distance to the nearest other cell (+inf where there is none). Without
    branches on q's side, which is a coin toss for the processor's branch predictor."""
    up = int(f - c >= 0.5)
    lo = max(c - 1 + up, 0)
    hi = min(c + up, n - 1)
    lb = min(q - (o + lo * h) if lo > 0 else np.inf,
             o + (hi + 1) * h - q if hi < n - 1 else np.inf)
    return lo, hi, lb


@njit(cache=True)
def _cells(lo, hi, x0, h, n):
    """The cells i0..i1 (clamped to 0..n-1) that meet the interval [lo, hi]."""
    return _clamp_cell((lo - x0) / h, n), _clamp_cell((hi - x0) / h, n)


@njit(cache=True)
def grid_query(qx, qy, qz, pts, idx, start, nx, ny, nz, x0, y0, z0, h, slack):
    """Exact nearest neighbour of (qx, qy, qz) in a grid: (squared distance, original index).

    First the 2 x 2 x 2 cells nearest to q, which settle most queries; else a cube of cells
    around q's cell (clamped to the grid), grown while it holds no point, then every cell that
    meets the ball of the best distance so far (grown by the rounding margin): every point
    nearer than that lies in one of those cells.
    """
    fx = (qx - x0) / h
    fy = (qy - y0) / h
    fz = (qz - z0) / h
    cx = _clamp_cell(fx, nx)
    cy = _clamp_cell(fy, ny)
    cz = _clamp_cell(fz, nz)
    margin = slack + 1e-9 * (abs(qx) + abs(qy) + abs(qz))
    # The 2 x 2 x 2 cells nearest to q (fewer at the grid's edges): enough when the nearest
    # point in them is no farther than every cell outside them.
    ia, ib, lbx = _half(fx, cx, nx, qx, x0, h)
    ja, jb, lby = _half(fy, cy, ny, qy, y0, h)
    ka, kb, lbz = _half(fz, cz, nz, qz, z0, h)
    best = np.inf
    bk = -1
    for k in range(ka, kb + 1):
        for j in range(ja, jb + 1):
            row = (k * ny + j) * nx
            best, bk = _scan(qx, qy, qz, pts, start[row + ia], start[row + ib + 1], best, bk)
    lb = min(lbx, lby, lbz) - margin
    if bk >= 0 and lb > 0.0 and best <= lb * lb:
        return best, idx[bk]
    skip = (ia, ib, ja, jb, ka, kb)   # scanned
    r = 1
    while bk < 0:   # they hold no point: a growing cube of cells around q's cell
        box = (max(cx - r, 0), min(cx + r, nx - 1), max(cy - r, 0), min(cy + r, ny - 1),
               max(cz - r, 0), min(cz + r, nz - 1))
        best, bk = _scan_box(qx, qy, qz, pts, start, nx, ny, x0, y0, z0, h, margin, box, skip,
                             best, bk)
        r += 1
    R = math.sqrt(best) * (1.0 + 1e-9) + margin
    i0, i1 = _cells(qx - R, qx + R, x0, h, nx)
    j0, j1 = _cells(qy - R, qy + R, y0, h, ny)
    k0, k1 = _cells(qz - R, qz + R, z0, h, nz)
    best, bk = _scan_box(qx, qy, qz, pts, start, nx, ny, x0, y0, z0, h, margin,
                         (i0, i1, j0, j1, k0, k1), skip, best, bk)
    return best, idx[bk]


@njit(cache=True)
def _query_block(gq, gt, dq, iq, lo, hi):
    """Query sorted points lo:hi of grid ``gq`` in grid ``gt``; fill dq, iq in original order.

    Queries run in their own grid's cell order, so that consecutive queries are close."""
    qpts, qidx = gq[0], gq[1]
    pts, idx, start, nx, ny, nz, x0, y0, z0, h, slack = gt[:11]
    for k in range(lo, hi):
        d, j = grid_query(qpts[k, 0], qpts[k, 1], qpts[k, 2], pts, idx, start, nx, ny, nz,
                          x0, y0, z0, h, slack)
        dq[qidx[k]] = d
        iq[qidx[k]] = j


@njit(cache=True)
def _grid_pair(A, B, dA, iA, dB, iB):
    """Nearest neighbours both ways between A and B with one grid per set (sequential)."""
    ga = grid_build(A)
    gb = grid_build(B)
    _query_block(ga, gb, dA, iA, 0, A.shape[0])
    _query_block(gb, ga, dB, iB, 0, B.shape[0])


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
    n = gq[0].shape[0]
    nchunk = max(1, min(n // 256, 4096))
    for c in prange(nchunk):
        _query_block(gq, gt, dq, iq, c * n // nchunk, (c + 1) * n // nchunk)
