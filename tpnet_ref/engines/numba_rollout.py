"""A rollout's steps in one compiled call: the Numba engine's prediction network, the new frame's
canonical order, its global feature and BiLSTM 1's projection of it, step after step, without
returning to Python in between.

:func:`tpnet_ref.engines.rollout.rollout` runs each step as four calls (head, sort, features,
projection) and chooses each step's thread plan; at the small sizes those calls' own cost is a
third of a step. Where the plan is one thread anyway (the policy measured one thread faster for
this model's rollout steps, or another process takes the second core), the loop hands the
remaining steps to :func:`rollout_steps`, which calls the very same kernels on the very same
numbers: the same bits (``tests/test_engines_numba_rollout.py``).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..checks import overflow_error
from .compile_watch import may_compile
from .numba_checks import DIMS, sort_frames
from .numba_features import frame_range
from .numba_lstm import head_serial, project_serial


@njit(cache=True, nogil=True, error_model="numpy")
def rollout_steps(feats, buf, first, s0, steps, m, batch, order, kernels, recs, kscs, rscs,
                  gks, csts, units, gammas, betas, head_w, head_b, relu, one, eps, limit, w0, b0, ws, bs,
                  gw, gb, zero, out):
    """Steps ``s0 .. steps-1`` of a rollout of ``batch`` windows of ``m`` frames.

    ``feats (batch, m + steps, k)``: the frames' global features, known up to frame
    ``m + s0 - 1``; ``buf (2m, batch, 2N)``: BiLSTM 1's projections of the window's frames in
    rows ``first .. first + m - 1`` (a buffer of ``2m`` rows whose last ``m - 1`` move to its
    front when full); ``order``: the head's order of the global features (its unit order;
    ``arange(k)`` for the file's); the head's arrays as :class:`tpnet_ref.engines.numba_engine.NumbaHead`
    holds them, the feature extractor's as :class:`~tpnet_ref.engines.numba_engine.NumbaFeatures`
    does; ``out (batch, steps, n_out, dim)`` in model coordinates. Returns ``(step, bad)``:
    ``bad`` 0 when every step ran; else the step that failed and ``bad`` the 1-based layer that
    overflowed, or -1 for a non-finite output."""
    n_out, dim = out.shape[2], out.shape[3]
    k = feats.shape[2]
    kern1, ksc1, cst1 = kernels[0], kscs[0], csts[0]
    pts = np.empty((batch * n_out, dim), dtype=out.dtype)
    starts = np.arange(batch) * n_out
    counts = np.full(batch, n_out)
    g = np.empty((batch, gw.shape[1]), dtype=out.dtype)
    x = np.empty((batch, k), dtype=out.dtype)
    proj = np.empty((batch, 2, buf.shape[2] // 2), dtype=out.dtype)
    for s in range(s0, steps):
        xp1 = np.ascontiguousarray(buf[first:first + m]).reshape(m * batch, 2, -1)
        y, bad = head_serial(xp1, kernels, recs, kscs, rscs, gks, csts, units, gammas, betas,
                             head_w, head_b, m, batch, relu, one, eps, limit)
        if bad:
            return s, bad
        for b in range(batch):
            for j in range(n_out * dim):
                if not np.isfinite(y[b, j]):
                    return s, -1
        for b in range(batch):
            for i in range(n_out):
                for d in range(dim):
                    out[b, s, i, d] = y[b, i * dim + d]
        if s + 1 == steps:
            break
        sort_frames(y.reshape(batch * n_out, dim), n_out, pts)
        # np.int64, not a constant: a literal type would compile the callee once more
        frame_range(pts, starts, counts, np.int64(0), batch, w0, b0, ws, bs, gw, gb, zero, g)
        for b in range(batch):
            for j in range(k):
                feats[b, m + s, j] = g[b, j]
                x[b, j] = g[b, order[j]]
        project_serial(x, kern1, ksc1, cst1, proj, np.int64(1), batch)
        if first + m == buf.shape[0]:
            buf[:m - 1] = buf[first + 1:]
            first = -1
        first += 1
        buf[first + m - 1] = proj.reshape(batch, -1)
    return steps, 0


#: steps a rollout runs one by one first, through the thread policy (which keeps measuring and
#: probing on them), before it may hand the rest to :func:`rollout_steps`
STEPS_FIRST = 8


def fusable(model, batch: int) -> bool:
    """Whether ``model``'s rollouts of ``batch`` windows can run as :func:`rollout_steps`: the
    Numba engine's own head (not a specialised one) and feature extractor, points of a
    dimension its sort reads (:data:`~tpnet_ref.engines.numba_checks.DIMS`) in canonical order."""
    head = model.head_for(batch)
    return (head.name == "numba" and model.engine_features is not None
            and model.config.dim in DIMS and model.sort_points)


_MEMO: dict = {}


def _args(model, feats, buf, first, s0, steps, batch, out) -> tuple:
    head, fx = model.head_for(batch), model.engine_features
    order = (np.arange(feats.shape[2]) if head.feature_order is None
             else np.asarray(head.feature_order, dtype=np.intp))
    return (feats, buf, first, s0, steps, model.config.m, batch, order, head.kernels, head.recs,
            head.kscs, head.rscs, head.gks, head.csts, head.units, head.gammas, head.betas, head.head_w, head.head_b,
            head.relu, head.one, head.eps, head.limit, fx.w0, fx.b0, fx.ws, fx.bs, fx.gw, fx.gb,
            fx.dtype.type(0), out)


def run_rest(model, feats, buf, first: int, s0: int, steps: int, batch: int,
             out: np.ndarray) -> bool:
    """Steps ``s0 ..`` of a rollout as :func:`rollout_steps` (``fusable`` checked by the
    caller), raising the overflow errors the step-by-step loop raises; False (nothing run)
    where the kernel may not be compiled now (:func:`tpnet_ref.engines.compile_watch.may_compile`)."""
    args = _args(model, feats, buf, first, s0, steps, batch, out)
    head = model.head_for(batch)
    key = (out.dtype, head.recs[0].dtype, len(head.recs), len(model.engine_features.ws))
    if not may_compile(rollout_steps, key, _MEMO, args):
        return False
    s, bad = rollout_steps(*args)
    if bad > 0:
        raise overflow_error(head.dtype, f"BiLSTM {bad}")
    if bad < 0:
        raise overflow_error(head.dtype, "the output layer")
    return True


__all__ = ["rollout_steps", "fusable", "run_rest", "STEPS_FIRST"]
