"""A prediction's network in one compiled call: the Numba engine's feature extractor, BiLSTM 1's
input projection, the prediction network and the way back to world units, without returning to
Python in between.

Run separately (:meth:`tpnet_ref.model.TPNet.frame_features`, then ``sequence_head``), these
are four calls (features, projection, head, denormalisation), each with its own Python around
it: at the small sizes that Python is a fifth of a call. The model hands its windows to :func:`network_steps`, which calls the very
same kernels on the very same numbers: the same bits (``tests/test_engines_numba_predict.py``).
A two-thread plan runs :func:`network_parallel`: the feature extractor's frames in two halves on
two threads, then the rest on one, in the same call (the same bits: each frame by the same code);
it keeps the separate calls where the prediction network's directions take the second thread
too (large weight reads: the full size).
"""
from __future__ import annotations

import weakref

import numpy as np
from numba import njit, prange

from ..checks import overflow_error
from .compile_watch import entry_point, may_compile
from .numba_features import frame_range
from .numba_lstm import head_serial, project_serial
from .two_thread_gate import LOCK, available, take


@njit(cache=True, nogil=True, inline="always")
def _frame_starts(counts, nf):
    """Each of the ``nf`` frames' first point in the points, from their ``counts``."""
    starts = np.zeros(nf, dtype=np.intp)
    for f in range(1, nf):
        starts[f] = starts[f - 1] + counts[f - 1]
    return starts


@njit(cache=True, nogil=True, error_model="numpy")
def network_steps(pts, counts, m, batch, order, kernels, recs, kscs, rscs, gks, csts, units,
                  gammas, betas, head_w, head_b, relu, one, eps, limit, w0, b0, ws, bs, gw, gb,
                  zero, normalized, lo, scale, feats, out):
    """``batch`` windows of ``m`` frames, the frames' points ``pts (P, dim)`` in model
    coordinates and canonical order, ``counts (batch * m,)`` a frame, window after window ->
    ``out (batch, n_out * dim)``, world units unless ``normalized`` (``y * scale + lo``, two
    roundings as NumPy's). ``order``: the head's order of the global features; the head's
    arrays as :class:`tpnet_ref.engines.numba_engine.NumbaHead` holds them, the extractor's as
    :class:`~tpnet_ref.engines.numba_engine.NumbaFeatures` does; ``feats``: the frames' global
    features if already known (``(batch * m, >= k)``; ``(0, 0)``: computed here). Returns 0,
    the 1-based layer that overflowed, or -1 for a non-finite output (``out`` then unfinished)."""
    nf = batch * m
    k = order.shape[0]
    g = feats
    if feats.shape[0] == 0:
        starts = _frame_starts(counts, nf)
        g = np.empty((nf, gw.shape[1]), dtype=out.dtype)
        # np.int64(0), not 0: a constant is a literal type, and frame_range compiled once more
        frame_range(pts, starts, counts, np.int64(0), nf, w0, b0, ws, bs, gw, gb, zero, g)
    x = np.empty((nf, k), dtype=out.dtype)              # time-major rows, the head's order
    for t in range(m):
        for b in range(batch):
            for j in range(k):
                x[t * batch + b, j] = g[b * m + t, order[j]]
    kern1 = kernels[0]
    proj = np.empty((nf, 2, kern1.shape[2]), dtype=out.dtype)
    project_serial(x, kern1, kscs[0], csts[0], proj, m, batch)
    y, bad = head_serial(proj, kernels, recs, kscs, rscs, gks, csts, units, gammas, betas,
                         head_w, head_b, m, batch, relu, one, eps, limit)
    if bad:
        return bad
    for b in range(batch):
        for j in range(y.shape[1]):
            v = y[b, j]
            if not np.isfinite(v):
                return -1
            out[b, j] = v if normalized else v * scale + lo
    return 0


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def network_parallel(pts, counts, m, batch, order, kernels, recs, kscs, rscs, gks, csts, units,
                     gammas, betas, head_w, head_b, relu, one, eps, limit, w0, b0, ws, bs, gw,
                     gb, zero, normalized, lo, scale, feats, out):
    """:func:`network_steps` (the same arguments, ``feats`` unused) with the frames' features
    computed on two threads, the frames in two halves (each by :func:`frame_range`, as the
    one-thread call computes it), then the rest on one: the same bits."""
    nf = batch * m
    starts = _frame_starts(counts, nf)
    g = np.empty((nf, gw.shape[1]), dtype=out.dtype)
    half = (nf + 1) // 2
    for h in prange(2):
        frame_range(pts, starts, counts, h * half, min(nf, (h + 1) * half), w0, b0, ws, bs, gw,
                    gb, zero, g)
    return network_steps(pts, counts, m, batch, order, kernels, recs, kscs, rscs, gks, csts,
                         units, gammas, betas, head_w, head_b, relu, one, eps, limit, w0, b0, ws,
                         bs, gw, gb, zero, normalized, lo, scale, g, out)


def fusable(model, batch: int) -> bool:
    """Whether ``model``'s predictions of ``batch`` windows can run as :func:`network_steps`:
    the Numba engine's own head (not a specialised one) and feature extractor."""
    return model.head_for(batch).name == "numba" and model.engine_features is not None


#: :func:`tpnet_ref.engines.compile_watch.may_compile`'s answers by the kernels' argument types
#: (the two-thread kernel's keys begin with "two")
_MEMO: dict = {}
#: per head: ``(feature extractor, the kernels' arguments that do not change between calls,
#: may_compile's key without the points' dimension, the kernels' compiled code by the types of
#: the arguments that do change (:func:`_call`))``
_CONSTANTS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _constants(head, fx, dt) -> tuple:
    """``_CONSTANTS[head]``, built on the first call."""
    got = _CONSTANTS.get(head)
    if got is None or got[0] is not fx:
        order = head.feature_order
        if order is None:
            order = np.arange(fx.k)
        const = (order, head.kernels, head.recs, head.kscs, head.rscs, head.gks, head.csts,
                 head.units, head.gammas, head.betas, head.head_w, head.head_b, head.relu,
                 head.one, head.eps, head.limit, fx.w0, fx.b0, fx.ws, fx.bs, fx.gw, fx.gb,
                 dt.type(0))
        got = _CONSTANTS[head] = (fx, const, (dt, head.recs[0].dtype, len(head.recs),
                                              len(fx.ws)), {})
    return got


def _call(calls: dict, kernel, types: tuple, args: tuple) -> int:
    """``kernel(*args)``: from the second call on arguments of the same ``types`` (what tells
    apart the numba types of the arguments that change between calls of one head), numba's
    compiled code for them, called directly (:func:`~tpnet_ref.engines.compile_watch.entry_point`:
    3 us less a call); ``calls``: that code by kernel and types."""
    fn = calls.get((kernel, types))
    if fn is not None:
        return fn(*args)
    bad = kernel(*args)
    calls[(kernel, types)] = entry_point(kernel, args) or kernel
    return bad


def run(model, points: np.ndarray, counts: np.ndarray, batch: int, normalized: bool,
        two: bool = False) -> np.ndarray | None:
    """The windows' predictions ``(batch, n_out, dim)`` as :func:`network_steps` gives them,
    raising the overflow errors the separate calls raise; None (nothing run) where the model
    is not :func:`fusable` or the kernel may not be compiled now
    (:func:`tpnet_ref.engines.compile_watch.may_compile`). ``two``: the call's plan has a
    second thread: :func:`network_parallel` takes it (where numba has it or may compile it,
    else the feature extractor takes it in a call of its own, then the rest runs as one call),
    unless the prediction network's directions take it too
    (:meth:`~tpnet_ref.engines.numba_engine.NumbaHead.apart`: None)."""
    head, fx, c = model.head_for(batch), model.engine_features, model.config
    if head.name != "numba" or fx is None or (two and head.apart(batch)):
        return None
    dt = model.dtype
    fx, const, key, calls = _constants(head, fx, dt)
    out = np.empty((batch, c.n_out, c.dim), dtype=dt)
    # one numba type whatever the caller's arrays: a read-only or unaligned array is copied
    # (each of those flags would compile the kernels once more)
    points = _plain(points, dt)
    counts = _plain(counts, np.intp)
    normalized = bool(normalized)
    args = (points, counts, c.m, int(batch), *const, normalized, model._lo, model._scale,
            _NO_FEATURES[dt], out.reshape(batch, -1))
    key = key + (points.shape[1],)
    if not may_compile(network_steps, key, _MEMO, args):
        return None
    # the numba types of the arguments that change (the rest: the head's, the model's, fixed)
    types = (normalized,)
    if not two:
        bad = _call(calls, network_steps, types, args)
    elif take(available(network_parallel, _MEMO, args, ("two",) + key)):
        try:
            bad = _call(calls, network_parallel, types, args)
        finally:
            LOCK.release()
    else:
        bad = network_steps(*(args[:-2] + (fx(points, counts, True), args[-1])))
    if bad > 0:
        raise overflow_error(head.dtype, f"BiLSTM {bad}")
    if bad < 0:
        raise overflow_error(head.dtype, "the output layer")
    return out


def _plain(a: np.ndarray, dtype) -> np.ndarray:
    """``a`` as a C-contiguous, writeable, aligned array of ``dtype`` (a copy where it is not):
    ``np.require(a, dtype, "CAW")``'s answer at a fifth of its cost, on every call's path."""
    f = a.flags
    if a.dtype == dtype and f.c_contiguous and f.writeable and f.aligned:
        return a
    return np.array(a, dtype=dtype, order="C")


class Network:
    """What a model holds to reach :func:`run` (``model.fused``): picklable, as the model is."""

    def run(self, model, points: np.ndarray, counts: np.ndarray, batch: int, normalized: bool,
            two: bool = False) -> np.ndarray | None:
        return run(model, points, counts, batch, normalized, two)


#: :func:`network_steps`' ``feats`` when it computes them
_NO_FEATURES = {np.dtype(t): np.empty((0, 0), dtype=t) for t in (np.float32, np.float64)}


__all__ = ["network_steps", "network_parallel", "fusable", "run", "Network"]
