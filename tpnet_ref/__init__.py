"""tpnet_ref: a minimal, exact and fast NumPy reference implementation of TP-Net.

    >>> import tpnet_ref
    >>> model = tpnet_ref.load()                    # shipped m = 4 weights
    >>> nxt = tpnet_ref.predict(window)             # window (m, N, 2), world units -> (30, 2)
    >>> future = tpnet_ref.rollout(window, 80)      # (80, 30, 2)

``import tpnet_ref`` loads NumPy only; the metrics (numba), the simulator (pymunk) and the
weights reader (h5py) are imported when first used.
"""
from __future__ import annotations

import importlib
from typing import Any

import numpy as np

from .model import TPNet, TPNetConfig, init_random

__version__ = "0.1.0"

_default_model: TPNet | None = None


def load(path: Any = None, dtype: str = "float32") -> TPNet:
    """Load a native weights file; ``path=None`` loads the shipped m = 4 model."""
    from .weights import load as _load
    return _load(path, dtype)


def _model(model: TPNet | None) -> TPNet:
    global _default_model
    if model is not None:
        if not isinstance(model, TPNet):
            raise TypeError(f"model: expected a tpnet_ref TPNet, got {type(model).__name__}")
        return model
    if _default_model is None:
        _default_model = load()
    return _default_model


def predict(window: Any, model: TPNet | None = None, normalized: bool = False) -> np.ndarray:
    """Next point set ``(n_out, 2)`` from a window ``(m, N, 2)`` or m arrays ``(N_i, 2)``."""
    return _model(model).predict(window, normalized=normalized)


def predict_batch(windows: Any, model: TPNet | None = None, normalized: bool = False) -> np.ndarray:
    """Next point set of each window: ``(B, m, N, 2)`` or a list of windows -> ``(B, n_out, 2)``."""
    return _model(model).predict_batch(windows, normalized=normalized)


def rollout(window: Any, steps: int, model: TPNet | None = None,
            normalized: bool = False) -> np.ndarray:
    """``steps`` recursive predictions ``(steps, n_out, 2)``; the window slides by one frame."""
    return _model(model).rollout(window, steps, normalized=normalized)


_LAZY = ("metrics", "sim", "weights", "data", "evaluation", "layers", "model", "checks", "config", "blas")


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'tpnet_ref' has no attribute {name!r}")


__all__ = ["load", "predict", "predict_batch", "rollout", "TPNet", "TPNetConfig", "init_random",
           "__version__"]
