"""Weights: the native HDF5 file and the importers of framework checkpoints.

- :mod:`~tpnet_ref.weights.native`: the native file, ``write_native`` / ``read_native`` on plain
  ``(config, params, meta)``, ``describe`` (a readable summary), the shipped models' paths.
- :mod:`~tpnet_ref.weights.hdf5`: the guards every reader uses on untrusted files (no links, no
  external storage, sizes checked before reading, no NaN/Inf, nothing unpickled).
- :mod:`~tpnet_ref.weights.keras`: ``import_keras_h5``, Keras checkpoints of the released code.
- :mod:`~tpnet_ref.weights.torch`: ``import_torch``, state dicts of the PyTorch model (``train``
  extra).
- :func:`import_checkpoint`: any of these, told apart by content (``tpnet import SRC DST``).

Mapping tables and measured differences: ``docs/weights.md``. A :class:`~tpnet_ref.model.TPNet`
is written with ``TPNet.save`` and read with :func:`tpnet_ref.load`.

This package imports only :mod:`~tpnet_ref.config` and NumPy when it is imported:
:mod:`tpnet_ref.model` is built on :mod:`.native`, so the importers (which build a ``TPNet``)
are imported at first use.
"""
from __future__ import annotations

import os
import zipfile
from pathlib import Path
from typing import Any

from . import hdf5
from .native import (FORMAT, FORMAT_VERSION, default_weights_path, describe, is_native,
                     read_native, shipped_weights_path, weights_dir, write_native)


@hdf5.damaged_file_is_value_error
def import_checkpoint(path: str | os.PathLike, dtype: Any = "float32", **kw: Any) -> Any:
    """Any supported checkpoint -> :class:`~tpnet_ref.model.TPNet`: a native file, a Keras
    HDF5 / ``.keras`` file (:func:`~tpnet_ref.weights.keras.import_keras_h5`) or a torch state
    dict (:func:`~tpnet_ref.weights.torch.import_torch`), told apart by content, not by name.
    ``kw``: ``m``, ``layer_norm_eps``, ``lstm_activation`` where the file does not say."""
    # first use: these modules build a TPNet, and tpnet_ref.model imports this package
    from ..model import TPNet
    from .keras import import_keras_h5

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
    from .torch import import_torch

    model = import_torch(p, dtype=dtype, **{k: v for k, v in kw.items() if v is not None})
    model.meta["import_report"] = (f"torch state dict; m={model.config.m}, N={model.config.n_out}, "
                                   f"params={model.num_params:,}; {model.meta['import_note']}")
    return model


def __getattr__(name: str) -> Any:
    """``import_keras_h5`` / ``import_torch`` at first use (see the module docstring)."""
    if name == "import_keras_h5":
        from .keras import import_keras_h5
        return import_keras_h5
    if name == "import_torch":
        from .torch import import_torch
        return import_torch
    raise AttributeError(f"module 'tpnet_ref.weights' has no attribute {name!r}")


__all__ = ["import_checkpoint", "import_keras_h5", "import_torch", "write_native", "read_native",
           "is_native", "describe", "weights_dir", "shipped_weights_path", "default_weights_path",
           "FORMAT", "FORMAT_VERSION"]
