"""The layers a conformance trace names, in forward order: their names, shapes and meanings
(the names :func:`tpnet_ref.engines.reference.forward` records with ``trace=``; docs/crosscheck.md
lists them)."""
from __future__ import annotations

from typing import Any

from ..config import TPNetConfig


def layer_names(config: TPNetConfig) -> list[str]:
    """The names :func:`tpnet_ref.engines.reference.forward` records, in forward order."""
    names = ["input", "input.normalized"]
    if config.input_transform_trained:
        names += ["input_tnet.transform", "input.transformed"]
    names += [f"mlp1.{i}" for i in range(len(config.mlp1))]
    if config.feature_transform_trained:
        names += ["feature_tnet.transform", "mlp1.transformed"]
    names += [f"mlp2.{i}" for i in range(len(config.mlp2))] + ["pooled", "global"]
    for i in range(1, len(config.lstm_units) + 1):
        names += [f"lstm{i}.fwd", f"lstm{i}.bwd", f"lstm{i}.concat", f"ln{i}"]
    return names + ["head.logits", "head.sigmoid", "output"]


def layer_shapes(config: TPNetConfig) -> dict[str, list[Any]]:
    """Each layer's shape with ``P`` (the window's points, frame after frame) and ``m``."""
    c = config
    out: dict[str, list[Any]] = {"input": ["P", c.dim], "input.normalized": ["P", c.dim],
                                 "input_tnet.transform": ["m", c.dim, c.dim],
                                 "input.transformed": ["P", c.dim],
                                 "feature_tnet.transform": ["m", c.mlp1[-1], c.mlp1[-1]],
                                 "mlp1.transformed": ["P", c.mlp1[-1]],
                                 "pooled": ["m", c.mlp2[-1]], "global": ["m", c.global_features],
                                 "head.logits": [c.n_out * c.dim],
                                 "head.sigmoid": [c.n_out, c.dim], "output": [c.n_out, c.dim]}
    for stack in ("mlp1", "mlp2"):
        for i, w in enumerate(getattr(c, stack)):
            out[f"{stack}.{i}"] = ["P", w]
    last = len(c.lstm_units)
    for i, u in enumerate(c.lstm_units, start=1):
        out[f"lstm{i}.fwd"] = out[f"lstm{i}.bwd"] = ["m", u]
        out[f"lstm{i}.concat"] = out[f"ln{i}"] = ["m", 2 * u] if i < last else [2 * u]
    return {k: out[k] for k in layer_names(c)}


#: what each layer is, for the manifest and docs/crosscheck.md
MEANINGS = {
    "input": "the window as given, world units",
    "input.normalized": "(x - norm_lo) / (norm_hi - norm_lo), model coordinates",
    "input_tnet.transform": "the input transform net's K x K matrix per frame",
    "input.transformed": "the points times their frame's input transform",
    "feature_tnet.transform": "the feature transform net's 64 x 64 matrix per frame",
    "mlp1.transformed": "MLP 1's output times its frame's feature transform",
    "mlp1": "per-point MLP 1, layer i, after its ReLU",
    "mlp2": "per-point MLP 2, layer i, after its ReLU",
    "pooled": "max over each frame's points of the last MLP 2 layer",
    "global": "FC + ReLU: each frame's global feature G_t",
    "fwd": "BiLSTM i, forward direction: row t its output after consuming steps 0..t",
    "bwd": "BiLSTM i, backward direction: row t its output after consuming steps m-1..t",
    "concat": "BiLSTM i's output: [forward, backward] per step (the last BiLSTM: forward after "
              "step m-1, backward after step 0)",
    "ln": "LayerNorm after BiLSTM i",
    "head.logits": "the head's FC output before its sigmoid",
    "head.sigmoid": "after the sigmoid, reshaped (n_out, dim): model coordinates",
    "output": "the prediction in world units",
}


def meaning(name: str) -> str:
    if name in MEANINGS:
        return MEANINGS[name]
    stem, _, last = name.rpartition(".")
    if stem in ("mlp1", "mlp2"):
        return MEANINGS[stem].replace("layer i", f"layer {last}")
    if name.startswith("ln"):
        return MEANINGS["ln"].replace("BiLSTM i", f"BiLSTM {name[2:]}")
    return MEANINGS[last].replace("BiLSTM i", f"BiLSTM {stem[4:]}")


__all__ = ["layer_names", "layer_shapes", "MEANINGS", "meaning"]
