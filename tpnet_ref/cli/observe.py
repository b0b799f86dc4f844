"""``tpnet observe``: a video or PNG frames -> the model's window of point sets (.npy, world units).

The frames 4/45 s apart are picked (:func:`tpnet_ref.observe.model_rate_indices`), the body is
found in each by background subtraction (:func:`tpnet_ref.observe.points_from_image`) and its
outline resampled to ``--points`` points; ``tpnet predict`` takes the result.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from .files import output_path, save_npy

#: frames averaged (median) into a background when none is given
_BACKGROUND_FRAMES = 45


def add_cli(sub: Any) -> None:
    p = sub.add_parser("observe", help="extract the model's window (m point sets, world units) "
                                       "from a video or PNG frames")
    p.add_argument("source", help="a video file (.mp4, .avi, ...) or a directory of PNG frames "
                                  "(read in name order)")
    p.add_argument("--camera", required=True,
                   help="LEFT,RIGHT,FLOOR: the columns of the walls' inner faces and the row of "
                        "the floor's top, in px; or a calibration JSON (tpnet sim render writes "
                        "one; it also gives --fps and --background)")
    p.add_argument("--fps", type=float, default=None,
                   help="frame rate (default: the calibration's, else the video's)")
    p.add_argument("--background", default=None,
                   help="image of the scene without the body (default: the calibration's, else "
                        "the per-pixel median of frames across the video)")
    p.add_argument("--frames", type=int, default=4,
                   help="model frames to extract, 4/45 s apart (4: one m = 4 window; more for a "
                        "longer record)")
    p.add_argument("--start", type=float, default=0.0, help="time of the first frame, s")
    p.add_argument("--points", type=int, default=30, help="points per frame")
    p.add_argument("--threshold", type=float, default=None,
                   help="difference from the background that counts as the body, grey levels "
                        "(default: half the body's contrast, found per frame)")
    p.add_argument("-o", "--output", required=True, help=".npy file for the (frames, points, 2) "
                                                         "window, world units")
    p.set_defaults(func=_cli_observe)


def _calibration(text: str) -> tuple[Any, dict, Path | None]:
    from ..observe import Camera
    cam = Camera.parse(text)
    path = Path(text)
    if path.is_file():
        return cam, json.loads(path.read_text()), path.parent
    return cam, {}, None


def _read_image(path: Path, what: str) -> np.ndarray:
    from ..observe import require_cv2
    cv2 = require_cv2()
    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError(f"{what} {path}: not an image OpenCV can read")
    return img


class _Source:
    """Frames of a video file or of a directory of PNGs, by index."""

    def __init__(self, source: str) -> None:
        from ..observe import require_cv2
        self.cv2 = require_cv2()
        self.path = Path(source)
        if self.path.is_dir():
            self.files = sorted(f for f in self.path.glob("*.png")
                                if f.name != "background.png")
            if not self.files:
                raise FileNotFoundError(f"{source}: no PNG frames in this directory")
            self.count = len(self.files)
            self.video_fps = None
        elif self.path.is_file():
            self.files = []
            cap = self.cv2.VideoCapture(str(self.path))
            if not cap.isOpened():
                raise ValueError(f"{source}: not a video OpenCV can read")
            self.count = int(cap.get(self.cv2.CAP_PROP_FRAME_COUNT))
            fps = float(cap.get(self.cv2.CAP_PROP_FPS))
            self.video_fps = fps if fps > 0 else None
            cap.release()
            if self.count <= 0:
                self.count = sum(1 for _ in self._decode())
        else:
            raise FileNotFoundError(f"{source}: no such video file or frame directory")

    def _decode(self) -> Any:
        cap = self.cv2.VideoCapture(str(self.path))
        try:
            while True:
                ok, img = cap.read()
                if not ok:
                    return
                yield img
        finally:
            cap.release()

    def frames(self, indices: Any) -> dict[int, np.ndarray]:
        want = sorted(set(int(i) for i in indices))
        if self.files:
            return {i: _read_image(self.files[i], "frame") for i in want}
        got: dict[int, np.ndarray] = {}
        for j, img in enumerate(self._decode()):
            if j in want:
                got[j] = img
            if j >= want[-1]:
                break
        missing = [i for i in want if i not in got]
        if missing:
            raise ValueError(f"{self.path}: frame {missing[0]} could not be read (the video "
                             f"holds {len(got) and max(got) + 1} readable frames)")
        return got


def _cli_observe(args: Any) -> int:
    from ..observe import MODEL_FRAME_S, model_rate_indices, points_from_image
    output_path(args.output, "--output", ".npy")
    if args.frames < 1:
        raise ValueError(f"--frames: must be >= 1, got {args.frames}")
    camera, calib, calib_dir = _calibration(args.camera)
    src = _Source(args.source)
    fps = args.fps or calib.get("fps") or src.video_fps
    if not fps:
        raise ValueError(f"{args.source}: frame rate unknown; pass --fps")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"--fps: must be a positive number, got {fps}")
    times = np.arange(src.count) / float(fps)
    idx = model_rate_indices(times, count=args.frames, start_s=args.start)
    imgs = src.frames(idx)
    if args.background:
        bg = _read_image(Path(args.background), "--background")
    elif calib.get("background") and calib_dir is not None:
        bg = _read_image(calib_dir / calib["background"], "background (from the calibration)")
    else:
        step = max(1, src.count // _BACKGROUND_FRAMES)
        stack = src.frames(range(0, src.count, step))
        bg = np.median(np.stack(list(stack.values())), axis=0).astype(np.uint8)
    window = np.stack([points_from_image(imgs[int(i)], bg, camera, args.points,
                                         threshold=args.threshold) for i in idx])
    path = save_npy(args.output, window, "--output")
    err = float(np.abs(times[idx] - (args.start + MODEL_FRAME_S * np.arange(args.frames))).max())
    shown = ", ".join(str(int(i)) for i in idx[:8]) + (", ..." if len(idx) > 8 else "")
    print(f"wrote {window.shape} to {path}: frames {shown} of {src.count} at {fps:g} fps "
          f"(t = {times[idx[0]]:.3f} .. {times[idx[-1]]:.3f} s, within {err * 1e3:.1f} ms of the "
          "model's 4/45 s steps)")
    from ..checks import window_body_problem
    problem = window_body_problem(window)
    if problem:
        print(f"tpnet observe: warning: {problem}", file=sys.stderr)
    return 0
