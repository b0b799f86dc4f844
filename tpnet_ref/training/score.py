"""Model selection without the test cases: baselines and rollout scores on validation data.

:func:`baselines` scores copy-last and constant velocity (:mod:`tpnet_ref.protocol`) like the
training validation; :func:`score_rollouts` runs the test protocol (frames ``0..m-1`` in,
``horizon`` recursive predictions, released E_p / E_s) on the *validation trajectories* of the
training grid for native weights files; :func:`spacing_report` says how evenly one-step
predictions cover the ring. NumPy only (no torch).
"""
from __future__ import annotations

import os

import numpy as np

from .. import load
from ..evaluation.run import batched_rollout, errors
from ..evaluation.shape import spacing_stats
from ..metrics import position_error
from ..protocol import constant_velocity, copy_last, split_protocol
from .recipe import N_STEPS_MAX, WindowData


def baselines(data: WindowData, wins: np.ndarray | None = None, steps: int = N_STEPS_MAX,
              first_weight: float = 9.0) -> dict[str, dict[str, float]]:
    """Two model-free references on ``wins`` (default: the validation windows), scored like
    :func:`~tpnet_ref.training.loop.evaluate`: ``copy_last`` (the last input frame, repeated) and ``const_velocity``
    (points matched by index, the last two frames' displacement continued)."""
    wins = data.val_win if wins is None else wins
    x, y = data.gather(wins)
    y = y[:, :steps].astype(np.float64)
    x = x.astype(np.float64)
    preds = {"copy_last": copy_last(x, steps), "const_velocity": constant_velocity(x, steps)}
    w = np.ones(steps)
    w[0] = first_weight
    out = {}
    for name, p in preds.items():
        cd = np.asarray(position_error(y, p, variant="released")).mean(0)   # (S,) batch mean
        out[name] = {"val_loss": float((cd * w).sum()), "val_cd1": float(cd[0]),
                     f"val_cd{steps}": float(cd[-1])}
    return out


def score_rollouts(data: WindowData, weights: list[str | os.PathLike], horizon: int = 80,
                   at: tuple[int, ...] = (40, 80)) -> dict[str, dict[str, float]]:
    """Model selection without the test cases: the test protocol (frames 0..m-1 in, ``horizon``
    recursive predictions, released E_p / E_s averaged over trajectories) on the *validation*
    trajectories of the training grid, for each weights file and the two baselines.
    Returns ``{name: {"Ep@40": ..., "Es@40": ..., ...}}``."""
    frames = data.frames[data.val_traj].astype(np.float64)
    windows, truth = split_protocol(frames, data.m, horizon)
    preds = {"copy last": copy_last(windows, horizon),
             "constant velocity": constant_velocity(windows, horizon)}
    for w in weights:
        model = load(w, engine="numpy")      # batches: the NumPy head runs them either way
        if model.config.m != data.m:
            raise ValueError(f"{w}: m={model.config.m}, the dataset has m={data.m}")
        preds[str(w)] = batched_rollout(model, windows, horizon)
    out = {}
    for name, p in preds.items():
        err = errors(truth, p)
        out[name] = {f"{k}@{h}": float(err[f"{k}_released"][:, h - 1].mean())
                     for h in at for k in ("Ep", "Es")}
    return out


def spacing_report(data: WindowData, weights: list[str | os.PathLike],
                   every: int = 8) -> dict[str, dict[str, float]]:
    """:func:`~tpnet_ref.evaluation.shape.spacing_stats` of the one-step predictions of each weights
    file on every ``every``-th validation window, and of the true next frames (``"truth"``)."""
    x, y = data.gather(data.val_win[::every])
    out = {"truth": spacing_stats(y[:, 0])}
    for w in weights:
        out[str(w)] = spacing_stats(load(w, engine="numpy").predict_batch(x.astype(np.float64), normalized=True))
    return out


__all__ = ["baselines", "score_rollouts", "spacing_report"]
