"""Input checks shared by every public function: clear errors instead of silent NaN.

Each checker names the argument and the problem in its message. ``TypeError`` is raised for
a wrong kind of object or dtype (strings, objects, complex, booleans), ``ValueError`` for a
wrong shape or value (rank, last dimension, empty, NaN/Inf).
"""
from __future__ import annotations

from typing import Any

import numpy as np


class NonFiniteResultError(ArithmeticError):
    """Raised when finite input would give a non-finite result (for example float32 overflow)."""


def as_real_array(x: Any, name: str, dtype: np.dtype | type | None = None) -> np.ndarray:
    """``x`` as a NumPy array of a real numeric dtype (integers are accepted and converted).

    Raises ``TypeError`` for strings, objects, booleans and complex numbers.
    """
    if isinstance(x, (str, bytes)):
        raise TypeError(f"{name}: expected a numeric array, got {type(x).__name__}")
    try:
        arr = np.asarray(x)
    except ValueError as exc:  # ragged nested lists
        raise ValueError(f"{name}: cannot be read as one array ({exc})") from None
    if arr.dtype == object:
        raise TypeError(f"{name}: expected a numeric array, got an object array "
                        "(ragged or non-numeric content)")
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"{name}: expected real numbers, got dtype {arr.dtype}")
    if dtype is not None:
        arr = arr.astype(dtype, copy=False)
    return arr


def check_finite(arr: np.ndarray, name: str) -> np.ndarray:
    """Raise ``ValueError`` naming ``name`` if ``arr`` holds NaN or Inf."""
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
        raise ValueError(f"{name}: contains {bad} NaN or infinite value(s)")
    return arr


def as_point_set(x: Any, name: str, dim: int = 2, dtype: np.dtype | type | None = None,
                 allow_empty: bool = False) -> np.ndarray:
    """``x`` as a finite ``(N, dim)`` array with ``N >= 1`` (unless ``allow_empty``)."""
    arr = as_real_array(x, name, dtype)
    if arr.ndim != 2 or arr.shape[-1] != dim:
        raise ValueError(f"{name}: expected shape (N, {dim}), got {arr.shape}")
    if arr.shape[0] == 0 and not allow_empty:
        raise ValueError(f"{name}: is empty (0 points)")
    return check_finite(arr, name)


def as_point_sets(x: Any, name: str, dim: int = 2, dtype: np.dtype | type | None = None) -> np.ndarray:
    """``x`` as a finite ``(..., N, dim)`` array (a batch of point sets) with ``N >= 1``."""
    arr = as_real_array(x, name, dtype)
    if arr.ndim < 2 or arr.shape[-1] != dim:
        raise ValueError(f"{name}: expected shape (..., N, {dim}), got {arr.shape}")
    if arr.shape[-2] == 0:
        raise ValueError(f"{name}: is empty (0 points per set, shape {arr.shape})")
    return check_finite(arr, name)
