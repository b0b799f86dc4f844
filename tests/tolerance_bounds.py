"""The tolerances the docs state (docs/tolerances.md): the largest difference, in world units,
between two ways of computing the same prediction that are not bit-identical, per prediction
and at predictions 10, 40 and 80 of a rollout. Measured on the shipped m = 4 model and windows
of simulated training-grid trajectories (``python bench/tolerances.py --kernels``: at most
1.9e-5 per prediction and 7.5e-3 at the 80th in float32, 1.1e-13 and 9.3e-11 in float64);
the bounds leave a margin of 2.5x or more for other windows and CPUs.

Every step of a rollout is checked: step 1 (the prediction) against the per-prediction bound,
a step between two stated ones against the bound of the next stated step (steps 2..10 against
step 10's, 11..40 against step 40's, 41..80 against step 80's). A value that is not finite
(NaN, inf) on either side fails: ``NaN > bound`` is False, so it would otherwise pass."""
from __future__ import annotations

import numpy as np

#: dtype -> {"predict" or rollout step: bound in world units}
BOUNDS = {
    "float32": {"predict": 5e-5, 10: 3e-4, 40: 3e-3, 80: 2e-2},
    "float64": {"predict": 5e-13, 10: 1e-11, 40: 1e-10, 80: 5e-10},
}


def step_bound(bound: dict, step: int) -> float:
    """The bound that applies at rollout ``step`` (1-based): step 1 is a prediction; any other
    step takes the bound of the first stated step at or after it."""
    if step == 1:
        return bound["predict"]
    stated = sorted(k for k in bound if k != "predict")
    after = [k for k in stated if k >= step]
    if not after:
        raise ValueError(f"no stated bound for rollout step {step} (stated up to {stated[-1]})")
    return bound[after[0]]


def gaps(a: np.ndarray, b: np.ndarray) -> dict:
    """Largest |a - b| per rollout step: ``a``, ``b`` ``(..., steps, n, 2)`` -> {step: gap},
    every step, 1-based; a step where either side is not finite gaps ``inf``."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    assert a.shape == b.shape, f"shapes differ: {a.shape} against {b.shape}"
    d = np.abs(a - b)
    d[~(np.isfinite(a) & np.isfinite(b))] = np.inf
    d = d.reshape(-1, *d.shape[-3:]).max(axis=(0, 2, 3))
    return {s: float(d[s - 1]) for s in range(1, len(d) + 1)}


def assert_within(a_pred, b_pred, a_roll, b_roll, dtype: str, what: str) -> dict:
    """Predictions ``(K, n, 2)`` and rollouts ``(K, steps, n, 2)`` (up to 80 steps) of two ways
    within :data:`BOUNDS` of ``dtype`` at every step, every value finite; returns the gaps (for
    the message of a caller)."""
    bound = BOUNDS[dtype]
    a_pred, b_pred = np.asarray(a_pred, np.float64), np.asarray(b_pred, np.float64)
    assert a_pred.shape == b_pred.shape, f"{what}: shapes differ, {a_pred.shape} against {b_pred.shape}"
    finite = np.isfinite(a_pred) & np.isfinite(b_pred)
    g = {"predict": float(np.max(np.where(finite, np.abs(a_pred - b_pred), np.inf), initial=0.0)),
         **gaps(a_roll, b_roll)}
    over = {k: v for k, v in g.items()
            if not v <= (bound["predict"] if k == "predict" else step_bound(bound, k))}
    assert not over, f"{what} ({dtype}): {over} exceed the stated bounds {bound}"
    return g
