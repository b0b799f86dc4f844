"""Input checks shared by every public function: clear errors instead of silent NaN.

Each checker names the argument and the problem in its message. ``TypeError`` is raised for
a wrong kind of object or dtype (strings, objects, complex, booleans), ``ValueError`` for a
wrong shape or value (rank, last dimension, empty, NaN/Inf).
"""
from __future__ import annotations

import math
import os
import sys
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

_PACKAGE = os.path.dirname(os.path.abspath(__file__))     # the package (:func:`_caller_level`)


class NonFiniteResultError(ArithmeticError):
    """Raised when finite input would give a non-finite result (for example float32 overflow)."""


#: what an error that float64 cures advises: each form works as written (tests/test_error_advice.py)
FLOAT64_ADVICE = ("predict in float64: dtype='float64' (tpnet_ref.predict(window, dtype='float64'), "
                  "tpnet_ref.load(dtype='float64'), model.astype('float64'); "
                  "tpnet predict --dtype float64)")


def overflow_error(dtype: np.dtype, where: str) -> NonFiniteResultError:
    """The one-line error of a prediction network that overflowed in ``dtype`` at ``where``."""
    remedy = (FLOAT64_ADVICE if dtype == np.float32
              else "rescale the input towards the training range")
    return NonFiniteResultError(
        f"the prediction network overflowed in {dtype.name} at {where} (the ReLU LSTM's state "
        "is unbounded); the input is far outside the training range — " + remedy)


def as_real_array(x: Any, name: str, dtype: np.dtype | type | None = None) -> np.ndarray:
    """``x`` as a NumPy array of a real numeric dtype (integers are accepted and converted).

    Raises ``TypeError`` for strings, objects, booleans and complex numbers.
    """
    if isinstance(x, (str, bytes)):
        raise TypeError(f"{name}: expected a numeric array, got {type(x).__name__}")
    try:
        arr = np.asarray(x)
    except ValueError as exc:  # ragged nested lists
        raise ValueError(f"{name}: cannot be read as one array ({exc})") from None
    if arr.dtype == object:
        raise TypeError(f"{name}: expected a numeric array, got an object array "
                        "(ragged or non-numeric content)")
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"{name}: expected real numbers, got dtype {arr.dtype}")
    if dtype is not None:
        arr = arr.astype(dtype, copy=False)
    return arr


def check_finite(arr: np.ndarray, name: str) -> np.ndarray:
    """Raise ``ValueError`` naming ``name`` if ``arr`` holds NaN or Inf."""
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
        raise ValueError(f"{name}: contains {bad} NaN or infinite value(s)")
    return arr


def as_point_set(x: Any, name: str, dim: int = 2, dtype: np.dtype | type | None = None,
                 allow_empty: bool = False) -> np.ndarray:
    """``x`` as a finite ``(N, dim)`` array with ``N >= 1`` (unless ``allow_empty``)."""
    arr = as_real_array(x, name, dtype)
    if arr.ndim != 2 or arr.shape[-1] != dim:
        raise ValueError(f"{name}: expected shape (N, {dim}), got {arr.shape}")
    if arr.shape[0] == 0 and not allow_empty:
        raise ValueError(f"{name}: is empty (0 points)")
    return check_finite(arr, name)


def as_point_sets(x: Any, name: str, dim: int = 2, dtype: np.dtype | type | None = None) -> np.ndarray:
    """``x`` as a finite ``(..., N, dim)`` array (a batch of point sets) with ``N >= 1``."""
    arr = as_real_array(x, name, dtype)
    if arr.ndim < 2 or arr.shape[-1] != dim:
        raise ValueError(f"{name}: expected shape (..., N, {dim}), got {arr.shape}")
    if arr.shape[-2] == 0:
        raise ValueError(f"{name}: is empty (0 points per set, shape {arr.shape})")
    return check_finite(arr, name)


def check_params(params: dict[str, Any], shapes: dict[str, tuple[int, ...]],
                 dtype: np.dtype) -> dict[str, np.ndarray]:
    """``params`` checked against ``shapes`` (names and shapes, no NaN or Inf), as contiguous
    ``dtype`` arrays in the order of ``shapes``."""
    missing = [k for k in shapes if k not in params]
    extra = [k for k in params if k not in shapes]
    if missing or extra:
        raise ValueError(f"parameters do not fit the config: missing {missing}, unexpected {extra}")
    out = {}
    for name, shape in shapes.items():
        p = as_real_array(params[name], f"parameter {name!r}")
        if p.shape != shape:
            raise ValueError(f"parameter {name!r}: expected shape {shape}, got {p.shape}")
        if not np.isfinite(p).all():
            raise ValueError(f"parameter {name!r}: contains NaN or infinite values")
        out[name] = np.ascontiguousarray(p, dtype=dtype)
    return out


def check_window(window: Any, m: int, dim: int, dtype: np.dtype,
                 name: str = "window") -> list[np.ndarray]:
    """One window, ``(m, N, dim)`` or a sequence of ``m`` arrays ``(N_i, dim)``, as its ``m``
    finite frames; refuses paths and strings, and values beyond the model's ``dtype``."""
    if isinstance(window, (str, bytes, os.PathLike)):
        raise TypeError(f"{name}: expected points, got the path or string {window!r}; "
                        "load the file first, e.g. np.load(path), or run `tpnet predict PATH`")
    if isinstance(window, np.ndarray) or not isinstance(window, Sequence):
        arr = as_real_array(window, name)
        if arr.ndim != 3 or arr.shape[-1] != dim:   # a 2-D window to a 3-D model, or back: both dims
            note = f" (the model is {dim}-D, these points {arr.shape[2]}-D)" if arr.ndim == 3 else ""
            raise ValueError(f"{name}: expected shape (m={m}, N, {dim}) or a sequence of m arrays "
                             f"(N_i, {dim}){note}, got an array of shape {arr.shape}")
        frames = [arr[i] for i in range(arr.shape[0])]
    else:
        frames = list(window)
    if len(frames) != m:
        raise ValueError(f"{name}: the model takes m={m} frames, got {len(frames)}")
    out = [as_point_set(f, f"{name}[{i}]", dim) for i, f in enumerate(frames)]
    for i, f in enumerate(out):
        if not _fits(f, dtype):
            raise ValueError(f"{name}[{i}]: values beyond the {dtype.name} range "
                             f"(|x| > {np.finfo(dtype).max:.3g}); {FLOAT64_ADVICE}")
    return out


def _fits(x: np.ndarray, dtype: np.dtype) -> bool:
    """Whether the finite array ``x`` holds no value beyond ``dtype``'s range."""
    return x.dtype.itemsize <= dtype.itemsize or not np.abs(x).max() > np.finfo(dtype).max


def check_windows(windows: Any, m: int, dim: int, dtype: np.dtype) -> tuple[list[np.ndarray], int]:
    """A batch, ``(B, m, N, dim)`` or a sequence of windows -> its frames, window after window
    (:func:`check_window` each), and ``B``."""
    if isinstance(windows, np.ndarray):
        arr = as_real_array(windows, "windows")
        if arr.ndim != 4:
            raise ValueError(f"windows: expected shape (B, m, N, {dim}) or a sequence of "
                             f"windows, got an array of shape {arr.shape}")
        b, mm, n, d = arr.shape
        if b and mm == m and n and d == dim and np.isfinite(arr).all() and _fits(arr, dtype):
            # the whole batch at once (what check_window finds frame by frame); the loop below names a fault
            return list(arr.reshape(b * m, n, dim)), b
        windows = list(arr)
    elif isinstance(windows, (str, bytes, os.PathLike)):
        check_window(windows, m, dim, dtype, "windows")          # the one-line path error
    elif not isinstance(windows, Sequence):
        raise TypeError(f"windows: expected an array or a sequence of windows, "
                        f"got {type(windows).__name__}")
    if len(windows) == 0:
        raise ValueError("windows: empty batch")
    frames: list[np.ndarray] = []
    for b, w in enumerate(windows):
        frames.extend(check_window(w, m, dim, dtype, f"windows[{b}]"))
    return frames, len(windows)


class OutsideTrainingRangeWarning(UserWarning):
    """An input lies outside what the shipped models were trained on; the result is computed
    unchanged but is an extrapolation."""


#: the training scene in model coordinates: particle centres inside the box's free area
#: [1.15, 43.85] world units map to [0, 1] (3-D: -0.002..1.001 on its grid); a 5 % margin accepted
RANGE_LO, RANGE_HI = -0.05, 1.05
#: the body's mean distance from its centroid, world units: a ring (3-D: a ball, 1.78..2.15) of radius 2
RADIUS_RANGE = (1.0, 3.0)
#: the radius is judged on frames of at least this many points only (a partial arc of the ring,
#: as an occluded observation gives, has a shifted centroid)
RADIUS_MIN_POINTS = 20


def training_range_problem(frames: np.ndarray | list[np.ndarray], norm_lo: float,
                           norm_hi: float, normalized: bool = False) -> str | None:
    """Why ``frames`` (model coordinates: an ``(F, N, dim)`` array, or a list of ``(N_i, dim)``
    frames) lie outside the training range, or ``None``. ``norm_lo``, ``norm_hi``: the model's
    world-unit normalisation; ``normalized``: whether the caller passed model units (the hint)."""
    scale = norm_hi - norm_lo
    if isinstance(frames, np.ndarray):
        groups = [frames]
    elif len({f.shape[0] for f in frames}) == 1:
        groups = [np.stack(frames)]                     # (F, N, dim) at once when N is shared
    else:
        groups = [f[None] for f in frames]
    lo, hi = min(float(g.min()) for g in groups), max(float(g.max()) for g in groups)
    if lo < RANGE_LO or hi > RANGE_HI:
        return span_problem(lo, hi, norm_lo, norm_hi, normalized)
    for g in groups:
        if g.shape[1] < RADIUS_MIN_POINTS:
            continue
        r = np.sqrt(((g - g.mean(axis=1, keepdims=True)) ** 2).sum(axis=2)).mean(axis=1) * scale
        bad = r[(r < RADIUS_RANGE[0]) | (r > RADIUS_RANGE[1])]
        if bad.size:
            return radius_problem(float(bad[0]), normalized, g.shape[2])
    return None


def span_problem(lo: float, hi: float, norm_lo: float, norm_hi: float, normalized: bool) -> str:
    """:func:`training_range_problem`'s words for coordinates spanning ``[lo, hi]`` (model units)."""
    if normalized:
        hint = (" (world units passed as normalized=True / --normalized?)" if hi > 2.0
                else "")
        return (f"coordinates span [{lo:.3g}, {hi:.3g}] in model units, outside the training "
                f"box [0, 1]{hint}")
    scale = norm_hi - norm_lo
    return (f"coordinates span [{lo * scale + norm_lo:.3g}, {hi * scale + norm_lo:.3g}] world "
            f"units, outside the training box [{norm_lo:g}, {norm_hi:g}]")


def radius_problem(radius: float, normalized: bool, dim: int = 2) -> str:
    """:func:`training_range_problem`'s words for a frame's mean radius (world units), ``dim``-D."""
    hint = (" (model coordinates given as world units? pass normalized=True)"
            if not normalized and radius < 0.1 else "")
    return (f"a frame's mean radius is {radius:.3g} world units; the trained body "
            f"is a {'ring' if dim == 2 else 'ball'} of radius 2 (accepted "
            f"{RADIUS_RANGE[0]:g}..{RADIUS_RANGE[1]:g})"
            + hint)


def warn_outside_training_range(frames: np.ndarray | list[np.ndarray], norm_lo: float, norm_hi: float,
                                name: str, normalized: bool = False, stacklevel: int | None = None) -> bool:
    """One-line :class:`OutsideTrainingRangeWarning` if :func:`training_range_problem` finds one
    (``stacklevel`` None: the first caller outside the package); whether it warned."""
    problem = training_range_problem(frames, norm_lo, norm_hi, normalized)
    if problem:
        warn_range(name, problem, stacklevel)
    return problem is not None


def warn_range(name: str, problem: str, stacklevel: int | None = None) -> None:
    """The one-line :class:`OutsideTrainingRangeWarning` of ``problem`` (``stacklevel``: None,
    the first caller outside the package)."""
    warnings.warn(f"{name}: outside the training range: {problem}; the prediction is an "
                  "extrapolation", OutsideTrainingRangeWarning,
                  stacklevel=stacklevel + 1 if stacklevel else _caller_level())


def warn_motion(name: str, problem: str) -> None:
    warnings.warn(f"{name}: unusual motion: {problem}; the prediction is an extrapolation",
                  FrameSpacingWarning, stacklevel=_caller_level())


# --------------------------------------------------------------------------- one body?
class NotOneBodyWarning(OutsideTrainingRangeWarning):
    """A window whose frames do not look like one body (stray points, two blobs, a frame far from
    its neighbours); the result is computed unchanged."""


#: one body (docs/robustness.md): points closer than max(LINK_FACTOR x the median nearest-neighbour
#: distance, LINK_MIN) world units are one group; the largest group is the body, and of it the
#: points within MAX_RADIUS of its median centre (the scene's bodies reach 2.84 from their centroid
#: and their nearest neighbours lie up to 2.84 median spacings apart: 200 training-grid
#: trajectories, every frame)
BODY_LINK_FACTOR = 3.0
BODY_LINK_MIN = 1.2
BODY_MAX_RADIUS = 3.6
#: drop_outliers also removes spurs (see body_outliers): on 200 training-grid trajectories it
#: flags one clean frame of 30,000 (``python bench/robustness.py --calibration``) and every stray
#: point about a world unit or more off the undeformed outline; 1.5 would also catch strays 0.8
#: off, but removes more points of noisy outlines (docs/robustness.md)
BODY_SPUR_FACTOR = 2.0
#: frames with fewer points are not judged
BODY_MIN_POINTS = 5
#: the body's centre moves at most 2.08 world units per model frame in the training scenes
BODY_MAX_STEP = 4.0
#: the one-body test compares every pair of a frame's points (N x N distances: 32 MiB at this
#: size); frames with more points are not judged by the warning, and body_outliers refuses them
BODY_MAX_POINTS = 2048


def _groups(adj: np.ndarray) -> np.ndarray:
    """Connected-component labels of a symmetric boolean adjacency matrix (min-label spreading)."""
    n = adj.shape[0]
    lab = np.arange(n)
    while True:
        new = np.where(adj, lab[None, :], n).min(axis=1)
        new = np.minimum(new, lab)
        new = new[new]                                  # pointer jumping
        if np.array_equal(new, lab):
            return lab
        lab = new


def body_outliers(points: np.ndarray, link: float | None = None,
                  max_radius: float = BODY_MAX_RADIUS,
                  spur_factor: float | None = None) -> np.ndarray:
    """Boolean ``(N,)``: which points of a finite ``(N, 2)`` world-unit set lie apart from the body
    (not in the largest group of points joined closer than ``link``, nor in another group of 3 or
    more points that fits with it within ``max_radius`` of their common centre, or further than
    ``max_radius`` from the centre of the body's bounding box). Sets of fewer than 5 points: none.

    ``spur_factor``: also flag *spurs*, points whose nearest neighbour is further than
    ``spur_factor`` x the median nearest-neighbour distance and whose two nearest neighbours lie on
    the same side of them (a point on the body's outline has one on each side): a stray point
    just off the outline. Off (``None``) for the warning, which must stay silent on clean and
    noisy bodies; :func:`tpnet_ref.observe.drop_outliers` turns it on (2)."""
    p = np.asarray(points, dtype=np.float64)
    n = p.shape[0]
    out = np.zeros(n, dtype=bool)
    if n < BODY_MIN_POINTS:
        return out
    if n > BODY_MAX_POINTS:
        raise ValueError(f"points: {n} points, the one-body test takes at most {BODY_MAX_POINTS} "
                         "(it compares every pair); resample the outline to fewer points first")
    dx, dy = p[:, None, 0] - p[None, :, 0], p[:, None, 1] - p[None, :, 1]
    d = np.sqrt(dx * dx + dy * dy)
    del dx, dy
    np.fill_diagonal(d, np.inf)
    if link is None:
        link = max(BODY_LINK_FACTOR * float(np.median(d.min(axis=1))), BODY_LINK_MIN)
    elif not (math.isfinite(float(link)) and float(link) > 0):
        raise ValueError(f"link: must be a finite distance > 0, got {link}")
    if not (math.isfinite(float(max_radius)) and float(max_radius) > 0):
        raise ValueError(f"max_radius: must be a finite distance > 0, got {max_radius}")
    lab = _groups(d <= float(link))
    sizes = np.bincount(lab)
    body = lab == sizes.argmax()

    def reach(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centre of the points' bounding box, and each point's distance from it."""
        centre = 0.5 * (p[mask].min(axis=0) + p[mask].max(axis=0))
        return centre, np.sqrt(((p - centre) ** 2).sum(axis=1))

    # pieces of a broken outline (an occluded or sparsely sampled body): another group of at
    # least 3 points is the body too when the two together still fit in the body's reach
    for g in np.argsort(-sizes):
        if g != sizes.argmax() and sizes[g] >= 3:
            both = body | (lab == g)
            if reach(both)[1][both].max() <= float(max_radius):
                body = both
    body &= reach(body)[1] <= float(max_radius)
    if spur_factor is not None and body.sum() >= BODY_MIN_POINTS:
        idx = np.nonzero(body)[0]
        sub = d[np.ix_(idx, idx)]
        near = np.argsort(sub, axis=1)[:, :2]
        d1 = sub[np.arange(len(idx)), near[:, 0]]
        a = p[idx[near[:, 0]]] - p[idx]
        b = p[idx[near[:, 1]]] - p[idx]
        same_side = (a * b).sum(axis=1) > 0
        spur = (d1 > float(spur_factor) * float(np.median(d1))) & same_side
        body[idx[spur]] = False
    return ~body


def _all_one_body(frames: np.ndarray) -> bool:
    """Whether every frame of ``frames (F, N, 2)`` is one linked group lying within
    ``BODY_MAX_RADIUS`` of its bounding box's centre, in which case :func:`body_outliers` finds
    no outlier in any frame (the common case, decided for all frames at once)."""
    f, n = frames.shape[:2]
    if n < BODY_MIN_POINTS:
        return True
    # few NumPy calls: this runs on every predict (a window is 4 x 30 points, so each call's
    # fixed cost, not the arithmetic, is what it costs)
    e = frames - 0.5 * (frames.min(axis=1) + frames.max(axis=1))[:, None, :]
    ex, ey = e[..., 0], e[..., 1]
    if not (np.sqrt(np.einsum("fnk,fnk->fn", e, e)) <= BODY_MAX_RADIUS).all():
        return False
    # an outline (the scene's body is a ring): the points in the order of their angle about the
    # centre form a closed path; with no step longer than BODY_LINK_MIN (the smallest link) they
    # are one linked group whatever the link, and no pairwise distances are needed
    path = frames[np.arange(f)[:, None], np.argsort(np.arctan2(ey, ex), axis=1)]
    step = np.empty_like(path)
    np.subtract(path[:, 1:], path[:, :-1], out=step[:, 1:])
    np.subtract(path[:, 0], path[:, -1], out=step[:, 0])
    if np.einsum("fnk,fnk->fn", step, step).max() <= BODY_LINK_MIN ** 2:
        return True
    if f * n * n > BODY_MAX_POINTS ** 2:            # all frames' pairs at once would not be small
        return False                                # (the caller then judges frame by frame)
    dx = frames[:, :, None, 0] - frames[:, None, :, 0]
    dy = frames[:, :, None, 1] - frames[:, None, :, 1]
    d = np.sqrt(dx * dx + dy * dy)                  # the same numbers as body_outliers' d
    d[:, np.arange(n), np.arange(n)] = np.inf
    link = np.maximum(BODY_LINK_FACTOR * np.median(d.min(axis=2), axis=1), BODY_LINK_MIN)
    adj = d <= link[:, None, None]
    lab = np.broadcast_to(np.arange(n), (f, n))
    while True:                                     # min-label spreading, as _groups
        new = np.minimum(np.where(adj, lab[:, None, :], n).min(axis=2), lab)
        new = np.take_along_axis(new, new, axis=1)
        if np.array_equal(new, lab):
            return bool((lab == 0).all())
        lab = new


def _cannot_hold_a_body(frames: np.ndarray) -> np.ndarray:
    """Boolean ``(F,)`` for ``frames (F, N, 2)``: True where no strip ``2 * BODY_MAX_RADIUS`` wide,
    along x or along y, holds ``max(BODY_MIN_POINTS, N / 2)`` points, so that
    :func:`body_outliers` cannot find a body of the scene's size there (the body it keeps lies
    within ``BODY_MAX_RADIUS`` of one centre, so inside such a strip both ways) and
    :func:`window_body_problem` leaves the frame to the training-range check. Scattered points
    (a window of random points) are decided in a few NumPy calls instead of the pairwise
    grouping; the strip is taken a hair wider, so that a True is never wrong (a False only costs
    the full test)."""
    f, n = frames.shape[:2]
    if n < BODY_MIN_POINTS:
        return np.zeros(f, dtype=bool)
    side = 2 * BODY_MAX_RADIUS * (1 + 1e-9) + 1e-9
    need = max(BODY_MIN_POINTS, math.ceil(n / 2))
    s = np.sort(frames, axis=1)                            # each coordinate on its own
    # a strip holds `need` points iff some `need` consecutive sorted values span at most `side`
    fits = ((s[:, need - 1:] - s[:, :n - need + 1]) <= side).any(axis=1)   # (F, 2): x, y
    return ~fits.all(axis=1)


def window_body_problem(frames: np.ndarray | list[np.ndarray]) -> str | None:
    """Why a window (``(F, N, 2)`` or a list of ``(N_i, 2)`` frames, world units) does not look
    like one body moving, or ``None``: stray points or a second blob in a frame
    (:func:`body_outliers`: at most as many as the body's points), or a frame whose body is far
    from the previous frame's. A frame without a body of the scene's size (points scattered, or
    in other units) is left to :func:`training_range_problem`, and so is a frame of more than
    ``BODY_MAX_POINTS`` points (not judged: the test compares every pair)."""
    if any(len(f) > BODY_MAX_POINTS for f in frames):
        return None
    centres = []
    if isinstance(frames, np.ndarray) or len({len(f) for f in frames}) == 1:
        stacked = np.asarray(np.stack(frames) if isinstance(frames, list) else frames,
                             dtype=np.float64)
        if np.isfinite(stacked).all() and _all_one_body(stacked):
            # no outliers: only the steps between the frames' centres to judge
            c = stacked.mean(axis=1)
            d = c[1:] - c[:-1]
            if not (np.sqrt(np.einsum("fk,fk->f", d, d)) > BODY_MAX_STEP).any():
                return None
            centres = list(c)
            frames = []
        elif np.isfinite(stacked).all():
            # scattered points cannot hold a body: the loop below would stop at the first such
            # frame, so only the frames before it need the pairwise test
            scattered = np.flatnonzero(_cannot_hold_a_body(stacked))
            if scattered.size:
                frames = list(frames[:int(scattered[0]) + 1])
    for i, f in enumerate(frames):
        f = np.asarray(f, dtype=np.float64)
        if len(f) >= BODY_MIN_POINTS and len(f) <= BODY_MAX_POINTS and \
                _cannot_hold_a_body(f[None])[0]:
            return None                                    # no body: as body_outliers says below
        out = body_outliers(f)
        k = int(out.sum())
        if k and (len(f) - k < BODY_MIN_POINTS or k > len(f) - k):
            # no body of the scene's size at all (wrong units or scale, scattered points): the
            # training-range check says what is wrong
            return None
        if k:
            what = "a second blob" if k >= BODY_MIN_POINTS else "stray points"
            return (f"frame {i} does not look like one body: {k} of {len(f)} points lie apart "
                    f"from it (likely {what}: background specks, reflections, another object); "
                    "max pooling takes them as part of the body, so clean each frame with "
                    "tpnet_ref.observe.drop_outliers")
        centres.append(f.mean(axis=0))
    for i in range(1, len(centres)):
        step = float(np.sqrt(((centres[i] - centres[i - 1]) ** 2).sum()))
        if step > BODY_MAX_STEP:
            return (f"frame {i}'s body is {step:.3g} world units from frame {i - 1}'s (the "
                    f"scene's bodies move at most ~2.1 per frame): a frame from another moment "
                    "or object, or frames not 4/45 s apart? (tpnet_ref.observe."
                    "frames_at_model_rate picks them; drop_outliers removes stray points)")
    return None


def warn_not_one_body(frames: np.ndarray | list[np.ndarray], name: str,
                      stacklevel: int | None = None) -> bool:
    """One-line :class:`NotOneBodyWarning` if :func:`window_body_problem` finds one (``stacklevel``
    None: the first caller outside the package); whether it warned."""
    problem = window_body_problem(frames)
    if problem:
        warnings.warn(f"{name}: {problem}; the prediction is unreliable", NotOneBodyWarning,
                      stacklevel=stacklevel or _caller_level())
    return problem is not None


# --------------------------------------------------------------------------- sparse frames, motion
class TooFewPointsWarning(OutsideTrainingRangeWarning):
    """A frame with fewer than :data:`MIN_FRAME_POINTS` points: too few to describe a body's
    outline (the model was trained on 30 per frame); the result is computed unchanged."""


class FrameSpacingWarning(OutsideTrainingRangeWarning):
    """A window whose frames look otherwise spaced in time than 4/45 s (e.g. consecutive
    simulator rows instead of every fourth): a falling body's centroid falls as at another
    spacing, or the body moves slower or faster than in any training window
    (:func:`motion_problem`); the result is computed unchanged."""


#: a frame needs at least this many points: fewer than 3 cannot span an area nor outline a body
MIN_FRAME_POINTS = 3
#: the accepted mean move of a window's centroid per frame, world units, for windows not in free
#: fall (:func:`free_fall_rows` reads those): the training windows (frames 4 simulator rows =
#: 4/45 s apart) move 0.025 to 2.08. With both rules, of every m = 4 window of 200 training-grid
#: trajectories (float32), 0.18 % at the model's spacing are flagged, 93.9 % of consecutive rows,
#: 89.3 % of every 2nd row, 82.4 % of every 8th (``python bench/robustness.py --motion 200``); of
#: the 3-D grid's 342 trajectories (docs/spec.md §8, the same speeds) 0.04 %, 93.4, 87.8, 82.2 %
MOTION_RANGE = (0.1, 2.5)
#: the scene's gravity (world units / s², down the last axis: y in 2-D, z in 3-D), simulator step
#: (s) and rows per model frame (docs/spec.md §3, §8; the same as the scenes' ``SceneParams`` and
#: ``protocol.REFERENCE_DT`` / ``FRAME_EVERY``, which this bottom layer cannot import: a test
#: holds them equal): a body in free fall has its centroid's second difference
#: (0, -GRAVITY * (FRAME_ROWS * SIM_DT)²) per frame, whatever its springs do (internal forces)
GRAVITY, SIM_DT, FRAME_ROWS = 0.5, 1.0 / 45.0, 4
#: a window is "in free fall" when its centroid's second differences match (0, -g h²) for one h
#: within this many world units (5 % of one simulator row's fall, 1.2e-5); 85 % of the training
#: windows are, and their spacing is then read to within 0.003 rows (``python bench/robustness.py
#: --motion 200``)
FREE_FALL_TOL = 0.05 * GRAVITY * SIM_DT ** 2


def free_fall_rows(centroids: np.ndarray) -> float | None:
    """The simulator rows between frames that a window's centroid path ``(m, dim)`` shows when the
    body is in free fall (its second differences all ``(0, .., -g (rows * dt)²)`` within
    :data:`FREE_FALL_TOL`), or ``None`` when it is not (a contact, a body at rest, m < 4)."""
    if len(centroids) < 4:
        return None
    dd = centroids[2:] - 2.0 * centroids[1:-1] + centroids[:-2]
    fall = -dd[:, -1]                       # gravity along the last axis, as in both scenes
    if (np.abs(dd[:, :-1]).max(initial=0.0) > FREE_FALL_TOL or np.ptp(fall) > FREE_FALL_TOL
            or fall.mean() < 0.5 * GRAVITY * SIM_DT ** 2):
        return None
    return float(np.sqrt(fall.mean() / GRAVITY) / SIM_DT)


def sparse_frames_problem(counts: Sequence[int], dim: int = 2) -> str | None:
    """Why a window of ``dim``-D frames of ``counts`` points is too sparse for a body, or ``None``."""
    few = [i for i, n in enumerate(counts) if n < MIN_FRAME_POINTS]
    if not few:
        return None
    i = few[0]
    return (f"frame {i} has {counts[i]} point(s){f' ({len(few)} frames have too few)' if len(few) > 1 else ''}; "
            f"a body's outline needs at least {MIN_FRAME_POINTS} (fewer cannot span an area; the "
            f"model was trained on {30 if dim == 2 else 42} per frame)")


def motion_problem(world: np.ndarray | list[np.ndarray]) -> str | None:
    """Why the frames of one window (world units: ``(m, N, dim)`` or a list of ``(N_i, dim)``)
    look spaced in time otherwise than the training windows, or ``None``: a body in free fall
    whose centroid falls as at another spacing than :data:`FRAME_ROWS` rows
    (:func:`free_fall_rows`, one row or more off), else the mean distance between consecutive
    frames' centroids outside :data:`MOTION_RANGE`."""
    if len(world) < 2:
        return None
    c = (world.mean(axis=1) if isinstance(world, np.ndarray)
         else np.array([f.mean(axis=0) for f in world]))
    rows = free_fall_rows(c)
    if rows is not None:                    # the scene's gravity reads the spacing exactly
        if abs(rows - FRAME_ROWS) < 1.0:
            return None
        return fall_problem(rows)
    d = c[1:] - c[:-1]
    step = float(np.sqrt(np.einsum("fk,fk->f", d, d)).mean())
    lo, hi = MOTION_RANGE
    if lo <= step <= hi:
        return None
    return step_problem(step)


def fall_problem(rows: float) -> str:
    """:func:`motion_problem`'s words for a free fall as at ``rows`` simulator rows a frame."""
    return (f"the body falls freely, and its centroid falls as if the frames were "
            f"{rows:.2g}/45 s apart, not {FRAME_ROWS}/45 s (gravity {GRAVITY:g} world "
            f"units/s², the simulator's step 1/45 s): "
            + ("consecutive simulator rows instead of every fourth?" if rows < 1.5 else
               "frames picked at another rate?")
            + " (tpnet_ref.observe.frames_at_model_rate picks frames at the model's rate)")


def step_problem(step: float) -> str:
    """:func:`motion_problem`'s words for a centroid's mean ``step`` a frame (world units)."""
    lo, hi = MOTION_RANGE
    why = ("frames closer in time than 4/45 s, e.g. consecutive simulator rows instead of every "
           "fourth, or a body at rest" if step < lo else
           "frames further apart in time than 4/45 s, e.g. every 8th simulator row")
    return (f"the body's centroid moves {step:.3g} world units per frame on average; the training "
            f"windows move {lo:g}..{hi:g} (frames 4/45 s apart): {why}? "
            "(tpnet_ref.observe.frames_at_model_rate picks frames at the model's rate)")


def _caller_level() -> int:
    """The ``stacklevel`` that points a warning raised by this module's caller at the first
    frame outside the package (the user's line, however deep the call came from)."""
    frame, level = sys._getframe(2), 2
    while frame is not None and frame.f_code.co_filename.startswith(_PACKAGE):
        frame, level = frame.f_back, level + 1
    return level


def warn_about_input(frames: list[np.ndarray], norm_lo: float, norm_hi: float,
                     normalized: bool, name: str, one_window: bool) -> None:
    """The input warnings of a prediction on checked ``frames``: for ``one_window`` a
    :class:`NotOneBodyWarning` when its frames do not look like one body (stray points, two blobs,
    a frame far from its neighbours), otherwise an :class:`OutsideTrainingRangeWarning` when it
    leaves the training range (stray points trip both; one line names the likely cause); then, for
    input inside the training range, a :class:`TooFewPointsWarning` for a frame of fewer than
    :data:`MIN_FRAME_POINTS` points and, for ``one_window``, a :class:`FrameSpacingWarning` when
    :func:`motion_problem` finds its frames otherwise spaced in time than the training windows'.
    3-D frames (docs/spec.md §8) get all but the one-body test (its outline, the 2-D ring's)."""
    scale, dim = norm_hi - norm_lo, frames[0].shape[1]
    with np.errstate(over="ignore", invalid="ignore"):      # far-out input: judged, not warned twice
        x: Any = ([np.asarray(f, dtype=np.float64) for f in frames]
                  if len({f.shape[0] for f in frames}) > 1 else
                  np.asarray(np.stack(frames), dtype=np.float64))      # (F, N, dim) at once
        each = (lambda fn: fn(x)) if isinstance(x, np.ndarray) else (lambda fn: [fn(f) for f in x])
        world = each(lambda f: f * scale + norm_lo) if normalized else x
        if one_window and dim == 2 and warn_not_one_body(world, name):
            return
        model = x if normalized else each(lambda f: (f - norm_lo) / scale)
        if warn_outside_training_range(model, norm_lo, norm_hi, name, normalized):
            return
        sparse = sparse_frames_problem([len(f) for f in frames], dim)
        if sparse:
            warnings.warn(f"{name}: too few points: {sparse}; the prediction is an "
                          "extrapolation", TooFewPointsWarning, stacklevel=_caller_level())
        moved = motion_problem(world) if one_window else None
        if moved:
            warn_motion(name, moved)

