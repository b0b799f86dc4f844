"""``tpnet animate``: a GIF of one held-out case, the simulator and TP-Net's rollout side by side.

The model gets the first m frames with the points of each frame shuffled (as ``tpnet demo``)
and predicts every later frame from its own predictions. Left: the simulator's ring; right: the
prediction, with the simulator's ring faint behind it; both the whole box. matplotlib's Pillow
writer (matplotlib depends on Pillow), no ffmpeg.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..config import normalize
from ..model import load
from ..sim.protocol import FRAME_EVERY, SIM_ROWS, order_points, split_protocol
from ..sim import simulate
from .demo import DEMO_CASE
from .plots import BOX, draw_walls, pyplot
from .run import errors

#: simulator steps per second (docs/spec.md §5): model frame j is at t = 4 j / 45 s
STEPS_PER_S = 45.0


def check_gif_settings(every: int, fps: int, dpi: int) -> None:
    """One-line error unless ``every``, ``fps`` >= 1 and ``dpi`` >= 10."""
    if every < 1 or fps < 1 or dpi < 10:
        raise ValueError(f"animate: every, fps >= 1 and dpi >= 10, got {every}, {fps}, {dpi}")


def rollout_case(model: Any, frames: np.ndarray, last_frame: int | None,
                 seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The model's rollout of a simulated case ``frames (F, N, dim)`` (world units): its first m
    frames shuffled (``seed``) in, predictions of frames m .. ``last_frame`` (default: the last)
    out. Returns ``(window, pred, err, last)``: the shuffled input, the predictions and their
    squared position error per prediction (normalised)."""
    m, F = model.config.m, frames.shape[0]
    last = F - 1 if last_frame is None else int(last_frame)
    if not m <= last < F:
        raise ValueError(f"animate: last_frame must lie in [{m}, {F - 1}], got {last_frame}")
    inputs, targets = split_protocol(frames[None], m, last - m + 1)
    window = order_points(inputs, "shuffle", seed)[0]                    # shuffled input frames
    pred = model.rollout(window, last - m + 1)                           # frames m .. last
    err = errors(normalize(targets), normalize(pred[None].astype(np.float64)))["Ep_squared"][0]
    return window, pred, err, last


def write_gif(fig: Any, draw: Callable[[int], Any], m: int, last: int, every: int,
              path: str | os.PathLike, fps: int, dpi: int, err: np.ndarray) -> dict[str, object]:
    """Draw every input frame, then every ``every``-th model frame up to ``last`` (always
    included), into the GIF ``path``; close ``fig``. Every frame shares one palette of at most 256
    colours, taken from the frames themselves (no dithering: flat colours stay flat), so Pillow
    stores each frame as what changed since the one before: under half the bytes of
    matplotlib's Pillow writer (a palette a frame, every frame whole). Returns what
    :func:`animate` returns."""
    from PIL import Image
    shown = list(range(m)) + list(range(m, last + 1, every))
    if shown[-1] != last:
        shown.append(last)
    fig.set_dpi(dpi)
    rgb = []
    for j in shown:
        draw(j)
        fig.canvas.draw()
        rgb.append(np.asarray(fig.canvas.buffer_rgba())[..., :3].copy())
    pyplot().close(fig)
    sample = np.concatenate(rgb[::max(1, len(rgb) // 16)], axis=0)   # <= ~16 frames for the palette
    palette = Image.fromarray(sample).quantize(256, method=Image.Quantize.MEDIANCUT,
                                               dither=Image.Dither.NONE)
    gif = [Image.fromarray(a).quantize(palette=palette, dither=Image.Dither.NONE) for a in rgb]
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    gif[0].save(out, format="GIF", save_all=True, append_images=gif[1:], optimize=True,
                duration=round(1000 / fps), loop=0)
    return {"path": out, "gif_frames": len(shown), "m": m,
            "Ep_squared": {h: float(err[h - 1]) for h in (40, 80) if h <= last - m + 1}}


def animate(path: str | os.PathLike = "docs/rollout.gif", weights: str | None = None, *,
            case: Sequence[float] = DEMO_CASE, last_frame: int | None = None, every: int = 2,
            fps: int = 12, dpi: int = 64, seed: int = 0,
            model: Any = None) -> dict[str, object]:
    """Write a GIF of ``case``: the m input frames, then model frames m .. ``last_frame``
    (default: the last simulated one), every ``every``-th, at ``fps`` GIF frames per second; ``dpi`` sets the size
    (64: 416 x 250 pixels). ``model``: an already loaded :class:`~tpnet_ref.model.TPNet`
    instead of ``weights``. Returns the path, the GIF frame count, the model's m and the squared
    position error of the prediction at 40 and 80 predictions (normalised, docs/glossary.md)."""
    check_gif_settings(every, fps, dpi)
    plt = pyplot()
    model = load(weights, dtype="float32") if model is None else model
    m = model.config.m
    frames = simulate(*case, SIM_ROWS)[::FRAME_EVERY]                    # (F, N, 2) world units
    window, pred, err, last = rollout_case(model, frames, last_frame, seed)

    fig, (ax_t, ax_p) = plt.subplots(1, 2, figsize=(6.5, 3.9))
    for ax, title in ((ax_t, "simulator"), (ax_p, f"TP-Net, from {m} shuffled frames")):
        draw_walls(ax)
        ax.set_xlim(*BOX)
        ax.set_ylim(*BOX)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(title, fontsize=10)
    # centre paths so far (the body is small in the box: the path shows where it went)
    tc = frames.mean(axis=1)
    pc = np.vstack([tc[:m], pred.mean(axis=1)])
    path_t, = ax_t.plot([], [], "-", color="0.6", lw=0.8)
    path_p, = ax_p.plot([], [], "-", color="tab:red", lw=0.8, alpha=0.45)
    ring_t, = ax_t.plot([], [], "-o", color="k", ms=2.5, lw=1.0)
    ghost, = ax_p.plot([], [], "-", color="0.6", lw=1.0, label="simulator's ring")
    dots_p, = ax_p.plot([], [], "o", color="tab:red", ms=2.8, label="TP-Net's points")
    inp_p, = ax_p.plot([], [], "o", color="tab:blue", ms=2.8, label="input (shuffled)")
    fig.legend(handles=[inp_p, dots_p, ghost], loc="lower center", ncol=3, fontsize=8,
               frameon=False, handletextpad=0.3, columnspacing=1.2, markerscale=1.6)
    counter = fig.text(0.5, 0.94, "", ha="center", fontsize=10, family="monospace")
    fig.subplots_adjust(left=0.02, right=0.98, top=0.86, bottom=0.1, wspace=0.06)

    def closed(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = np.vstack([p, p[:1]])
        return q[:, 0], q[:, 1]

    def draw(j: int) -> tuple[object, ...]:
        t = frames[j]
        ring_t.set_data(*closed(t))
        path_t.set_data(tc[: j + 1, 0], tc[: j + 1, 1])
        path_p.set_data(pc[: j + 1, 0], pc[: j + 1, 1])
        if j < m:
            ghost.set_data([], [])
            dots_p.set_data([], [])
            inp_p.set_data(window[j][:, 0], window[j][:, 1])
            what = f"input frame {j + 1} of {m}"
        else:
            ghost.set_data(*closed(t))
            q = pred[j - m]
            dots_p.set_data(q[:, 0], q[:, 1])
            inp_p.set_data([], [])
            what = f"prediction {j - m + 1}, E_p {err[j - m]:.2g}"
        counter.set_text(f"frame {j:3d}   t = {j * FRAME_EVERY / STEPS_PER_S:4.1f} s   {what}")
        return ring_t, ghost, dots_p, inp_p, counter, path_t, path_p

    return write_gif(fig, draw, m, last, every, path, fps, dpi, err)


__all__ = ["animate", "rollout_case", "write_gif", "check_gif_settings", "STEPS_PER_S"]
