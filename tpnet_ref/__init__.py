"""tpnet_ref: a minimal, exact and fast NumPy reference implementation of TP-Net.

    >>> import tpnet_ref
    >>> model = tpnet_ref.load()                    # shipped m = 4 weights
    >>> nxt = tpnet_ref.predict(window)             # window (m, N, 2), world units -> (30, 2)
    >>> future = tpnet_ref.rollout(window, 80)      # (80, 30, 2)

``import tpnet_ref`` loads NumPy only; the weights reader (h5py), the metrics (numba, extra
``metrics``), the simulator (pymunk, extra ``sim``) and the rest are imported when first used.
"""
from __future__ import annotations

import importlib as _importlib
import importlib.abc as _importlib_abc
import importlib.util as _importlib_util
import sys as _sys
import warnings as _warnings
import weakref as _weakref
from typing import Any as _Any

import numpy as _np

from .config import TPNetConfig
from .model import TPNet, init_random
from .model import load as _load_file

__version__ = "0.2.0"

_default_model: TPNet | None = None


def load(path: _Any = None, dtype: _Any = "float32", engine: str = "auto", *,
         m: int = 4, size: str = "full", weights: str | None = None) -> TPNet:
    """A :class:`TPNet` from a native weights file (:func:`tpnet_ref.model.load`).

    Without ``path``, the shipped model for windows of ``m`` frames at network ``size``:
    ``full`` (the paper's widths; the default, m = 4) or a reduced size shipped for m = 4
    (``"half"``, ``"quarter"``: every width halved or quartered, faster, less accurate;
    ``weights/MODEL_CARD.md``),
    found by :func:`tpnet_ref.weights.shipped.shipped_weights_path`. ``m`` and ``size`` are only
    for the shipped files: with a ``path`` they must stay at their defaults.

    ``engine``: "auto" (the default: the compiled Numba head where numba is installed, else the
    NumPy one; a process's first call then loads numba and its cached code, and the very first
    one after installing compiles it: docs/deployment.md), "numpy" or "numba".

    ``weights``: None (the file's own: float32, or the bf16 / int8 of a file written by
    ``tpnet quantize``), "bf16" or "int8" (the BiLSTM matrices rounded to that grid at load,
    read by the Numba engine in about two thirds or a quarter of the bytes:
    :func:`tpnet_ref.weights.convert.with_weights`, docs/deployment.md)."""
    if weights is not None and weights not in ("float32", "bf16", "int8"):
        raise ValueError(f"weights must be None, 'float32', 'bf16' or 'int8', got {weights!r}")
    if path is None and (m != 4 or size != "full"):
        from .weights.shipped import shipped_weights_path
        path = shipped_weights_path(m, size)
    elif path is not None and (m != 4 or size != "full"):
        raise ValueError("load: give either a path or m= / size= (a shipped model), not both")
    model = _load_file(path, dtype, engine)
    if weights is None:
        return model
    from .weights.convert import with_weights
    return with_weights(model, weights)


def _model(model: TPNet | None, dtype: _Any = None) -> TPNet:
    """``model`` (default: the shipped m = 4 model, loaded once), in ``dtype`` when one is given
    (a converted copy, kept while the model lives)."""
    global _default_model
    if model is not None:
        if not isinstance(model, TPNet):
            raise TypeError(f"model: expected a tpnet_ref TPNet, got {type(model).__name__}")
    else:
        if _default_model is None:
            _default_model = load()
        model = _default_model
    if dtype is None or _np.dtype(dtype) == model.dtype:
        return model
    if _np.dtype(dtype) not in (_np.dtype(_np.float32), _np.dtype(_np.float64)):
        raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
    key = _np.dtype(dtype).name
    copies = _AS_DTYPE.setdefault(model, {})
    if key not in copies:
        copies[key] = model.astype(key)
    return copies[key]


#: each model's copies in another dtype (:func:`_model`), dropped with the model
_AS_DTYPE: _Any = _weakref.WeakKeyDictionary()


def predict(window: _Any, model: TPNet | None = None, normalized: bool = False,
            dtype: _Any = None) -> _np.ndarray:
    """Next point set ``(n_out, 2)`` from a window ``(m, N, 2)`` or m arrays ``(N_i, 2)``.
    Input outside the training range gives a one-line ``OutsideTrainingRangeWarning``, a window
    that does not look like one body (stray points) a ``NotOneBodyWarning``, a frame of fewer
    than 3 points a ``TooFewPointsWarning``, a window whose centroid moves outside 0.1..2.5
    world units per frame (frames not 4/45 s apart) a ``FrameSpacingWarning``; the result is
    computed unchanged. ``dtype`` ("float32" or "float64"; default: the model's): compute in this
    dtype (the model converted once and kept). The output has the dtype computed in, whatever the
    input's: with the default float32 model a float64 window is rounded to float32 and comes back
    float32; pass ``dtype="float64"`` (or a float64 model) for float64 results."""
    return _model(model, dtype).predict(window, normalized=normalized)


def predict_batch(windows: _Any, model: TPNet | None = None, normalized: bool = False,
                  dtype: _Any = None) -> _np.ndarray:
    """Next point set of each window: ``(B, m, N, 2)`` or a list of windows -> ``(B, n_out, 2)``
    (``dtype``: as :func:`predict`)."""
    return _model(model, dtype).predict_batch(windows, normalized=normalized)


def rollout(window: _Any, steps: int, model: TPNet | None = None, normalized: bool = False,
            dtype: _Any = None) -> _np.ndarray:
    """``steps`` recursive predictions ``(steps, n_out, 2)``; the window slides by one frame
    (``dtype``: as :func:`predict`)."""
    return _model(model, dtype).rollout(window, steps, normalized=normalized)


def rollout_batch(windows: _Any, steps: int, model: TPNet | None = None,
                  normalized: bool = False, dtype: _Any = None) -> _np.ndarray:
    """:func:`rollout` of every window, stepped together: ``(B, m, N, 2)`` ->
    ``(B, steps, n_out, 2)`` (``dtype``: as :func:`predict`)."""
    return _model(model, dtype).rollout_batch(windows, steps, normalized=normalized)


def example_window() -> _np.ndarray:
    """A real m = 4 window to start from: ``(4, 30, 2)`` world units, four frames of a simulated
    training-grid scene 4 simulation steps apart (:mod:`tpnet_ref.weights.shipped`)."""
    from importlib.resources import files
    with files("tpnet_ref.weights.shipped").joinpath("example_window.npy").open("rb") as f:
        return _np.load(f, allow_pickle=False)


#: submodules imported on first attribute access (``tpnet_ref.metrics`` needs the metrics extra)
_LAZY = ("config", "checks", "model", "extras", "engines", "weights", "metrics", "sim",
         "evaluation", "training", "conformance", "observe", "testing")

# ------------------------------------------------------------------ old import paths
#: modules that moved (docs/architecture.md draws where everything lives now), by their old name
#: under ``tpnet_ref``: the modules that hold their names now. ``import tpnet_ref.heads``,
#: ``from tpnet_ref.blas import one_thread``, ``tpnet_ref.specialize`` and objects pickled under
#: an old path still work until the next release, with a ``DeprecationWarning`` naming the new
#: place.
_MOVED: dict[str, tuple[str, ...]] = {
    "heads": ("engines.interface",),
    "fast_numpy": ("engines.numpy_engine",),
    "engine_numba": ("engines.numba_engine", "engines.numba_lstm", "engines.numba_features",
                     "engines.numba_products", "engines.numba_tiles", "engines.numba_codegen"),
    "specialize": ("engines.specialised",),
    "unit_order": ("engines.unit_order",),
    "blas": ("engines.blas", "engines.thread_policy", "engines.load_monitor",
             "engines.batch_split"),
    "layers": ("engines.layers",),
    "reference": ("engines.reference",),
    "recursive": ("engines.rollout",),
    "compile_watch": ("engines.compile_watch",),
    "_chamfer_kernels": ("metrics.chamfer_kernels",),
    "crosscheck": ("conformance.layer_names", "conformance.tolerances", "conformance.cases",
                   "conformance.vectors", "conformance.compare", "conformance.report"),
    "traces": ("conformance.traces",),
    "onnx_peer": ("conformance.onnx_peer",),
    "torch_model": ("training.torch_model",),
    "native": ("weights.native", "weights.shipped"),
    "hdf5": ("weights.hdf5",),
    "provenance": ("weights.provenance",),
    "data": ("sim.dataset",),
    "protocol": ("sim.protocol",),
    "sim.render": ("observe.render",),
}
#: names renamed on the way: ``"old module.old name": "new module.new name"``
_RENAMED: dict[str, str] = {
    "crosscheck.read_vectors": "conformance.vectors.read_conformance_vectors",
    "crosscheck.write_vectors": "conformance.vectors.write_conformance_vectors",
}


class _OldPaths(_importlib_abc.MetaPathFinder, _importlib_abc.Loader):
    """Imports an old module path (:data:`_MOVED`) as a module whose names are looked up in the
    modules that hold them now."""

    def find_spec(self, fullname: str, path: _Any = None, target: _Any = None) -> _Any:
        head, _, old = fullname.partition(".")
        if head != __name__ or old not in _MOVED:
            return None
        return _importlib_util.spec_from_loader(fullname, self)

    def create_module(self, spec: _Any) -> None:
        return None

    def exec_module(self, module: _Any) -> None:
        old = module.__name__.partition(".")[2]
        new = [f"{__name__}.{m}" for m in _MOVED[old]]
        _warnings.warn(f"{module.__name__} has moved to {' and '.join(new)}; the old path goes "
                       "in the next release", DeprecationWarning, stacklevel=2)
        homes = [_importlib.import_module(m) for m in new]

        def __getattr__(name: str) -> _Any:
            renamed = _RENAMED.get(f"{old}.{name}")
            if renamed is not None:
                where, _, attr = renamed.rpartition(".")
                return getattr(_importlib.import_module(f"{__name__}.{where}"), attr)
            for home in homes:
                if hasattr(home, name):
                    return getattr(home, name)
            raise AttributeError(f"module {module.__name__!r} has no attribute {name!r}")

        module.__getattr__ = __getattr__
        module.__dir__ = lambda: sorted(set().union(*(dir(h) for h in homes)))


if not any(type(f).__name__ == "_OldPaths" for f in _sys.meta_path):
    _sys.meta_path.insert(0, _OldPaths())       # before any finder that might know the old files


def __getattr__(name: str) -> _Any:
    if name in _LAZY or name in _MOVED:
        return _importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'tpnet_ref' has no attribute {name!r}")


__all__ = ["load", "predict", "predict_batch", "rollout", "rollout_batch", "example_window",
           "TPNet", "TPNetConfig", "init_random", "__version__"]


def __dir__() -> list[str]:
    return sorted(__all__ + list(_LAZY))
