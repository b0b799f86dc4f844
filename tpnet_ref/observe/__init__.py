"""From a camera to a window: the paper's real-world input path (its appendix "Real-World Data").

The paper films the thrown body, subtracts the background, takes the object's outer contour,
divides it uniformly into n points and normalises the pixel coordinates by the walls and the floor.
This module does the same, in the scene's world units (docs/spec.md §5), so that the result goes
straight into :func:`tpnet_ref.predict` / :func:`tpnet_ref.rollout`:

* :class:`Camera` maps continuous pixel coordinates (column, row; row 0 at the top; pixel
  ``(c, r)`` covers ``[c, c+1) x [r, r+1)``) to world units with the inner faces of the side walls
  (x = 1 and x = 44) and the top of the floor (y = 1);
* :func:`points_from_mask`: the largest connected blob's outer contour, resampled to ``n`` points
  uniformly by arc length (start point and offset correction below);
* :func:`points_from_image`: background subtraction + threshold + :func:`points_from_mask`;
* :func:`drop_outliers`: the points that belong to the body (one compact blob of known size);
* :func:`frames_at_model_rate` / :func:`model_rate_indices`: the video frames nearest to the
  model's frame interval, 4 simulator steps of 1/45 s;
* :mod:`tpnet_ref.observe.render`: the other way round, a synthetic camera filming the scene
  (``tpnet sim render``), what the path above is tested on.

The contour (decided and measured; docs/robustness.md has the effect of each choice):

* **edge, not pixel centres**: OpenCV traces the centres of the blob's boundary pixels, half a pixel
  inside the mask's edge; the contour is moved out by half a pixel along its normal so that it lies
  on the edge at any resolution;
* **smoothing over one particle spacing**: the paper's body is 30 particles joined by a filled
  outline, so its outline has 30 bumps; 30 points resampled on it alias (the observed radius jitters
  with the start point). The dense contour is averaged over a window of one bump period
  (perimeter / 30), which removes the bumps exactly and moves a smooth outline by less than 0.3 %
  of its radius;
* **offset correction** (``inset``): the model was trained on particle centres; the outline of the
  filled body lies :data:`BODY_INSET` world units outside the circle through the centres (on
  average, for particles of radius 0.15 on a ring of radius 2: :func:`outline_offset`). The
  contour is moved inwards along its normal by ``inset`` (pass ``inset=0`` for the raw outline, or
  your object's own value);
* **start point and direction**: the first point is where the vertical line through the contour's
  centroid meets the contour at the top, and the points run clockwise (from +y towards +x), as the
  simulator numbers its particles (docs/spec.md §5). TP-Net does not depend on the order; the
  choice makes the output reproducible.

OpenCV (``opencv-python-headless``, the ``vision`` extra) is imported only by the functions that
read masks and images; :class:`Camera`, :func:`drop_outliers` and the frame picking need NumPy only.
OpenCV rather than scikit-image: one wheel gives connected components, contour tracing, image and
video reading and writing (scikit-image needs imageio and an FFmpeg plug-in for video) and it is
several times faster on the 640-1280 px frames this module handles.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..checks import (BODY_LINK_FACTOR, BODY_LINK_MIN, BODY_MAX_RADIUS, BODY_SPUR_FACTOR,
                     as_point_set, as_real_array, body_outliers, check_finite)
from ..extras import require
from ..sim.protocol import FRAME_EVERY, REFERENCE_DT

#: the scene's free area (docs/spec.md §5): inner faces of the walls and the top of the floor
WALL_LO = 1.0
WALL_HI = 44.0
#: the model's frame interval: 4 simulator steps of 1/45 s
MODEL_FRAME_S = FRAME_EVERY * REFERENCE_DT
#: the body: 30 particles of radius 0.15 on a ring of radius 2 (docs/spec.md §5)
BODY_PARTICLES = 30
BODY_RING_RADIUS = 2.0
BODY_PARTICLE_RADIUS = 0.15


def require_cv2() -> Any:
    """OpenCV (the module `cv2`), or a one-line error naming the `vision` extra."""
    return require("cv2", "vision", "reading masks, images and videos (OpenCV)")


# --------------------------------------------------------------------------- the camera
@dataclass(frozen=True)
class Camera:
    """Image pixels -> world units, from the walls' inner faces and the floor's top in the image.

    Coordinates are continuous: pixel ``(c, r)`` covers ``[c, c+1) x [r, r+1)`` (its centre is
    ``(c + 0.5, r + 0.5)``), row 0 at the top. ``left_wall_px`` / ``right_wall_px``: the columns of
    the inner faces of the left and right walls (world x = 1 and x = 44); ``floor_px``: the row of
    the floor's top (world y = 1). Pixels are square: the walls fix the scale, so
    ``Camera(0, 640, 640)`` is a 640 x 640 image whose edges are the walls and the floor.
    """

    left_wall_px: float
    right_wall_px: float
    floor_px: float

    def __post_init__(self) -> None:
        for name in ("left_wall_px", "right_wall_px", "floor_px"):
            v = getattr(self, name)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer,
                                                                     np.floating)):
                raise TypeError(f"Camera: {name} must be a number of pixels, got "
                                f"{type(v).__name__}")
            if not math.isfinite(float(v)):
                raise ValueError(f"Camera: {name} must be finite, got {v}")
            object.__setattr__(self, name, float(v))
        if not self.right_wall_px - self.left_wall_px >= 1.0:
            raise ValueError(f"Camera: degenerate calibration, the right wall "
                             f"({self.right_wall_px:g} px) must lie at least 1 px right of the "
                             f"left wall ({self.left_wall_px:g} px)")

    @property
    def px_per_unit(self) -> float:
        """Pixels per world unit."""
        return (self.right_wall_px - self.left_wall_px) / (WALL_HI - WALL_LO)

    def to_world(self, px: Any) -> np.ndarray:
        """``(..., 2)`` continuous pixel coordinates (column, row) -> world units (x, y)."""
        p = check_finite(as_real_array(px, "px", np.float64), "px")
        if p.shape[-1:] != (2,):
            raise ValueError(f"px: expected shape (..., 2), got {p.shape}")
        s = self.px_per_unit
        return np.stack([WALL_LO + (p[..., 0] - self.left_wall_px) / s,
                         WALL_LO + (self.floor_px - p[..., 1]) / s], axis=-1)

    def to_pixels(self, world: Any) -> np.ndarray:
        """``(..., 2)`` world units (x, y) -> continuous pixel coordinates (column, row)."""
        w = check_finite(as_real_array(world, "world", np.float64), "world")
        if w.shape[-1:] != (2,):
            raise ValueError(f"world: expected shape (..., 2), got {w.shape}")
        s = self.px_per_unit
        return np.stack([self.left_wall_px + (w[..., 0] - WALL_LO) * s,
                         self.floor_px - (w[..., 1] - WALL_LO) * s], axis=-1)

    @classmethod
    def for_box_image(cls, size_px: int, box_size: float = 45.0) -> "Camera":
        """The camera of a square image of ``size_px`` showing the whole ``box_size`` box (walls
        included), as ``tpnet sim render`` draws it."""
        s = size_px / box_size
        return cls(WALL_LO * s, WALL_HI * s, (box_size - WALL_LO) * s)

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Any) -> "Camera":
        if not isinstance(d, dict):
            raise ValueError(f"camera: expected a JSON object, got {type(d).__name__}")
        cam = d.get("camera", d)
        keys = ("left_wall_px", "right_wall_px", "floor_px")
        missing = [k for k in keys if not isinstance(cam, dict) or k not in cam]
        if missing:
            raise ValueError(f"camera: missing {', '.join(missing)}")
        return cls(*(cam[k] for k in keys))

    @classmethod
    def parse(cls, text: str) -> "Camera":
        """``"LEFT,RIGHT,FLOOR"`` (pixels) or the path of a calibration JSON file (as written by
        ``tpnet sim render``: a ``"camera"`` object with the three fields)."""
        parts = text.split(",")
        if len(parts) == 3:
            try:
                vals = [float(p) for p in parts]
            except ValueError:
                vals = None
            if vals is not None:
                return cls(*vals)
        path = Path(text)
        if not path.is_file():
            raise FileNotFoundError(f"camera: {text} is neither LEFT,RIGHT,FLOOR (pixels) nor a "
                                    "calibration JSON file")
        try:
            d = json.loads(path.read_text())
        except (ValueError, UnicodeDecodeError) as exc:
            raise ValueError(f"camera: {text}: not a JSON file ({exc})") from None
        return cls.from_dict(d)


# --------------------------------------------------------------------------- body geometry
def outline_offset(ring_radius: float = BODY_RING_RADIUS,
                   particle_radius: float = BODY_PARTICLE_RADIUS,
                   n_particles: int = BODY_PARTICLES, samples: int = 36000) -> float:
    """How far the outline of the filled body (the polygon through the particle centres, with a
    disc of ``particle_radius`` at every centre) lies outside the circle through the centres, on
    average over the outline's length, for the undeformed ring (world units)."""
    phi = np.linspace(0.0, 2 * np.pi, samples, endpoint=False)
    step = 2 * np.pi / n_particles
    # the polygon's boundary along the ray at angle phi (vertex at angle 0)
    local = np.mod(phi, step) - step / 2
    r = ring_radius * math.cos(step / 2) / np.cos(local)
    # each disc's far intersection with the ray
    alpha = np.arange(n_particles) * step
    d = phi[:, None] - alpha[None, :]
    s = ring_radius * np.sin(d)
    inside = np.abs(s) <= particle_radius
    far = ring_radius * np.cos(d) + np.sqrt(np.maximum(particle_radius ** 2 - s ** 2, 0.0))
    r = np.maximum(r, np.where(inside & (np.cos(d) > 0), far, 0.0).max(axis=1))
    xy = np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)
    seg = np.linalg.norm(np.roll(xy, -1, axis=0) - xy, axis=1)
    return float((r * seg).sum() / seg.sum() - ring_radius)


#: the offset correction :func:`points_from_mask` applies by default (world units, ~0.08)
BODY_INSET = outline_offset()


def _resample_closed(curve: np.ndarray, count: int, start: float = 0.0) -> np.ndarray:
    """``count`` points uniformly by arc length on the closed polyline ``curve (K, 2)``, the
    first at arc length ``start``."""
    closed = np.vstack([curve, curve[:1]])
    seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    total = s[-1]
    t = np.mod(start + np.arange(count) * (total / count), total)
    return np.stack([np.interp(t, s, closed[:, 0]), np.interp(t, s, closed[:, 1])], axis=1)


def _signed_area(c: np.ndarray) -> float:
    x, y = c[:, 0], c[:, 1]
    return 0.5 * float((x * np.roll(y, -1) - np.roll(x, -1) * y).sum())


def _perimeter(c: np.ndarray) -> float:
    return float(np.linalg.norm(np.roll(c, -1, axis=0) - c, axis=1).sum())


def _inward_normals(c: np.ndarray) -> np.ndarray:
    """Unit inward normals of a clockwise closed curve (world axes, y up)."""
    t = np.roll(c, -1, axis=0) - np.roll(c, 1, axis=0)
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-300)
    return np.stack([t[:, 1], -t[:, 0]], axis=1)


def _top_start(c: np.ndarray) -> float:
    """Arc length (from ``c[0]``) where the vertical line through the centroid meets the closed
    curve ``c`` highest."""
    closed = np.vstack([c, c[:1]])
    seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    cx = float(c[:, 0].mean())
    dx = closed[:, 0] - cx
    a, b = dx[:-1], dx[1:]
    hit = np.nonzero((a <= 0) & (b > 0) | (a >= 0) & (b < 0) | (a == 0))[0]
    if hit.size == 0:                                # pragma: no cover - a closed curve crosses
        return float(s[int(np.argmax(c[:, 1]))])
    denom = np.where(b[hit] != a[hit], a[hit] - b[hit], 1.0)
    f = np.clip(np.where(b[hit] != a[hit], a[hit] / denom, 0.0), 0.0, 1.0)
    y = closed[hit, 1] + f * (closed[hit + 1, 1] - closed[hit, 1])
    k = int(np.argmax(y))
    return float(s[hit[k]] + f[k] * seg[hit[k]])


def _as_mask(mask: Any) -> np.ndarray:
    if isinstance(mask, (str, bytes)):
        raise TypeError(f"mask: expected a 2-D array, got {type(mask).__name__}")
    m = np.asarray(mask)
    if m.dtype == object or m.dtype.kind not in "biuf":
        raise TypeError(f"mask: expected a boolean or numeric 2-D array, got dtype {m.dtype}")
    if m.ndim != 2:
        raise ValueError(f"mask: expected a 2-D array (rows, columns), got shape {m.shape}")
    if m.shape[0] == 0 or m.shape[1] == 0:
        raise ValueError(f"mask: is empty (shape {m.shape})")
    if m.dtype.kind == "f" and not np.isfinite(m).all():
        raise ValueError("mask: contains NaN or infinite values")
    return (m != 0).astype(np.uint8)


def largest_component(mask: Any) -> np.ndarray:
    """The largest 8-connected blob of ``mask`` (nonzero = foreground) as a ``uint8`` 0/1 array;
    ``ValueError`` for a mask without foreground."""
    cv2 = require_cv2()
    m = _as_mask(mask)
    if not m.any():
        raise ValueError(f"mask: no foreground pixel in the {m.shape[1]} x {m.shape[0]} mask (an "
                         "empty mask): nothing to take the body's contour from")
    x, y, w, h = cv2.boundingRect(m)                   # label only the foreground's box
    count, labels, stats, _ = cv2.connectedComponentsWithStats(
        np.ascontiguousarray(m[y:y + h, x:x + w]), connectivity=8)
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    out = np.zeros_like(m)
    out[y:y + h, x:x + w] = labels == k
    return out


def points_from_mask(mask: Any, camera: Camera, n: int = 30, *, inset: float = BODY_INSET,
                     smooth: bool = True) -> np.ndarray:
    """``(n, 2)`` world-unit points on the outer contour of the largest blob of ``mask``.

    ``mask``: 2-D, nonzero = the body (other, smaller blobs are ignored; holes do not matter);
    ``camera``: the image's :class:`Camera`; ``n``: points, uniformly spaced by arc length,
    clockwise from the top (module docstring); ``inset``: world units the contour is moved inwards
    to sit on the particle centres (default :data:`BODY_INSET` for the paper's body; 0: the
    object's edge); ``smooth``: average the contour over one particle spacing before resampling.
    A blob touching the image border is cut by it: the border is part of its contour.
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"camera: expected a tpnet_ref.observe.Camera, got {type(camera).__name__}")
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)):
        raise TypeError(f"n: expected an integer, got {type(n).__name__}")
    if n < 3:
        raise ValueError(f"n: need at least 3 points, got {n}")
    inset = float(inset)
    if not math.isfinite(inset):
        raise ValueError(f"inset: must be finite, got {inset}")
    cv2 = require_cv2()
    comp = largest_component(mask)
    x0, y0, w, h = cv2.boundingRect(comp)
    comp = comp[y0:y0 + h, x0:x0 + w]
    area = int(comp.sum())
    # one pixel of margin so that a blob touching the border still has a closed outline
    contours, _ = cv2.findContours(np.pad(comp, 1), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    c = max(contours, key=len)[:, 0, :].astype(np.float64) - 1.0 + 0.5   # pixel centres
    c += [x0, y0]
    if len(np.unique(c, axis=0)) < 3:
        raise ValueError(f"mask: the largest blob ({area} pixel(s)) is too small for an outline; "
                         "the body should span several pixels")
    w = camera.to_world(c)
    if _signed_area(w) > 0:                            # clockwise in world axes (y up)
        w = w[::-1]
    # the outline, sampled densely (4 samples per contour pixel, at least 16 per particle
    # spacing; a multiple of the 30 bumps), whatever n is
    per_bump = max(16, -(-4 * len(c) // BODY_PARTICLES))
    dense = _resample_closed(w, BODY_PARTICLES * per_bump)
    if smooth:                                         # box filter over one bump period
        k = len(dense) // BODY_PARTICLES
        ext = np.concatenate([dense[-(k // 2):], dense, dense[:k - k // 2]])
        cs = np.concatenate([np.zeros((1, 2)), np.cumsum(ext, axis=0)])
        dense = (cs[k:] - cs[:-k])[: len(dense)] / k
    half_px = 0.5 / camera.px_per_unit
    shift = inset - half_px                            # to the edge, then onto the centres
    dense = dense + shift * _inward_normals(dense)
    dense = _resample_closed(dense, len(dense))
    return _resample_closed(dense, n, start=_top_start(dense))


def _as_image(x: Any, name: str) -> np.ndarray:
    if isinstance(x, (str, bytes)):
        raise TypeError(f"{name}: expected an image array, got {type(x).__name__}")
    a = np.asarray(x)
    if a.dtype == object or a.dtype.kind not in "buif":
        raise TypeError(f"{name}: expected a numeric image, got dtype {a.dtype}")
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] in (3, 4))):
        raise ValueError(f"{name}: expected a grey (H, W) or colour (H, W, 3|4) image, got shape "
                         f"{a.shape}")
    if a.shape[0] == 0 or a.shape[1] == 0:
        raise ValueError(f"{name}: is empty (shape {a.shape})")
    a = a.astype(np.float32)
    if not np.isfinite(a).all():
        raise ValueError(f"{name}: contains NaN or infinite values")
    return a[..., :3] if a.ndim == 3 else a


def foreground_mask(image: Any, background: Any, threshold: float | None = None) -> np.ndarray:
    """``uint8`` 0/1 mask of what differs from ``background`` (same shape, grey or colour).

    The difference (largest over the colour channels) is smoothed over a pixel (Gaussian,
    sigma 1) against sensor noise. ``threshold`` (in the image's grey levels): fixed, or ``None``:
    half-way between the background's and the body's typical difference (Otsu's threshold first
    finds the body: its largest blob; the edge then lies where a pixel is half covered, whatever
    the body's contrast).
    """
    cv2 = require_cv2()
    img = _as_image(image, "image")
    bg = _as_image(background, "background")
    if img.shape != bg.shape:
        raise ValueError(f"image, background: shapes differ ({img.shape} vs {bg.shape})")
    diff = np.abs(img - bg)
    if diff.ndim == 3:
        diff = diff.max(axis=2)
    diff = cv2.GaussianBlur(diff, (0, 0), 1.0)
    if threshold is not None:
        t = float(threshold)
        if not math.isfinite(t) or t < 0:
            raise ValueError(f"threshold: must be a finite number >= 0, got {threshold}")
        return (diff > t).astype(np.uint8)
    top = float(diff.max())
    if top <= 0:
        raise ValueError("image: identical to the background: no body to find")
    d8 = np.clip(diff * (255.0 / top), 0, 255).astype(np.uint8)
    t8, first = cv2.threshold(d8, 0, 1, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    body = largest_component(first).astype(bool)
    rest = diff[~body][::7]                            # a sample is plenty for a median
    t = 0.5 * (float(np.median(rest)) + float(np.median(diff[body]))) if rest.size \
        else t8 * top / 255.0
    return (diff > t).astype(np.uint8)


def points_from_image(image: Any, background: Any, camera: Camera, n: int = 30, *,
                      threshold: float | None = None, inset: float = BODY_INSET,
                      smooth: bool = True) -> np.ndarray:
    """``(n, 2)`` world-unit points of the body in ``image``: background subtraction
    (:func:`foreground_mask`), then :func:`points_from_mask` (largest blob, outer contour).

    ``image``, ``background``: grey ``(H, W)`` or colour ``(H, W, 3)`` arrays of one camera (any
    channel order; uint8 or float). Blobs smaller than the body (specks, distractors) are ignored.
    """
    return points_from_mask(foreground_mask(image, background, threshold), camera, n,
                            inset=inset, smooth=smooth)


# --------------------------------------------------------------------------- stray points
def drop_outliers(points: Any, *, link: float | None = None,
                  max_radius: float = BODY_MAX_RADIUS,
                  spur_factor: float | None = BODY_SPUR_FACTOR, return_mask: bool = False) -> Any:
    """The points of ``points (N, 2)`` (world units) that belong to the body, in their order.

    The body is one compact blob of known size: points are joined when closer than ``link``
    (default: ``max(3 x the median nearest-neighbour distance, 1.2)`` world units), the largest
    group is kept, and of it the points within ``max_radius`` (3.6: the scene's bodies reach 2.84
    from their centroid) of its median centre; then *spurs* go, points further than
    ``spur_factor`` (2) x the median nearest-neighbour distance from the next point with both
    nearest neighbours on one side of them (a stray just off the outline; ``None``: keep them).
    It errs towards dropping: a missing body point costs the model nothing measurable, a stray
    point a great deal (docs/robustness.md). Returns fewer points, never new ones (with
    ``return_mask``, also the boolean mask of the kept points). Fewer than 5 points are returned
    unchanged. NumPy only.
    """
    p = as_point_set(points, "points", dtype=np.float64)
    keep = ~body_outliers(p, link=link, max_radius=max_radius, spur_factor=spur_factor)
    for _ in range(3):          # what is left must pass the warning's test (checks.body_outliers)
        idx = np.nonzero(keep)[0]
        more = body_outliers(p[idx], link=link, max_radius=max_radius)
        if not more.any():
            break
        keep[idx[more]] = False
    out = np.asarray(points)[keep] if isinstance(points, np.ndarray) and points.ndim == 2 \
        else p[keep]
    return (out, keep) if return_mask else out


# --------------------------------------------------------------------------- frame timing
def model_rate_indices(times_s: Any, *, count: int | None = None, start_s: float | None = None,
                       tolerance_s: float | None = None) -> np.ndarray:
    """Indices of the frames nearest to ``start_s + k * 4/45 s`` (k = 0, 1, ...): the model's frame
    interval, picked from frames taken at ``times_s`` (seconds, strictly increasing; any rate).

    ``count``: frames wanted (default: as many as the times cover); ``start_s``: the first
    wanted time (default: the first frame's). Frames are picked, not interpolated: an image
    between two frames would show two half bodies, and points of two frames have no
    correspondence to interpolate. A pick further than ``tolerance_s`` (default a quarter of the
    model interval, 22 ms: any video of 23 fps or more) from its wanted time raises
    ``ValueError``; rates that are multiples of 45/4 = 11.25 fps pick exactly.
    """
    t = check_finite(as_real_array(times_s, "times_s", np.float64), "times_s")
    if t.ndim != 1 or t.size == 0:
        raise ValueError(f"times_s: expected a non-empty 1-D array of seconds, got shape {t.shape}")
    if t.size > 1 and not (np.diff(t) > 0).all():
        raise ValueError("times_s: must be strictly increasing")
    tol = 0.25 * MODEL_FRAME_S if tolerance_s is None else float(tolerance_s)
    if not (math.isfinite(tol) and tol >= 0):
        raise ValueError(f"tolerance_s: must be a finite number >= 0, got {tolerance_s}")
    t0 = float(t[0]) if start_s is None else float(start_s)
    if not math.isfinite(t0):
        raise ValueError(f"start_s: must be finite, got {start_s}")
    if count is None:
        k_max = int(math.floor((float(t[-1]) + tol - t0) / MODEL_FRAME_S + 1e-9)) + 1
        if k_max < 1:
            raise ValueError(f"start_s: {t0:g} s is after the last frame ({float(t[-1]):g} s)")
        count = k_max
    elif isinstance(count, (bool, np.bool_)) or not isinstance(count, (int, np.integer)) \
            or count < 1:
        raise ValueError(f"count: expected an integer >= 1, got {count!r}")
    want = t0 + MODEL_FRAME_S * np.arange(count)
    j = np.clip(np.searchsorted(t, want), 1, max(t.size - 1, 1))
    lo = np.maximum(j - 1, 0)
    idx = np.where(np.abs(t[lo] - want) <= np.abs(t[np.minimum(j, t.size - 1)] - want), lo,
                   np.minimum(j, t.size - 1))
    err = np.abs(t[idx] - want)
    bad = np.nonzero(err > tol + 1e-12)[0]
    if bad.size:
        k = int(bad[0])
        raise ValueError(f"times_s: no frame within {tol * 1e3:.1f} ms of {want[k]:.4f} s (model "
                         f"frame {k}; nearest {t[idx[k]]:.4f} s): the video is too short or its "
                         "frame rate too low for the model's 4/45 s interval (raise "
                         "tolerance_s to accept it)")
    if count > 1 and len(np.unique(idx)) < count:
        raise ValueError("times_s: frames are too sparse; one frame would be used twice")
    return idx


def frames_at_model_rate(times_s: Any, frames: Any, **kwargs: Any) -> Any:
    """The frames of ``frames`` (a sequence or an array, one per time in ``times_s``) nearest to
    the model's frame interval, 4/45 s apart (:func:`model_rate_indices` says how and takes the
    same keywords). An array gives an array, anything else a list."""
    idx = model_rate_indices(times_s, **kwargs)
    if len(frames) != len(np.asarray(times_s)):
        raise ValueError(f"frames: {len(frames)} frames for {len(np.asarray(times_s))} times")
    if isinstance(frames, np.ndarray):
        return frames[idx]
    return [frames[int(i)] for i in idx]


__all__ = ["Camera", "points_from_mask", "points_from_image", "drop_outliers",
           "frames_at_model_rate", "model_rate_indices", "foreground_mask", "largest_component",
           "outline_offset", "require_cv2", "BODY_INSET", "MODEL_FRAME_S", "WALL_LO", "WALL_HI",
           "BODY_LINK_FACTOR", "BODY_LINK_MIN", "BODY_MAX_RADIUS", "BODY_SPUR_FACTOR"]
