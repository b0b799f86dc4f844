"""The NumPy fast path: TP-Net's feature extractor and prediction network laid out for speed.

The same network as :mod:`tpnet_ref.engines.reference` (and tested against it), computed the fast way:

- the weights in the model's unit order (:mod:`tpnet_ref.engines.unit_order`: most used units first),
  so every product reads only the weight rows up to the last unit that is non-zero somewhere
  in its input (a ReLU network's activations are mostly zeros; :func:`~tpnet_ref.engines.layers.used_columns`);
- each BiLSTM's two directions fused (:func:`~tpnet_ref.engines.layers.fuse_bilstm`), their input
  projection as stacked column blocks, LayerNorm folded into the next layer's input projection
  (:func:`~tpnet_ref.engines.layers.project_layer_norm`);
- the feature extractor on blocks of whole frames of about :data:`BLOCK_POINTS` points.

:class:`NumpyFeatures` is the feature extractor every engine uses; :class:`NumpyHead` is the
prediction network behind the :class:`tpnet_ref.engines.interface.Head` interface, the head that takes any
batch and the one the others fall back to.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from . import layers as L
from .thread_policy import two_threads
from ..checks import overflow_error

#: points per block of the feature extractor (activations of a block stay in cache)
BLOCK_POINTS = 2048
_POOL: list[Any] = []


def _pair(fn: Any, parts: list[tuple]) -> list:
    """``[fn(*p) for p in parts]``, the second half of ``parts`` on a second thread when the
    calling block may take one (:func:`tpnet_ref.engines.thread_policy.two_threads`); the same results either way
    (each part is computed by the same code, whichever thread runs it)."""
    if len(parts) < 2 or not two_threads():
        return [fn(*p) for p in parts]
    if not _POOL:                        # one worker for the whole process, made on first use
        from concurrent.futures import ThreadPoolExecutor
        _POOL.append(ThreadPoolExecutor(max_workers=1, thread_name_prefix="tpnet-features"))
    half = len(parts) // 2
    other = _POOL[0].submit(lambda: [fn(*p) for p in parts[half:]])
    mine = [fn(*p) for p in parts[:half]]
    return mine + other.result()


class _Layer(NamedTuple):
    """One BiLSTM of the NumPy head's layout (units in the model's unit order)."""

    fused: L.FusedBiLSTM
    gamma: np.ndarray          # (2u,) this layer's LayerNorm
    beta: np.ndarray
    gk: np.ndarray | None      # (8u,) previous LayerNorm's gamma @ kernel (None for BiLSTM 1)
    bk: np.ndarray | None      # (8u,) previous LayerNorm's beta @ kernel
    merge: np.ndarray | None   # (2u,) output columns [forward | backward] -> the layer's order


def _stack(p: dict[str, np.ndarray], prefix: str, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    return [(p[f"{prefix}.{i}.w"], p[f"{prefix}.{i}.b"]) for i in range(n)]


def _tnet(p: dict[str, np.ndarray], prefix: str, mlp: Sequence[int], fc: Sequence[int]) -> tuple:
    return (_stack(p, f"{prefix}.mlp", len(mlp)), _stack(p, f"{prefix}.fc", len(fc)),
            (p[f"{prefix}.out.w"], p[f"{prefix}.out.b"]))


def _ordered(p: dict[str, np.ndarray], order: dict[str, np.ndarray], prefix: str, n: int,
             prev: np.ndarray | None) -> tuple[list, np.ndarray | None]:
    """A per-point MLP's layers, each layer's units (columns, bias, the next layer's rows) in the
    unit order; also the last layer's order."""
    out = []
    for i in range(n):
        w, b = p[f"{prefix}.{i}.w"], p[f"{prefix}.{i}.b"]
        po = order.get(f"{prefix}.{i}")
        if prev is not None:
            w = w[prev]
        if po is not None:
            w, b = w[:, po], b[po]
        out.append((np.ascontiguousarray(w), np.ascontiguousarray(b)))
        prev = po
    return out, prev


class NumpyFeatures:
    """The feature extractor: ``(points (P, dim), counts (F,))`` -> global features ``(F, k)``,
    laid out in the unit order; the features come out in the file's order of units."""

    def __init__(self, config: Any, params: dict[str, np.ndarray],
                 unit_order: dict[str, np.ndarray] | None) -> None:
        cfg, p, order = config, params, unit_order or {}
        self.input_tnet = (_tnet(p, "input_tnet", cfg.input_tnet_mlp, cfg.input_tnet_fc)
                           if cfg.input_transform_trained else None)
        self.mlp1, prev = _ordered(p, order, "mlp1", len(cfg.mlp1), None)
        self.feature_tnet = (_tnet(p, "feature_tnet", cfg.feature_tnet_mlp, cfg.feature_tnet_fc)
                             if cfg.feature_transform_trained else None)
        self.mlp2, prev = _ordered(p, order, "mlp2", len(cfg.mlp2), prev)
        self.global_w = p["global.w"] if prev is None else np.ascontiguousarray(p["global.w"][prev])
        self.global_b = p["global.b"]
        self.k = cfg.global_features

    def __call__(self, points: np.ndarray, counts: np.ndarray) -> np.ndarray:
        """Global feature ``G`` of every frame. ``points (P, dim)``: the frames' points one frame
        after another, each frame in canonical order; ``counts (F,)`` -> ``(F, k)``. Large inputs
        go through in blocks of whole frames (about ``BLOCK_POINTS`` points each) so that the
        per-point activations stay in cache; the blocks run on two threads where the calling
        block may take a second one (the same blocks either way). Each frame's feature depends
        on its own points and the input's shapes alone."""
        counts = np.asarray(counts)
        if points.shape[0] <= BLOCK_POINTS:
            return self._block(points, counts)
        ends = np.cumsum(counts)
        parts, f0, p0 = [], 0, 0
        while f0 < len(counts):
            f1 = max(f0 + 1, int(np.searchsorted(ends, p0 + BLOCK_POINTS, side="right")))
            parts.append((points[p0:ends[f1 - 1]], counts[f0:f1]))
            f0, p0 = f1, int(ends[f1 - 1])
        return np.concatenate(_pair(self._block, parts))

    def _block(self, points: np.ndarray, counts: np.ndarray) -> np.ndarray:
        # far-out input may overflow here (float32): the head checks what comes out and
        # raises one NonFiniteResultError, so NumPy's RuntimeWarnings would only be noise
        with np.errstate(over="ignore", invalid="ignore"):
            x = points
            if self.input_tnet is not None:
                x = L.apply_transform(x, L.transform_net(x, counts, *self.input_tnet), counts)
            # every product after the first reads only the weight rows up to the last unit
            # that is non-zero at some point of the block (L.used_columns; exact)
            h = L.pointwise_mlp(x, self.mlp1, used=True)
            if self.feature_tnet is not None:
                h = L.apply_transform(h, L.transform_net(h, counts, *self.feature_tnet), counts)
            g = L.mlp_max(h, self.mlp2, counts, used=True)
            return L.dense(g, self.global_w, self.global_b, "relu", used=True)


class NumpyHead:
    """The prediction network in NumPy (the :class:`tpnet_ref.engines.interface.Head` that runs any batch):
    each BiLSTM's direction's gate columns, recurrent rows and bias, the next layer's kernel rows,
    the LayerNorm's gamma and beta and the output layer's rows follow the unit order."""

    name = "numpy"
    max_batch: int | None = None
    threaded = False

    def __init__(self, config: Any, params: dict[str, np.ndarray], dtype: np.dtype,
                 unit_order: dict[str, np.ndarray] | None) -> None:
        p, order = params, unit_order or {}
        self.dtype, self.config = dtype, config
        self.feature_order = order.get("global")
        prev = self.feature_order
        self.layers: list[_Layer] = []
        for i, u in enumerate(config.lstm_units, start=1):
            po = order.get(f"lstm{i}")         # the outputs' order, both directions together
            merge = None
            if po is not None:                 # each direction's units in the same order
                per_dir = (po[po < u], po[po >= u] - u)
                pos = np.empty(2 * u, dtype=np.intp)
                pos[per_dir[0]] = np.arange(u)
                pos[u + per_dir[1]] = u + np.arange(u)
                merge = pos[po]                # where each output sits after the recurrence
                if np.array_equal(merge, np.arange(2 * u)):
                    merge = None
            dirs = []
            for d, name in enumerate(("fwd", "bwd")):
                k, r, b = (p[f"lstm{i}.{name}.{x}"] for x in ("kernel", "recurrent", "bias"))
                if po is not None:
                    pd = per_dir[d]
                    cols = np.concatenate([g * u + pd for g in range(4)])
                    k, r, b = k[:, cols], r[pd][:, cols], b[cols]
                if prev is not None:
                    k = k[prev]
                dirs.append((k, r, b))
            fused = L.fuse_bilstm(*dirs, block_rows=config.m)
            gamma, beta = p[f"ln{i}.gamma"], p[f"ln{i}.beta"]
            if po is not None:
                gamma, beta = gamma[po], beta[po]
            gk = bk = None
            if self.layers:      # LayerNorm i-1 folded into this layer's input projection
                g0, b0 = self.layers[-1].gamma, self.layers[-1].beta
                wide = fused.kernel.astype(np.float64)
                gk = (g0.astype(np.float64) @ wide).astype(dtype)
                bk = (b0.astype(np.float64) @ wide).astype(dtype)
            self.layers.append(_Layer(fused, np.ascontiguousarray(gamma),
                                      np.ascontiguousarray(beta), gk, bk, merge))
            prev = po
        self.head_w = p["head.w"] if prev is None else np.ascontiguousarray(p["head.w"][prev])
        self.head_b = p["head.b"]

    def project(self, features: np.ndarray, batch: int = 1) -> np.ndarray:
        """BiLSTM 1's input projection (without bias) of each frame's feature ``(F, k)`` ->
        ``(F, 8u)``: kernel rows past the last non-zero feature are not read."""
        if self.feature_order is not None:
            features = features[:, self.feature_order]
        fused = self.layers[0].fused
        return L.project_spans(features, fused.kernel, fused.blocks,
                               [(0, L.used_columns(features))])

    def __call__(self, features: np.ndarray, proj1: np.ndarray | None = None) -> np.ndarray:
        """``features (B, m, k)`` -> ``(B, n_out, dim)`` in [0, 1]; ``proj1`` ``(m, B, 8u)``:
        :meth:`project` of the frames, time-major, if already known."""
        batch, m = features.shape[:2]
        act, eps = self.config.lstm_activation, self.config.layer_norm_eps
        if proj1 is None:                 # time-major rows (t, b)
            proj1 = self.project(features.transpose(1, 0, 2).reshape(m * batch, -1), batch)
        last = len(self.layers) - 1
        # LayerNorm squares its centred input: a ReLU LSTM output above sqrt(max)/2 would
        # overflow the variance to inf and silently turn the layer's output into beta
        # (finite but wrong), so every LSTM output is checked against that bound.
        limit = np.sqrt(np.finfo(self.dtype).max) / 4
        xp = proj1
        with np.errstate(over="ignore", invalid="ignore"):
            for i, lay in enumerate(self.layers):
                h = L.bilstm_steps(xp, lay.fused.recurrent, lay.fused.bias, m, batch, act,
                                   return_sequences=i < last)
                if act == "relu" and not h.max() < limit:   # also catches NaN
                    raise overflow_error(self.dtype, f"BiLSTM {i + 1}")
                n = h.shape[-1]
                if lay.merge is not None:     # both directions' outputs in one order
                    h = np.take(h, lay.merge, axis=-1)
                if i < last:              # LayerNorm folded into the next input projection
                    nxt = self.layers[i + 1]
                    spans = ((0, n),) if lay.merge is not None else ((0, n // 2), (n // 2, n))
                    xp = L.project_layer_norm(h.reshape(m * batch, -1), lay.gamma, lay.beta, eps,
                                              nxt.fused.kernel, nxt.fused.blocks, nxt.gk, nxt.bk,
                                              spans)
                else:
                    h = L.layer_norm(h, lay.gamma, lay.beta, eps)
            y = L.dense(h, self.head_w, self.head_b, "sigmoid")
        if not np.isfinite(y).all():
            raise overflow_error(self.dtype, "the output layer")
        return y.reshape(-1, self.config.n_out, self.config.dim)


def file_order_lstms(config: Any, params: dict[str, np.ndarray]
                     ) -> list[tuple[L.FusedBiLSTM, np.ndarray, np.ndarray]]:
    """Each BiLSTM's fused weights and LayerNorm ``(gamma, beta)``, units in the file's order
    (for measuring units' use: :func:`tpnet_ref.engines.unit_order.measure`)."""
    p = params
    return [(L.fuse_bilstm(*(tuple(p[f"lstm{i}.{d}.{k}"] for k in ("kernel", "recurrent", "bias"))
                             for d in ("fwd", "bwd")), block_rows=config.m),
             p[f"ln{i}.gamma"], p[f"ln{i}.beta"])
            for i in range(1, len(config.lstm_units) + 1)]


__all__ = ["BLOCK_POINTS", "NumpyFeatures", "NumpyHead", "file_order_lstms"]
