"""Importers of framework checkpoints, above the model (they build a ``TPNet``).

- :mod:`~tpnet_ref.weights.keras`: ``import_keras_h5``, Keras checkpoints of the released code.
- :mod:`~tpnet_ref.weights.torch`: ``import_torch``, state dicts of the PyTorch model (torch is
  imported only when a file is read: the ``train`` extra).
- :mod:`~tpnet_ref.weights.convert`: ``import_checkpoint``, any of these or a native file, told
  apart by content (``tpnet import SRC DST``).

The native weights file itself (:mod:`tpnet_ref.native`) and the guards every reader uses on
untrusted files (:mod:`tpnet_ref.hdf5`) sit below the model, in the inference core; their names
are re-exported here. Mapping tables and measured differences: ``docs/weights.md``.
"""
from __future__ import annotations

from ..native import (FORMAT, FORMAT_VERSION, default_weights_path, describe, is_native,
                      read_native, shipped_weights_path, weights_dir, write_native)
from .convert import import_checkpoint
from .keras import import_keras_h5
from .torch import import_torch

__all__ = ["import_checkpoint", "import_keras_h5", "import_torch", "write_native", "read_native",
           "is_native", "describe", "weights_dir", "shipped_weights_path", "default_weights_path",
           "FORMAT", "FORMAT_VERSION"]
