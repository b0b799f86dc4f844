"""A training step's pieces: the device, the optimizer, the recursive loss, the input noise."""
from __future__ import annotations

import math
import os
import platform
from typing import Any

from ..extras import require
from .recipe import Recipe

torch = require("torch", "train")


def resolve_device(device: str) -> str:
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device not in ("cpu", "cuda"):
        raise ValueError(f"device must be auto, cpu or cuda, got {device!r}")
    if device == "cuda" and not torch.cuda.is_available():
        raise ValueError("device cuda asked for but torch.cuda.is_available() is False")
    return device


def hardware(device: str) -> str:
    if device == "cuda":
        return f"cuda:{torch.cuda.get_device_name(0)}"
    return (f"cpu:{platform.processor() or platform.machine()} "
            f"({os.cpu_count()} cores, {torch.get_num_threads()} torch threads)")


def make_optimizer(net: Any, r: Recipe) -> Any:
    return torch.optim.Adam(net.parameters(), lr=r.lr, betas=(r.beta1, r.beta2), eps=r.eps)


def loss_fn(net: Any, x: Any, y: Any, steps: int, first_weight: float,
            shape_weight: float = 0.0, match_weight: float = 0.0, grad_steps: int = 0) -> Any:
    """The recursive loss over the first ``steps`` targets (``steps=1``: 1-step teacher forced),
    plus ``shape_weight`` times the same sum of shape Chamfer distances (centred sets) and
    ``match_weight`` times the same sum of matched (earth mover's) distances; with
    ``grad_steps`` G in 1..steps-1 over the last G predictions alone, the others made without
    gradient (the pushforward trick, :meth:`~tpnet_ref.training.torch_model.TorchTPNet.recursive_loss`)."""
    return net.recursive_loss(x, y[:, :steps], first_weight=first_weight,
                              shape_weight=shape_weight, match_weight=match_weight,
                              grad_steps=grad_steps)


def input_noise(x: Any, std: float, kind: str, seed: int, step: int) -> Any:
    """``x`` (``(B, m, N, dim)`` input windows) plus Gaussian noise drawn from a generator
    seeded with ``(seed, step)``; ``std`` 0: ``x`` itself. ``iid``: std ``std`` on every
    coordinate of every frame, independently. ``walk`` (the random walk of Sanchez-Gonzalez et
    al. 2020): per point and coordinate, increments of std ``std / √m`` summed over the frames,
    so frame i (from 0) has std ``std·√((i+1)/m)``, the last one ``std``, and a velocity
    between two frames is off by one increment."""
    if std == 0:
        return x
    g = torch.Generator().manual_seed(seed * 1_000_003 + step)
    eps = torch.randn(x.shape, generator=g, dtype=x.dtype)
    if kind == "walk":
        eps = eps.cumsum(dim=1) / math.sqrt(x.shape[1])
    elif kind != "iid":
        raise ValueError(f"noise kind must be 'iid' or 'walk', got {kind!r}")
    return x + std * eps


__all__ = ["resolve_device", "hardware", "make_optimizer", "loss_fn", "input_noise"]
