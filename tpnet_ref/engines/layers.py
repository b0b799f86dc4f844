"""TP-Net's layers as small NumPy functions (Keras semantics, as the released code uses).

Shapes use these letters: ``P`` points (all frames concatenated), ``F`` frames, ``B`` windows
in a batch, ``T`` time steps (= m), ``C`` channels, ``u`` LSTM units. Weights are stored the
Keras way: a dense kernel is ``(in, out)`` and is applied on the right, ``x @ w + b``.
Every function works in the dtype of its inputs (float32 or float64) and allocates nothing
that it does not return.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from .blas import BLOCK_COLUMNS, SMALL_PRODUCT

#: :func:`bilstm_steps` runs one direction after the other when one direction's recurrent
#: weights take this many bytes or more (the 2 MB L2 of a Sapphire Rapids core: the released
#: BiLSTM 1, 4 MB a direction in float32, and not BiLSTMs 2 and 3, 1 MB)
DIRECTION_MAJOR_BYTES = 2 << 20


def relu(x: np.ndarray) -> np.ndarray:
    """Rectified linear unit, in place when ``x`` is a temporary. Shape preserved."""
    return np.maximum(x, 0, out=x)


def sigmoid(x: np.ndarray) -> np.ndarray:
    """Logistic function that never overflows: ``exp`` only ever sees ``-|x|``. Shape preserved."""
    e = np.exp(-np.abs(x))
    return np.where(x >= 0, 1.0 / (1.0 + e), e / (1.0 + e)).astype(x.dtype, copy=False)


def dense(x: np.ndarray, w: np.ndarray, b: np.ndarray | None = None,
          activation: str | None = None, used: bool = False) -> np.ndarray:
    """Fully connected layer. ``x (..., in) @ w (in, out) + b (out,)`` -> ``(..., out)``.
    ``used``: ``x (R, in)`` is mostly zeros (a ReLU's output), so only the rows of ``w`` up to
    the last non-zero column of ``x`` are read (:func:`used_columns`; the same result)."""
    if used and x.ndim == 2:
        k = used_columns(x)
        y = x[:, :k] @ w[:k] if k < x.shape[1] else x @ w
    else:
        y = x @ w
    if activation == "relu" and b is not None:
        # relu(y + b) as max(y, -b) + b: the same bits (where y > -b both round y + b; elsewhere
        # both give +0), and NumPy's maximum runs faster with a row operand than with a
        # scalar 0
        np.maximum(y, -b, out=y)
        y += b
        return y
    if b is not None:
        y += b
    if activation == "relu":
        relu(y)
    elif activation == "sigmoid":
        y = sigmoid(y)
    elif activation is not None:
        raise ValueError(f"unknown activation {activation!r}")
    return y


def pointwise_mlp(x: np.ndarray, layers: Sequence[tuple[np.ndarray, np.ndarray]],
                  used: bool = False) -> np.ndarray:
    """Shared per-point MLP (the released code's 1x1 convolutions), ReLU after every layer.

    ``x (P, C_in)`` -> ``(P, C_out)``; ``layers`` is a list of ``(w (C_i, C_i+1), b (C_i+1,))``.
    Each point's row is computed independently of the others. ``used``: every layer reads only
    the weight rows of its input's used columns (see :func:`dense`).
    """
    for w, b in layers:
        x = dense(x, w, b, "relu", used=used and x.shape[-1] > 2)   # not the points' coordinates
    return x


def segment_max(x: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Max-pool over the points of each frame (the symmetric function of PointNet).

    ``x (P, C)`` with the frames' points stored one frame after another, ``counts (F,)`` the
    points per frame (each >= 1, summing to P) -> ``(F, C)``.
    """
    counts = np.asarray(counts)
    if counts.size and np.all(counts == counts[0]):
        return x.reshape(counts.size, int(counts[0]), x.shape[-1]).max(axis=1)
    starts = np.concatenate(([0], np.cumsum(counts)[:-1]))
    return np.maximum.reduceat(x, starts, axis=0)


def mlp_max(x: np.ndarray, layers: Sequence[tuple[np.ndarray, np.ndarray]],
            counts: np.ndarray, used: bool = False) -> np.ndarray:
    """``segment_max(pointwise_mlp(x, layers), counts)``, the last layer's bias and ReLU applied
    after the max: ``(P, C_in)`` -> ``(F, C_out)``.

    Exact, not an approximation: adding a constant and ReLU are monotone, and so is rounding to
    nearest, so ``max_n relu(fl(y_n + b)) == relu(fl(max_n y_n + b))`` bit for bit. It saves two
    passes over the widest activation (``P x 512`` in TP-Net).
    """
    x = pointwise_mlp(x, layers[:-1], used)
    w, b = layers[-1]
    g = segment_max(dense(x, w, used=used), counts)
    g += b
    return relu(g)


def apply_transform(x: np.ndarray, transforms: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Right-multiply every frame's points by its own matrix: ``P_f <- P_f @ T_f``.

    ``x (P, K)``, ``transforms (F, K, K)``, ``counts (F,)`` -> ``(P, K)``.
    """
    counts = np.asarray(counts)
    if np.all(counts == counts[0]):
        n = int(counts[0])
        return np.matmul(x.reshape(counts.size, n, x.shape[-1]), transforms).reshape(x.shape)
    out = np.empty_like(x)
    start = 0
    for t, n in zip(transforms, counts):
        out[start:start + n] = x[start:start + n] @ t
        start += n
    return out


def transform_net(x: np.ndarray, counts: np.ndarray,
                  mlp: Sequence[tuple[np.ndarray, np.ndarray]],
                  fc: Sequence[tuple[np.ndarray, np.ndarray]],
                  out: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """PointNet's T-Net: per-point MLP, max over points, FC stack, linear FC to ``K*K``.

    ``x (P, K)`` -> one ``(K, K)`` matrix per frame, ``(F, K, K)``. With ``out`` = (zeros,
    flattened identity), as the released code initialises it, every matrix is the identity.
    """
    k = x.shape[-1]
    g = mlp_max(x, mlp, counts)
    for w, b in fc:
        g = dense(g, w, b, "relu")
    t = dense(g, *out)
    return t.reshape(-1, k, k)


def lstm(x: np.ndarray, kernel: np.ndarray, recurrent: np.ndarray, bias: np.ndarray,
         activation: str = "relu", reverse: bool = False) -> np.ndarray:
    """One LSTM direction with Keras semantics, returning every hidden state.

    ``x (B, T, C)``; ``kernel (C, 4u)``, ``recurrent (u, 4u)``, ``bias (4u,)`` with the gates
    fused in Keras order input, forget, cell, output. Gates use the logistic sigmoid; the cell
    candidate and the output use ``activation`` (``relu`` in the released code, or ``tanh``):

        i, f, o = sigmoid(.), g = act(.), c = f*c + i*g, h = o*act(c).

    Returns ``(B, T, u)`` where row ``t`` is the state after consuming step ``t``; with
    ``reverse=True`` the sequence is consumed from the last step to the first, and row ``t``
    is the state after consuming steps ``T-1 .. t`` (Keras's re-aligned backward output).
    """
    act = _activation(activation)
    bsz, steps, _ = x.shape
    u = recurrent.shape[0]
    # the input projection of every step in one GEMM
    xp = (x.reshape(bsz * steps, -1) @ kernel).reshape(bsz, steps, 4 * u)
    xp += bias
    h = np.zeros((bsz, u), dtype=x.dtype)
    c = np.zeros((bsz, u), dtype=x.dtype)
    out = np.empty((bsz, steps, u), dtype=x.dtype)
    order = range(steps - 1, -1, -1) if reverse else range(steps)
    for t in order:
        z = xp[:, t] + h @ recurrent
        i = sigmoid(z[:, :u])
        f = sigmoid(z[:, u:2 * u])
        g = act(z[:, 2 * u:3 * u])
        o = sigmoid(z[:, 3 * u:])
        c = f * c + i * g
        h = o * act(c)
        out[:, t] = h
    return out


class FusedBiLSTM(NamedTuple):
    """A bidirectional LSTM's weights laid out for :func:`bilstm_fused` (see :func:`fuse_bilstm`)."""

    kernel: np.ndarray                  # (C, 8u): [forward | backward], gates i, f, o, c
    recurrent: np.ndarray               # (2, u, 4u)
    bias: np.ndarray                    # (8u,)
    blocks: np.ndarray | None = None    # (8u / nb, C, nb): the kernel's columns in blocks


def fuse_bilstm(fwd: tuple[np.ndarray, np.ndarray, np.ndarray],
                bwd: tuple[np.ndarray, np.ndarray, np.ndarray],
                block_rows: int | None = None) -> FusedBiLSTM:
    """Lay out a bidirectional LSTM's Keras weights for :func:`bilstm_fused`.

    ``fwd``/``bwd``: (kernel ``(C, 4u)``, recurrent ``(u, 4u)``, bias ``(4u,)``), gates i, f, c, o.
    Returns the contiguous kernel ``(C, 8u)`` = [forward | backward], recurrent ``(2, u, 4u)``
    and bias ``(8u,)``. Each direction's gates are reordered to i, f, o, c so the three sigmoid
    gates are adjacent, and their columns are negated (exact) so that the step loop gets ``-x``
    and computes sigmoid(x) = 1 / (1 + exp(-x)) in three in-place passes. With ``block_rows``
    (the rows of the input projection of one window, ``m``), also the kernel's columns cut
    into equal contiguous blocks ``(8u / nb, C, nb)`` with ``block_rows * C * nb`` at most
    :data:`SMALL_PRODUCT` and ``nb`` at most :data:`~tpnet_ref.engines.blas.BLOCK_COLUMNS`, for
    :func:`project`.
    """
    def reorder(a: np.ndarray) -> np.ndarray:
        u = a.shape[-1] // 4
        out = np.concatenate([a[..., :2 * u], a[..., 3 * u:], a[..., 2 * u:3 * u]], axis=-1)
        out[..., :3 * u] *= -1.0
        return out

    kernel = np.ascontiguousarray(np.concatenate([reorder(fwd[0]), reorder(bwd[0])], axis=-1))
    recurrent = np.ascontiguousarray(np.stack([reorder(fwd[1]), reorder(bwd[1])]))
    bias = np.concatenate([reorder(fwd[2]), reorder(bwd[2])])
    blocks = None
    if block_rows:
        c_in, n = kernel.shape
        fits = [nb for nb in range(1, min(n, BLOCK_COLUMNS) + 1)
                if n % nb == 0 and block_rows * c_in * nb <= SMALL_PRODUCT]
        if fits and fits[-1] < n:
            nb = fits[-1]
            blocks = np.ascontiguousarray(kernel.reshape(c_in, n // nb, nb).transpose(1, 0, 2))
    return FusedBiLSTM(kernel, recurrent, bias, blocks)


def project(x: np.ndarray, kernel: np.ndarray, blocks: np.ndarray | None = None,
            small: bool = True) -> np.ndarray:
    """``x (R, C) @ kernel (C, N)`` -> ``(R, N)``. With ``blocks`` (the kernel's columns in
    blocks, from :func:`fuse_bilstm`), ``small`` and ``R * C * nb <= SMALL_PRODUCT``, the same
    product as one stacked product over the blocks, each small enough for the BLAS to skip
    packing the weights (faster on OpenBLAS's SkylakeX kernel and later; the model always asks
    for the blocks, so how the work is cut never depends on a timing)."""
    return project_spans(x, kernel, blocks, [(0, x.shape[1])], small)


def used_columns(x: np.ndarray, start: int = 0, stop: int | None = None) -> int:
    """How many leading columns of ``x[:, start:stop]`` (``x (R, C)``) can be non-zero: one past
    the last column with a non-zero (or NaN) entry in any row, 0 when all are zero. The columns
    after it are exactly zero in every row, so a product ``x @ w`` may leave out the rows of
    ``w`` they multiply (a ReLU network's activations are mostly zeros, often the same ones)."""
    cols = x[:, start:stop]
    nz = np.flatnonzero(cols[0] if cols.shape[0] == 1 else cols.any(axis=0))
    return int(nz[-1]) + 1 if nz.size else 0


def used_prefixes(x: np.ndarray) -> list[int]:
    """:func:`used_columns` of each ``x[d]`` for ``x (D, R, C)`` in one pass (a row of ``D``
    that is all zeros gives ``C``: every weight row read, still exact)."""
    nz = (x[:, 0] != 0) if x.shape[1] == 1 else (x != 0).any(axis=1)
    return (x.shape[2] - np.argmax(nz[:, ::-1], axis=1)).tolist()


def project_spans(x: np.ndarray, kernel: np.ndarray, blocks: np.ndarray | None,
                  spans: Sequence[tuple[int, int]], small: bool = True,
                  out: np.ndarray | None = None) -> np.ndarray:
    """``x (R, C) @ kernel (C, N)`` -> ``(R, N)`` when the columns of ``x`` outside ``spans``
    (``[(a, b), ...]``, column ranges) are zero: only those rows of the kernel are read. Like
    :func:`project`, as one stacked product over the kernel's column ``blocks`` when each block's
    product is small enough for the BLAS's small-matrix kernels. ``out``: a C-contiguous
    ``(R, N)`` buffer that receives the result (returned)."""
    rows = x.shape[0]
    spans = [(a, b) for a, b in spans if b > a]
    if not spans:
        if out is None:
            return np.zeros((rows, kernel.shape[1]), dtype=x.dtype)
        out[...] = 0
        return out
    stacked = (blocks is not None and small
               and rows * max(b - a for a, b in spans) * blocks.shape[2] <= SMALL_PRODUCT)
    w = blocks if stacked else kernel               # the kernel rows: axis -2 of both
    acc = out                                       # (N / nb, R, nb) stacked, else (R, N)
    if out is not None and stacked:
        acc = out.reshape(rows, -1, w.shape[2]).transpose(1, 0, 2)
    for i, (a, b) in enumerate(spans):
        if i == 0:
            acc = np.matmul(x[:, a:b], w[..., a:b, :], out=acc)
        else:
            acc += np.matmul(x[:, a:b], w[..., a:b, :])
    if out is not None:
        return out
    return acc.transpose(1, 0, 2).reshape(rows, -1) if stacked else acc


def project_layer_norm(h: np.ndarray, gamma: np.ndarray, beta: np.ndarray, eps: float,
                       kernel: np.ndarray, blocks: np.ndarray | None, gk: np.ndarray,
                       bk: np.ndarray, ranges: Sequence[tuple[int, int]],
                       small: bool = True, fold_max: float = 0.85) -> np.ndarray:
    """``layer_norm(h, gamma, beta, eps) @ kernel`` -> ``(R, N)`` for ``h (R, C)``, reading only
    the kernel rows of the columns where ``h`` can be non-zero.

    LayerNorm is affine in ``h`` per row: with ``r = 1 / sqrt(var + eps)`` and the row mean
    ``mu``, ``LN(h) @ K = r * ((h * gamma) @ K) - r * mu * (gamma @ K) + beta @ K``. The zeros
    of ``h`` (a ReLU LSTM's output is mostly zeros) add nothing to the first product, so each of
    ``ranges`` (column ranges: all outputs in the layer's unit order, or each direction's) is cut
    after its last non-zero column (:func:`used_columns`); ``gk = gamma @ K`` and
    ``bk = beta @ K`` are computed once at load. Mean and variance are :func:`layer_norm`'s.
    When the kept columns exceed ``fold_max`` of all, the plain ``layer_norm`` then
    :func:`project` is used (same result up to rounding, fewer passes)."""
    spans = [(a, a + used_columns(h, a, b)) for a, b in ranges]
    if sum(b - a for a, b in spans) > fold_max * h.shape[1]:
        return project(layer_norm(h, gamma, beta, eps), kernel, blocks, small)
    mean, _, r = _norm_stats(h, eps)
    out = project_spans(h * gamma, kernel, blocks, spans, small)
    out *= r
    mean *= r
    out -= mean * gk
    out += bk
    return out


def bilstm_fused(x: np.ndarray, kernel: np.ndarray, recurrent: np.ndarray, bias: np.ndarray,
                 blocks: np.ndarray | None = None, activation: str = "relu",
                 return_sequences: bool = True, small: bool = True,
                 xp: np.ndarray | None = None) -> np.ndarray:
    """Keras ``Bidirectional(LSTM)`` (``merge_mode='concat'``) on weights from :func:`fuse_bilstm`,
    time-major: ``x (T, B, C)`` -> ``(T, B, 2u)`` or, with ``return_sequences=False``, ``(B, 2u)``.

    The fused layer as one function, for measuring units' use (:mod:`tpnet_ref.engines.unit_order`)
    and for tests: the NumPy head (:mod:`tpnet_ref.engines.numpy_engine`) runs its two parts itself, the
    input projection (:func:`project_spans` / :func:`project_layer_norm`, LayerNorm folded) and
    :func:`bilstm_steps`. Its specification is :func:`lstm` (one direction, written for reading)
    and :func:`bidirectional_lstm`; ``tests/test_engines_layers.py`` checks that this function equals
    them, and ``tests/test_engines_reference.py`` checks the head the model runs against
    :mod:`tpnet_ref.engines.reference`.
    ``xp`` ``(T, B, 8u)``, when given, is the input projection ``x @ kernel`` (without the bias)
    computed beforehand, e.g. one frame at a time by a rollout; ``x`` then only gives the shapes.
    """
    steps, bsz, _ = x.shape
    if xp is None:
        xp = project(x.reshape(steps * bsz, -1), kernel, blocks, small)
    return bilstm_steps(xp, recurrent, bias, steps, bsz, activation, return_sequences, x.dtype)


def advance_directions(xs: np.ndarray, hs: np.ndarray, c: np.ndarray, recurrent: np.ndarray,
                       relu_act: bool = True) -> None:
    """The step loop of :func:`bilstm_steps` for ``D`` directions together, in place.

    ``xs (T, D, B, 4u)``: each direction's input projections plus bias, in its step order (they
    become the gates; each spent step's slice then takes the next step's recurrent products);
    ``hs (T, D, B, u)`` receives ``h`` after each step, ``c (D, B, u)`` the cell state;
    ``recurrent (D, u, 4u)`` in the fused layout (:func:`fuse_bilstm`). ``relu_act``: ReLU as the
    cell activation, else tanh. Any ``D`` gives each direction the same numbers: the element-wise
    passes act on each number alone, and each direction has its own product."""
    steps, _, bsz, u = hs.shape
    zero = np.zeros(u, dtype=hs.dtype)                  # relu's operand: faster than a scalar
    one = hs.dtype.type(1.0)
    mixed = recurrent.dtype != hs.dtype
    with np.errstate(over="ignore"):
        for s in range(steps):
            z = xs[s]                                   # gates computed in place
            if s:                                       # + h @ recurrent (h = c = 0 at step 0)
                hp = hs[s - 1]
                zr = xs[s - 1]                          # the spent buffer takes the products
                for d, k in enumerate(used_prefixes(hp)):
                    if mixed:
                        zr[d] = hp[d, :, :k] @ recurrent[d, :k]
                    elif bsz == 1:
                        np.dot(hp[d, 0, :k], recurrent[d, :k], out=zr[d, 0])
                    else:
                        np.matmul(hp[d, :, :k], recurrent[d, :k], out=zr[d])
                z += zr
            gates = z[..., :3 * u]                      # -x for i, f, o (negated weights)
            np.exp(gates, out=gates)                    # may overflow to inf: 1/(1+inf) = 0
            gates += one
            np.divide(one, gates, out=gates)
            g = z[..., 3 * u:]                          # cell candidate
            if relu_act:
                np.maximum(g, zero, out=g)
            else:
                np.tanh(g, out=g)
            np.multiply(z[..., :u], g, out=g)           # i * g
            if s == 0:                                  # c = i*g
                c[...] = g
            else:                                       # c = f*c + i*g
                c *= z[..., u:2 * u]
                c += g
            h = hs[s]                                   # h = o * act(c)
            if relu_act:
                np.maximum(c, zero, out=h)
            else:
                np.tanh(c, out=h)
            h *= z[..., 2 * u:3 * u]


def bilstm_steps(xp: np.ndarray, recurrent: np.ndarray, bias: np.ndarray, steps: int, bsz: int,
                 activation: str = "relu", return_sequences: bool = True,
                 dtype: np.dtype | None = None) -> np.ndarray:
    """The recurrence of :func:`bilstm_fused` from the input projections ``xp (T*B, 8u)`` (rows
    time-major, without the bias) -> ``(T, B, 2u)`` or ``(B, 2u)``.

    The projections are laid out once in step order (step ``s`` is forward time ``s`` and
    backward time ``T-1-s``), both directions advance together (for one window with large
    recurrent weights, one direction after the other: :data:`DIRECTION_MAJOR_BYTES`), and the
    gates are updated in place (:func:`advance_directions`). Each direction's recurrent product
    reads only the rows of ``recurrent`` that the non-zero part of its state multiplies
    (:func:`used_columns`: a ReLU LSTM's state is mostly zeros, and none at step 0, where
    h = c = 0). Time-major layout keeps every step's slice contiguous, so nothing is
    re-laid-out between layers. ``dtype``: of the result (default ``xp``'s).
    """
    u = recurrent.shape[1]
    relu_act = activation == "relu"
    if not relu_act and activation != "tanh":
        _activation(activation)  # raises the error naming the activation
    dt = xp.dtype if dtype is None else np.dtype(dtype)
    xp = xp.reshape(steps, bsz, 2, 4 * u)
    xs = np.empty((steps, 2, bsz, 4 * u), dtype=dt)     # input projections in step order
    np.add(xp[:, :, 0], bias[:4 * u], out=xs[:, 0])
    np.add(xp[::-1, :, 1], bias[4 * u:], out=xs[:, 1])
    c = np.empty((2, bsz, u), dtype=dt)
    hs = np.empty((steps, 2, bsz, u), dtype=dt)         # h after each step
    # both directions advance together (half the calls), or, for one window whose recurrent
    # weights fill a core's L2 cache a direction, one direction after the other (the used rows
    # of one direction then stay in cache from step to step, bench/probes/numpy_two_threads.py;
    # a batch reads each row once for all its windows anyway); the same operations on every
    # number either way
    by_direction = bsz == 1 and recurrent[0].nbytes >= DIRECTION_MAJOR_BYTES
    for sel in ((slice(0, 1), slice(1, 2)) if by_direction else (slice(0, 2),)):
        advance_directions(xs[:, sel], hs[:, sel], c[sel], recurrent[sel], relu_act)
    if not return_sequences:
        return np.concatenate([hs[-1, 0], hs[-1, 1]], axis=-1)
    # forward output at time t is hs[t, 0]; backward output at time t is hs[T-1-t, 1]
    return np.concatenate([hs[:, 0], hs[::-1, 1]], axis=-1)


def bidirectional_lstm(x: np.ndarray, fwd: tuple[np.ndarray, np.ndarray, np.ndarray],
                       bwd: tuple[np.ndarray, np.ndarray, np.ndarray], activation: str = "relu",
                       return_sequences: bool = True) -> np.ndarray:
    """Keras ``Bidirectional(LSTM)`` with ``merge_mode='concat'``.

    ``x (B, T, C)``; ``fwd``/``bwd`` are (kernel, recurrent, bias) of each direction.
    ``return_sequences=True`` -> ``(B, T, 2u)``, each step ``[forward_t, backward_t]``.
    ``return_sequences=False`` -> ``(B, 2u)``: the forward state after the last step and the
    backward state after it has consumed the whole reversed sequence (its row ``t = 0``).
    Written for reading: the model runs :func:`bilstm_fused`, which must equal this.
    """
    f = lstm(x, *fwd, activation=activation)
    b = lstm(x, *bwd, activation=activation, reverse=True)
    if return_sequences:
        return np.concatenate([f, b], axis=-1)
    return np.concatenate([f[:, -1], b[:, 0]], axis=-1)


def _norm_stats(x: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """LayerNorm's statistics over the last axis: the mean, ``x - mean`` and
    ``r = 1 / sqrt(var + eps)`` (biased variance), the last two in ``x``'s dtype."""
    mean = x.mean(axis=-1, keepdims=True)
    d = x - mean
    var = np.mean(d * d, axis=-1, keepdims=True)
    return mean, d, (1.0 / np.sqrt(var + x.dtype.type(eps))).astype(x.dtype, copy=False)


def layer_norm(x: np.ndarray, gamma: np.ndarray, beta: np.ndarray, eps: float) -> np.ndarray:
    """Layer normalisation over the last axis (Keras: biased variance, ``eps`` inside the sqrt).

    ``x (..., C)`` -> ``(..., C)``: ``(x - mean) / sqrt(var + eps) * gamma + beta``.
    """
    _, d, r = _norm_stats(x, eps)
    d *= r
    d *= gamma
    d += beta
    return d


def _relu_copy(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0)


def _activation(name: str):
    if name == "relu":
        return _relu_copy
    if name == "tanh":
        return np.tanh
    raise ValueError(f"unknown LSTM activation {name!r}: expected 'relu' or 'tanh'")
