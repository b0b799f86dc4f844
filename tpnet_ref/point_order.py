"""The canonical order of a frame's points: what makes permutation invariance exact.

Each frame's points are sorted lexicographically (x, then y, then z in 3-D: every coordinate in
turn) before the feature extractor, so every permutation of a frame produces the very same matrix
and hence bit-identical output (docs/architecture.md, "Exact permutation invariance"). NumPy only.
"""
from __future__ import annotations

import numpy as np

#: up to this many points the canonical order is one lexsort; above it, row-wise stable argsorts
#: (each the faster at its sizes)
SMALL_SORT = 512


def canonical_order(points: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Indices that sort each frame's points by x, then y (then the remaining coordinates).

    ``points (P, dim)``, ``counts (F,)`` -> ``(P,)`` indices into ``points``. Points that tie
    on every coordinate are identical rows, so the sorted matrix does not depend on the input
    order at all.
    """
    counts = np.asarray(counts)
    dim = points.shape[1]
    if points.shape[0] <= SMALL_SORT:
        # few points (a window, a rollout's new frame): one lexsort is cheapest (same indices)
        frame_id = np.repeat(np.arange(len(counts)), counts)
        return np.lexsort([points[:, d] for d in range(dim - 1, -1, -1)] + [frame_id])
    if counts.size and np.all(counts == counts[0]):
        # equal frames: stable sorts within each row, least significant coordinate first
        a = points.reshape(counts.size, int(counts[0]), dim)
        idx = np.argsort(a[..., dim - 1], axis=1, kind="stable")
        for d in range(dim - 2, -1, -1):
            key = np.take_along_axis(a[..., d], idx, axis=1)
            idx = np.take_along_axis(idx, np.argsort(key, axis=1, kind="stable"), axis=1)
        idx += (np.arange(counts.size) * int(counts[0]))[:, None]
        return idx.ravel()
    frame_id = np.repeat(np.arange(len(counts)), counts)
    keys = [points[:, d] for d in range(dim - 1, -1, -1)] + [frame_id]
    return np.lexsort(keys)


__all__ = ["SMALL_SORT", "canonical_order"]
