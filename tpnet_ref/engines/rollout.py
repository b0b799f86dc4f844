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
from .thread_policy import adaptive


#: the steps after :data:`~tpnet_ref.engines.numba_rollout.STEPS_FIRST` go to the one-thread
#: compiled call (faster than one-thread steps one by one: AMD EPYC VM, Zen 4, us a step, the
#: quarter 53 against 89, the half 142 against 175, the full size 468 against 512) unless two
#: threads took the steps one by one at least this much faster than one thread (the full size's
#: 342 against 512); below, the call of the rest wins
FUSED_GAIN = 0.15
#: a rollout whose plan is settled (the policy's latencies of this model's rollout steps say one
#: thread, by :data:`FUSED_GAIN`) runs every step in the compiled call, but every this many
#: rollouts of one model and batch runs its first steps one by one, so the policy's latencies
#: stay current
REFRESH_EVERY = 8
#: rollouts so far, by the policy's kind of their steps
_ROLLOUTS: dict = {}


def rollout(model: Any, points: np.ndarray, counts: np.ndarray, batch: int, normalized: bool,
            steps: Any) -> np.ndarray:
    """``model.canonical_points``' ``points`` and ``counts`` of ``batch`` windows' frames (checked,
    window after window) -> ``(batch, steps, n_out, dim)``, world units unless ``normalized``."""
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
    # head takes it: a specialised one projects its kept units itself), kept in a buffer of
    # 2m rows whose last m-1 move to its front when it is full (the head reads m in a row).
    # One one-thread BLAS block around all the steps, the thread plan still chosen per step
    # (unless the rollout is itself nested in a block: a chunk of a split batch)
    held = not in_one_thread()
    with one_thread():
        with model._threads("features", batch, len(points), held):
            feats[:, :m] = model.frame_features(points, counts, batch).reshape(batch, m, -1)
            proj = model.project_frames(
                feats[:, :m].transpose(1, 0, 2).reshape(m * batch, -1), batch)
            if proj is not None:
                buf = np.empty((2 * m,) + proj.reshape(m, batch, -1).shape[1:], dtype=proj.dtype)
                buf[:m] = proj.reshape(m, batch, -1)
        first = 0                                     # the window's first row in buf
        counts = np.full(batch, c.n_out)
        fused = None
        if model.engine == "numba" and proj is not None:
            from . import numba_rollout               # the Numba engine's: numba is installed
            fused = numba_rollout if numba_rollout.fusable(model, batch) else None
        kind = (id(model), "rollout step", batch, c.n_out)   # model._threads' kind of a step
        handover = _handover(fused, kind, held)
        for s in range(steps):
            if (s == handover and (s == 0 or adaptive.one_thread_plan(kind, held, FUSED_GAIN))
                    and fused.run_rest(model, feats, buf, first, s, steps, batch, out)):
                break       # one thread from here on: the rest of the steps in one compiled call
            with model._threads("rollout step", batch, c.n_out, held):   # follows the load
                y = model.sequence_head(feats[:, s:s + m],            # (batch, n_out, dim)
                                        None if proj is None else buf[first:first + m])
                out[:, s] = y
                flat = model.sorted_points(y.reshape(-1, c.dim), counts)
                feats[:, m + s] = model.frame_features(flat, counts, batch)
                if proj is not None and s + 1 < steps:
                    if first + m == len(buf):
                        buf[:m - 1] = buf[first + 1:]
                        first = -1
                    first += 1
                    buf[first + m - 1] = model.project_frames(feats[:, m + s], batch)
    return out if normalized else model.denormalize(out)


def _handover(fused: Any, kind: Any, held: bool) -> int:
    """The step at which a rollout may hand the rest to the compiled call: 0 where the plan of
    its steps is one thread (fixed, or measured so by :data:`FUSED_GAIN`; of a measured plan,
    not every :data:`REFRESH_EVERY`-th rollout of the kind), else ``fused.STEPS_FIRST`` (the
    policy measures the steps before it); -1: never."""
    if fused is None:
        return -1
    if not adaptive.one_thread_plan(kind, held, FUSED_GAIN):
        return fused.STEPS_FIRST
    if adaptive.preferred(kind) is None:        # one thread fixed: nothing to measure
        return 0
    if len(_ROLLOUTS) >= 256 and kind not in _ROLLOUTS:
        _ROLLOUTS.clear()
    n = _ROLLOUTS[kind] = _ROLLOUTS.get(kind, -1) + 1
    return fused.STEPS_FIRST if n % REFRESH_EVERY == 0 else 0


__all__ = ["rollout"]
