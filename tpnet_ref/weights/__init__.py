"""Weights files: the native file the model reads and writes, the shipped models, and the
importers of framework checkpoints.

Below the model, in the inference core (NumPy and h5py only):

- :mod:`~tpnet_ref.weights.native`: the native HDF5 weights file (``write_native`` /
  ``read_native`` / ``describe``), its storage and its content digest.
- :mod:`~tpnet_ref.weights.hdf5`: the guards every reader uses on untrusted HDF5 and zip files.
- :mod:`~tpnet_ref.weights.provenance`: what a file says of where it came from.
- :mod:`~tpnet_ref.weights.shipped`: the shipped models and where they are looked up (the
  package data that carries them in a wheel).

Above the model (they build a ``TPNet``):

- :mod:`~tpnet_ref.weights.keras`: ``import_keras_h5``, Keras checkpoints of the released code.
- :mod:`~tpnet_ref.weights.torch`: ``import_torch``, state dicts of the PyTorch model (torch is
  imported only when a file is read: the ``train`` extra).
- :mod:`~tpnet_ref.weights.convert`: ``import_checkpoint``, any of these or a native file, told
  apart by content (``tpnet import SRC DST``).

The names below are imported at first use (so the core can import the native file's module
without the importers). Mapping tables and measured differences: ``docs/weights.md``.
"""
from __future__ import annotations

import importlib
from typing import Any

_NAMES = {
    "import_checkpoint": "convert", "import_keras_h5": "keras", "import_torch": "torch",
    **{name: "native" for name in ("write_native", "read_native", "is_native", "describe",
                                   "FORMAT", "FORMAT_VERSION")},
    **{name: "shipped" for name in ("weights_dir", "shipped_weights_path",
                                    "default_weights_path")},
}


def __getattr__(name: str) -> Any:
    if name in _NAMES:
        return getattr(importlib.import_module(f".{_NAMES[name]}", __name__), name)
    raise AttributeError(f"module 'tpnet_ref.weights' has no attribute {name!r}")


__all__ = ["import_checkpoint", "import_keras_h5", "import_torch", "write_native", "read_native",
           "is_native", "describe", "weights_dir", "shipped_weights_path", "default_weights_path",
           "FORMAT", "FORMAT_VERSION"]


def __dir__() -> list[str]:
    return sorted(__all__)
