"""The prediction network's heads: one small interface, several ways to run it.

A head runs TP-Net's prediction network (three BiLSTMs with LayerNorm, the sigmoid output layer)
on the frames' global features. Every head gives the result of :mod:`tpnet_ref.engines.reference` up to
rounding (``tests/test_engines_reference.py`` checks each one at the released shape); only speed and
the order of the sums differ.

=============  ========================================  ==================  ==================
head           class                                     runs batches of     needs
=============  ========================================  ==================  ==================
numpy          :class:`tpnet_ref.engines.numpy_engine.NumpyHead`   any size            NumPy
numba          :class:`tpnet_ref.engines.numba_engine.NumbaHead` any size            numba (``metrics``)
specialised    :class:`tpnet_ref.engines.specialised.SpecialisedHead`  any size; flagged windows go to numpy
=============  ========================================  ==================  ==================

The numba head of a specialised model runs batches of up to :data:`ENGINE_MAX_BATCH` windows;
the larger ones go to the specialised head.

A model keeps its heads fastest first (:func:`build`) and gives a batch to the first whose
``max_batch`` admits it (:func:`for_batch`); the NumPy head takes any batch, so it comes last.
The optional ones are imported only when a model asks for them.
"""
from __future__ import annotations

import importlib.util
from typing import Any, Protocol

import numpy as np

from . import specialised as S
from ..extras import require
from ..weights.quantize import wide_of
from .numpy_engine import NumpyHead

#: the prediction engines: "numpy" (the NumPy head), "numba" (the compiled head of
#: :mod:`tpnet_ref.engines.numba_engine`; extra ``metrics``), "auto" (numba when installed)
ENGINES = ("numpy", "numba", "auto")
#: the numba head runs batches of every size (faster than the NumPy head at 1 to 64 windows, and
#: free of the GIL, so a split batch's chunks run side by side), and its compiled feature
#: extractor too (1.6-2.4x NumPy's BLAS products at 16 and 64 windows: docs/performance.md); a
#: specialised model's numba head runs batches of up to this many windows, the larger ones go
#: to the specialised head
ENGINE_MAX_BATCH = 8


class Head(Protocol):
    """A way to run the prediction network."""

    name: str                   # "numpy", "numba", "specialised"
    max_batch: int | None       # the largest batch it runs (None: any)
    threaded: bool              # whether its calls may take a second thread (same bits either way)

    def project(self, features: np.ndarray, batch: int = 1) -> np.ndarray | None:
        """BiLSTM 1's input projection of each frame's feature ``(F, k)``, in this head's layout
        (a function of one frame: a rollout computes it once per frame), or None when the head
        projects its inputs itself."""

    def __call__(self, features: np.ndarray, proj1: np.ndarray | None = None) -> np.ndarray:
        """``features (B, m, k)`` -> the next point sets ``(B, n_out, dim)`` in model coordinates
        ([0, 1]); ``proj1 (m, B, ...)``: :meth:`project` of the frames, time-major, if known.
        Raises :class:`tpnet_ref.checks.NonFiniteResultError` where the network overflows."""


def resolve_engine(engine: Any) -> str:
    """``engine`` checked, "auto" resolved (numba if installed)."""
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {', '.join(map(repr, ENGINES))}, got {engine!r}")
    if engine == "auto":
        return "numba" if importlib.util.find_spec("numba") is not None else "numpy"
    return engine


def build(model: Any, engine: str, used: dict[str, np.ndarray] | None) -> list[Head]:
    """``model``'s heads, fastest first: the numba head for ``engine="numba"``, the specialised
    one when ``used`` (masks from :func:`tpnet_ref.engines.specialised.calibrate`) is given, and the
    NumPy head. The model's ``counts`` count the specialised head's windows and fallbacks."""
    cfg = model.config
    full: list[Head] = [NumpyHead(cfg, model.params, model.dtype, model.unit_order)]
    if engine == "numba":
        require("numba", "metrics", "engine='numba' (the Numba inference engine)")
        from . import numba_engine as engine_numba  # optional: imports numba
        # every batch, or (specialised) the batches up to ENGINE_MAX_BATCH, the larger ones
        # going to the specialised head, which computes only the scene's units
        scheme = model.meta.get("quantization")
        full.insert(0, engine_numba.NumbaHead(cfg, model.params, model.dtype, model.unit_order,
                                              None if used is None else ENGINE_MAX_BATCH, scheme,
                                              None if scheme is None else wide_of(cfg, model.meta)))
    if used is None:
        return full
    # the specialised head after the numba one (faster on the batches it runs), its flagged
    # windows computed by the full network's heads
    spec = S.SpecialisedHead(S.SceneHead(model, used), full, model.counts, (cfg.n_out, cfg.dim))
    return full[:-1] + [spec, full[-1]]


def build_features(model: Any, engine: str) -> Any:
    """The compiled feature extractor (:class:`tpnet_ref.engines.numba_engine.NumbaFeatures`) that
    goes with the numba head, or None: engine "numpy", or trained transform nets (the NumPy
    extractor then serves every batch)."""
    if engine != "numba":
        return None
    from . import numba_engine as engine_numba
    if not engine_numba.NumbaFeatures.supports(model.config):
        return None
    return engine_numba.NumbaFeatures(model.config, model.params, model.dtype)


def build_screen(engine: str, config: Any) -> Any:
    """The compiled first pass over an array of windows
    (:class:`tpnet_ref.engines.numba_checks.Screen`) that goes with the numba head, or None: engine
    "numpy", or points of a dimension it does not read (``numba_checks.DIMS``; the checks then
    serve every call)."""
    if engine != "numba":
        return None
    from . import numba_checks
    return numba_checks.Screen() if config.dim in numba_checks.DIMS else None


def build_fused(engine: str) -> Any:
    """The prediction's network as one compiled call (:mod:`tpnet_ref.engines.numba_predict`)
    that goes with the numba head, or None: engine "numpy"."""
    if engine != "numba":
        return None
    from . import numba_predict
    return numba_predict.Network()


def for_batch(heads: list[Head], batch: int) -> Head:
    """The first of ``heads`` that runs batches of ``batch`` windows."""
    return next(h for h in heads if h.max_batch is None or batch <= h.max_batch)


__all__ = ["ENGINES", "ENGINE_MAX_BATCH", "Head", "resolve_engine", "build", "build_features",
           "build_screen", "for_batch"]
