"""How a training step runs: compiled or not (:data:`COMPILE_MODES`, :func:`resolve_compile`),
in float32 or bfloat16 (:data:`PRECISIONS`, :func:`autocast`, the choice of ``auto`` by
:func:`preferred_precision`), and the step's loss so run (:func:`step_loss`)."""
from __future__ import annotations

import contextlib
from typing import Any

from ..extras import require
from .step import loss_fn

torch = require("torch", "train")


#: how a training step's loss is run: ``off`` (eager), ``reduce-overhead`` (``torch.compile``:
#: Inductor kernels replayed as CUDA graphs on a GPU, the small-kernel launches that bound the
#: H100 step), ``default`` (``torch.compile`` without graphs), ``eager`` (``torch.compile`` with
#: the eager backend: the step is traced by TorchDynamo but runs the eager kernels; what CI uses
#: to prove on the CPU that the step traces), ``auto`` (``reduce-overhead`` on CUDA, else off)
COMPILE_MODES = ("off", "auto", "reduce-overhead", "default", "eager")


def resolve_compile(mode: str, device: str) -> str:
    """The compile mode a run uses on ``device`` (``auto``: ``reduce-overhead`` on CUDA, ``off``
    on the CPU, where compiling the full step costs more than it gains)."""
    if mode not in COMPILE_MODES:
        raise ValueError(f"compile must be one of {COMPILE_MODES}, got {mode!r}")
    if mode == "auto":
        return "reduce-overhead" if device == "cuda" else "off"
    return mode


#: the arithmetic of a training step: ``float32``, or ``bf16`` (mixed precision:
#: ``torch.autocast`` to bfloat16 runs the matrix products, the LSTM gates and the max pool in
#: bfloat16; the parameters, their gradients and Adam's state stay float32, and so do the layers
#: that read or write coordinates and the loss, :func:`tpnet_ref.training.torch_model.full_precision`);
#: ``auto`` chooses per machine (:func:`choose_precision`)
PRECISIONS = ("auto", "float32", "bf16")
#: ``auto`` takes bf16 where its timed step is at least this much faster than float32's
BF16_MIN_GAIN = 1.15


def autocast(precision: str, device: str) -> Any:
    """The context a step's forward pass runs in at ``precision`` (a resolved one)."""
    if precision == "bf16":
        return torch.autocast(device, dtype=torch.bfloat16)
    if precision != "float32":
        raise ValueError(f"precision must be float32 or bf16 here, got {precision!r}")
    return contextlib.nullcontext()


def step_loss(net: Any, mode: str = "off", precision: str = "float32") -> Any:
    """``f(x, y, steps, first_weight, shape_weight, match_weight, grad_steps=0)``: the training
    step's loss (:func:`loss_fn`) at ``precision`` (:func:`autocast`), captured with
    ``torch.compile`` unless ``mode`` is ``off`` (a resolved mode, :func:`resolve_compile`).
    Shapes are static (every step has the recipe's batch), so a run compiles once per rollout
    length (and number of graded steps); the matched term's CPU pairing is a graph break, the
    graphs on either side of it are still captured."""
    dev = next(net.parameters()).device.type
    if mode == "off":
        def eager(x: Any, y: Any, k: int, fw: float, sw: float, mw: float, gs: int = 0) -> Any:
            with autocast(precision, dev):
                return loss_fn(net, x, y, k, fw, sw, mw, gs)
        return eager
    kw: dict[str, Any] = {"backend": "eager"} if mode == "eager" else {"mode": mode}
    compiled = torch.compile(net.recursive_loss, dynamic=False, **kw)

    def f(x: Any, y: Any, k: int, fw: float, sw: float, mw: float, gs: int = 0) -> Any:
        if mode == "reduce-overhead":
            torch.compiler.cudagraph_mark_step_begin()
        with autocast(precision, dev):
            return compiled(x, y[:, :k], first_weight=fw, shape_weight=sw, match_weight=mw,
                            grad_steps=gs)
    return f


def preferred_precision(timings: dict[str, float]) -> str:
    """The precision ``auto`` takes given windows-per-second ``timings`` of both."""
    return "bf16" if timings["bf16"] >= BF16_MIN_GAIN * timings["float32"] else "float32"


__all__ = ["COMPILE_MODES", "resolve_compile", "PRECISIONS", "BF16_MIN_GAIN", "autocast",
           "step_loss", "preferred_precision"]
