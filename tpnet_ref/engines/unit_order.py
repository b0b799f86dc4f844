"""The order in which the NumPy engine lays out each layer's units: most used first.

A ReLU TP-Net's activations are mostly exact zeros (shipped m = 4 model on the scene's windows:
about 80 % of the global features, 65-75 % of every BiLSTM's outputs), and mostly the same
units stay zero from window to window. The NumPy engine reads only the weight rows up to the
last non-zero unit of each product (:func:`tpnet_ref.engines.layers.used_columns`), which is exact on
every input whatever the order. With the units laid out most-used first, that prefix is short on
the windows the order was measured on, so a prediction reads a fraction of the weights.

Permuting the units of a layer is an exact re-parameterisation (the same function, up to the
rounding of LayerNorm's sums): the order only changes the fast paths' layout
(:mod:`tpnet_ref.engines.numpy_engine`, :mod:`tpnet_ref.engines.numba_engine`); ``model.params`` keep the file's order.
:meth:`tpnet_ref.model.TPNet.sort_units` measures an order; :func:`write` / :func:`read` keep
it in the native weights file as a group ``unit_order`` (ignored by readers that do not know it).

Orders: ``{"mlp1.0": (64,), ..., "global": (k,), "lstm1": (2u_1,), ...}`` integer arrays;
position ``j`` of the layout holds unit ``order[j]`` of the file. An LSTM's order is that of its
``2u`` outputs ``[forward | backward]``, both directions together (the LayerNorm, the next
layer's input rows); each direction's recurrence takes its units in the same relative order.
"""
from __future__ import annotations

import os
from typing import Any

import numpy as np

from . import layers as L
from ..checks import check_window
from .numpy_engine import file_order_lstms
from ..weights.hdf5 import read_vectors, write_vectors
from ..weights.native import seal

#: name of the HDF5 group that holds a unit order in the native weights file
GROUP = "unit_order"
FORMAT = "tpnet_ref.unit_order/1"


def sizes(config: Any) -> dict[str, int]:
    """``{name: units}`` of every layer with an order: the per-point MLPs' layers ``mlp1.i``
    and ``mlp2.i`` (``mlp2.<last>``: the max-pooled features; not ``mlp1.<last>`` when a trained
    feature transform multiplies it), ``global`` and ``lstm1 ..``."""
    mlp = {f"mlp1.{i}": n for i, n in enumerate(config.mlp1)}
    if config.feature_transform_trained:
        mlp.pop(f"mlp1.{len(config.mlp1) - 1}")
    mlp.update({f"mlp2.{i}": n for i, n in enumerate(config.mlp2)})
    return {**mlp, "global": config.global_features,
            **{f"lstm{i}": 2 * u for i, u in enumerate(config.lstm_units, 1)}}


def check(order: dict[str, Any] | None, config: Any) -> dict[str, np.ndarray] | None:
    """``order`` validated against ``config`` (each a permutation of the right size) as ``intp``
    arrays; None stays None. One-line ``ValueError``."""
    if order is None:
        return None
    want = sizes(config)
    unknown = sorted(set(order) - set(want))
    if unknown:
        raise ValueError(f"unit order: unknown layers {unknown}; expected some of {sorted(want)}")
    out = {}
    for name, arr in order.items():
        a = np.asarray(arr)
        n = want[name]
        if a.shape != (n,) or a.dtype.kind not in "iu":
            raise ValueError(f"unit order {name!r}: expected {n} integers, got {a.dtype} {a.shape}")
        a = a.astype(np.intp)
        if not np.array_equal(np.sort(a), np.arange(n)):
            raise ValueError(f"unit order {name!r}: not a permutation of 0..{n - 1}")
        out[name] = a
    return out


def measure(model: Any, windows: Any, normalized: bool = False, chunk: int = 256,
            mlp: bool = True) -> dict[str, np.ndarray]:
    """Each unit's share of non-zero values on ``windows (B, m, N, dim)`` (MLP units per point,
    max-pooled and global features per frame, LSTM outputs per window and step):
    ``{name: (units,) float64}`` in the file's order. ``mlp=False``: the global features and
    LSTMs only."""
    cfg = model.config
    windows = np.asarray(windows)
    if windows.ndim != 4 or windows.shape[1] != cfg.m or len(windows) == 0:
        raise ValueError(f"windows: expected shape (B, m={cfg.m}, N, {cfg.dim}) with B >= 1, "
                         f"got {windows.shape}")
    want = sizes(cfg)
    counts = {k: np.zeros(n) for k, n in want.items()}
    p = model.params
    points = 0
    # the per-point MLPs' units are measured up to the first trained transform after the points
    mlps = [] if cfg.input_transform_trained or not mlp else (
        [("mlp1", len(cfg.mlp1))] + ([] if cfg.feature_transform_trained else [("mlp2", len(cfg.mlp2))]))
    for s in range(0, len(windows), chunk):
        part = windows[s:s + chunk]
        frames = [f for w in part for f in check_window(w, cfg.m, cfg.dim, model.dtype, "windows")]
        pts, n = model.canonical_points(frames, normalized)
        x = pts                                  # the per-point MLPs in the file's order
        points += len(x)
        for name, width in mlps:
            for i in range(width):
                x = L.dense(x, p[f"{name}.{i}.w"], p[f"{name}.{i}.b"], "relu")
                key = f"{name}.{i}"
                if name == "mlp2" and i == width - 1:     # max-pooled: per frame
                    counts[key] += (L.segment_max(x, n) != 0).sum(axis=0)
                elif key in want:
                    counts[key] += (x != 0).sum(axis=0)
        g = model.frame_features(pts, n).reshape(len(part), cfg.m, -1)
        counts["global"] += (g != 0).sum(axis=(0, 1))
        h = g.transpose(1, 0, 2)
        with np.errstate(over="ignore", invalid="ignore"):
            for i, (fused, gamma, beta) in enumerate(file_order_lstms(cfg, p), 1):
                y = L.bilstm_fused(h, *fused, activation=cfg.lstm_activation,
                                   return_sequences=True)
                counts[f"lstm{i}"] += (y != 0).sum(axis=(0, 1))
                h = L.layer_norm(y, gamma, beta, cfg.layer_norm_eps)
    measured = {f"{name}.{i}" for name, width in mlps for i in range(width)} & set(want)
    frames_n = len(windows) * cfg.m
    last2 = f"mlp2.{len(cfg.mlp2) - 1}"
    return {k: v / (points if k.startswith("mlp") and k != last2 else frames_n)
            for k, v in counts.items() if not k.startswith("mlp") or k in measured}


def from_use(use: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The order putting the most used units first (ties: the file's order)."""
    return {name: np.argsort(-share, kind="stable") for name, share in use.items()}


# ------------------------------------------------------------------ native file
def group(order: dict[str, np.ndarray]) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """``order`` as the native file's ``unit_order`` group: ``(attrs, {layer: int32 array})``
    (:func:`tpnet_ref.weights.native.write_native`'s ``groups``)."""
    return {"format": FORMAT}, {k: np.asarray(v, dtype=np.int32) for k, v in order.items()}


def write(path: str | os.PathLike, order: dict[str, np.ndarray], **attrs: Any) -> None:
    """Add ``order`` as group ``unit_order`` (int32 datasets) to an existing native weights
    file, replacing any group of that name, and renew the file's content digest."""
    write_vectors(path, GROUP, FORMAT, order, np.int32, **attrs)
    seal(path)


def read(path: str | os.PathLike) -> dict[str, np.ndarray] | None:
    """The ``unit_order`` group of a native weights file, or None without one. The file is
    untrusted: links, external storage, oversized or non-integer datasets are refused (the
    values are checked against the config by :func:`check`)."""
    return read_vectors(path, GROUP, FORMAT, "unit order")


__all__ = ["GROUP", "FORMAT", "sizes", "check", "measure", "from_use", "group", "write", "read"]
