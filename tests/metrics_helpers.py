"""Shared by tests/test_metrics.py and tests/test_metrics3d.py: the Chamfer errors computed the
slow, obvious ways (NumPy brute force, scipy's cKDTree), any dimension."""
from __future__ import annotations

import numpy as np

METHODS = ["auto", "brute", "grid", "kdtree"]
VARIANTS = ["paper", "squared", "released"]


def ref_sums(P, Q):
    """Squared nearest distances both ways, brute force in NumPy (float64)."""
    P = np.asarray(P, np.float64)
    Q = np.asarray(Q, np.float64)
    d = ((P[:, None, :] - Q[None, :, :]) ** 2).sum(-1)
    return d.min(axis=1), d.min(axis=0)


def ref_error(P, Q, variant, centre=False):
    P = np.asarray(P, np.float64)
    Q = np.asarray(Q, np.float64)
    if centre:
        P, Q = P - P.mean(0), Q - Q.mean(0)
    a, b = ref_sums(P, Q)
    if variant == "paper":
        return (a.sum() + b.sum()) / len(P)
    if variant == "squared":
        return a.sum() + b.sum()
    return np.sqrt(a).sum() + np.sqrt(b).sum()


def kd_error(P, Q, variant):
    from scipy.spatial import cKDTree
    a = cKDTree(Q).query(P)[0]
    b = cKDTree(P).query(Q)[0]
    if variant == "paper":
        return ((a ** 2).sum() + (b ** 2).sum()) / len(P)
    if variant == "squared":
        return (a ** 2).sum() + (b ** 2).sum()
    return a.sum() + b.sum()


def assert_gradient_is_central_difference(gP, gQ, P, Q, variant, reduction, eps=1e-6):
    """``chamfer_loss``'s gradients ``gP``, ``gQ`` at ``(P, Q)`` equal central differences of
    the summed loss, coordinate by coordinate (rtol 1e-5, atol 1e-7)."""
    from tpnet_ref.metrics import chamfer_loss

    def f(P, Q):
        return float(np.sum(chamfer_loss(P, Q, variant, reduction=reduction)))

    for X, G, first in ((P, gP, True), (Q, gQ, False)):
        num = np.zeros_like(X)
        for idx in np.ndindex(X.shape):
            Xp, Xm = X.copy(), X.copy()
            Xp[idx] += eps
            Xm[idx] -= eps
            fp = f(Xp, Q) if first else f(P, Xp)
            fm = f(Xm, Q) if first else f(P, Xm)
            num[idx] = (fp - fm) / (2 * eps)
        np.testing.assert_allclose(G, num, rtol=1e-5, atol=1e-7)
