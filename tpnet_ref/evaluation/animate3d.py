"""``tpnet animate`` for a 3-D model: a GIF of one held-out 3-D throw in three views.

The 3-D twin of :mod:`tpnet_ref.evaluation.animate`: the model gets the first m frames of a
3-D test case (docs/spec.md §8) with the points of each frame shuffled and predicts every later
frame from its own predictions. Three panels show the box from above (x-y), from the front
(x-z) and from the side (y-z): the simulator's ball in grey, TP-Net's points in red, each
centre's path so far. matplotlib's Pillow writer, no ffmpeg; the scene needs the ``sim3d``
extra (MuJoCo).
"""
from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np

from ..model import load
from ..sim.cases3d import TEST_CASES3D
from ..sim.protocol import FRAME_EVERY, SIM_ROWS
from .animate import STEPS_PER_S, check_gif_settings, rollout_case, write_gif
from .plots import BOX, draw_walls, pyplot

#: the 3-D demo throw: the first held-out 3-D case (force, azimuth, elevation, x, y, z)
DEMO_CASE3D: tuple[float, ...] = tuple(TEST_CASES3D[0])
#: the three views: (title, horizontal axis, vertical axis) as coordinate indices
VIEWS = (("from above (x, y)", 0, 1), ("from the front (x, z)", 0, 2),
         ("from the side (y, z)", 1, 2))


def simulate_case3d(case: Sequence[float], rows: int = SIM_ROWS) -> np.ndarray:
    """Model frames ``(F, N, 3)`` (world units) of one 3-D throw ``(force, azimuth_deg,
    elevation_deg, x, y, z)``: rows 0, 4, ... of :func:`tpnet_ref.sim.scene3d.simulate3d`."""
    from ..sim.scene3d import simulate3d
    c = [float(v) for v in case]
    if len(c) != 6:
        raise ValueError(f"case: a 3-D throw has 6 numbers (force, azimuth, elevation, x, y, z), "
                         f"got {len(c)}")
    return simulate3d(*c, rows)[::FRAME_EVERY]


def animate3d(path: str | os.PathLike = "docs/rollout3d.gif", weights: str | None = None, *,
              case: Sequence[float] = DEMO_CASE3D, last_frame: int | None = None,
              every: int = 2, fps: int = 12, dpi: int = 64, seed: int = 0,
              model: object | None = None) -> dict[str, object]:
    """Write a GIF of the 3-D ``case``: the m input frames, then model frames m .. ``last_frame``
    (default: the last simulated one), every ``every``-th, at ``fps`` GIF frames per second,
    ``dpi`` sets the size. ``model``: an already loaded 3-D :class:`~tpnet_ref.model.TPNet`
    instead of ``weights``. Returns the path, the GIF frame count, the model's m and the squared
    position error at 40 and 80 predictions (normalised)."""
    check_gif_settings(every, fps, dpi)
    net = load(weights, dtype="float32") if model is None else model
    if net.config.dim != 3:
        raise ValueError(f"animate3d: needs a 3-D model, got dim = {net.config.dim}")
    plt = pyplot()
    m = net.config.m
    frames = simulate_case3d(case)                                      # (F, N, 3)
    window, pred, err, last = rollout_case(net, frames, last_frame, seed)

    fig, axes = plt.subplots(1, 3, figsize=(9.0, 3.6))
    artists = []
    tc = frames.mean(axis=1)
    pc = np.vstack([tc[:m], pred.mean(axis=1)])
    for ax, (title, a, b) in zip(axes, VIEWS):
        draw_walls(ax)
        ax.set_xlim(*BOX)
        ax.set_ylim(*BOX)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(title, fontsize=9)
        path_t, = ax.plot([], [], "-", color="0.6", lw=0.8)
        path_p, = ax.plot([], [], "-", color="tab:red", lw=0.8, alpha=0.45)
        truth, = ax.plot([], [], "o", color="0.35", ms=2.0, label="simulator")
        dots, = ax.plot([], [], "o", color="tab:red", ms=2.2, label="TP-Net's points")
        inp, = ax.plot([], [], "o", color="tab:blue", ms=2.2, label="input (shuffled)")
        artists.append((a, b, path_t, path_p, truth, dots, inp))
    fig.legend(handles=artists[0][4:7], loc="lower center", ncol=3, fontsize=8, frameon=False,
               markerscale=1.6)
    counter = fig.text(0.5, 0.93, "", ha="center", fontsize=9, family="monospace")
    fig.subplots_adjust(left=0.02, right=0.98, top=0.84, bottom=0.1, wspace=0.06)

    def draw(j: int) -> tuple[object, ...]:
        for a, b, path_t, path_p, truth, dots, inp in artists:
            truth.set_data(frames[j][:, a], frames[j][:, b])
            path_t.set_data(tc[: j + 1, a], tc[: j + 1, b])
            path_p.set_data(pc[: j + 1, a], pc[: j + 1, b])
            if j < m:
                dots.set_data([], [])
                inp.set_data(window[j][:, a], window[j][:, b])
            else:
                dots.set_data(pred[j - m][:, a], pred[j - m][:, b])
                inp.set_data([], [])
        what = (f"input frame {j + 1} of {m}" if j < m
                else f"prediction {j - m + 1}, E_p {err[j - m]:.2g}")
        counter.set_text(f"frame {j:3d}   t = {j * FRAME_EVERY / STEPS_PER_S:4.1f} s   {what}")
        return (counter,)

    return write_gif(fig, draw, m, last, every, path, fps, dpi, err)


__all__ = ["animate3d", "simulate_case3d", "DEMO_CASE3D", "VIEWS"]
