"""Model selection without the test cases: baselines and rollout scores on validation data.

:func:`baselines` scores copy-last and constant velocity (:mod:`tpnet_ref.sim.protocol`) like the
training validation; :func:`score_rollouts` runs the test protocol (frames ``0..m-1`` in,
``horizon`` recursive predictions, E_p / E_s in the released or the squared reading) on the
*validation trajectories* of the training grid for native weights files, and
:func:`score_snapshots` for every snapshot of a run (cached); :func:`best_snapshot` picks a
run's snapshot by its validation loss (as the released ``train.py`` picks its shipped file) or
by a rollout score; :func:`spacing_report` says how evenly one-step predictions cover the ring.
NumPy only (no torch).
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
from ..sim.protocol import constant_velocity, copy_last, split_protocol
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


#: the readings :func:`score_snapshots` caches
SNAPSHOT_READINGS = ("released", "squared")


def score_snapshots(data: WindowData, run_dir: str | os.PathLike) -> dict[str, dict[str, float]]:
    """:func:`score_rollouts` (both readings) of every snapshot of a ``--snapshots`` run, keyed
    by file name, plus ``"copy last"``; cached in ``RUN/snapshots/scores.json``, so a second
    call scores only the snapshots written since."""
    run = Path(run_dir)
    snaps = sorted((run / "snapshots").glob("step-*.h5"))
    cache_path = run / "snapshots" / "scores.json"
    cache = json.loads(cache_path.read_text()) if cache_path.is_file() else {}
    todo = [p for p in snaps if "Ep@80 squared" not in cache.get(p.name, {})]
    if todo:
        scores = score_rollouts(data, [str(p) for p in todo], readings=SNAPSHOT_READINGS)
        for p in todo:
            cache[p.name] = scores[str(p)]
        cache["copy last"] = scores["copy last"]
        cache_path.write_text(json.dumps(cache, indent=1, sort_keys=True))
    return {k: v for k, v in cache.items() if k == "copy last" or (run / "snapshots" / k).is_file()}


def best_snapshot(run_dir: str | os.PathLike, key: str = "val_loss",
                  data: WindowData | None = None) -> tuple[Path, dict]:
    """The snapshot (``snapshots/step-NNNNNNN.h5`` of a ``--snapshots`` run) with the lowest
    ``key``, and its validation record (with the rollout scores when ``data`` is given).
    ``val_loss`` (the default) is read from ``log.jsonl``: the released ``train.py`` ships
    ``ModelCheckpoint(monitor="val_loss", save_best_only=True)``'s file, the epoch with the
    lowest validation loss (docs/spec.md §5). A rollout key (``"Ep@80 squared"``) needs
    ``data``: :func:`score_snapshots` on its validation trajectories."""
    run = Path(run_dir)
    if not (run / "log.jsonl").is_file():
        raise FileNotFoundError(f"{run}: no log.jsonl (not a training run directory)")
    vals = {}
    for line in (run / "log.jsonl").read_text().splitlines():
        rec = json.loads(line)
        if rec.get("kind") == "val":
            vals[int(rec["step"])] = rec
    snaps = {int(p.stem.split("-")[1]): p for p in (run / "snapshots").glob("step-*.h5")}
    if data is not None:
        scores = score_snapshots(data, run)
        for step, p in snaps.items():
            vals.setdefault(step, {"step": step}).update(scores.get(p.name, {}))
    elif key != "val_loss" and not key.startswith("val_"):
        raise ValueError(f"best snapshot by {key!r}: a rollout score needs the grid (data)")
    vals = {s: r for s, r in vals.items() if key in r}
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


__all__ = ["baselines", "best_snapshot", "score_rollouts", "score_snapshots", "spacing_report"]
