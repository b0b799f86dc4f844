"""Any supported checkpoint -> :class:`~tpnet_ref.model.TPNet`, told apart by content: a native
file, a Keras HDF5 / ``.keras`` file or a torch state dict (``tpnet import SRC DST``); a model's
weights of fewer bits (:func:`with_weights`: ``tpnet_ref.load(..., weights=...)``,
``tpnet quantize``)."""
from __future__ import annotations

import os
import zipfile
from pathlib import Path
from typing import Any

from ..model import TPNet
from . import hdf5
from .keras import import_keras_h5
from .native import is_native, read_native
from . import quantize as Q
from .torch import import_torch


@hdf5.damaged_file_is_value_error
def import_checkpoint(path: str | os.PathLike, dtype: Any = "float32", **kw: Any) -> Any:
    """Any supported checkpoint -> :class:`~tpnet_ref.model.TPNet`: a native file, a Keras
    HDF5 / ``.keras`` file (:func:`~tpnet_ref.weights.keras.import_keras_h5`) or a torch state
    dict (:func:`~tpnet_ref.weights.torch.import_torch`), told apart by content, not by name.
    ``kw``: ``m``, ``layer_norm_eps``, ``lstm_activation`` where the file does not say."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"checkpoint not found: {p}")
    with open(p, "rb") as fh:
        head = fh.read(8)
    if head == hdf5.HDF5_MAGIC:
        if is_native(p):
            cfg, params, meta = read_native(p)
            model = TPNet(cfg, params, dtype, meta)
            model.meta["import_report"] = "native tpnet_ref weights file"
            return model
        return import_keras_h5(p, dtype=dtype, **kw)
    if not zipfile.is_zipfile(p):
        raise ValueError(f"{p}: not a checkpoint at all: neither HDF5 (a Keras .h5 or a native "
                         "weights file) nor a zip archive (.keras, torch.save); legacy pickled "
                         "torch files are never read")
    if zipfile.is_zipfile(p):
        try:
            with zipfile.ZipFile(p) as z:
                is_keras = "model.weights.h5" in z.namelist()
        except (zipfile.BadZipFile, EOFError, OSError) as exc:
            raise ValueError(f"{p}: damaged zip archive ({exc})") from None
        if is_keras:
            return import_keras_h5(p, dtype=dtype, **kw)
    try:
        import torch  # noqa: F401  (optional: the train extra)
    except ImportError:
        raise ValueError(f"{p}: neither HDF5 nor a .keras archive; reading it as a PyTorch "
                         "checkpoint needs torch (pip install 'tpnet-ref[train]')") from None
    model = import_torch(p, dtype=dtype, **{k: v for k, v in kw.items() if v is not None})
    model.meta["import_report"] = (f"torch state dict; m={model.config.m}, N={model.config.n_out}, "
                                   f"params={model.num_params:,}; {model.meta['import_note']}")
    return model


def quantized_meta(model: TPNet, scheme: str) -> dict:
    """``model.meta`` with the scheme and its source (``quantized_from``: the file and its
    digest) added."""
    src = model.meta.get("path", "a model in memory")
    digest = model.meta.get("content_sha256")
    return {**model.meta, Q.ATTR: scheme,
            Q.FROM_ATTR: f"{Path(src).name} ({digest})" if digest else str(src)}


def with_weights(model: TPNet, weights: str | None, wide: list[str] | None = None) -> TPNet:
    """``model`` with its BiLSTM matrices on the grid of ``weights`` ("bf16" or "int8":
    :mod:`tpnet_ref.weights.quantize`; the Numba engine then reads their codes), or as it is
    (None, or the scheme it already has); ``wide``: the matrices in two planes (default: the
    scheme's :func:`~tpnet_ref.weights.quantize.wide_names`; a list given, ``[]`` for one
    plane, is recorded in ``meta``). The scheme and the source (``quantized_from``: the
    file and its digest) go to ``meta``; ``model.save`` writes the codes. A model already
    quantized otherwise, or "float32" asked of a quantized model, is a one-line ``ValueError``
    (quantize the float32 file)."""
    have = model.meta.get(Q.ATTR)
    if weights is None or weights == have or (weights == "float32" and have is None):
        return model
    if have is not None:
        raise ValueError(f"weights={weights!r}: this model's weights are already {have} "
                         f"({model.meta.get('path', 'in memory')}); quantize the float32 file")
    Q.check_scheme(weights, "weights")
    names = set(Q.quantized_names(model.config))
    two = set(Q.wide_names(model.config, weights) if wide is None else wide)
    if not two <= names:
        raise ValueError(f"wide={wide!r}: not quantized matrices of this network")
    params = {n: (Q.round_to(p, weights, n in two) if n in names else p)
              for n, p in model.params.items()}
    meta = quantized_meta(model, weights)
    if wide is not None:
        meta[Q.WIDE_ATTR] = ",".join(n for n in Q.quantized_names(model.config) if n in two)
    used = None if model.specialization is None else model.specialization.used
    out = TPNet(model.config, params, model.dtype, meta, model.engine,
                unit_order=model.unit_order, used=used, sort_points=model.sort_points)
    out.threads = model.threads
    return out


__all__ = ["import_checkpoint", "with_weights", "quantized_meta"]
