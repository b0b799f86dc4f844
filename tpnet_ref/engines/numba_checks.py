"""The input checks' first pass, compiled: one window (or a small batch) read once, its points
put in canonical order in model coordinates, and a verdict on what :mod:`tpnet_ref.checks`
would say about it.

:func:`screen` is the Numba engine's way into a prediction. It certifies only what it can decide
for certain, and leaves the rest to the checks it mirrors: a value that is not finite or beyond
the model's dtype, a frame that is not clearly one linked outline, or any number within a hair of
a threshold gives :data:`VERDICT_UNDECIDED`, and the caller then runs
:func:`tpnet_ref.checks.check_window` and :func:`~tpnet_ref.checks.warn_about_input` as the
NumPy engine does. Every decided verdict is the one those checks reach (the same warning class;
its numbers computed here, so the words may differ in the last digit only where a number sits
on a rounding boundary of its printed digits), and the points are bit for bit those of
:meth:`tpnet_ref.model.TPNet.canonical_points`: ``tests/test_engines_numba_checks.py`` holds both
against the checks, on scene windows, random points, and windows built to sit on each threshold.

What it decides, for frames of ``N`` points each (``5 <= N``) in 2-D or 3-D, in the order the
checks give their warnings:

1. one body (one window of 2-D points only; the checks have no one-body test in 3-D): every
   frame within ``BODY_MAX_RADIUS`` of its bounding box's centre and its points, taken in the
   order of their angle about that centre, never more than ``BODY_LINK_MIN`` apart
   (:func:`tpnet_ref.checks._all_one_body`'s shortcut), and no frame's centre more than
   ``BODY_MAX_STEP`` from the last's; or, failing that, a first frame whose
   points cannot hold a body of the scene's size (no stray-point test applies then). Anything
   else is undecided.
2. the training range: the span of the coordinates, then each frame's mean radius
   (``N >= RADIUS_MIN_POINTS``).
3. the motion (one window only): a free fall read at another spacing, else the centroid's mean
   step outside ``MOTION_RANGE``.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import compile_watch

from .. import checks as C
from .batch_split import SPLIT_MIN_BATCH

#: a number within this much (relative to the threshold, at least absolute) of a threshold is
#: undecided: the checks compute it by other sums, whose rounding may fall on the other side
_REL = 1e-9
#: the same for the free-fall tests' second differences (about 1e-5 world units; their rounding
#: is about 1e-14)
_FALL_BAND = 1e-11

#: what :func:`screen` found: nothing to say; undecided (a frame not clearly one body, a value at
#: a threshold, a refused value: the checks then run); or the one warning
#: :func:`tpnet_ref.checks.warn_about_input` gives, with its numbers
VERDICT_CLEAR, VERDICT_UNDECIDED, VERDICT_SPAN, VERDICT_RADIUS, VERDICT_FALL, VERDICT_STEP = range(6)


def warn_verdict(code: int, a: float, b: float, norm_lo: float, norm_hi: float,
                 normalized: bool, name: str, dim: int = 2) -> None:
    """The warning :func:`tpnet_ref.checks.warn_about_input` gives for a decided verdict ``code`` (one of the
    ``VERDICT_*`` other than undecided) with its numbers: ``a, b`` the span's ends in model
    units (``VERDICT_SPAN``), ``a`` the frame's mean radius in world units (``VERDICT_RADIUS``),
    the rows per frame of a free fall (``VERDICT_FALL``) or the centroid's mean step in world
    units (``VERDICT_STEP``); nothing for ``VERDICT_CLEAR``. ``dim``: the points' dimension."""
    if code == VERDICT_SPAN:
        C.warn_range(name, C.span_problem(a, b, norm_lo, norm_hi, normalized))
    elif code == VERDICT_RADIUS:
        C.warn_range(name, C.radius_problem(a, normalized, dim))
    elif code == VERDICT_FALL:
        C.warn_motion(name, C.fall_problem(a))
    elif code == VERDICT_STEP:
        C.warn_motion(name, C.step_problem(a))
    elif code != VERDICT_CLEAR:
        raise ValueError(f"verdict: no warning for code {code}")


_CLEAR, _UNDECIDED = VERDICT_CLEAR, VERDICT_UNDECIDED
_SPAN, _RADIUS, _FALL, _STEP = VERDICT_SPAN, VERDICT_RADIUS, VERDICT_FALL, VERDICT_STEP
_R_MAX, _LINK_MIN, _MAX_STEP = C.BODY_MAX_RADIUS, C.BODY_LINK_MIN, C.BODY_MAX_STEP
_MIN_POINTS, _RADIUS_MIN_POINTS = C.BODY_MIN_POINTS, C.RADIUS_MIN_POINTS
_RANGE_LO, _RANGE_HI = C.RANGE_LO, C.RANGE_HI
_RADIUS_LO, _RADIUS_HI = C.RADIUS_RANGE
_MOTION_LO, _MOTION_HI = C.MOTION_RANGE
_GRAVITY, _SIM_DT, _FRAME_ROWS, _FALL_TOL = C.GRAVITY, C.SIM_DT, C.FRAME_ROWS, C.FREE_FALL_TOL
#: frames of more points go the checks' way (the outline's sort here is by insertion)
MAX_POINTS = 256
#: the points' dimensions it reads (its sort keeps up to three coordinates in registers)
DIMS = (2, 3)


@njit(cache=True, nogil=True)
def _side(value, threshold, band):
    """-1 if ``value`` is clearly below ``threshold``, 1 if clearly above, 0 if within ``band``."""
    if value < threshold - band:
        return -1
    if value > threshold + band:
        return 1
    return 0


@njit(cache=True, nogil=True)
def _band(threshold):
    return _REL * max(1.0, abs(threshold))


@njit(cache=True, nogil=True)
def _sort_rows(out, base, n):
    """Rows ``base .. base + n - 1`` of ``out (P, dim)``, ``dim`` in :data:`DIMS`, sorted in
    place by x, then y (then z): an insertion sort (a frame is a few dozen points) on scalars,
    stable as ``np.lexsort`` (rows that tie on every coordinate are the same numbers)."""
    three = out.shape[1] == 3
    last = out.shape[1] - 1
    for i in range(1, n):
        px, py, pz = out[base + i, 0], out[base + i, 1], out[base + i, last]
        j = i - 1
        while j >= 0:                           # move row j up while it comes after p
            a = out[base + j, 0]
            if a < px:
                break
            if a == px:
                b = out[base + j, 1]
                if b < py or (b == py and (not three or out[base + j, 2] <= pz)):
                    break
            out[base + j + 1, 0] = a
            out[base + j + 1, 1] = out[base + j, 1]
            if three:
                out[base + j + 1, 2] = out[base + j, 2]
            j -= 1
        out[base + j + 1, 0] = px
        out[base + j + 1, 1] = py
        if three:
            out[base + j + 1, 2] = pz


@njit(cache=True, nogil=True)
def _normalise_and_sort(x, f, normalized, lo_d, scale_d, sort, out):
    """Frame ``f`` of ``x`` in model coordinates (the model's dtype, as ``canonical_points``
    computes them) into its rows of ``out``, in canonical order when ``sort``."""
    n = x.shape[1]
    zero = out.dtype.type(0.0)
    for i in range(n):
        for k in range(x.shape[2]):
            v = out.dtype.type(x[f, i, k])
            out[f * n + i, k] = v + zero if normalized else (v - lo_d) / scale_d
    if sort:
        _sort_rows(out, f * n, n)


@njit(cache=True, nogil=True)
def sort_frames(points, n, out):
    """``out``: ``points (F * n, dim)`` with each frame of ``n`` rows in canonical order (x,
    then y, then z; stable, as ``np.lexsort``)."""
    for f in range(points.shape[0] // n):
        for i in range(n):
            for k in range(points.shape[1]):
                out[f * n + i, k] = points[f * n + i, k]
        _sort_rows(out, f * n, n)


@njit(cache=True, nogil=True)
def _world(x, f, i, k, normalized, norm_lo, scale):
    v = np.float64(x[f, i, k])
    return v * scale + norm_lo if normalized else v


@njit(cache=True, nogil=True)
def _pseudo_angle(ex, ey):
    """A number in [0, 4) that grows with the angle of ``(ex, ey)`` from the x axis over a turn
    (the "diamond angle": one division, not an arctangent)."""
    r = abs(ex) + abs(ey)
    if r == 0.0:
        return 0.0
    if ey >= 0.0:
        return ey / r if ex >= 0.0 else 1.0 - ex / r
    return 2.0 - ey / r if ex < 0.0 else 3.0 + ex / r


@njit(cache=True, nogil=True)
def _outline(x, f, normalized, norm_lo, scale, ang, idx):
    """Frame ``f`` against the one-body shortcut: 1 one linked outline within reach of its
    centre, -1 clearly not, 0 undecided. The points go in the order of their angle about the
    centre, by :func:`_pseudo_angle` (the checks sort by ``arctan2``; two points at nearly one
    angle may come in the other order): any closed path through every point whose steps are
    all shorter than ``BODY_LINK_MIN`` proves one linked group, whatever the order that found
    it, so 1 is what the checks conclude too (their shortcut, or their pairwise test after
    it), and -1 only sends the frame on to the stray-point test or to the checks."""
    n = x.shape[1]
    lo0 = hi0 = _world(x, f, 0, 0, normalized, norm_lo, scale)
    lo1 = hi1 = _world(x, f, 0, 1, normalized, norm_lo, scale)
    for i in range(1, n):
        a, b = _world(x, f, i, 0, normalized, norm_lo, scale), _world(x, f, i, 1, normalized, norm_lo, scale)
        lo0, hi0 = min(lo0, a), max(hi0, a)
        lo1, hi1 = min(lo1, b), max(hi1, b)
    c0, c1 = 0.5 * (lo0 + hi0), 0.5 * (lo1 + hi1)
    undecided = False
    for i in range(n):
        ex = _world(x, f, i, 0, normalized, norm_lo, scale) - c0
        ey = _world(x, f, i, 1, normalized, norm_lo, scale) - c1
        s = _side(math.sqrt(ex * ex + ey * ey), _R_MAX, _band(_R_MAX))
        if s > 0:
            return -1
        undecided |= s == 0
        ang[i] = _pseudo_angle(ex, ey)
        idx[i] = i
    for i in range(1, n):                       # the points in the order of their angle
        a, k = ang[i], idx[i]
        j = i - 1
        while j >= 0 and ang[j] > a:
            ang[j + 1], idx[j + 1] = ang[j], idx[j]
            j -= 1
        ang[j + 1], idx[j + 1] = a, k
    worst = 0.0
    for i in range(n):
        p, q = idx[i], idx[i - 1]              # i - 1 = -1: the step closing the outline
        dx = _world(x, f, p, 0, normalized, norm_lo, scale) - _world(x, f, q, 0, normalized, norm_lo, scale)
        dy = _world(x, f, p, 1, normalized, norm_lo, scale) - _world(x, f, q, 1, normalized, norm_lo, scale)
        worst = max(worst, dx * dx + dy * dy)
    s = _side(worst, _LINK_MIN ** 2, _band(_LINK_MIN ** 2))
    if s > 0:
        return -1
    return 0 if undecided or s == 0 else 1


@njit(cache=True, nogil=True)
def _scattered(x, f, normalized, norm_lo, scale, v):
    """Whether frame ``f`` clearly cannot hold a body (:func:`tpnet_ref.checks._cannot_hold_a_body`):
    1 yes, -1 no, 0 undecided."""
    n = x.shape[1]
    side = 2 * _R_MAX * (1 + 1e-9) + 1e-9
    need = max(_MIN_POINTS, (n + 1) // 2)
    fits_both = True
    for k in range(2):
        for i in range(n):
            v[i] = _world(x, f, i, k, normalized, norm_lo, scale)
        v[:n].sort()
        best = np.inf
        for i in range(n - need + 1):
            best = min(best, v[i + need - 1] - v[i])
        s = _side(best, side, _band(side))
        if s == 0:
            return 0
        fits_both &= s < 0
    return -1 if fits_both else 1


@njit(cache=True, nogil=True)
def _centroids(x, normalized, norm_lo, scale, c):
    f_all, n = x.shape[0], x.shape[1]
    for f in range(f_all):
        for k in range(x.shape[2]):
            s = 0.0
            for i in range(n):
                s += _world(x, f, i, k, normalized, norm_lo, scale)
            c[f, k] = s / n


@njit(cache=True, nogil=True)
def _body(x, normalized, norm_lo, scale, c):
    """The one-body test of one window: 1 no warning, 0 undecided."""
    f_all, n = x.shape[0], x.shape[1]
    ang = np.empty(n)
    idx = np.empty(n, dtype=np.intp)
    outline = 1
    for f in range(f_all):
        outline = min(outline, _outline(x, f, normalized, norm_lo, scale, ang, idx))
        if outline < 0:
            break
    if outline < 0:
        # not one outline: no warning only when the first frame cannot hold a body
        return 1 if _scattered(x, 0, normalized, norm_lo, scale, ang) > 0 else 0
    if outline == 0:
        return 0
    for f in range(1, f_all):
        dx, dy = c[f, 0] - c[f - 1, 0], c[f, 1] - c[f - 1, 1]
        if _side(math.sqrt(dx * dx + dy * dy), _MAX_STEP, _band(_MAX_STEP)) >= 0:
            return 0                            # a jump (rare): the checks word it
    return 1


@njit(cache=True, nogil=True)
def _motion(c):
    """The motion test of one window's centroids ``c (m, dim)``: (verdict, number). Gravity
    acts along the last axis (y in 2-D, z in 3-D)."""
    m, down = c.shape[0], c.shape[1] - 1
    if m < 2:
        return _CLEAR, 0.0
    if m >= 4:
        fall_lo, fall_hi, fall_sum, dx_max = np.inf, -np.inf, 0.0, 0.0
        for i in range(m - 2):
            for k in range(down):
                dx_max = max(dx_max, abs(c[i + 2, k] - 2.0 * c[i + 1, k] + c[i, k]))
            fall = -(c[i + 2, down] - 2.0 * c[i + 1, down] + c[i, down])
            fall_lo, fall_hi = min(fall_lo, fall), max(fall_hi, fall)
            fall_sum += fall
        mean = fall_sum / (m - 2)
        a = _side(dx_max, _FALL_TOL, _FALL_BAND)
        b = _side(fall_hi - fall_lo, _FALL_TOL, _FALL_BAND)
        g = _side(mean, 0.5 * _GRAVITY * _SIM_DT ** 2, _FALL_BAND)
        if not (a > 0 or b > 0 or g < 0):       # not clearly out of free fall
            if a == 0 or b == 0 or g == 0:
                return _UNDECIDED, 0.0
            # free fall: the spacing read from gravity
            rows = math.sqrt(mean / _GRAVITY) / _SIM_DT
            s = _side(abs(rows - _FRAME_ROWS), 1.0, _band(1.0))
            if s == 0:
                return _UNDECIDED, 0.0
            return (_CLEAR, 0.0) if s < 0 else (_FALL, rows)
    total = 0.0
    for i in range(m - 1):
        d2 = 0.0
        for k in range(down + 1):
            d2 += (c[i + 1, k] - c[i, k]) ** 2
        total += math.sqrt(d2)
    step = total / (m - 1)
    lo, hi = _side(step, _MOTION_LO, _band(_MOTION_LO)), _side(step, _MOTION_HI, _band(_MOTION_HI))
    if lo == 0 or hi == 0:
        return _UNDECIDED, 0.0
    return (_CLEAR, 0.0) if lo > 0 and hi < 0 else (_STEP, step)


@njit(cache=True, nogil=True)
def screen(x, m, normalized, norm_lo, scale, lo_d, scale_d, limit, one_window, sort, out):
    """``x (F, N, dim)``, ``dim`` in :data:`DIMS`: ``F / m`` windows of ``m`` frames (one window
    when ``one_window``), world units unless ``normalized``; ``norm_lo``, ``scale``: the model's
    normalisation (float64), ``lo_d``, ``scale_d`` the same in the model's dtype; ``limit``: the
    largest magnitude the model's dtype holds (infinity when ``x``'s dtype is no wider). Fills
    ``out (F * N, dim)`` (the model's dtype) with the points in model coordinates, each frame
    sorted when ``sort``, and returns ``(verdict, a, b)`` (:func:`warn_verdict`)."""
    f_all, n, dim = x.shape[0], x.shape[1], x.shape[2]
    if n < _MIN_POINTS or n > MAX_POINTS or dim not in DIMS:
        return _UNDECIDED, 0.0, 0.0
    for f in range(f_all):                      # refused values: the checks word the error
        for i in range(n):
            for k in range(dim):
                v = x[f, i, k]
                if not np.isfinite(v) or abs(v) > limit:
                    return _UNDECIDED, 0.0, 0.0
    for f in range(f_all):
        _normalise_and_sort(x, f, normalized, lo_d, scale_d, sort, out)
    c = np.empty((f_all, dim))
    _centroids(x, normalized, norm_lo, scale, c)
    if not np.isfinite(c).all():                # a world or model value beyond float64
        return _UNDECIDED, 0.0, 0.0
    if one_window and dim == 2 and _body(x, normalized, norm_lo, scale, c) == 0:
        return _UNDECIDED, 0.0, 0.0
    lo, hi = np.inf, -np.inf                    # the span, in model units
    for f in range(f_all):
        for i in range(n):
            for k in range(dim):
                v = np.float64(x[f, i, k])
                if not normalized:
                    v = (v - norm_lo) / scale
                lo, hi = min(lo, v), max(hi, v)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return _UNDECIDED, 0.0, 0.0
    if lo < _RANGE_LO or hi > _RANGE_HI:
        return _SPAN, lo, hi
    if n >= _RADIUS_MIN_POINTS:                 # each frame's mean radius, world units
        g = np.empty(dim)
        for f in range(f_all):
            g[:] = 0.0
            for i in range(n):
                for k in range(dim):
                    g[k] += np.float64(x[f, i, k])
            g /= n
            total = 0.0
            for i in range(n):
                d2 = 0.0
                for k in range(dim):
                    d2 += (np.float64(x[f, i, k]) - g[k]) ** 2
                total += math.sqrt(d2)
            r = total / n * scale if normalized else total / n
            a, b = _side(r, _RADIUS_LO, _band(_RADIUS_LO)), _side(r, _RADIUS_HI, _band(_RADIUS_HI))
            if a == 0 or b == 0:
                return _UNDECIDED, 0.0, 0.0
            if a < 0 or b > 0:
                return _RADIUS, r, 0.0
    if one_window:
        verdict, number = _motion(c)
        return verdict, number, 0.0
    return _CLEAR, 0.0, 0.0


class Screen:
    """:func:`screen` as a model's way into a prediction (``model.screen``, built by
    :func:`tpnet_ref.engines.interface.build_screen` for the Numba engine). Like the two-thread kernels, it
    runs in the short commands only when numba already has it
    (:func:`tpnet_ref.engines.compile_watch.may_compile`)."""

    def __init__(self) -> None:
        self._memo: dict = {}

    def __call__(self, model, x, one: bool, normalized: bool):
        """For an array of one window ``(m, N, dim)`` (``one``) or of fewer than
        ``SPLIT_MIN_BATCH`` windows ``(B, m, N, dim)``, float32 or float64: the warnings the checks
        give, and ``(points, counts, batch)`` as ``model.canonical_points`` gives them; None
        for any other input, or where :func:`screen` leaves the verdict to the checks."""
        c = model.config
        if type(x) is not np.ndarray or x.dtype.kind != "f" or x.dtype.itemsize not in (4, 8):
            return None
        if one:
            if x.ndim != 3 or x.shape[0] != c.m or x.shape[2] != c.dim:
                return None
            batch = 1
        elif (x.ndim != 4 or x.shape[1] != c.m or x.shape[3] != c.dim
              or not 0 < x.shape[0] < SPLIT_MIN_BATCH):
            return None
        else:
            batch = x.shape[0]
        n = x.shape[-2]
        frames = np.ascontiguousarray(x).reshape(batch * c.m, n, c.dim)
        pts = np.empty((batch * c.m * n, c.dim), dtype=model.dtype)
        limit = (float(np.finfo(model.dtype).max) if x.dtype.itemsize > model.dtype.itemsize
                 else np.inf)
        args = (frames, c.m, normalized, c.norm_lo, c.norm_hi - c.norm_lo, model._lo,
                model._scale, limit, one, model.sort_points, pts)
        if not compile_watch.may_compile(screen, (frames.dtype, pts.dtype), self._memo, args):
            return None
        code, a, b = screen(*args)
        if code == _UNDECIDED:
            return None
        if code != _CLEAR:
            warn_verdict(code, a, b, c.norm_lo, c.norm_hi, normalized,
                         "window" if one else "windows", c.dim)
        return pts, np.full(batch * c.m, n, dtype=np.intp), batch

    def sorted(self, points: np.ndarray, counts: np.ndarray) -> np.ndarray | None:
        """``points (P, dim)`` in canonical order (``points[canonical_order(points, counts)]``,
        :mod:`tpnet_ref.point_order`) when every frame has the same number of points, at most
        :data:`MAX_POINTS` (a rollout's predicted frames); else None."""
        n = int(counts[0]) if len(counts) else 0
        if (points.ndim != 2 or points.shape[1] not in DIMS or not 0 < n <= MAX_POINTS
                or points.shape[0] != n * len(counts) or (counts != n).any()):
            return None
        out = np.empty_like(points, order="C")
        key = ("sort", points.dtype, points.flags.c_contiguous)
        if not compile_watch.may_compile(sort_frames, key, self._memo, (points, n, out)):
            return None
        sort_frames(points, n, out)
        return out


__all__ = ["screen", "Screen", "MAX_POINTS", "DIMS", "sort_frames", "warn_verdict",
           "VERDICT_CLEAR", "VERDICT_UNDECIDED", "VERDICT_SPAN", "VERDICT_RADIUS", "VERDICT_FALL",
           "VERDICT_STEP"]
