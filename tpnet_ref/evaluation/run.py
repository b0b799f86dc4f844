"""The evaluation run: simulate the cases, roll the models out, score every way of predicting.

:func:`evaluate` gives one :class:`Curve` per (model or baseline, m, input ordering): the errors
of every case at every horizon in the three metric readings (docs/spec.md §3), computed on
normalised coordinates, ground truth first. The protocol (frames, horizons, orderings,
baselines) is :mod:`tpnet_ref.sim.protocol`.
"""
from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..sim.cases import TEST_CASES, TRAIN_POSITIONS
from ..config import normalize
from ..extras import require
from ..model import TPNet
from ..sim.protocol import (FRAME_EVERY, HORIZONS, ORDERINGS, SIM_ROWS, constant_velocity, copy_last,
                        order_points, split_protocol)

#: the metric readings every curve holds (docs/spec.md §3); the first is the headline, the one
#: the paper's table can physically be
VARIANTS = ("squared", "released", "paper")
HEADLINE = VARIANTS[0]
#: docs/spec.md §4: TP-Net on the 60 held-out cases, ordered input, "squared" reading,
#: normalised: m -> (E_p @40, E_s @40, E_p @80, E_s @80)
PAPER_TABLE: dict[int, tuple[float, float, float, float]] = {
    3: (0.094, 0.007, 0.246, 0.007),
    4: (0.071, 0.007, 0.164, 0.007),
    5: (0.101, 0.008, 0.225, 0.007),
}


def table_horizons(n: int) -> tuple[int, ...]:
    """The paper's horizons (40, 80) that a rollout of ``n`` predictions reaches, else ``(n,)``."""
    return tuple(h for h in HORIZONS if h <= n) or (int(n),)


def progress_bar(it: Any, enabled: bool, total: int, desc: str) -> Any:
    """``it`` with a tqdm progress bar on stderr when ``enabled`` (tqdm: the ``eval`` extra)."""
    if not enabled:
        return it
    tqdm = require("tqdm", "eval", "progress bars").tqdm
    return tqdm(it, total=total, desc=desc, leave=False, file=sys.stderr)


def _sim_frames(job: tuple[tuple[float, float, float, float], int, dict]) -> np.ndarray:
    case, rows, kw = job
    from ..sim import simulate
    return simulate(*case, rows, **kw)[::FRAME_EVERY]


def simulate_cases(cases: Any, rows: int = SIM_ROWS, *, workers: int = 0, progress: bool = False,
                   desc: str = "simulate", **scene: Any) -> np.ndarray:
    """Model frames ``(C, ceil(rows/4), N, 2)`` (world units, float64) of each case
    ``(force, angle_deg, x, y)``, simulated with :func:`tpnet_ref.sim.simulate` (rows 0, 4, ...).

    ``workers``: processes (0: automatic, one per core up to 4 when there are at least 16
    cases, else in this process). ``scene``: simulator keyword overrides.
    """
    cases = [tuple(float(v) for v in c) for c in np.asarray(cases, dtype=float).reshape(-1, 4)]
    if workers == 0:
        workers = min(4, os.cpu_count() or 1) if len(cases) >= 16 else 1
    jobs = [(c, rows, scene) for c in cases]
    if workers > 1:
        with ProcessPoolExecutor(max_workers=workers) as ex:
            it = ex.map(_sim_frames, jobs, chunksize=max(1, len(jobs) // (4 * workers)))
            out = list(progress_bar(it, progress, len(jobs), desc))
    else:
        out = [_sim_frames(j) for j in progress_bar(jobs, progress, len(jobs), desc)]
    return np.stack(out)


def batched_rollout(model: TPNet, windows: np.ndarray, steps: int, *, normalized: bool = True,
                    batch: int = 256, progress: bool = False) -> np.ndarray:
    """``steps`` recursive predictions of every window, ``batch`` windows stepped together
    (:meth:`TPNet.rollout_batch` on each chunk, with a progress bar over the chunks).

    ``windows (B, m, N, 2)`` -> ``(B, steps, n_out, 2)`` in ``model.dtype``. Equal to
    ``model.rollout`` on each window (up to BLAS rounding).
    """
    w = np.asarray(windows)
    if w.ndim != 4 or w.shape[1] != model.config.m or w.shape[-1] != model.config.dim:
        raise ValueError(f"windows: expected (B, m={model.config.m}, N, {model.config.dim}), "
                         f"got {w.shape}")
    chunks = range(0, w.shape[0], batch)
    parts = [model.rollout_batch(w[b0:b0 + batch], steps, normalized=normalized)
             for b0 in progress_bar(chunks, progress, len(chunks), "rollout")]
    return np.concatenate(parts, axis=0)


def errors(truth: np.ndarray, pred: np.ndarray) -> dict[str, np.ndarray]:
    """Per case and horizon errors ``(C, H)``: keys ``Ep_<v>``, ``Es_<v>`` for every reading
    ``v`` in :data:`VARIANTS`. ``truth``/``pred`` ``(C, H, N, 2)`` in normalised coordinates."""
    from ..metrics import position_error, shape_error
    t = np.ascontiguousarray(truth, dtype=np.float64)
    p = np.ascontiguousarray(pred, dtype=np.float64)
    out = {}
    for v in VARIANTS:
        out[f"Ep_{v}"] = np.asarray(position_error(t, p, variant=v))
        out[f"Es_{v}"] = np.asarray(shape_error(t, p, variant=v))
    return out


@dataclass
class Curve:
    """Errors of one way of predicting, per case and horizon (``(C, H)`` arrays)."""

    name: str
    m: int
    ordering: str
    err: dict[str, np.ndarray]
    group: str = "test"

    def mean(self, key: str = f"Ep_{HEADLINE}") -> np.ndarray:
        return self.err[key].mean(axis=0)

    def at(self, h: int, key: str = f"Ep_{HEADLINE}") -> float:
        """Mean over cases of the error of the ``h``-th prediction (1-based)."""
        return float(self.err[key][:, h - 1].mean())


@dataclass
class ModelSpec:
    """A model under evaluation: its label (the weights file) and the network."""

    label: str
    model: TPNet


def evaluate(frames: np.ndarray, models: Sequence[ModelSpec] = (), *, ms: Sequence[int] = (4,),
             horizon: int | None = None, orderings: Sequence[str] = ORDERINGS, seed: int = 0,
             group: str = "test", progress: bool = False,
             keep: dict[str, np.ndarray] | None = None) -> list[Curve]:
    """Errors of every model and both baselines on ``frames (C, F, N, 2)`` (world units).

    ``ms``: the window lengths the baselines are computed for (each model uses its own m).
    ``horizon``: predictions per case (default: as many as the shortest window allows).
    ``keep``: if a dict, receives the predictions of ordering ``given`` (for the gallery).
    """
    frames_n = normalize(np.asarray(frames, dtype=np.float64))
    all_m = sorted({int(x) for x in ms} | {s.model.config.m for s in models})
    if horizon is None:
        horizon = frames_n.shape[1] - max(all_m)
    curves: list[Curve] = []
    for m in all_m:
        inputs, targets = split_protocol(frames_n, m, horizon)
        for o_i, ordering in enumerate(orderings):
            win = order_points(inputs, ordering, seed + o_i)
            for name, fn in (("copy last", copy_last), ("constant velocity", constant_velocity)):
                pred = fn(win, horizon)
                curves.append(Curve(name, m, ordering, errors(targets, pred), group))
                if keep is not None and ordering == "given":
                    keep[f"{name} m={m}"] = pred
            for spec in models:
                if spec.model.config.m != m:
                    continue
                pred = batched_rollout(spec.model, win, horizon, normalized=True,
                                       progress=progress)
                curves.append(Curve(spec.label, m, ordering, errors(targets, pred), group))
                if keep is not None and ordering == "given":
                    keep[spec.label] = pred
    return curves


def generalisation_cases(per_group: int = 20, seed: int = 0) -> dict[str, np.ndarray]:
    """Scenes outside the training ranges, ``(per_group, 4)`` cases (force, angle, x, y) per group:

    * ``force > 1.6``: force in [1.8, 2.6], angle and start from the training ranges;
    * ``angle outside 180-270``: angle in [275°, 535°) mod 360 (i.e. away from the training
      sector by at least 5°), force and start from the training ranges;
    * ``start near other walls``: the centre within 2.9–8 of the left or the bottom wall
      (training starts are all in the upper-right quadrant), force and angle in range.
    Deterministic in ``seed``.
    """
    rng = np.random.default_rng(seed)
    pos = np.asarray(TRAIN_POSITIONS)

    def train_pos(n: int) -> np.ndarray:
        return pos[rng.integers(0, len(pos), n)]

    n = per_group
    f_in = np.round(rng.uniform(1.0, 1.6, (3, n)), 2)
    a_in = np.round(rng.uniform(180.0, 270.0, (3, n)), 1)
    g1 = np.column_stack([np.round(rng.uniform(1.8, 2.6, n), 2), a_in[0], train_pos(n)])
    g2 = np.column_stack([f_in[1], np.round(rng.uniform(275.0, 535.0, n), 1) % 360.0, train_pos(n)])
    near = np.round(rng.uniform(2.9, 8.0, n), 1)
    along = np.round(rng.uniform(10.0, 40.0, n), 1)
    left = rng.random(n) < 0.5
    xy = np.where(left[:, None], np.column_stack([near, along]), np.column_stack([along, near]))
    g3 = np.column_stack([f_in[2], a_in[2], xy])
    return {"force > 1.6": g1, "angle outside 180-270": g2, "start near other walls": g3}


__all__ = ["VARIANTS", "HEADLINE", "PAPER_TABLE", "TEST_CASES", "progress_bar", "table_horizons", "simulate_cases",
           "batched_rollout", "errors", "Curve", "ModelSpec", "evaluate", "generalisation_cases"]
