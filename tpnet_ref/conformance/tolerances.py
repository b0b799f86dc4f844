"""The reference's trace of a window, and each layer's float32 tolerance measured from rounding
(docs/crosscheck.md, "Tolerances"): the largest gap between the reference in float32 and in
float64 over a few runs of the same window, times :data:`SAFETY`, plus :data:`FLOOR`."""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..config import TPNetConfig
from ..engines import reference
from .layer_names import layer_shapes

#: a layer's float32 tolerance: SAFETY x the largest float32 rounding gap measured on the cases
#: + FLOOR x max(1, the layer's largest magnitude) (docs/crosscheck.md, "Tolerances")
SAFETY = 8.0
FLOOR = 2.0 ** -20
#: the float32 runs whose gap to float64 is measured (docs/crosscheck.md)
RUNS = ("float32", "float32, input moved by one ulp", "float32, points reversed")


def _frames(window: Any, dim: int) -> list[np.ndarray]:
    frames = [np.asarray(f, dtype=np.float64) for f in window]
    for t, f in enumerate(frames):
        if f.ndim != 2 or f.shape[1] != dim or len(f) == 0:
            raise ValueError(f"window frame {t}: expected (N, {dim}) points, got {f.shape}")
    return frames


def trace(config: TPNetConfig, params: dict[str, np.ndarray], window: Any,
          dtype: Any = "float64") -> dict[str, np.ndarray]:
    """The reference's trace of one window (world units) in ``dtype``: layer -> array."""
    dt = np.dtype(dtype)
    p = {k: np.asarray(v).astype(dt) for k, v in params.items()}
    out: dict[str, np.ndarray] = {}
    reference.forward(config, p, [f.astype(dt) for f in _frames(window, config.dim)], trace=out)
    return out


def _point_layer(shape: Sequence[Any]) -> bool:
    return bool(shape) and shape[0] == "P"


def measure_gaps(config: TPNetConfig, params: dict[str, np.ndarray], window: Any,
                 expected: dict[str, np.ndarray] | None = None,
                 seed: int = 0) -> dict[str, float]:
    """Per layer, the largest ``|float32 run - float64|`` over :data:`RUNS` on one window."""
    frames = _frames(window, config.dim)
    want = expected if expected is not None else trace(config, params, frames)
    shapes = layer_shapes(config)
    rng = np.random.default_rng(seed)
    f32 = [f.astype(np.float32) for f in frames]
    nudged = [np.where(rng.random(f.shape) < 0.5, np.nextafter(f, np.float32(-np.inf)),
                       np.nextafter(f, np.float32(np.inf))) for f in f32]
    rev = [f[::-1] for f in f32]
    gaps = {k: 0.0 for k in want}
    for run, win in zip(RUNS, (f32, nudged, rev)):
        got = trace(config, params, win, "float32")
        if run.endswith("reversed"):        # put the per-point rows back in the frames' order
            counts = [len(f) for f in frames]
            for k, v in got.items():
                if _point_layer(shapes[k]):
                    parts = np.split(v, np.cumsum(counts)[:-1])
                    got[k] = np.concatenate([x[::-1] for x in parts])
        for k, v in got.items():
            if k == "input" and run != "float32":
                continue                     # the input itself is what was moved
            d = np.abs(v.astype(np.float64) - want[k])
            gaps[k] = max(gaps[k], float(d.max()) if d.size else 0.0)
    return gaps


def tolerances_from(gaps: dict[str, float], magnitudes: dict[str, float]) -> dict[str, float]:
    """``SAFETY * gap + FLOOR * max(1, magnitude)`` per layer."""
    return {k: SAFETY * gaps[k] + FLOOR * max(1.0, magnitudes[k]) for k in gaps}


def measure_tolerances(config: TPNetConfig, params: dict[str, np.ndarray],
                       windows: Sequence[Any],
                       expected: Sequence[dict[str, np.ndarray]] | None = None
                       ) -> tuple[dict[str, float], dict[str, float]]:
    """``(tolerances, gaps)`` per layer over ``windows``: the float32 rounding gap measured
    (:func:`measure_gaps`), its maximum over the windows, then :func:`tolerances_from`."""
    exp = list(expected) if expected is not None else [trace(config, params, w) for w in windows]
    gaps = {k: 0.0 for k in exp[0]}
    mags = {k: 0.0 for k in exp[0]}
    for w, e in zip(windows, exp):
        for k, v in measure_gaps(config, params, w, e).items():
            gaps[k] = max(gaps[k], v)
        for k, v in e.items():
            mags[k] = max(mags[k], float(np.abs(v).max()))
    return tolerances_from(gaps, mags), gaps


__all__ = ["SAFETY", "FLOOR", "RUNS", "trace", "measure_gaps", "tolerances_from",
           "measure_tolerances"]
