"""Calibrated int8 and bf16: each BiLSTM matrix rounded to the scheme's grid with the rounding
errors fed forward (NumPy only).

Round-to-nearest int8 (:mod:`tpnet_ref.weights.quantize`) rounds each weight on its own; a
layer's output error is then ``x @ (W - Q)``, whatever the inputs ``x`` the layer sees. Rounding
the rows of ``W`` (its inputs) one after another, and moving each row's rounding error onto the
rows not yet rounded in proportion to how the inputs co-vary (``H = X^T X`` over calibration
inputs), minimises that error on inputs like those (GPTQ: Frantar, Ashkboos, Hoefler and
Alistarh, "GPTQ: Accurate Post-Training Quantization for Generative Pre-trained Transformers",
ICLR 2023; their Algorithm 1 without blocks). Here:

- the calibration inputs are windows of a dataset's training split (``tpnet data generate``;
  never the test cases): BiLSTM 1's input kernels see the frames' global features, the later
  input kernels the LayerNorm outputs before them, each recurrent matrix its direction's
  previous states, from a float64 forward pass of the float model (:func:`layer_inputs`);
- int8: its grid (one scale per output column, ``max |column| / 127`` of the float weights, 17
  significand bits), each column's largest weight keeping its code +-127 (no error is moved
  onto it), so that the scale re-derives from the rounded weights as for any int8 model
  (:func:`tpnet_ref.weights.quantize.codes_of`); bf16: each weight rounded to bfloat16. The
  Numba engine, the file and every check read a calibrated model as they read any other of
  its scheme;
- every matrix in one plane (:data:`tpnet_ref.weights.quantize.WIDE_ATTR` empty): measured on
  the full size, the largest move of a prediction from float32 on 256 scene windows (NumPy
  engine) int8 0.026-0.033 world units, against round-to-nearest's 0.099 in one plane and 0.043
  with four matrices in two; bf16 0.0061, against 0.0125 in one plane and 0.0044 with six in
  two (``python bench/probes/bench_quantized.py --calibrate DATA``).

The rounding's arithmetic is float64 NumPy and LAPACK; a file written by ``tpnet quantize
--calibrate`` holds the codes, so loading it gives the same bits everywhere.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from . import quantize as Q

#: calibration windows drawn from the training split (their count is the file's record)
WINDOWS = 256
#: the damping added to ``H``'s diagonal, a fraction of its mean (GPTQ's ``percdamp``)
DAMP = 0.03
#: root attribute (and ``model.meta`` key) saying how the codes were rounded (defined beside
#: the other quantization attributes: :data:`tpnet_ref.weights.quantize.ROUNDING_ATTR`)
ROUNDING_ATTR = Q.ROUNDING_ATTR


def training_windows(path: str, m: int, dim: int, n: int = WINDOWS,
                     seed: int = 0) -> np.ndarray:
    """``n`` windows ``(n, m, N, dim)`` in model coordinates from the training split of a
    dataset file (``/train/normalized`` at ``/train/windows``' starts), drawn without
    replacement with ``seed``; a one-line ``ValueError`` for a file without them, of another
    dimension, or with fewer windows."""
    from pathlib import Path

    from .hdf5 import open_h5

    if not Path(path).is_file():
        raise FileNotFoundError(f"dataset file not found: {path}")
    with open_h5(path) as f:
        if "train/normalized" not in f or "train/windows" not in f:
            raise ValueError(f"{path}: no training windows (/train/normalized, /train/windows): "
                             "give a dataset file of `tpnet data generate`")
        norm = f["train/normalized"]
        have = int(f.attrs["dim"]) if "dim" in f.attrs else 2
        if have != dim or norm.shape[-1] != dim:
            raise ValueError(f"{path}: a {have}-D dataset, the model is {dim}-D")
        win = f["train/windows"][...]
        if len(win) < n:
            raise ValueError(f"{path}: {len(win)} training windows, {n} asked")
        pick = np.sort(np.random.default_rng(seed).choice(len(win), n, replace=False))
        out = np.stack([norm[int(t), int(s):int(s) + m] for t, s in win[pick, :2]])
    if out.shape[1] != m:
        raise ValueError(f"{path}: its windows do not hold {m} frames")
    return out.astype(np.float64)


def layer_inputs(model: Any, windows: np.ndarray) -> dict[str, np.ndarray]:
    """``H = X^T X`` (float64) of the inputs each quantized matrix multiplies, over ``windows``
    ``(B, m, N, dim)`` in model coordinates, from a float64 forward pass of ``model``'s float
    weights (its NumPy feature extractor, then each BiLSTM's directions as
    :func:`tpnet_ref.engines.layers.lstm` computes them)."""
    from ..engines import layers as L

    net = model.astype("float64").with_engine("numpy")
    c, p = net.config, net.params
    seq = net.window_features(windows, normalized=True)            # (B, m, k)
    out: dict[str, np.ndarray] = {}
    last = len(c.lstm_units)
    for i in range(1, last + 1):
        x = seq.reshape(-1, seq.shape[-1])
        states = []
        for d, rev in (("fwd", False), ("bwd", True)):
            h = L.lstm(seq, p[f"lstm{i}.{d}.kernel"], p[f"lstm{i}.{d}.recurrent"],
                       p[f"lstm{i}.{d}.bias"], activation=c.lstm_activation, reverse=rev)
            prev = h[:, 1:] if rev else h[:, :-1]                  # the state before each step
            prev = prev.reshape(-1, h.shape[-1])
            out[f"lstm{i}.{d}.kernel"] = x.T @ x
            out[f"lstm{i}.{d}.recurrent"] = prev.T @ prev
            states.append(h)
        if i < last:
            seq = L.layer_norm(np.concatenate(states, axis=-1), p[f"ln{i}.gamma"],
                               p[f"ln{i}.beta"], c.layer_norm_eps)
    return out


def round_rows(w: np.ndarray, h: np.ndarray, scheme: str = "int8",
               damp: float = DAMP) -> np.ndarray:
    """``w (C, N)`` on ``scheme``'s grid (float32; int8: the scales
    :func:`tpnet_ref.weights.quantize.int8_scales` of ``w``), its rows rounded in order with each
    row's error moved onto the rows after it through the upper Cholesky factor of
    ``(H + damp * mean(diag H) * I)^-1`` (GPTQ); int8: each column's largest weight keeps its
    code +-127. Where inputs do not co-vary (``H`` diagonal) this is rounding to nearest."""
    w = np.array(w, dtype=np.float64)
    int8 = Q.check_scheme(scheme) == "int8"
    s = Q.int8_scales(w).astype(np.float64) if int8 else None
    rows, cols = w.shape
    h = np.array(h, dtype=np.float64)
    dead = np.diag(h) == 0
    h[dead, dead] = 1.0
    h[np.diag_indices(rows)] += damp * float(np.mean(np.diag(h)))
    u = np.linalg.cholesky(np.linalg.inv(h)).T                    # upper: Hinv = U^T U
    frozen = np.zeros((rows, cols), dtype=bool)
    if int8:
        frozen[np.argmax(np.abs(w), axis=0), np.arange(cols)] = True
    q = np.empty((rows, cols))
    for i in range(rows):
        if int8:
            q[i] = np.clip(np.rint(w[i] / s), -127, 127) * s
        else:
            q[i] = Q.round_to(w[i].astype(np.float32), "bf16")  # float32 first, as at load
        err = (w[i] - q[i]) / u[i, i]
        err[frozen[i]] = 0.0                                        # exact: nothing to move
        if i + 1 < rows:
            upd = np.outer(u[i, i + 1:], err)
            upd[frozen[i + 1:]] = 0.0
            w[i + 1:] -= upd
    out = q.astype(np.float32)
    Q.codes_of(out, scheme, "round_rows", False)                    # on the grid, re-derived
    return out


def calibrated(model: Any, windows: np.ndarray, source: str, scheme: str = "int8",
               damp: float = DAMP) -> Any:
    """``model`` (float32, not quantized) with every BiLSTM matrix rounded to ``scheme`` by
    :func:`round_rows` on ``windows`` (``(B, m, N, dim)``, model coordinates, from
    ``source``), in one plane; ``meta`` records the scheme, the source file, the empty list
    of two-plane matrices and the rounding."""
    from ..model import TPNet
    from .convert import quantized_meta

    if model.meta.get(Q.ATTR) is not None:
        raise ValueError(f"calibrated {scheme}: this model's weights are already "
                         f"{model.meta[Q.ATTR]}; quantize the float32 file")
    hs = layer_inputs(model, windows)
    names = set(Q.quantized_names(model.config))
    params = {n: (round_rows(p, hs[n], scheme, damp) if n in names else p)
              for n, p in model.params.items()}
    meta = {**quantized_meta(model, scheme), Q.WIDE_ATTR: ""}
    meta[ROUNDING_ATTR] = (f"rows in order, errors fed forward (GPTQ), damping {damp:g}, "
                           f"{len(windows)} training windows of {source}")
    used = None if model.specialization is None else model.specialization.used
    out = TPNet(model.config, params, model.dtype, meta, model.engine,
                unit_order=model.unit_order, used=used, sort_points=model.sort_points)
    out.threads = model.threads
    return out


__all__ = ["WINDOWS", "DAMP", "ROUNDING_ATTR", "training_windows", "layer_inputs", "round_rows",
           "calibrated"]
