"""The order in which the NumPy engine lays out each layer's units: most used first.

A ReLU TP-Net's activations are mostly exact zeros (shipped m = 4 model on the scene's windows:
about 80 % of the global features, 65-75 % of every BiLSTM's outputs), and mostly the same
units stay zero from window to window. The NumPy engine reads only the weight rows up to the
last non-zero unit of each product (:func:`tpnet_ref.layers.used_columns`), which is exact on
every input whatever the order. With the units laid out most-used first, that prefix is short on
the windows the order was measured on, so a prediction reads a fraction of the weights.

Permuting the units of a layer is an exact re-parameterisation (the same function, up to the
rounding of LayerNorm's sums): the order only changes the model's private layout
(:meth:`tpnet_ref.model.TPNet._prepare`); ``model.params`` keep the file's order.
:meth:`tpnet_ref.model.TPNet.sort_units` measures an order; :func:`write` / :func:`read` keep
it in the native weights file as a group ``unit_order`` (ignored by readers that do not know it).

Orders: ``{"global": (k,), "lstm1": (2u_1,), ...}`` integer arrays; position ``j`` of the
layout holds unit ``order[j]`` of the file. An LSTM's order keeps the directions apart: its
first ``u`` entries permute ``0 .. u-1`` (forward), the last ``u`` permute ``u .. 2u-1``.
"""
from __future__ import annotations

import os
from typing import Any

import numpy as np

from .weights.hdf5 import attr, safe_dataset, safe_group

#: name of the HDF5 group that holds a unit order in the native weights file
GROUP = "unit_order"
FORMAT = "tpnet_ref.unit_order/1"


def sizes(config: Any) -> dict[str, int]:
    """``{name: units}`` of every layer with an order."""
    return {"global": config.global_features,
            **{f"lstm{i}": 2 * u for i, u in enumerate(config.lstm_units, 1)}}


def check(order: dict[str, Any] | None, config: Any) -> dict[str, np.ndarray] | None:
    """``order`` validated against ``config`` (each a permutation of the right size, LSTM
    directions kept apart) as ``intp`` arrays; None stays None. One-line ``ValueError``."""
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
        halves = [a] if name == "global" else [a[:n // 2], a[n // 2:] - n // 2]
        for part in halves:
            if not np.array_equal(np.sort(part), np.arange(part.size)):
                raise ValueError(f"unit order {name!r}: not a permutation"
                                 + ("" if name == "global" else " of each direction's units"))
        out[name] = a
    return out


def measure(model: Any, windows: Any, normalized: bool = False,
            chunk: int = 256) -> dict[str, np.ndarray]:
    """Each unit's share of non-zero values on ``windows (B, m, N, dim)`` (global features per
    frame, LSTM outputs per window and step): ``{name: (units,) float64}`` in the file's order."""
    from . import layers as L
    cfg = model.config
    windows = np.asarray(windows)
    if windows.ndim != 4 or windows.shape[1] != cfg.m or len(windows) == 0:
        raise ValueError(f"windows: expected shape (B, m={cfg.m}, N, {cfg.dim}) with B >= 1, "
                         f"got {windows.shape}")
    counts = {k: np.zeros(n) for k, n in sizes(cfg).items()}
    p = model.params
    for s in range(0, len(windows), chunk):
        part = windows[s:s + chunk]
        frames = [f for w in part for f in model._check_window(w, "windows")]
        g = model._frames_to_features(frames, normalized).reshape(len(part), cfg.m, -1)
        counts["global"] += (g != 0).sum(axis=(0, 1))
        h = g.transpose(1, 0, 2)
        with np.errstate(over="ignore", invalid="ignore"):
            for i in range(1, len(cfg.lstm_units) + 1):
                fwd, bwd = (tuple(p[f"lstm{i}.{d}.{k}"] for k in ("kernel", "recurrent", "bias"))
                            for d in ("fwd", "bwd"))
                y = L.bilstm_fused(h, *L.fuse_bilstm(fwd, bwd),
                                   activation=cfg.lstm_activation, return_sequences=True)
                counts[f"lstm{i}"] += (y != 0).sum(axis=(0, 1))
                h = L.layer_norm(y, p[f"ln{i}.gamma"], p[f"ln{i}.beta"], cfg.layer_norm_eps)
    n = len(windows) * cfg.m
    return {k: v / n for k, v in counts.items()}


def from_use(use: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The order putting the most used units first (ties: the file's order), per direction."""
    out = {}
    for name, share in use.items():
        if name == "global":
            out[name] = np.argsort(-share, kind="stable")
        else:
            u = share.size // 2
            out[name] = np.concatenate([np.argsort(-share[:u], kind="stable"),
                                        u + np.argsort(-share[u:], kind="stable")])
    return out


# ------------------------------------------------------------------ native file
def write(path: str | os.PathLike, order: dict[str, np.ndarray], **attrs: Any) -> None:
    """Add ``order`` as group ``unit_order`` (int32 datasets) to an existing native weights
    file, replacing any group of that name."""
    import h5py
    with h5py.File(path, "a") as f:
        if GROUP in f:
            del f[GROUP]
        g = f.create_group(GROUP)
        g.attrs["format"] = FORMAT
        for k, v in attrs.items():
            g.attrs[k] = v
        for k, v in order.items():
            g.create_dataset(k, data=np.asarray(v, dtype=np.int32))


def read(path: str | os.PathLike) -> dict[str, np.ndarray] | None:
    """The ``unit_order`` group of a native weights file, or None without one. The file is
    untrusted: links, external storage, oversized or non-integer datasets are refused (the
    values are checked against the config by :func:`check`)."""
    import h5py
    where = str(path)
    with h5py.File(path, "r") as f:
        if GROUP not in f:
            return None
        g = safe_group(f, GROUP, where)
        if attr(g, "format", where) not in (FORMAT, FORMAT.encode()):
            raise ValueError(f"{path}: group {GROUP!r} is not a {FORMAT} unit order")
        out = {}
        for k in g:
            d = safe_dataset(g, k, where)
            if d.ndim != 1 or d.size > 1 << 20 or d.dtype.kind not in "iu":
                raise ValueError(f"{path}: {GROUP}/{k} is not a unit order")
            out[k] = np.asarray(d[()])
        return out


__all__ = ["GROUP", "FORMAT", "sizes", "check", "measure", "from_use", "write", "read"]
