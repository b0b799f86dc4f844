"""A training checkpoint exported to the native weights file, checked against the torch module
and carrying its provenance."""
from __future__ import annotations

import json
import os
import warnings
from typing import Any

import numpy as np

from ..checks import OutsideTrainingRangeWarning
from ..extras import require
from ..weights import quantize as Q
from ..weights.convert import with_weights
from ..weights.provenance import portable_path, scrub_text
from ..weights.torch import import_torch
from .checkpoint import load_checkpoint
from .fake_quant import ROUNDING
from .torch_model import TorchTPNet

torch = require("torch", "train")


def export(source: str | os.PathLike, out: str | os.PathLike, dtype: str = "float32",
           check_bound: float = 1e-5) -> Any:
    """Native weights file from a training checkpoint (run directory or ``checkpoint.pt``),
    through :func:`tpnet_ref.weights.torch.import_torch`, with provenance; a quantization-aware
    run's (:mod:`~tpnet_ref.training.fake_quant`) with its BiLSTM matrices rounded, one plane,
    as the run computed them. Checks before writing that
    the NumPy model's forward pass equals the torch module's (max abs difference <= check_bound
    on random windows, whose training-range warnings it silences: they are no body) and records
    the difference."""
    payload, state = load_checkpoint(source)
    model = import_torch(payload["model"], dtype=dtype)
    net = TorchTPNet(model.config)
    net.load_state_dict(payload["model"])
    net.eval()
    scheme = state.get("recipe", {}).get("quantize_aware", "")
    if scheme:                     # the network the run computed: its matrices rounded
        net.set_fake_quant(scheme)
        model = with_weights(model, scheme, wide=[])
        model.meta[Q.ROUNDING_ATTR] = ROUNDING
        model.meta[Q.FROM_ATTR] = portable_path(source)
    cfg = model.config
    w = np.random.default_rng(0).uniform(0.1, 0.9, (8, cfg.m, cfg.n_out, cfg.dim)).astype(np.float32)
    with torch.no_grad():
        yt = net(torch.from_numpy(w)).numpy()
    with warnings.catch_warnings():     # random points in the box: no body, by design
        warnings.simplefilter("ignore", OutsideTrainingRangeWarning)
        diff = float(np.abs(model.predict_batch(w, normalized=True) - yt).max())
    if not diff <= check_bound:
        raise ValueError(f"export check failed: NumPy vs torch max abs diff {diff:.3g} > "
                         f"{check_bound:g}")
    spe = state.get("steps_per_epoch", 0) or 1
    inh = state.get("inherited", {"runs": [], "windows_seen": 0, "wall_s": 0.0, "steps": 0,
                                  "epochs": 0.0})
    # every file named as the repository names it (or by file name), never by this machine's
    # absolute path (tpnet_ref.weights.provenance); the data also by its SHA-256
    prov = {"source": portable_path(source), "producer": "tpnet_ref.training",
            "recipe": scrub_text(json.dumps(state.get("recipe", {}), sort_keys=True)),
            "training_steps": int(state.get("step", 0)) + int(inh["steps"]),
            "epochs": float(state.get("step", 0)) / spe + float(inh["epochs"]),
            "windows_seen": int(state.get("windows_seen", 0)) + int(inh["windows_seen"]),
            "wall_time_s": float(state.get("wall_s", 0.0)) + float(inh["wall_s"]),
            "parent_runs": scrub_text(json.dumps(inh["runs"], sort_keys=True)),
            "hardware": str(state.get("hardware", "unknown")),
            "torch": str(state.get("torch", torch.__version__)),
            "data": portable_path(str(state.get("data", ""))),
            "data_sha256": str(state.get("data_sha256", "")),
            "val": json.dumps(state.get("last_val", {}), sort_keys=True),
            "precision": json.dumps(state.get("precision", []), sort_keys=True),
            "export_max_abs_diff": diff}
    model.save(str(out), **prov)
    return model


__all__ = ["export"]
