"""Chamfer metrics of TP-Net: position error, shape error and training loss (docs/spec.md §3).

Three readings of the same sums, named by ``variant`` (docs/spec.md §3 says which one the paper's
table can physically be: ``"squared"``):

``"paper"``     the paper's equation: squared Euclidean distances, both directions, divided by |P|::

                    E_p(P, Q) = (1/|P|) (Σ_{x∈P} min_{y∈Q} ||x−y||² + Σ_{y∈Q} min_{x∈P} ||x−y||²)

                P is the FIRST argument, the ground truth; |P| is its number of points.
``"squared"``   the same squared sums without the 1/|P| (the released ``get_squared_cd_loss_func``,
                the training-loss scale)::

                    E_p(P, Q) = Σ_{x∈P} min_{y∈Q} ||x−y||² + Σ_{y∈Q} min_{x∈P} ||x−y||²

``"released"``  the released evaluation script (``get_cd_loss_func``): Euclidean distances, NOT
                squared, summed over both directions, no division::

                    E_p(P, Q) = Σ_{x∈P} min_{y∈Q} ||x−y|| + Σ_{y∈Q} min_{x∈P} ||x−y||

Shape error is the position error after centring each set on its own centroid. The loss is the
two sums without any division (the paper's L_CD for ``"paper"`` and ``"squared"``; for
``"released"`` it equals the position error). The default variant stays ``"paper"``.

Shapes: ``P`` is ``(..., N, d)``, ``Q`` is ``(..., M, d)`` with points of the same dim d = 2 or
3 (``DIMS``); N ≠ M is allowed and the leading dimensions broadcast. A single pair (both inputs
one set, ``(N, d)``) gives a Python ``float``; otherwise a
float64 array with the broadcast leading shape, e.g. ``(B,)`` for a batch or ``(T,)`` for a
rollout. Inputs may be any real dtype (float32, float64, integers); distances are computed and
summed in float64, so the value does not depend on the input precision beyond the inputs'
own rounding. Units are those of the inputs (normalized coordinates for the paper's table).

Nearest neighbours are exact. Small pairs use brute force; large ones a uniform 2-D or 3-D grid
in numba (see ``docs/metrics.md``). numba (the ``metrics`` extra) is imported on first use, not by
``import tpnet_ref.metrics``.
"""
from __future__ import annotations

from typing import Any, Literal

import numpy as np

from ..checks import NonFiniteResultError, as_point_sets, as_real_array
from ..extras import require

__all__ = ["position_error", "shape_error", "chamfer_loss", "VARIANTS", "DIMS"]

Variant = Literal["paper", "squared", "released"]
Method = Literal["auto", "brute", "grid", "kdtree"]
VARIANTS: tuple[str, ...] = ("paper", "squared", "released")
#: the dims of points the metrics take (the last axis of P and Q)
DIMS: tuple[int, ...] = (2, 3)
_VARIANTS = VARIANTS
_METHODS = ("auto", "brute", "grid", "kdtree")
_REDUCTIONS = ("none", "sum", "mean")

# Brute force when N·M <= _BRUTE_FACTOR·(N + M) (roughly min(N, M) <= 2·_BRUTE_FACTOR).
_BRUTE_FACTOR = 128
_BRUTE_FACTOR_3D = 256   # 3-D brute force vectorizes: it pays up to about 512 points a set
# Work (distance evaluations) below which one thread beats starting the thread pool.
_PARALLEL_WORK = 1 << 18
# A pair with N + M >= _LARGE is handled alone, parallel over its query points.
_LARGE = 20_000
# Grid search is abandoned for scipy's k-d tree when points crowd into a few cells:
# sum(count²) / count, the mean occupancy seen by a point, above this value.
_CROWDED = 64.0
# Coordinates beyond this may overflow squared distances; such inputs use brute force only.
_HUGE = 1e150


def _kernels(dim: int = 2):
    require("numba", "metrics")   # one line naming the extra when numba is missing
    if dim == 3:
        from . import chamfer_kernels3d  # imports numba; compiled code is cached on disk
        return chamfer_kernels3d
    from . import chamfer_kernels
    return chamfer_kernels


def _check_choice(value: Any, name: str, choices: tuple[str, ...]) -> str:
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"{name}: expected one of {', '.join(map(repr, choices))}, got {value!r}")
    return value


def _point_dim(x: np.ndarray, name: str) -> int:
    if x.ndim < 2 or x.shape[-1] not in DIMS:
        raise ValueError(f"{name}: expected shape (..., N, 2) or (..., N, 3), got {x.shape}")
    return x.shape[-1]


def _check_dims(P: Any, Q: Any) -> tuple[np.ndarray, np.ndarray, int]:
    """P and Q as arrays and their points' dim, 2 or 3, which they share (else a one-line
    ValueError naming the argument)."""
    Pa = as_real_array(P, "P")
    dp = _point_dim(Pa, "P")
    Qa = as_real_array(Q, "Q")
    dq = _point_dim(Qa, "Q")
    if dp != dq:   # the 3-D one is named, against the 2-D one
        bad, shape, other, ok = ("P", Pa.shape, "Q", Qa.shape) if dp == 3 else \
            ("Q", Qa.shape, "P", Pa.shape)
        raise ValueError(f"{bad}: expected shape (..., N, 2) like {other} {ok}, got {shape}: "
                         "P and Q must hold points of the same dim (2 or 3)")
    return Pa, Qa, dp


def _prepare(P: Any, Q: Any, centre: bool):
    """Validate, centre if asked, flatten: (Pf (Bp, N, d), Qf (Bq, M, d), ip, iq (B,), lead)."""
    Pa, Qa, dim = _check_dims(P, Q)
    Pa = as_point_sets(Pa, "P", dim)
    Qa = as_point_sets(Qa, "Q", dim)
    lp, lq = Pa.shape[:-2], Qa.shape[:-2]
    try:
        lead = np.broadcast_shapes(lp, lq)
    except ValueError:
        raise ValueError(f"P and Q: leading dimensions {lp} (P) and {lq} (Q) do not broadcast") from None
    Pf = np.ascontiguousarray(Pa.reshape(-1, Pa.shape[-2], dim), dtype=np.float64)
    Qf = np.ascontiguousarray(Qa.reshape(-1, Qa.shape[-2], dim), dtype=np.float64)
    if centre:
        Pf = Pf - Pf.mean(axis=1, keepdims=True)
        Qf = Qf - Qf.mean(axis=1, keepdims=True)
    Pf = Pf if Pf.flags.writeable else Pf.copy()  # read-only arrays are another numba type
    Qf = Qf if Qf.flags.writeable else Qf.copy()
    # pair b is (Pf[ip[b]], Qf[iq[b]]); fresh writable int64 arrays (one numba signature)
    if lp == lq:
        ip = iq = np.arange(Pf.shape[0], dtype=np.int64)
    else:
        ip = np.array(np.broadcast_to(np.arange(Pf.shape[0]).reshape(lp), lead), np.int64).ravel()
        iq = np.array(np.broadcast_to(np.arange(Qf.shape[0]).reshape(lq), lead), np.int64).ravel()
    return Pf, Qf, ip, iq, lead


def _pair_kdtree(A: np.ndarray, B: np.ndarray, dA, iA, dB, iB) -> None:
    from scipy.spatial import cKDTree
    iA[:] = cKDTree(B).query(A, workers=-1)[1]
    iB[:] = cKDTree(A).query(B, workers=-1)[1]
    dA[:] = ((A - B[iA]) ** 2).sum(axis=1)
    dB[:] = ((B - A[iB]) ** 2).sum(axis=1)


def _nearest(Pf, Qf, ip, iq, method: str, with_index: bool = False):
    """Squared nearest-neighbour distances and indices both ways for each pair b.

    Returns dP, iP (B, N) (for P[ip[b]] in Q[iq[b]]) and dQ, iQ (B, M); the indices are
    only guaranteed with ``with_index=True``.
    """
    B, N, M = ip.shape[0], Pf.shape[1], Qf.shape[1]
    dP = np.empty((B, N), np.float64)
    dQ = np.empty((B, M), np.float64)
    iP = np.empty((B, N), np.int64)
    iQ = np.empty((B, M), np.int64)
    if B == 0:
        return dP, iP, dQ, iQ
    if method == "kdtree":
        for b in range(B):
            _pair_kdtree(Pf[ip[b]], Qf[iq[b]], dP[b], iP[b], dQ[b], iQ[b])
        return dP, iP, dQ, iQ
    dim = Pf.shape[2]
    K = _kernels(dim)
    huge = max(np.abs(Pf).max(), np.abs(Qf).max()) > _HUGE
    brute_factor = _BRUTE_FACTOR if dim == 2 else _BRUTE_FACTOR_3D
    if method == "brute" or huge or (method == "auto" and N * M <= brute_factor * (N + M)):
        nn = K.nn_brute if B * N * M >= _PARALLEL_WORK else K.nn_brute_serial
        nn(Pf, Qf, ip, iq, dP, iP, dQ, iQ, with_index)
    elif N + M >= _LARGE or (B == 1 and 32 * (N + M) >= _PARALLEL_WORK):
        for b in range(B):
            A, C = Pf[ip[b]], Qf[iq[b]]
            ga, gc = K.grid_build(A), K.grid_build(C)
            if method == "auto" and (ga[-1] > _CROWDED * N or gc[-1] > _CROWDED * M):
                _pair_kdtree(A, C, dP[b], iP[b], dQ[b], iQ[b])
            else:
                K.grid_query_all(ga, gc, dP[b], iP[b])
                K.grid_query_all(gc, ga, dQ[b], iQ[b])
    else:
        nn = K.nn_grid if 32 * B * (N + M) >= _PARALLEL_WORK else K.nn_grid_serial
        nn(Pf, Qf, ip, iq, dP, iP, dQ, iQ)
    return dP, iP, dQ, iQ


def _finish(values: np.ndarray, lead: tuple[int, ...], what: str) -> float | np.ndarray:
    if not np.isfinite(values).all():
        raise NonFiniteResultError(f"{what}: finite inputs gave a non-finite result "
                                   "(squared distances overflow float64; rescale the points)")
    values = values.reshape(lead)
    return float(values) if values.ndim == 0 else values


def _error(P: Any, Q: Any, variant: str, method: str, centre: bool, what: str):
    _check_choice(variant, "variant", _VARIANTS)
    _check_choice(method, "method", _METHODS)
    Pf, Qf, ip, iq, lead = _prepare(P, Q, centre)
    dP, _, dQ, _ = _nearest(Pf, Qf, ip, iq, method)
    if variant == "paper":
        values = (dP.sum(axis=1) + dQ.sum(axis=1)) / Pf.shape[1]
    elif variant == "squared":
        values = dP.sum(axis=1) + dQ.sum(axis=1)
    else:
        values = np.sqrt(dP).sum(axis=1) + np.sqrt(dQ).sum(axis=1)
    return _finish(values, lead, what)


def position_error(P: Any, Q: Any, variant: Variant = "paper", *,
                   method: Method = "auto") -> float | np.ndarray:
    """Position error E_p between ground truth ``P`` (..., N, d) and prediction ``Q`` (..., M, d).

    d, the points' dim, is 2 or 3, the same for both.

    ``variant="paper"``: squared distances, both directions, divided by N = |P|.
    ``variant="squared"``: squared distances, both directions, no division (the reading the
    paper's table fits, docs/spec.md §3).
    ``variant="released"``: Euclidean distances, both directions, no division (the released
    evaluation script).
    Returns a float for one pair, else a float64 array of the broadcast leading shape.
    ``method``: ``"auto"`` (default), or force ``"brute"``, ``"grid"`` (numba) or ``"kdtree"``
    (scipy); all are exact.
    """
    return _error(P, Q, variant, method, False, "position_error")


def shape_error(P: Any, Q: Any, variant: Variant = "paper", *,
                method: Method = "auto") -> float | np.ndarray:
    """Shape error E_s: ``position_error`` after centring each set on its own centroid.

    Same shapes, variants and return type as ``position_error``; translation-invariant in each set.
    """
    return _error(P, Q, variant, method, True, "shape_error")


def chamfer_loss(P: Any, Q: Any, variant: Variant = "paper", *,
                 reduction: Literal["none", "sum", "mean"] = "mean",
                 return_grad: bool = False, method: Method = "auto") -> Any:
    """Chamfer training loss between target ``P`` (..., N, d) and prediction ``Q`` (..., M, d),
    d = 2 or 3.

    Per pair: ``Σ_x min_y d(x, y) + Σ_y min_x d(x, y)`` with d the squared distance
    (``"paper"`` and ``"squared"``, L_CD: the two are the same loss) or the Euclidean distance
    (``"released"``); no division by |P|.
    ``reduction``: ``"mean"`` over the leading (batch) dimensions as the released code does,
    ``"sum"``, or ``"none"`` (per pair, shaped like the leading dimensions; a float for one pair).
    Weighted sums such as the paper's ``9·L(t+1) + Σ L(t+i)`` are formed from ``"none"``.

    With ``return_grad=True`` returns ``(loss, grad_P, grad_Q)``: the gradient of the reduced
    loss (of the sum of the per-pair losses for ``"none"``) with respect to P and Q, shaped like
    them (float64, or the input's floating dtype). It is the gradient for fixed nearest-neighbour
    assignments (ties broken by search order); for ``"released"`` a zero distance contributes 0.
    """
    _check_choice(variant, "variant", _VARIANTS)
    _check_choice(reduction, "reduction", _REDUCTIONS)
    _check_choice(method, "method", _METHODS)
    if not isinstance(return_grad, (bool, np.bool_)):
        raise TypeError(f"return_grad: expected a bool, got {type(return_grad).__name__}")
    Pf, Qf, ip, iq, lead = _prepare(P, Q, False)
    dP, iP, dQ, iQ = _nearest(Pf, Qf, ip, iq, method, bool(return_grad))
    if variant in ("paper", "squared"):
        values = dP.sum(axis=1) + dQ.sum(axis=1)
    else:
        values = np.sqrt(dP).sum(axis=1) + np.sqrt(dQ).sum(axis=1)
    B = ip.shape[0]
    if reduction == "none":
        loss = _finish(values, lead, "chamfer_loss")
    else:
        total = _finish(values, (B,), "chamfer_loss").sum()
        loss = float(total / B if (reduction == "mean" and B) else total)
    if not return_grad:
        return loss
    scale = 1.0 / B if (reduction == "mean" and B) else 1.0
    Pb, Qb = Pf[ip], Qf[iq]                                        # (B, N, d), (B, M, d)
    diffP = Pb - np.take_along_axis(Qb, iP[..., None], axis=1)     # x − nearest y
    diffQ = Qb - np.take_along_axis(Pb, iQ[..., None], axis=1)     # y − nearest x
    if variant in ("paper", "squared"):
        wP = np.full_like(dP, 2.0 * scale)
        wQ = np.full_like(dQ, 2.0 * scale)
    else:
        with np.errstate(divide="ignore"):
            wP = np.where(dP > 0, scale / np.sqrt(dP), 0.0)
            wQ = np.where(dQ > 0, scale / np.sqrt(dQ), 0.0)
    tP = wP[..., None] * diffP
    tQ = wQ[..., None] * diffQ
    N, M, dim = Pf.shape[1], Qf.shape[1], Pf.shape[2]
    gPb = tP.reshape(-1, dim).copy()
    gQb = tQ.reshape(-1, dim).copy()
    rows = np.arange(B)[:, None]
    np.add.at(gQb, (rows * M + iP).ravel(), -tP.reshape(-1, dim))
    np.add.at(gPb, (rows * N + iQ).ravel(), -tQ.reshape(-1, dim))
    gP = np.zeros_like(Pf)
    gQ = np.zeros_like(Qf)
    np.add.at(gP, ip, gPb.reshape(B, N, dim))
    np.add.at(gQ, iq, gQb.reshape(B, M, dim))
    P_shape, Q_shape = np.shape(P), np.shape(Q)
    dtP = np.asarray(P).dtype if np.asarray(P).dtype.kind == "f" else np.float64
    dtQ = np.asarray(Q).dtype if np.asarray(Q).dtype.kind == "f" else np.float64
    return loss, gP.reshape(P_shape).astype(dtP), gQ.reshape(Q_shape).astype(dtQ)
