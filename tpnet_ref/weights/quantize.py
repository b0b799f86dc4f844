"""Weights of fewer bits: bf16 and int8 versions of the BiLSTMs' matrices (NumPy only).

A quantized model is an ordinary float network whose BiLSTM matrices (each direction's input
kernel and recurrent matrix, :func:`quantized_names`: 96 % of the paper size's parameters and
of the bytes a prediction reads) lie on a coarser grid:

- ``bf16``: each weight rounded to bfloat16 (8 significand bits, round half to even), stored
  as its 16 high bits. The matrices a prediction is most sensitive to in bf16
  (:func:`wide_names`: the first BiLSTM's input kernels and both of the last one's matrices;
  31 % of the BiLSTM weights at the paper size) get a second bf16 plane:
  ``w = hi + lo / 256`` with ``hi = bf16(w)`` and ``lo = bf16((w - hi) * 256)`` (about 16
  significand bits; exact in float32: ``lo / 256`` is at most half an ulp of ``hi`` and its
  last bit within 17 bits of ``hi``'s first; weights below :data:`TINY` keep a zero ``lo``),
  codes ``(2C, N)``, the high plane's rows first; the kernels widen each pair to that float32
  weight in registers (one exact fused multiply-add), so bf16's kernels stay the float32
  kernels on the dequantized weights. Measured on the full size (256 windows of the scene):
  every matrix in one plane moves a prediction by up to 0.0125 world units, these six in two
  planes by 0.0044 (docs/deployment.md);
- ``int8``: symmetric, one float32 scale per output column (each gate pre-activation of each
  unit): ``w = q * s`` with ``q`` an integer in ``-127 .. 127`` and
  ``s = max |column| / 127`` rounded to 17 significand bits, so that ``q * s`` is exact in
  float32 and re-deriving ``(q, s)`` from the dequantized weights gives them back exactly
  (:func:`codes_of`); a column whose largest weight is below :data:`TINY` becomes zeros
  (scale 1). The matrices a prediction is most sensitive to (:func:`wide_names`: the first
  BiLSTM's input kernels, the last one's recurrent matrices; 15 % of the int8 bytes at the paper
  size) get a second int8 plane: ``w = s * (q_hi + q_lo / 256)`` (16 bits, ``s`` of 9
  significand bits, the column's largest weight stored as ``127 s``), codes ``(2C, N)``, the
  high plane's rows first; the kernels multiply the low plane by the input times 2^-8.
  Measured on the scene's windows: every matrix in one plane moves a prediction by up to
  0.1 world units, these four in two planes by 0.04 (docs/deployment.md).

Everything else stays float32: the per-point MLP and the global layer (0.9 MB at the paper
size; each weight is reused by every point of every frame, so these products are bound by
arithmetic, not by reading weights), the output layer (its rounding lands on the prediction
unaveraged), the biases, LayerNorm's scale and shift, and every activation and sum.

The model keeps the dequantized float weights in ``model.params`` (so the NumPy engine, the
float64 reference and the specialised head run exactly the quantized network) and the scheme
in ``model.meta["quantization"]``; the Numba engine reads the codes (:func:`codes_of`), about
two thirds (bf16, at the paper size) or a quarter (int8) of the bytes. A native file stores the
codes and scales themselves (:mod:`tpnet_ref.weights.native`): ``/params/<name>`` as int8 or
uint16 (bf16 bits; the wide names' two planes ``(2C, N)``) for the quantized names,
``/scales/<name>`` the int8 scales, the root attributes
:data:`ATTR` (the scheme) and :data:`FROM_ATTR` (the source file and its digest).
"""
from __future__ import annotations

from typing import Any

import numpy as np

#: the schemes, by name
SCHEMES = ("bf16", "int8")
#: root attribute (and ``model.meta`` key) naming a file's scheme
ATTR = "quantization"
#: root attribute naming the file a quantized file was made from (path and digest)
FROM_ATTR = "quantized_from"
#: root attribute (and ``model.meta`` key) saying how the codes were rounded where not to nearest
#: with :func:`wide_names` (calibrated: :mod:`tpnet_ref.weights.calibrate`; a quantization-aware
#: fine-tune: :mod:`tpnet_ref.training.fake_quant`)
ROUNDING_ATTR = "quantized_rounding"
#: root attribute (and ``model.meta`` key) listing the matrices in two planes, comma-separated
#: ("" none: calibrated int8, :mod:`tpnet_ref.weights.calibrate`); absent: :func:`wide_names`
WIDE_ATTR = "quantized_wide"
#: the group holding the int8 scales, one dataset per quantized tensor
SCALES = "scales"
#: columns whose largest weight is below this become zeros (scale 1)
TINY = 1e-30
#: significand bits of an int8 scale (so that ``q * s`` is exact in float32)
SCALE_BITS = 17


def quantized_names(config: Any) -> list[str]:
    """The parameters a scheme quantizes: every BiLSTM's input kernel and recurrent matrix."""
    return [f"lstm{i}.{d}.{t}" for i in range(1, len(config.lstm_units) + 1)
            for d in ("fwd", "bwd") for t in ("kernel", "recurrent")]


def wide_names(config: Any, scheme: str = "int8") -> list[str]:
    """The matrices ``scheme`` stores in two planes (see the module): BiLSTM 1's input kernels
    and the last BiLSTM's recurrent matrices, and for bf16 also the last BiLSTM's input kernels
    (chosen on 256 windows of the training grid's validation trajectories, `python
    bench/probes/bench_quantized.py --wide-choice data/grid-m4.h5 --sizes full`: with int8's
    four, the largest move 0.0117; with these six, 0.0051)."""
    last = len(config.lstm_units)
    kinds = ("kernel", "recurrent") if check_scheme(scheme) == "bf16" else ("recurrent",)
    return list(dict.fromkeys([f"lstm1.{d}.kernel" for d in ("fwd", "bwd")] + [
        f"lstm{last}.{d}.{t}" for t in kinds for d in ("fwd", "bwd")]))


def wide_of(config: Any, meta: dict[str, Any], where: str = "meta") -> list[str]:
    """The matrices a quantized model (``meta``: its scheme, and :data:`WIDE_ATTR` if recorded)
    holds in two planes: the recorded list, else the scheme's :func:`wide_names`; a one-line
    ``ValueError`` for a list naming anything but a quantized matrix."""
    scheme = check_scheme(meta.get(ATTR), where)
    got = meta.get(WIDE_ATTR)
    if got is None:
        return wide_names(config, scheme)
    names = [n for n in str(got).split(",") if n] if isinstance(got, str) else None
    known = set(quantized_names(config))
    if names is None or not set(names) <= known or len(set(names)) != len(names):
        raise ValueError(f"{where}: corrupted {WIDE_ATTR} {got!r} (comma-separated names of "
                         f"quantized matrices expected)")
    return names


def check_scheme(scheme: Any, where: str = "weights") -> str:
    """``scheme`` if it is one of :data:`SCHEMES`, else a one-line ``ValueError``."""
    if scheme not in SCHEMES:
        raise ValueError(f"{where}: unknown quantization scheme {scheme!r} "
                         f"(known: {', '.join(SCHEMES)})")
    return str(scheme)


def int8_scales(w: np.ndarray, bits: int = SCALE_BITS) -> np.ndarray:
    """The int8 scale of each column of ``w (C, N)``: ``max |column| / 127`` rounded to
    ``bits`` significand bits (1 for a column below :data:`TINY`), float32."""
    top = np.max(np.abs(np.asarray(w, dtype=np.float64)), axis=0)
    m, e = np.frexp(top / 127.0)
    s = np.ldexp(np.round(m * 2.0 ** bits), e - bits)
    return np.where(top < TINY, 1.0, s).astype(np.float32)


def _wide(w64: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two int8 planes ``(2C, N)`` and 9-bit scales of ``w (C, N)`` (see the module)."""
    s = int8_scales(w64, 9)
    top = np.max(np.abs(w64), axis=0)
    q16 = np.clip(np.rint(w64 / s * 256.0), -32512, 32512)
    q16 = np.where((np.abs(w64) == top) & (top >= TINY), np.sign(w64) * 32512, q16)
    hi = np.rint(q16 / 256.0)
    lo = q16 - 256.0 * hi
    hi, lo = np.where(lo > 127, hi + 1, hi), np.where(lo > 127, lo - 256, lo)
    return np.concatenate([hi, lo]).astype(np.int8), s


def _bf16_bits(w32: np.ndarray) -> np.ndarray:
    """The bf16 bits (uint16) of float32 ``w32``, rounded half to even."""
    bits = w32.view(np.uint32).astype(np.uint64)
    return ((bits + 0x7FFF + ((bits >> 16) & 1)) >> 16).astype(np.uint16)


def _bf16_wide(w32: np.ndarray) -> np.ndarray:
    """Two bf16 planes ``(2C, N)`` of float32 ``w (C, N)``: ``hi = bf16(w)``,
    ``lo = bf16((w - hi) * 256)`` (``w - hi`` and the product exact in float32); where
    ``|w| <`` :data:`TINY` a zero of ``hi``'s sign (``lo / 256`` never leaves float32's
    normal range, and -0 stays -0)."""
    hi = _bf16_bits(w32)
    rest = (w32 - decode(hi, None, "bf16")) * np.float32(256)
    lo = np.where(np.abs(w32) < TINY, hi & np.uint16(0x8000), _bf16_bits(rest))
    return np.concatenate([hi, lo.astype(np.uint16)])


def encode(w: np.ndarray, scheme: str, wide: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """``w``'s codes under ``scheme``: int8 ``q`` (``wide``: two planes) and the scales
    (:func:`int8_scales`), or the bf16 bits (uint16, rounded half to even; ``wide``: two
    planes) and None."""
    w32 = np.asarray(w, dtype=np.float32)
    if check_scheme(scheme) == "bf16":
        return (_bf16_wide(w32) if wide else _bf16_bits(w32)), None
    if wide:
        return _wide(w32.astype(np.float64))
    s = int8_scales(w32)
    q = np.clip(np.rint(w32.astype(np.float64) / s), -127, 127)
    return q.astype(np.int8), s


def decode(codes: np.ndarray, scales: np.ndarray | None, scheme: str) -> np.ndarray:
    """The float32 weights of ``codes`` (and ``scales``, int8; two planes when the codes have
    twice the rows the scales' caller expects: :func:`decode_wide`) -- exact."""
    if check_scheme(scheme) == "bf16":
        return (np.asarray(codes, dtype=np.uint32) << 16).view(np.float32)
    return np.asarray(codes, dtype=np.float32) * np.asarray(scales, dtype=np.float32)


def decode_wide(codes: np.ndarray, scales: np.ndarray | None, scheme: str = "int8") -> np.ndarray:
    """The float32 weights ``(C, N)`` of two planes ``(2C, N)``: int8 (15-bit codes times 9-bit
    scales: exact) or bf16 (``hi + lo / 256``, summed in float64 and rounded to float32: exact
    for the codes :func:`encode` makes, which :func:`check_codes` requires of a file)."""
    c = codes.shape[0] // 2
    if check_scheme(scheme) == "bf16":
        hi, lo = (decode(p, None, "bf16").astype(np.float64) for p in (codes[:c], codes[c:]))
        return (hi + lo * 2.0 ** -8).astype(np.float32)
    q16 = codes[:c].astype(np.int32) * 256 + codes[c:].astype(np.int32)
    return q16.astype(np.float32) * np.asarray(scales, dtype=np.float32) * np.float32(1 / 256)


def round_to(w: np.ndarray, scheme: str, wide: bool = False) -> np.ndarray:
    """``w`` on ``scheme``'s grid (float32): what the quantized model computes with."""
    codes, scales = encode(w, scheme, wide)
    return decode_wide(codes, scales, scheme) if wide else decode(codes, scales, scheme)


def codes_of(w: np.ndarray, scheme: str, what: str = "weights",
             wide: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """The codes (and int8 scales) of weights ``w`` already on ``scheme``'s grid (a quantized
    model's dequantized weights), re-derived exactly; a one-line ``ValueError`` naming ``what``
    when ``w`` is not on that grid."""
    codes, scales = encode(w, scheme, wide)
    back = decode_wide(codes, scales, scheme) if wide else decode(codes, scales, scheme)
    if not np.array_equal(back, np.asarray(w, dtype=np.float64)):
        raise ValueError(f"{what}: not on the {scheme} grid (quantize the float32 weights "
                         "first: tpnet_ref.load(..., weights=...) or `tpnet quantize`)")
    return codes, scales


def check_codes(codes: np.ndarray, scales: np.ndarray | None, scheme: str, shape: tuple[int, ...],
                what: str, wide: bool = False) -> np.ndarray:
    """The float32 weights ``shape`` of codes read from a file (``wide``: two planes, twice the
    rows), after checking their dtype, shape and (int8) scales: finite, positive, on the 17-bit
    grid and of one column each; (bf16's two planes) the low plane the high one's remainder,
    as :func:`encode` makes it; a one-line ``ValueError`` naming ``what`` otherwise."""
    want = np.int8 if scheme == "int8" else np.uint16
    if wide:
        shape = (2 * shape[0],) + tuple(shape[1:])
    if codes.dtype != want or tuple(codes.shape) != tuple(shape):
        raise ValueError(f"{what}: {scheme} codes must be {np.dtype(want).name} of shape "
                         f"{tuple(shape)}, got {codes.dtype} {tuple(codes.shape)}")
    if scheme == "int8":
        s = np.asarray(scales)
        if s.shape != (shape[-1],) or s.dtype.kind != "f":
            raise ValueError(f"{what}: its scales must be {shape[-1]} floats, got {s.dtype} "
                             f"{s.shape}")
        s64 = s.astype(np.float64)
        m, _ = np.frexp(np.where(np.isfinite(s64), s64, 0.0))
        if (not np.isfinite(s64).all() or (s64 <= 0).any()
                or (codes[:shape[0] // 2 if wide else shape[0]] == -128).any()
                or not np.array_equal(m * 2.0 ** SCALE_BITS, np.round(m * 2.0 ** SCALE_BITS))):
            raise ValueError(f"{what}: corrupted int8 scales or codes (each scale must be a "
                             "finite positive float of 17 significand bits, each code in "
                             "-127 .. 127)")
    w = decode_wide(codes, scales, scheme) if wide else decode(codes, scales, scheme)
    if not np.isfinite(w).all():
        raise ValueError(f"{what}: {scheme} codes decode to NaN or infinite values")
    if wide and scheme == "bf16" and not np.array_equal(_bf16_wide(w), codes):
        raise ValueError(f"{what}: corrupted bf16 codes (each low-plane code must be "
                         "bf16((w - hi) * 256) of its high-plane code hi = bf16(w))")
    return w


__all__ = ["SCHEMES", "ATTR", "FROM_ATTR", "ROUNDING_ATTR", "WIDE_ATTR", "SCALES", "TINY",
           "SCALE_BITS", "quantized_names", "wide_names", "wide_of",
           "check_scheme", "int8_scales", "encode", "decode", "decode_wide", "round_to", "codes_of",
           "check_codes"]
