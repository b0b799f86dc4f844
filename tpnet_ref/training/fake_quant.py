"""Quantization-aware fine-tuning: the BiLSTMs' matrices on a scheme's grid in the forward pass.

A run with ``Recipe.quantize_aware`` set (``tpnet train run --quantize-aware int8|bf16``)
computes every forward pass with each BiLSTM matrix (each direction's input kernel and
recurrent matrix: :func:`tpnet_ref.weights.quantize.quantized_names`) rounded to the
scheme's grid, one plane, exactly as :func:`tpnet_ref.weights.quantize.round_to` rounds it
(``tests/test_training_fake_quant.py`` checks it bit for bit); the gradient passes the
rounding unchanged (the straight-through estimator, Bengio et al. 2013), so the optimizer
moves float32 weights whose rounding the loss sees. The run's exported files
(:mod:`~tpnet_ref.training.native_export`) then hold the rounded weights: the network the
run was scored with.
"""
from __future__ import annotations

from typing import Any

from ..extras import require
from ..weights import quantize as Q

torch = require("torch", "train")

#: how an exported file of such a run records its rounding
ROUNDING = "to nearest, one plane, after a quantization-aware fine-tune"


def rounded(w: Any, scheme: str) -> Any:
    """``w`` (a torch weight ``(4u, C)``: a native matrix transposed, so a native column is a
    row here) on ``scheme``'s grid, with no gradient: int8 with one scale per row,
    ``max |row| / 127`` to 17 significand bits, codes rounded half to even and clipped to
    +-127; bf16 rounded half to even."""
    with torch.no_grad():
        if scheme == "bf16":
            return w.to(torch.bfloat16).to(w.dtype)
        w64 = w.double()
        top = w64.abs().amax(dim=1, keepdim=True)
        m, e = torch.frexp(top / 127.0)
        bits = Q.SCALE_BITS
        s = torch.ldexp(torch.round(m * 2.0 ** bits), e - bits)
        s32 = torch.where(top < Q.TINY, torch.ones_like(s), s).float()   # int8_scales' float32
        q = torch.clamp(torch.round(w64 / s32.double()), -127, 127)
        return (q.float() * s32).to(w.dtype)


def straight_through(w: Any, scheme: str) -> Any:
    """``w`` rounded to ``scheme``'s grid in value, ``w`` itself in gradient."""
    if not scheme:
        return w
    return w + (rounded(w, scheme) - w).detach()


__all__ = ["ROUNDING", "rounded", "straight_through"]
