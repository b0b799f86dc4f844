"""TP-Net's forward pass, written to be read: the definition the docs cite and the oracle every
fast path is tested against (docs/spec.md §2; the authors' released configuration, Keras
semantics).

One window of ``m`` frames, each an unordered set of ``N_t`` points ``(N_t, dim)`` in world units:

    normalise -> per frame: [input T-Net] -> shared MLP 2-64-64 -> [feature T-Net]
      -> shared MLP 64-128-256-512 -> max over points -> FC 512-128 ReLU = G_t   (k = 128)
    (G_1 .. G_m) -> BiLSTM 512 -> LN -> BiLSTM 256 -> LN -> BiLSTM 256 (last state) -> LN
      -> FC 512 -> n_out * dim, sigmoid -> (n_out, dim) -> denormalise

Built only from the readable functions of :mod:`tpnet_ref.engines.layers` (``lstm`` one direction at a
time, every gate in Keras order). No zero-skipping, no fused weights, no canonical point order,
no threads: max-pooling makes the result invariant to each frame's point order in exact
arithmetic (the fast paths sort each frame to make it bit-exact). Runs in the dtype of
``params`` (use float64 as the reference). The parameters are the file's, named as in
:func:`tpnet_ref.config.param_shapes`.

``trace``: a dict that receives every named intermediate in forward order, the result unchanged
(docs/crosscheck.md lists the names, shapes and meanings; :mod:`tpnet_ref.conformance` compares
them). Per-point layers are ``(P, C)``, the frames' points one frame after another; per-frame
ones ``(m, C)``; each LSTM direction ``(m, u)``, row ``t`` its output at time step ``t``.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from . import layers as L
from ..config import TPNetConfig


def forward(config: TPNetConfig, params: dict[str, np.ndarray],
            window: Sequence[np.ndarray], normalized: bool = False,
            trace: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """The next point set of one window: ``m`` frames ``(N_t, dim)`` -> ``(n_out, dim)``, in world
    units (model coordinates with ``normalized=True``); ``trace``: filled with the intermediates."""
    p = params
    frames: dict[str, list[np.ndarray]] = {}

    def keep(name: str, x: np.ndarray, per_frame: bool = False) -> np.ndarray:
        """Record ``x`` under ``name`` (per frame: concatenated over the frames on axis 0)."""
        if trace is not None:
            if per_frame:
                frames.setdefault(name, []).append(np.array(x))
                trace[name] = np.concatenate(frames[name])
            else:
                trace[name] = np.array(x)
        return x

    dt = p["global.w"].dtype
    lo, scale = dt.type(config.norm_lo), dt.type(config.norm_hi - config.norm_lo)
    if len(window) != config.m:
        raise ValueError(f"window: the model takes m={config.m} frames, got {len(window)}")

    def mlp(x: np.ndarray, prefix: str, n: int, name: str | None = None) -> np.ndarray:
        for i in range(n):                                              # shared per point
            x = L.dense(x, p[f"{prefix}.{i}.w"], p[f"{prefix}.{i}.b"], "relu")
            if name:
                keep(f"{name}.{i}", x, True)
        return x

    def tnet(x: np.ndarray, prefix: str, cfg_mlp: tuple, cfg_fc: tuple) -> np.ndarray:
        g = mlp(x, f"{prefix}.mlp", len(cfg_mlp)).max(axis=0)          # max over points
        g = mlp(g, f"{prefix}.fc", len(cfg_fc))
        k = x.shape[1]
        t = L.dense(g, p[f"{prefix}.out.w"], p[f"{prefix}.out.b"]).reshape(k, k)
        return x @ keep(f"{prefix}.transform", t[None], True)[0]

    features = []
    for frame in window:                                    # PointNet, one frame at a time
        x = keep("input", np.asarray(frame, dtype=dt), True)
        x = keep("input.normalized", x if normalized else (x - lo) / scale, True)
        if config.input_transform_trained:
            x = keep("input.transformed", tnet(x, "input_tnet", config.input_tnet_mlp,
                                               config.input_tnet_fc), True)
        h = mlp(x, "mlp1", len(config.mlp1), "mlp1")
        if config.feature_transform_trained:
            h = keep("mlp1.transformed", tnet(h, "feature_tnet", config.feature_tnet_mlp,
                                              config.feature_tnet_fc), True)
        h = mlp(h, "mlp2", len(config.mlp2), "mlp2").max(axis=0)   # the symmetric function
        keep("pooled", h[None], True)
        features.append(keep("global", L.dense(h, p["global.w"], p["global.b"], "relu")[None],
                             True)[0])
    seq = np.stack(features)[None]                          # (1, m, k)

    last = len(config.lstm_units)
    for i in range(1, last + 1):                            # three BiLSTMs, each + LayerNorm
        fwd, bwd = ((p[f"lstm{i}.{d}.kernel"], p[f"lstm{i}.{d}.recurrent"],
                     p[f"lstm{i}.{d}.bias"]) for d in ("fwd", "bwd"))
        # Keras Bidirectional(LSTM), merge "concat" (= L.bidirectional_lstm): row t of the
        # backward direction is its output after consuming steps m-1 .. t
        f = keep(f"lstm{i}.fwd", L.lstm(seq, *fwd, activation=config.lstm_activation)[0])[None]
        b = keep(f"lstm{i}.bwd", L.lstm(seq, *bwd, activation=config.lstm_activation,
                                        reverse=True)[0])[None]
        seq = (np.concatenate([f, b], axis=-1) if i < last else
               np.concatenate([f[:, -1], b[:, 0]], axis=-1))   # the last: final outputs
        keep(f"lstm{i}.concat", seq[0])
        seq = L.layer_norm(seq, p[f"ln{i}.gamma"], p[f"ln{i}.beta"], config.layer_norm_eps)
        keep(f"ln{i}", seq[0])
    z = keep("head.logits", L.dense(seq[0], p["head.w"], p["head.b"]))
    y = keep("head.sigmoid", L.sigmoid(z).reshape(config.n_out, config.dim))
    return keep("output", y if normalized else y * scale + lo)


__all__ = ["forward"]
