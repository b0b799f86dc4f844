"""A synthetic camera: the scene's trajectory as a video or PNG frames (OpenCV: the ``vision`` extra).

What it draws (square image of ``size`` px showing the whole 45 x 45 box, walls included):

* the box: the four walls (thickness 1) in grey around the free area [1, 44]^2;
* a textured background inside it (smooth random blotches plus a finer grain, ``texture`` grey
  levels peak to peak), the same in every frame: a static camera;
* the body as the paper draws it, a filled soft body: the polygon through the 30 particle centres,
  filled, with a disc of the particle radius (0.15) at every centre, anti-aliased;
* ``distractors`` blobs per frame (discs of radius 0.25-0.8 world units, random grey level, at
  random places at least one world unit clear of the body: specks, a ball, a hand);
* sensor noise: Gaussian, ``noise`` grey levels standard deviation, new in every frame;
* frames at ``fps`` (any rate): frame ``j`` shows the state at ``t = j / fps``, the trajectory's
  rows linearly interpolated (row ``k`` is at ``t = k / 45 s``; 45 fps gives the rows themselves
  and every 4th frame is a model frame).

:func:`write_render` writes the frames (``.mp4`` / ``.avi`` video, or a directory of PNGs) and,
next to them, the calibration (:class:`tpnet_ref.observe.Camera`, the frame rate, what was drawn:
JSON), the background without the body and noise (a PNG, what a camera would average from frames
without the body) and the true particle centres of every frame (``.npy``).
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..extras import require
from . import Camera
from ..sim.scene import SceneParams

#: colours (BGR, OpenCV's order): walls, the body
WALL_BGR = (80, 80, 80)
BODY_BGR = (40, 95, 215)
VIDEO_CODECS = {".mp4": "mp4v", ".avi": "MJPG"}


def _cv2() -> Any:
    return require("cv2", "vision", "rendering images and videos (OpenCV)")


@dataclass(frozen=True)
class RenderSettings:
    """How the synthetic camera draws the scene (see the module docstring)."""

    size: int = 640               # image width = height, px (the whole 45 x 45 box)
    fps: float = 45.0             # frames per second
    noise: float = 3.0            # sensor noise, standard deviation in grey levels
    texture: float = 60.0         # background texture, grey levels peak to peak (0: plain)
    distractors: int = 0          # stray blobs per frame
    seed: int = 0                 # texture, noise and distractors

    def __post_init__(self) -> None:
        if isinstance(self.size, bool) or not isinstance(self.size, (int, np.integer)) \
                or not 16 <= self.size <= 8192:
            raise ValueError(f"size: expected an integer number of pixels in 16..8192, got "
                             f"{self.size!r}")
        if not (math.isfinite(self.fps) and 1.0 <= self.fps <= 10000.0):
            raise ValueError(f"fps: expected a frame rate in 1..10000, got {self.fps}")
        for name in ("noise", "texture"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0.0 <= v <= 255.0):
                raise ValueError(f"{name}: expected 0..255 grey levels, got {v}")
        if isinstance(self.distractors, bool) or not isinstance(self.distractors,
                                                                 (int, np.integer)) \
                or not 0 <= self.distractors <= 100:
            raise ValueError(f"distractors: expected an integer in 0..100, got "
                             f"{self.distractors!r}")

    @property
    def camera(self) -> Camera:
        return Camera.for_box_image(self.size, SceneParams().box_size)


def background(settings: RenderSettings) -> np.ndarray:
    """``(size, size, 3)`` uint8: the walls and the textured floor of the box, no body, no noise."""
    cv2 = _cv2()
    s = settings.size
    rng = np.random.default_rng([settings.seed, 1])
    img = np.full((s, s, 3), 175.0, dtype=np.float32)
    if settings.texture > 0:
        tex = np.zeros((s, s, 3), dtype=np.float32)
        for cells, weight in ((8, 0.55), (40, 0.3), (160, 0.15)):
            low = rng.uniform(-1.0, 1.0, (cells, cells, 3)).astype(np.float32)
            tex += weight * cv2.resize(low, (s, s), interpolation=cv2.INTER_CUBIC)
        img += tex * (settings.texture / 2.0)
    cam = settings.camera
    lo = int(round(cam.left_wall_px))
    hi = int(round(cam.right_wall_px))
    img[:, :lo] = WALL_BGR
    img[:, hi:] = WALL_BGR
    img[:lo, :] = WALL_BGR
    img[hi:, :] = WALL_BGR
    return np.clip(img, 0, 255).astype(np.uint8)


def _signed_distance(q: np.ndarray, poly: np.ndarray, radius: float) -> np.ndarray:
    """Signed distance (negative inside) of the points ``q (P, 2)`` to the filled soft body: the
    polygon ``poly (N, 2)`` (even-odd rule) united with a disc of ``radius`` at every vertex."""
    a = poly
    b = np.roll(poly, -1, axis=0)
    ab = b - a
    aq = q[:, None, :] - a[None, :, :]
    t = np.clip((aq * ab).sum(axis=2) / np.maximum((ab * ab).sum(axis=1), 1e-300), 0.0, 1.0)
    edge = np.sqrt(((aq - t[:, :, None] * ab) ** 2).sum(axis=2)).min(axis=1)
    ay, by = a[None, :, 1], b[None, :, 1]
    qy, qx = q[:, 1:2], q[:, 0:1]
    cross = (ay > qy) != (by > qy)
    xint = a[None, :, 0] + (qy - ay) / np.where(by != ay, by - ay, 1.0) * ab[None, :, 0]
    inside = (cross & (qx < xint)).sum(axis=1) % 2 == 1
    sd = np.where(inside, -edge, edge)
    discs = np.sqrt(((q[:, None, :] - poly[None, :, :]) ** 2).sum(axis=2)).min(axis=1) - radius
    return np.minimum(sd, discs)


def _blend(img: np.ndarray, r0: int, c0: int, alpha: np.ndarray, colour: Any) -> None:
    h, w = alpha.shape
    region = img[r0:r0 + h, c0:c0 + w].astype(np.float32)
    col = np.asarray(colour, dtype=np.float32)
    a = alpha[..., None] if region.ndim == 3 else alpha
    img[r0:r0 + h, c0:c0 + w] = np.clip(region * (1 - a) + col * a + 0.5, 0, 255).astype(img.dtype)


def coverage(centres: np.ndarray, camera: Camera, shape: tuple[int, int],
             particle_radius: float = 0.15) -> tuple[int, int, np.ndarray]:
    """How much of each pixel the filled soft body of ``centres (N, 2)`` (world units) covers,
    anti-aliased over one pixel (the signed distance at the pixel's centre, ramped from +0.5 px
    to -0.5 px), in the bounding box of the body: ``(row0, col0, alpha (h, w) float32)``. A
    pixel is at least half covered exactly when its centre lies inside the body."""
    px = camera.to_pixels(centres)
    rad = particle_radius * camera.px_per_unit
    lo = np.floor(px.min(axis=0) - rad - 2).astype(int)
    hi = np.ceil(px.max(axis=0) + rad + 2).astype(int)
    c0, r0 = max(int(lo[0]), 0), max(int(lo[1]), 0)
    c1, r1 = min(int(hi[0]), shape[1]), min(int(hi[1]), shape[0])
    if c1 <= c0 or r1 <= r0:
        return 0, 0, np.zeros((0, 0), dtype=np.float32)
    rr, cc = np.mgrid[r0:r1, c0:c1]
    q = np.stack([cc.ravel() + 0.5, rr.ravel() + 0.5], axis=1)
    sd = _signed_distance(q, px, rad).reshape(rr.shape)
    return r0, c0, np.clip(0.5 - sd, 0.0, 1.0).astype(np.float32)


def draw_body(img: np.ndarray, centres: np.ndarray, camera: Camera, colour: Any = BODY_BGR,
              particle_radius: float = 0.15) -> np.ndarray:
    """Draw the filled soft body (polygon through the centres, a disc of ``particle_radius`` at
    every centre) of ``centres (N, 2)`` (world units) into ``img`` in place (:func:`coverage`);
    returns ``img``. NumPy only."""
    r0, c0, alpha = coverage(centres, camera, img.shape[:2], particle_radius)
    if alpha.size:
        _blend(img, r0, c0, alpha, colour)
    return img


def body_mask(centres: np.ndarray, size: int) -> np.ndarray:
    """``(size, size)`` uint8 0/1: the pixels whose centre lies inside the body (the box image of
    ``size`` px, as :class:`RenderSettings` frames it)."""
    cam = RenderSettings(size=size).camera
    mask = np.zeros((size, size), dtype=np.uint8)
    r0, c0, alpha = coverage(centres, cam, mask.shape)
    mask[r0:r0 + alpha.shape[0], c0:c0 + alpha.shape[1]] = alpha >= 0.5
    return mask


def _distractors(img: np.ndarray, centres: np.ndarray, camera: Camera, count: int,
                 rng: np.random.Generator) -> None:
    c0 = centres.mean(axis=0)
    reach = float(np.sqrt(((centres - c0) ** 2).sum(axis=1)).max()) + 0.15
    placed = 0
    for _ in range(100 * count):
        if placed == count:
            break
        r = rng.uniform(0.25, 0.8)
        xy = rng.uniform(1.0 + r, 44.0 - r, 2)
        if np.sqrt(((xy - c0) ** 2).sum()) < reach + r + 1.0:
            continue
        grey = int(rng.choice([rng.integers(10, 60), rng.integers(200, 250)]))
        rows, cols, alpha = coverage(xy[None], camera, img.shape[:2], r)
        if alpha.size:
            _blend(img, rows, cols, alpha, (grey, grey, grey))
        placed += 1


def render_frame(centres: np.ndarray, settings: RenderSettings, bg: np.ndarray,
                 rng: np.random.Generator) -> np.ndarray:
    """One ``(size, size, 3)`` uint8 BGR frame of the body at ``centres (N, 2)`` on ``bg``."""
    cam = settings.camera
    img = bg.copy()
    if settings.distractors:
        _distractors(img, centres, cam, settings.distractors, rng)
    draw_body(img, centres, cam)
    if settings.noise > 0:
        noisy = img.astype(np.float32)
        noisy += rng.standard_normal(img.shape, dtype=np.float32) * np.float32(settings.noise)
        img = np.clip(noisy + 0.5, 0, 255).astype(np.uint8)
    return img


def frame_positions(rows: np.ndarray, fps: float, dt: float = 1.0 / 45.0) -> np.ndarray:
    """Particle centres ``(F, N, 2)`` at the frame times ``j / fps`` of a trajectory whose row
    ``k`` is the state at ``k dt`` (linear interpolation between rows; as many frames as the rows
    cover)."""
    rows = np.asarray(rows, dtype=np.float64)
    duration = (len(rows) - 1) * dt
    count = int(math.floor(duration * fps + 1e-9)) + 1
    k = np.arange(count) / fps / dt
    i = np.minimum(np.floor(k + 1e-9).astype(int), len(rows) - 1)
    f = np.clip(k - i, 0.0, 1.0)[:, None, None]
    j = np.minimum(i + 1, len(rows) - 1)
    return rows[i] * (1.0 - f) + rows[j] * f


def render_frames(positions: np.ndarray, settings: RenderSettings,
                  bg: np.ndarray | None = None) -> Iterator[np.ndarray]:
    """The frames of ``positions (F, N, 2)`` (world units), one ``(size, size, 3)`` uint8 array
    at a time."""
    bg = background(settings) if bg is None else bg
    rng = np.random.default_rng([settings.seed, 2])
    for p in positions:
        yield render_frame(p, settings, bg, rng)


def output_paths(out: str | Path) -> dict[str, Path]:
    """Where :func:`write_render` puts the frames, the calibration, the background and the true
    centres for ``out`` (a ``.mp4``/``.avi`` video or a directory); ``ValueError`` for another
    suffix."""
    out = Path(out)
    if out.suffix.lower() in VIDEO_CODECS:
        stem = out.with_suffix("")
        return {"frames": out, "calibration": stem.with_suffix(".json"),
                "background": Path(f"{stem}.background.png"), "truth": Path(f"{stem}.truth.npy")}
    if out.suffix:
        raise ValueError(f"--output {out}: must end in .mp4 or .avi (a video) or be a directory "
                         "(PNG frames)")
    return {"frames": out, "calibration": out / "calibration.json",
            "background": out / "background.png", "truth": out / "truth.npy"}


def write_render(out: str | Path, rows: np.ndarray, settings: RenderSettings,
                 scene: dict[str, Any] | None = None, dt: float = 1.0 / 45.0) -> dict[str, Any]:
    """Render the trajectory ``rows`` (``(steps, N, 2)``, world units, row ``k`` at ``k dt``) to
    ``out``: a ``.mp4``/``.avi`` video or a directory of PNG frames (``frame_00000.png``, ...),
    with the calibration JSON, the background PNG and the true centres (``.npy``) next to it
    (``<stem>.json``, ``<stem>.background.png``, ``<stem>.truth.npy``; in a directory:
    ``calibration.json``, ``background.png``, ``truth.npy``). Returns the calibration."""
    cv2 = _cv2()
    out = Path(out)
    paths = output_paths(out)
    video = out.suffix.lower() in VIDEO_CODECS
    parent = out.parent if video else out
    if video and not parent.is_dir():
        raise FileNotFoundError(f"--output {out}: directory {parent} does not exist")
    if not video:
        if out.exists() and not out.is_dir():
            raise ValueError(f"--output {out}: exists and is not a directory")
        if not out.parent.is_dir():
            raise FileNotFoundError(f"--output {out}: directory {out.parent} does not exist")
        out.mkdir(exist_ok=True)
    positions = frame_positions(rows, settings.fps, dt)
    bg = background(settings)
    s = settings.size
    if video:
        writer = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*VIDEO_CODECS[out.suffix.lower()]),
                                 float(settings.fps), (s, s))
        if not writer.isOpened():
            raise OSError(f"--output {out}: OpenCV cannot write {out.suffix} video here")
        try:
            for img in render_frames(positions, settings, bg):
                writer.write(img)
        finally:
            writer.release()
    else:
        for j, img in enumerate(render_frames(positions, settings, bg)):
            if not cv2.imwrite(str(out / f"frame_{j:05d}.png"), img):
                raise OSError(f"--output {out}: cannot write frame_{j:05d}.png")
    if not cv2.imwrite(str(paths["background"]), bg):
        raise OSError(f"cannot write {paths['background']}")
    with open(paths["truth"], "wb") as fh:
        np.save(fh, positions.astype(np.float64), allow_pickle=False)
    calib = {
        "camera": settings.camera.to_dict(),
        "fps": float(settings.fps),
        "frames": int(len(positions)),
        "image_size": [s, s],
        "frames_path": paths["frames"].name,
        "background": paths["background"].name,
        "truth": paths["truth"].name,
        "world": {"walls_x": [1.0, 44.0], "floor_y": 1.0,
                  "note": "pixel (c, r) covers [c, c+1) x [r, r+1), row 0 at the top; "
                          "world units of docs/spec.md section 5"},
        "render": asdict(settings),
        "scene": scene or {},
    }
    paths["calibration"].write_text(json.dumps(calib, indent=1) + "\n")
    return calib


__all__ = ["RenderSettings", "background", "draw_body", "body_mask", "render_frame",
           "render_frames", "frame_positions", "write_render", "output_paths", "coverage",
           "VIDEO_CODECS"]
