"""The parameter checks both scenes share (:mod:`.scene`, :mod:`.scene3d`): a real number, and a
parameter object's integer, bool and positive fields, each refused in one line naming it."""
from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np


def check_number(value: Any, name: str) -> float:
    """``value`` as a finite float; ``TypeError`` for a non-number (a bool included),
    ``ValueError`` for NaN or an infinity, each naming ``name``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer,
                                                                      np.floating)):
        raise TypeError(f"{name}: expected a real number, got {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name}: must be finite, got {v}")
    return v


def check_fields(p: Any, ints: Iterable[str], bools: Iterable[str]) -> None:
    """``TypeError`` naming the first of ``p``'s ``ints`` that is not an integer (a bool is
    not) or of its ``bools`` that is not a bool."""
    for name in ints:
        v = getattr(p, name)
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
            raise TypeError(f"{name}: expected an integer, got {type(v).__name__}")
    for name in bools:
        if not isinstance(getattr(p, name), (bool, np.bool_)):
            raise TypeError(f"{name}: expected a bool, got {type(getattr(p, name)).__name__}")


def check_positive(p: Any, names: Iterable[str]) -> None:
    """One-line error naming the first of ``p``'s ``names`` that is not a finite number > 0."""
    for name in names:
        if check_number(getattr(p, name), name) <= 0:
            raise ValueError(f"{name}: must be > 0, got {getattr(p, name)}")


__all__ = ["check_number", "check_fields", "check_positive"]
