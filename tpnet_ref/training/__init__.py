"""Training TP-Net in PyTorch (optional ``train`` extra) and export to the native weights file.

- :mod:`~tpnet_ref.training.recipe`: :class:`Recipe` (what a run computes), the network sizes,
  :class:`WindowData` (the windows of a ``tpnet data generate`` file, split by trajectory).
- :mod:`~tpnet_ref.training.torch_model`: :class:`TorchTPNet` (the network in PyTorch, Keras
  semantics) and the Chamfer losses.
- :mod:`~tpnet_ref.training.loop`: :func:`train` (resumable, budgeted) and its validation;
  :mod:`~tpnet_ref.training.step`: a step's device, optimizer, loss and input noise;
  :mod:`~tpnet_ref.training.precision`: the step compiled or not, in float32 or bfloat16;
  :mod:`~tpnet_ref.training.throughput`: :func:`bench`, and ``auto``'s choice of precision;
  :mod:`~tpnet_ref.training.native_export`: :func:`export` to the native weights file.
- :mod:`~tpnet_ref.training.checkpoint`: checkpoints in one file or in parts, fine-tuning
  provenance.
- :mod:`~tpnet_ref.training.score`: baselines and model selection on validation trajectories.
- :mod:`~tpnet_ref.training.average`: the weighted mean of fine-tunes of one network
  (``tpnet train average``); :mod:`~tpnet_ref.training.lineage`: the provenance a run or an
  average carries of its parents (both NumPy only).

The command line is ``tpnet train run|export|average|bench|score|baselines`` (:mod:`tpnet_ref.cli.train`);
the recipe is in ``docs/training.md``, the runs in ``docs/history.md``. Importing this package needs nothing but
NumPy: the names below are imported at first use, and those that need torch say so in one line
when it is missing.
"""
from __future__ import annotations

import importlib
from typing import Any

_NAMES = {
    "Recipe": "recipe", "WindowData": "recipe", "SIZES": "recipe", "size_config": "recipe",
    "N_STEPS_MAX": "recipe", "N_ROLLOUT_MAX": "recipe",
    "TorchTPNet": "torch_model", "chamfer_released": "torch_model",
    "chamfer_shape": "torch_model", "matched_distance": "torch_model",
    "train": "loop", "export": "native_export", "bench": "throughput", "evaluate": "loop",
    "save_checkpoint": "checkpoint", "load_checkpoint": "checkpoint", "load_parent": "checkpoint",
    "load_parent_optimizer": "checkpoint",
    "baselines": "score", "best_snapshot": "score", "score_rollouts": "score",
    "spacing_report": "score",
}


def __getattr__(name: str) -> Any:
    if name in _NAMES:
        mod = _NAMES[name]
        return getattr(importlib.import_module(mod if mod.startswith(".") else f".{mod}",
                                               __name__), name)
    raise AttributeError(f"module 'tpnet_ref.training' has no attribute {name!r}")


__all__ = sorted(_NAMES)
