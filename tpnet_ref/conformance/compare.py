"""A port's trace against the conformance vectors, layer by layer: per case the first layer
beyond its tolerance, its largest error and where it starts (frame, point, channel; time step,
direction, unit; point, coordinate)."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..config import TPNetConfig
from .vectors import Vectors


@dataclass
class LayerResult:
    layer: str
    max_abs: float
    tolerance: float
    where: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.max_abs <= self.tolerance

    def where_text(self) -> str:
        return ", ".join(f"{k.replace('_', ' ')} {v}" if k not in ("direction",) else str(v)
                         for k, v in self.where.items())


@dataclass
class CaseResult:
    case: str
    layers: list[LayerResult]
    missing: list[str]

    @property
    def first(self) -> LayerResult | None:
        return next((r for r in self.layers if not r.ok), None)


def _kind(layer: str) -> str:
    if layer.endswith((".fwd", ".bwd")):
        return "lstm"
    if layer.endswith(".concat"):
        return "concat"
    if layer.startswith("ln"):
        return "ln"
    if layer in ("pooled", "global") or layer.endswith(".transform"):
        return "frame"
    if layer.startswith("head") or layer == "output":
        return "out"
    return "point"


def locate(layer: str, err: np.ndarray, tol: float, counts: Sequence[int],
           config: TPNetConfig) -> dict[str, Any]:
    """Where a layer's error starts: among the entries beyond ``tol`` (all, if none is), the
    earliest frame or time step in the order the network computes them (the backward direction
    from the last step), and in it the entry with the largest error."""
    bad = err > tol
    if not bad.any():
        bad = np.ones_like(bad)
    kind = _kind(layer)
    coord = "xyz"[:config.dim] if config.dim <= 3 else None

    def argmax(a: np.ndarray, mask: np.ndarray) -> tuple[int, ...]:
        return tuple(int(i) for i in np.unravel_index(np.argmax(np.where(mask, a, -1.0)),
                                                      a.shape))

    if kind == "point":
        ends = np.cumsum(counts)
        row0 = int(np.argmax(bad.any(axis=1)))
        f = int(np.searchsorted(ends, row0, side="right"))
        start = int(ends[f - 1]) if f else 0
        r, c = argmax(err[start:ends[f]], bad[start:ends[f]])
        return {"frame": f, "point": r, "channel": c}
    if kind == "frame":
        f = int(np.argmax(bad.reshape(len(bad), -1).any(axis=1)))
        return {"frame": f, "channel": int(argmax(err[f].ravel(), bad[f].ravel())[0])}
    if kind == "lstm":
        steps = range(err.shape[0]) if layer.endswith(".fwd") else range(err.shape[0] - 1, -1, -1)
        t = next(t for t in steps if bad[t].any())
        return {"time_step": t, "direction": "forward" if layer.endswith(".fwd") else "backward",
                "unit": argmax(err[t], bad[t])[0]}
    if kind in ("concat", "ln"):
        u = err.shape[-1] // 2
        where: dict[str, Any] = {}
        if err.ndim == 2:
            t = int(np.argmax(bad.any(axis=1)))
            where["time_step"] = t
            e, b = err[t], bad[t]
        else:
            e, b = err, bad
        j = argmax(e, b)[0]
        if kind == "concat":
            where.update(direction="forward" if j < u else "backward", unit=j % u)
        else:
            where.update(channel=j)
        return where
    j = argmax(err.reshape(-1), bad.reshape(-1))[0]            # the head and the output
    return {"point": j // config.dim,
            "coordinate": coord[j % config.dim] if coord else j % config.dim}


def compare_case(vectors: Vectors, case: str, got: dict[str, np.ndarray],
                 tolerances: dict[str, float] | None = None) -> CaseResult:
    """One case of a port's trace against the vectors, layer by layer in forward order."""
    tol = tolerances or vectors.tolerances
    want = vectors.arrays[case]
    counts = vectors.cases[case]["counts"]
    res, missing = [], []
    for layer in vectors.layers:
        if layer not in got:
            missing.append(layer)
            continue
        err = np.abs(np.asarray(got[layer], np.float64) - want[layer])
        err = np.where(np.isnan(err), np.inf, err)
        mx = float(err.max()) if err.size else 0.0
        res.append(LayerResult(layer, mx, tol[layer],
                               locate(layer, err, tol[layer], counts, vectors.config)))
    return CaseResult(case, res, missing)


def compare(vectors: Vectors, traces: dict[str, dict[str, np.ndarray]]) -> list[CaseResult]:
    """Every case the port's trace holds, in the manifest's order."""
    return [compare_case(vectors, c, traces[c]) for c in vectors.cases if c in traces]


def first_divergence(results: Sequence[CaseResult], layers: Sequence[str]
                     ) -> tuple[CaseResult, LayerResult] | None:
    """The earliest layer in forward order beyond its tolerance in any case (the first case
    on a tie), or None when every case agrees."""
    best = None
    for r in results:
        f = r.first
        if f is not None and (best is None or layers.index(f.layer) < layers.index(best[1].layer)):
            best = (r, f)
    return best


__all__ = ["LayerResult", "CaseResult", "locate", "compare_case", "compare", "first_divergence"]
