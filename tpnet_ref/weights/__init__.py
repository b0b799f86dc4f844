"""Weights: the native HDF5 file and the importers of framework checkpoints.

- :mod:`~tpnet_ref.weights.native`: the native file, ``write_native`` / ``read_native`` on plain
  ``(config, params, meta)``, ``describe`` (a readable summary), the shipped models' paths.
- :mod:`~tpnet_ref.weights.hdf5`: the guards every reader uses on untrusted files (no links, no
  external storage, sizes checked before reading, no NaN/Inf, nothing unpickled).
- :mod:`~tpnet_ref.weights.keras`: ``import_keras_h5``, Keras checkpoints of the released code.
- :mod:`~tpnet_ref.weights.torch`: ``import_torch``, state dicts of the PyTorch model (``train``
  extra).
- :mod:`~tpnet_ref.weights.convert`: ``import_checkpoint``, any of these, told apart by content
  (``tpnet import SRC DST``).

Mapping tables and measured differences: ``docs/weights.md``. A :class:`~tpnet_ref.model.TPNet`
is written with ``TPNet.save`` and read with :func:`tpnet_ref.load`.

This package imports only :mod:`.native` (NumPy, and h5py at first use) when it is imported:
:mod:`tpnet_ref.model` is built on :mod:`.native`, and the importers, which build a ``TPNet``,
are submodules reached on first use of their names.
"""
from __future__ import annotations

import importlib
from typing import Any

from .native import (FORMAT, FORMAT_VERSION, default_weights_path, describe, is_native,
                     read_native, shipped_weights_path, weights_dir, write_native)


#: the importers build a TPNet, and tpnet_ref.model is built on .native, so they are this
#: package's submodules reached on first use rather than imported with it
_IMPORTERS = {"import_checkpoint": "convert", "import_keras_h5": "keras", "import_torch": "torch"}


def __getattr__(name: str) -> Any:
    """``import_checkpoint`` / ``import_keras_h5`` / ``import_torch`` from their modules."""
    if name in _IMPORTERS:
        return getattr(importlib.import_module(f".{_IMPORTERS[name]}", __name__), name)
    raise AttributeError(f"module 'tpnet_ref.weights' has no attribute {name!r}")


__all__ = ["import_checkpoint", "import_keras_h5", "import_torch", "write_native", "read_native",
           "is_native", "describe", "weights_dir", "shipped_weights_path", "default_weights_path",
           "FORMAT", "FORMAT_VERSION"]
