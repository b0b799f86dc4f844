"""The tolerances the docs state (docs/tolerances.md): the largest difference, in world units,
between two ways of computing the same prediction that are not bit-identical, per prediction
and at predictions 10, 40 and 80 of a rollout. Measured on the shipped m = 4 model and windows
of simulated training-grid trajectories (``python bench/tolerances.py --kernels``: at most
1.9e-5 per prediction and 7.5e-3 at the 80th in float32, 1.1e-13 and 9.3e-11 in float64);
the bounds leave a margin of 2.5x or more for other windows and CPUs."""
from __future__ import annotations

import numpy as np

#: dtype -> {"predict" or rollout step: bound in world units}
BOUNDS = {
    "float32": {"predict": 5e-5, 10: 3e-4, 40: 3e-3, 80: 2e-2},
    "float64": {"predict": 5e-13, 10: 1e-11, 40: 1e-10, 80: 5e-10},
}


def gaps(a: np.ndarray, b: np.ndarray) -> dict:
    """Largest |a - b| per rollout step: ``a``, ``b`` ``(..., steps, n, 2)`` -> {step: gap}."""
    d = np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64))
    d = d.reshape(-1, *d.shape[-3:]).max(axis=(0, 2, 3))
    return {s: float(d[s - 1]) for s in (1, 10, 40, 80) if s <= len(d)}


def assert_within(a_pred, b_pred, a_roll, b_roll, dtype: str, what: str) -> dict:
    """Predictions ``(K, n, 2)`` and rollouts ``(K, 80, n, 2)`` of two ways within
    :data:`BOUNDS` of ``dtype``; returns the gaps (for the message of a caller)."""
    bound = BOUNDS[dtype]
    g = {"predict": float(np.abs(np.asarray(a_pred, np.float64) - b_pred).max()),
         **gaps(a_roll, b_roll)}
    over = {k: v for k, v in g.items() if k in bound and v > bound[k]}
    assert not over, f"{what} ({dtype}): {over} exceed the stated bounds {bound}"
    return g
