"""Model selection without the test cases: baselines and rollout scores on validation data.

:func:`baselines` scores copy-last and constant velocity (:mod:`tpnet_ref.protocol`) like the
training validation; :func:`score_rollouts` runs the test protocol (frames ``0..m-1`` in,
``horizon`` recursive predictions, E_p / E_s in the released or the squared reading) on the
*validation trajectories* of the training grid for native weights files; :func:`best_snapshot` picks a run's snapshot as the
released ``train.py`` picks its shipped file; :func:`spacing_report` says how evenly one-step
predictions cover the ring. NumPy only (no torch).
"""
from __future__ import annotations

import json
import os
from pathlib import Path

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
                   at: tuple[int, ...] = (40, 80), readings: tuple[str, ...] = ("released",)
                   ) -> dict[str, dict[str, float]]:
    """Model selection without the test cases: the test protocol (frames 0..m-1 in, ``horizon``
    recursive predictions, E_p / E_s averaged over trajectories) on the *validation*
    trajectories of the training grid, for each weights file and the two baselines.
    Returns ``{name: {"Ep@40": ..., "Es@40": ..., ...}}`` in the released reading; each other
    reading of ``readings`` (``squared``: the paper comparison's, ``docs/evaluation.md``) adds
    its keys with the reading after a space (``"Ep@80 squared"``)."""
    unknown = set(readings) - {"released", "squared"}
    if unknown:
        raise ValueError(f"readings must be 'released' or 'squared', got {sorted(unknown)}")
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
        out[name] = {f"{k}@{h}{'' if rd == 'released' else ' ' + rd}":
                     float(err[f"{k}_{rd}"][:, h - 1].mean())
                     for rd in readings for h in at for k in ("Ep", "Es")}
    return out


def best_snapshot(run_dir: str | os.PathLike, key: str = "val_loss") -> tuple[Path, dict]:
    """The snapshot (``snapshots/step-NNNNNNN.h5`` of a ``--snapshots`` run) whose validation
    record in ``log.jsonl`` has the lowest ``key``, and that record: the released ``train.py``
    ships ``ModelCheckpoint(monitor="val_loss", save_best_only=True)``'s file, the epoch with
    the lowest validation loss (docs/spec.md §5)."""
    run = Path(run_dir)
    if not (run / "log.jsonl").is_file():
        raise FileNotFoundError(f"{run}: no log.jsonl (not a training run directory)")
    vals = {}
    for line in (run / "log.jsonl").read_text().splitlines():
        rec = json.loads(line)
        if rec.get("kind") == "val" and key in rec:
            vals[int(rec["step"])] = rec
    snaps = {int(p.stem.split("-")[1]): p for p in (run / "snapshots").glob("step-*.h5")}
    both = sorted(set(vals) & set(snaps))
    if not both:
        raise ValueError(f"{run}: no snapshot with a validation record of {key!r} "
                         "(train with --snapshots)")
    step = min(both, key=lambda s: (vals[s][key], s))
    return snaps[step], vals[step]


def spacing_report(data: WindowData, weights: list[str | os.PathLike],
                   every: int = 8) -> dict[str, dict[str, float]]:
    """:func:`~tpnet_ref.evaluation.shape.spacing_stats` of the one-step predictions of each weights
    file on every ``every``-th validation window, and of the true next frames (``"truth"``)."""
    x, y = data.gather(data.val_win[::every])
    out = {"truth": spacing_stats(y[:, 0])}
    for w in weights:
        out[str(w)] = spacing_stats(load(w, engine="numpy").predict_batch(x.astype(np.float64), normalized=True))
    return out


__all__ = ["baselines", "best_snapshot", "score_rollouts", "spacing_report"]
