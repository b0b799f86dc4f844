"""The evaluation protocol's constants and its two baselines, in one place (docs/spec.md §5).

* a trajectory is the simulator's ``(SIM_ROWS, 30, 2)`` rows, ``dt = REFERENCE_DT``; model frame
  ``j`` is row ``FRAME_EVERY · j``, so a 600-row trajectory has 150 frames (4/45 s apart);
* a model with ``m`` input frames gets frames ``0 .. m-1`` (rows 0, 4, ..., 4(m-1));
* its ``h``-th recursive prediction (``h = 1, 2, ...``, the *horizon*) is compared with frame
  ``m - 1 + h``; "E_p @40" is the error of the 40th prediction (frame ``m + 39``); the paper's
  table reports ``HORIZONS = (40, 80)``.

Baselines computed the same way: *copy last* (every prediction is the last input frame) and
*constant velocity* (each point keeps the displacement between the last two input frames;
points are matched by their index, so it is only meaningful when both frames are ordered alike).

Input orderings (the paper's real-world study): ``given`` (the simulator's particle order, what
the paper's table uses), ``ascending_x``, ``descending_y``, ``shuffle`` (an independent random
permutation of every input frame).
"""
from __future__ import annotations

import numpy as np

FRAME_EVERY = 4                      # simulation rows per model frame
SIM_ROWS = 600                       # rows per trajectory
REFERENCE_DT = 1.0 / 45.0            # the simulator's time step, s
HORIZONS = (40, 80)                  # the paper's table: the 40th and 80th recursive prediction
ORDERINGS = ("given", "ascending_x", "descending_y", "shuffle")


def split_protocol(frames: np.ndarray, m: int, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """Inputs ``frames[:, 0:m]`` and targets ``frames[:, m:m+horizon]`` (horizon h ↔ frame m-1+h).

    ``frames (C, F, N, 2)``; raises ``ValueError`` when the trajectories are too short."""
    frames = np.asarray(frames)
    if frames.ndim != 4:
        raise ValueError(f"frames: expected (cases, frames, N, 2), got shape {frames.shape}")
    if m < 1 or horizon < 1:
        raise ValueError(f"need m >= 1 and horizon >= 1, got m={m}, horizon={horizon}")
    if frames.shape[1] < m + horizon:
        raise ValueError(f"trajectories have {frames.shape[1]} frames: too short for m={m} "
                         f"inputs and {horizon} predictions (need {m + horizon})")
    return frames[:, :m], frames[:, m:m + horizon]


def order_points(windows: np.ndarray, ordering: str, seed: int = 0) -> np.ndarray:
    """Reorder the points of every frame of ``windows (..., N, 2)`` (a copy).

    ``given``: unchanged; ``ascending_x``: by x ascending; ``descending_y``: by y descending;
    ``shuffle``: an independent random permutation per frame (deterministic in ``seed``)."""
    w = np.array(windows, copy=True)
    if ordering == "given":
        return w
    if ordering == "ascending_x":
        idx = np.argsort(w[..., 0], axis=-1, kind="stable")
    elif ordering == "descending_y":
        idx = np.argsort(-w[..., 1], axis=-1, kind="stable")
    elif ordering == "shuffle":
        rng = np.random.default_rng(seed)
        idx = np.argsort(rng.random(w.shape[:-1]), axis=-1)
    else:
        raise ValueError(f"ordering: expected one of {', '.join(ORDERINGS)}, got {ordering!r}")
    return np.take_along_axis(w, idx[..., None], axis=-2)


def copy_last(windows: np.ndarray, steps: int) -> np.ndarray:
    """Baseline: every prediction is the last input frame. ``(B, m, N, 2)`` -> ``(B, steps, N, 2)``."""
    w = np.asarray(windows)
    return np.repeat(w[:, -1:], int(steps), axis=1)


def constant_velocity(windows: np.ndarray, steps: int) -> np.ndarray:
    """Baseline: point ``i`` moves on by ``w[-1, i] - w[-2, i]`` per frame (points matched by
    their index). ``(B, m >= 2, N, 2)`` -> ``(B, steps, N, 2)`` float64."""
    w = np.asarray(windows, dtype=np.float64)
    if w.shape[1] < 2:
        raise ValueError("constant_velocity: needs at least 2 input frames")
    v = w[:, -1] - w[:, -2]
    k = np.arange(1, int(steps) + 1, dtype=np.float64)[None, :, None, None]
    return w[:, -1][:, None] + k * v[:, None]


__all__ = ["FRAME_EVERY", "SIM_ROWS", "REFERENCE_DT", "HORIZONS", "ORDERINGS", "split_protocol",
           "order_points", "copy_last", "constant_velocity"]
