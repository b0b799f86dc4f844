"""Recursive prediction: a rollout, each prediction the newest frame of the next window.

:func:`rollout` runs on a :class:`tpnet_ref.model.TPNet` (its checks done): it keeps a
``(B, m + steps, k)`` array of frame features, so each frame, given or predicted, goes through
the feature extractor exactly once (``tests/test_model.py``,
``test_rollout_computes_each_frame_feature_once``), and BiLSTM 1's input projection of each frame
is computed once too. Every step reruns the prediction network on the last ``m`` rows. The
thread plan is chosen per step (:data:`tpnet_ref.engines.thread_policy.adaptive`), which never changes a bit.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from .blas import in_one_thread, one_thread


def rollout(model: Any, frames: list[np.ndarray], batch: int, normalized: bool,
            steps: Any) -> np.ndarray:
    """``batch * m`` checked frames of ``model``'s windows, window after window ->
    ``(batch, steps, n_out, dim)``, world units unless ``normalized``."""
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
        raise ValueError(f"steps: expected a positive integer, got {steps!r}")
    c, steps = model.config, int(steps)
    m = c.m
    try:
        feats = np.empty((batch, m + steps, c.global_features), dtype=model.dtype)
        out = np.empty((batch, steps, c.n_out, c.dim), dtype=model.dtype)
    except MemoryError:
        raise ValueError(f"steps: {steps} steps do not fit in memory") from None
    # BiLSTM 1's input projection of each frame, also computed once per frame (when the
    # head takes it: a specialised one projects its kept units itself); the last m kept.
    # One one-thread BLAS block around all the steps, the thread plan still chosen per step
    # (unless the rollout is itself nested in a block: a chunk of a split batch)
    held = not in_one_thread()
    with one_thread():
        with model._threads("features", batch, sum(f.shape[0] for f in frames), held):
            feats[:, :m] = model.frame_features(
                *model.canonical_points(frames, normalized), batch).reshape(batch, m, -1)
            proj = model.project_frames(
                feats[:, :m].transpose(1, 0, 2).reshape(m * batch, -1), batch)
            proj = None if proj is None else list(proj.reshape(m, batch, -1))
        counts = np.full(batch, c.n_out)
        for s in range(steps):
            with model._threads("rollout step", batch, c.n_out, held):   # follows the load
                y = model.sequence_head(feats[:, s:s + m],            # (batch, n_out, dim)
                                        None if proj is None else np.stack(proj[-m:]))
                out[:, s] = y
                flat = model.sorted_points(y.reshape(-1, c.dim), counts)
                feats[:, m + s] = model.frame_features(flat, counts, batch)
                if proj is not None and s + 1 < steps:
                    proj = proj[len(proj) - m + 1:] + [
                        model.project_frames(feats[:, m + s], batch)]
    return out if normalized else model.denormalize(out)


__all__ = ["rollout"]
