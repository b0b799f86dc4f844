"""Any supported checkpoint -> :class:`~tpnet_ref.model.TPNet`, told apart by content: a native
file, a Keras HDF5 / ``.keras`` file or a torch state dict (``tpnet import SRC DST``)."""
from __future__ import annotations

import os
import zipfile
from pathlib import Path
from typing import Any

from ..model import TPNet
from . import hdf5
from .keras import import_keras_h5
from .native import is_native, read_native
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


__all__ = ["import_checkpoint"]
