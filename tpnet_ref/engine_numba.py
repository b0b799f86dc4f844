"""The optional Numba engine: TP-Net's prediction network (BiLSTMs, LayerNorms, head) as one
compiled function. ``TPNet(..., engine="numba")`` or ``model.with_engine("numba")``; needs numba
(the ``metrics`` extra). The NumPy path (:func:`tpnet_ref.layers.bilstm_fused`, specified by
:func:`tpnet_ref.layers.lstm`) is the reference; ``tests/test_engine_numba.py`` checks they agree.

What it does that NumPy cannot:

- one call per prediction instead of ~130 NumPy calls (plus one for BiLSTM 1's input projection,
  which a rollout computes once per frame): the gates, cell and output of each unit are computed
  in the loop that finishes its pre-activations, LayerNorm and head included;
- weights laid out at load for the products they feed: each direction's input kernel as each
  unit's four gate rows ``(u, 4, C)`` (four dot products with contiguous rows, every weight row
  read once for four input rows); the recurrent matrix as Keras stores it ``(u, 4u)``, row ``k``
  added ``h[k]`` times into the ``4u`` pre-activations, and rows with ``h[k] == 0`` not read at
  all (a ReLU LSTM's state is often half zeros; skipping whole 8 KB rows keeps the reads
  sequential);
- the two directions of a layer run in parallel (``prange`` over the direction: each direction's
  whole recurrence on one thread, no synchronisation between steps).

Determinism: every number is computed by one thread in a fixed order (the same compiled code
whatever the thread count), so the result does not depend on the thread count (bit for bit) or
on the other windows of a batch; the canonical point order before the extractor keeps permutation invariance exact.
Products accumulate in the model's dtype (as the BLAS does); LayerNorm statistics in float64.
"""
from __future__ import annotations

import threading
from typing import Any

import numpy as np

from .extras import require

numba = require("numba", "metrics", "the Numba inference engine (engine='numba')")
from numba import njit, prange  # noqa: E402

def unit_rows(w: np.ndarray) -> np.ndarray:
    """Keras gate-fused columns ``(C, 4u)`` (gates i, f, c, o) or a bias ``(4u,)`` -> each unit's
    four gate rows side by side, ``(u, 4, C)`` or ``(u, 4)``: the pre-activations of one unit
    are four dot products with contiguous rows."""
    u = w.shape[-1] // 4
    if w.ndim == 1:
        return np.ascontiguousarray(w.reshape(4, u).T)
    return np.ascontiguousarray(w.reshape(w.shape[0], 4, u).transpose(2, 1, 0))


# ------------------------------------------------------------------ kernels (plain functions,
# compiled below twice: serially and with the directions in parallel)

@njit(cache=True, nogil=True, inline="always")
def _sigmoid(x, one):
    e = np.exp(-abs(x))
    return one / (one + e) if x >= 0 else e / (one + e)


@njit(cache=True, nogil=True, inline="always")
def _act(x, relu, zero):
    if relu:
        return zero if x < zero else x
    return np.tanh(x)


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def _dot4(w, x0, x1, x2, x3, zero):
    """Four dot products with one row ``w``, read once: ``(w . x0, w . x1, w . x2, w . x3)``,
    vectorised (partial sums in a fixed order: the same machine code, hence the same bits, on
    every thread and for every row)."""
    a0 = zero
    a1 = zero
    a2 = zero
    a3 = zero
    for k in range(w.shape[0]):
        wk = w[k]
        a0 += wk * x0[k]
        a1 += wk * x1[k]
        a2 += wk * x2[k]
        a3 += wk * x3[k]
    return a0, a1, a2, a3


@njit(cache=True, nogil=True)
def _project_dir(x, k, bias, out, d):
    """One direction's input projection: ``out[r, d, j, g] = x[r] . k[j, g] + bias[j, g]`` for
    every row, ``x (R, C)``, kernel rows ``k (u, 4, C)``, ``bias (u, 4)``, ``out (R, 2, u, 4)``.
    Rows go four at a time (each weight row read once per four; a last group of fewer repeats
    its last row), so every row's result comes from the same code whatever ``R`` is."""
    zero = bias[0, 0] - bias[0, 0]
    rows = x.shape[0]
    for r0 in range(0, rows, 4):
        r1 = min(r0 + 1, rows - 1)
        r2 = min(r0 + 2, rows - 1)
        r3 = min(r0 + 3, rows - 1)
        x0, x1, x2, x3 = x[r0], x[r1], x[r2], x[r3]
        for j in range(k.shape[0]):
            for g in range(4):
                a0, a1, a2, a3 = _dot4(k[j, g], x0, x1, x2, x3, zero)
                bj = bias[j, g]
                out[r0, d, j, g] = a0 + bj
                out[r1, d, j, g] = a1 + bj
                out[r2, d, j, g] = a2 + bj
                out[r3, d, j, g] = a3 + bj


@njit(cache=True, nogil=True)
def _recur_dir(xs, rec, out, d, steps, bsz, relu, one):
    """One direction's recurrence over ``steps`` steps of ``bsz`` windows.

    ``xs (T*B, 2, u, 4)`` input projections with bias (row ``t*B + b``), ``rec (u, 4u)`` the
    recurrent matrix as Keras stores it (row ``k``: what ``h[k]`` adds to the 4u gate
    pre-activations), ``out (T*B, 2u)`` receives ``h`` at columns ``d*u ..`` (Keras's
    re-aligned backward output: row ``t`` of the backward direction is its state after
    consuming steps ``T-1 .. t``). Each window is computed on its own, and only the rows of
    ``rec`` whose ``h[k]`` is non-zero are read (whole contiguous rows: a ReLU LSTM's state is
    often half zeros)."""
    u = rec.shape[0]
    n4 = rec.shape[1]
    zero = one - one
    h = np.zeros(u, dtype=out.dtype)
    c = np.zeros(u, dtype=out.dtype)
    acc = np.empty(n4, dtype=out.dtype)
    for b in range(bsz):
        h[:] = 0
        c[:] = 0
        for s in range(steps):
            t = s if d == 0 else steps - 1 - s
            acc[:] = 0
            if s > 0:
                for k in range(u):
                    hv = h[k]
                    if hv != 0:
                        w = rec[k]
                        for q in range(n4):
                            acc[q] += hv * w[q]
            z = xs[t * bsz + b, d]
            for j in range(u):
                zi = acc[j] + z[j, 0]
                zf = acc[u + j] + z[j, 1]
                zc = acc[2 * u + j] + z[j, 2]
                zo = acc[3 * u + j] + z[j, 3]
                cc = _sigmoid(zf, one) * c[j] + _sigmoid(zi, one) * _act(zc, relu, zero)
                c[j] = cc
                hh = _sigmoid(zo, one) * _act(cc, relu, zero)
                h[j] = hh
                out[t * bsz + b, d * u + j] = hh


def _head_impl(xp1, kernels, recs, biases, gammas, betas, head_w, head_b, steps, bsz,
               relu, one, eps, limit):
    """The prediction network after BiLSTM 1's input projection ``xp1 (T*B, 2, u, 4)``
    (row ``t*B + b``) -> ``(y (B, n_out*dim), bad)``; ``bad`` is ``l + 1`` when the ReLU
    output of layer ``l`` reached ``limit`` (or NaN), else 0 (the caller raises)."""
    dt = xp1.dtype
    nl = len(recs)
    bad = 0
    x = np.empty((steps * bsz, 1), dtype=dt)          # LayerNorm output of the previous layer
    xs = xp1
    last = np.empty((bsz, 1), dtype=dt)
    cast = np.empty(1, dtype=dt)
    for li in range(nl):
        rec = recs[li]
        u = rec.shape[1]       # (2, u, 4u)
        if li > 0:
            xs = np.empty((steps * bsz, 2, u, 4), dtype=dt)
        out = np.empty((steps * bsz, 2 * u), dtype=dt)
        for d in prange(2):
            if li > 0:
                _project_dir(x, kernels[li][d], biases[li][d], xs, d)
            _recur_dir(xs, rec[d], out, d, steps, bsz, relu, one)
        gamma, beta = gammas[li], betas[li]
        if li < nl - 1:
            src = out
        else:                     # last layer: forward state at T-1, backward at 0
            src = np.empty((bsz, 2 * u), dtype=dt)
            for b in range(bsz):
                for q in range(u):
                    src[b, q] = out[(steps - 1) * bsz + b, q]
                    src[b, u + q] = out[b, u + q]
        y = np.empty_like(src)
        for r in range(src.shape[0]):
            s1 = 0.0
            for q in range(2 * u):
                v = src[r, q]
                if relu and not v < limit:
                    bad = li + 1 if bad == 0 else bad
                s1 += v
            cast[0] = s1 / (2 * u)                     # the mean in the model's dtype
            mean = cast[0]
            s2 = 0.0
            for q in range(2 * u):
                dv = src[r, q] - mean
                s2 += dv * dv
            cast[0] = s2 / (2 * u)
            cast[0] = one / np.sqrt(cast[0] + eps)
            rstd = cast[0]
            for q in range(2 * u):
                y[r, q] = (src[r, q] - mean) * rstd * gamma[q] + beta[q]
        if li < nl - 1:
            x = y
        else:
            last = y
    n = head_w.shape[1]
    res = np.empty((bsz, n), dtype=dt)
    for b in range(bsz):
        for o in range(n):
            res[b, o] = 0
        for q in range(head_w.shape[0]):
            v = last[b, q]
            for o in range(n):
                res[b, o] += v * head_w[q, o]
        for o in range(n):
            res[b, o] = _sigmoid(res[b, o] + head_b[o], one)
    return res, bad


def _project_impl(x, kernel, bias, out):
    """BiLSTM 1's input projection of rows ``x (R, C)`` -> ``out (R, 2, u, 4)`` (bias added)."""
    for d in prange(2):
        _project_dir(x, kernel[d], bias[d], out, d)


_head_serial = njit(cache=True, nogil=True)(_head_impl)
_head_parallel = njit(cache=True, nogil=True, parallel=True)(_head_impl)
_project_serial = njit(cache=True, nogil=True)(_project_impl)
_project_parallel = njit(cache=True, nogil=True, parallel=True)(_project_impl)

#: one parallel call at a time (another thread asking meanwhile runs the serial kernel)
_PARALLEL = threading.Lock()


class NumbaHead:
    """A model's prediction network laid out for the kernels above (built once per model)."""

    def __init__(self, config: Any, params: dict[str, np.ndarray], dtype: np.dtype) -> None:
        self.dtype = np.dtype(dtype)
        self.relu = config.lstm_activation == "relu"
        if not self.relu and config.lstm_activation != "tanh":
            raise ValueError(f"unknown LSTM activation {config.lstm_activation!r}: "
                             "expected 'relu' or 'tanh'")
        kernels, recs, biases = [], [], []
        for i, u in enumerate(config.lstm_units, start=1):
            lay = {k: np.stack([unit_rows(params[f"lstm{i}.{d}.{k}"]) for d in ("fwd", "bwd")])
                   for k in ("kernel", "bias")}
            kernels.append(lay["kernel"])             # (2, u, 4, C)
            recs.append(np.stack([params[f"lstm{i}.{d}.recurrent"] for d in ("fwd", "bwd")]))
            biases.append(lay["bias"])                # (2, u, 4)
        self.kernels, self.recs, self.biases = tuple(kernels), tuple(recs), tuple(biases)
        n = len(config.lstm_units)
        self.gammas = tuple(params[f"ln{i}.gamma"] for i in range(1, n + 1))
        self.betas = tuple(params[f"ln{i}.beta"] for i in range(1, n + 1))
        self.head_w, self.head_b = params["head.w"], params["head.b"]
        t = self.dtype.type
        self.one, self.eps = t(1.0), t(config.layer_norm_eps)
        self.limit = t(np.sqrt(np.finfo(self.dtype).max) / 4)

    def project(self, x: np.ndarray, parallel: bool = False) -> np.ndarray:
        """BiLSTM 1's input projection (with bias) of feature rows ``(R, k)`` -> ``(R, 2, u, 4)``."""
        k = self.kernels[0]
        out = np.empty((x.shape[0], 2, k.shape[1], 4), dtype=self.dtype)
        x = np.ascontiguousarray(x, dtype=self.dtype)
        if parallel and _PARALLEL.acquire(blocking=False):
            try:
                _project_parallel(x, k, self.biases[0], out)
            finally:
                _PARALLEL.release()
        else:
            _project_serial(x, k, self.biases[0], out)
        return out

    def __call__(self, xp1: np.ndarray, steps: int, batch: int,
                 parallel: bool = False) -> tuple[np.ndarray, int]:
        """The network from BiLSTM 1's projection ``xp1 (T*B, 2, u, 4)`` (rows time-major)
        -> ``(y (B, n_out*dim) in [0, 1], bad)``, ``bad`` = 1-based layer that overflowed, or 0."""
        args = (np.ascontiguousarray(xp1), self.kernels, self.recs, self.biases, self.gammas,
                self.betas, self.head_w, self.head_b, steps, batch, self.relu, self.one,
                self.eps, self.limit)
        if parallel and _PARALLEL.acquire(blocking=False):
            try:
                return _head_parallel(*args)
            finally:
                _PARALLEL.release()
        return _head_serial(*args)


__all__ = ["NumbaHead", "unit_rows"]
