"""The per-case spread of an error: the mean over the cases with a 95 % bootstrap interval, and
the median (docs/glossary.md, "spread").

A few cases dominate the mean at long horizons (one far-off rollout outweighs fifty good ones),
so every cell of ``results.md`` carries ``mean [lo, hi] med median``: ``[lo, hi]`` is the
percentile bootstrap interval of the mean (:data:`N_RESAMPLES` resamples of the cases with
replacement, drawn from ``numpy.random.default_rng(SEED)``, so the same errors always give the same
interval), ``median`` the per-case median. Two rows whose intervals overlap widely are not told
apart by these cases.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

#: bootstrap resamples, seed and level of every interval in results.md
N_RESAMPLES = 10_000
SEED = 0
LEVEL = 0.95


@lru_cache(maxsize=8)
def _resample_index(n: int, n_resamples: int, seed: int) -> np.ndarray:
    """``(n_resamples, n)`` indices into ``n`` cases, drawn with replacement (read-only)."""
    idx = np.random.default_rng(seed).integers(0, n, size=(n_resamples, n))
    idx.setflags(write=False)
    return idx


def _values(x: object) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 1:
        raise ValueError(f"per-case values: expected a 1-D array, got shape {a.shape}")
    if a.size == 0:
        raise ValueError("per-case values: empty")
    return a


def bootstrap_ci(x: object, *, n_resamples: int = N_RESAMPLES, seed: int = SEED,
                 level: float = LEVEL) -> tuple[float, float]:
    """The percentile bootstrap interval ``(lo, hi)`` of the mean of the per-case values ``x``:
    the ``(1 - level) / 2`` and ``(1 + level) / 2`` quantiles of the means of ``n_resamples``
    resamples of the cases with replacement. Deterministic in ``seed``; ``(nan, nan)`` if a
    value is not finite."""
    a = _values(x)
    if not 0.0 < level < 1.0:
        raise ValueError(f"level: must lie in (0, 1), got {level}")
    if n_resamples < 1:
        raise ValueError(f"n_resamples: must be >= 1, got {n_resamples}")
    if not np.isfinite(a).all():
        return (float("nan"), float("nan"))
    means = a[_resample_index(a.size, int(n_resamples), int(seed))].mean(axis=1)
    lo, hi = np.quantile(means, [(1.0 - level) / 2.0, (1.0 + level) / 2.0])
    return (float(lo), float(hi))


@dataclass(frozen=True)
class Spread:
    """Mean over the cases, its bootstrap interval ``[lo, hi]``, the median, the case count."""

    mean: float
    lo: float
    hi: float
    median: float
    n: int


def spread(x: object, **kw: object) -> Spread:
    """:class:`Spread` of the per-case values ``x`` (``kw``: as :func:`bootstrap_ci`)."""
    a = _values(x)
    lo, hi = bootstrap_ci(a, **kw)  # type: ignore[arg-type]
    return Spread(float(a.mean()), lo, hi, float(np.median(a)), int(a.size))


def fmt_err(x: float | None) -> str:
    """An error for a table: two significant digits below 0.1 (in decimals down to 1e-4),
    three decimals up to 10, two above; '–' if missing."""
    if x is None or not np.isfinite(x):
        return "–"
    if x == 0:
        return "0"
    if abs(x) < 1e-4:
        return f"{x:.1e}"
    if abs(x) < 0.1:
        return f"{x:.{1 - math.floor(math.log10(abs(x)))}f}"
    return f"{x:.3f}" if abs(x) < 10 else f"{x:.2f}"


def fmt_spread(s: Spread, fmt: object = None) -> str:
    """``mean [lo, hi] med median`` with each number formatted by ``fmt`` (default: the tables'
    :func:`fmt_err`); the mean alone for a single case."""
    f = fmt_err if fmt is None else fmt
    if s.n == 1:
        return f(s.mean)  # type: ignore[operator]
    return f"{f(s.mean)} [{f(s.lo)}, {f(s.hi)}] med {f(s.median)}"  # type: ignore[operator]


__all__ = ["N_RESAMPLES", "SEED", "LEVEL", "Spread", "bootstrap_ci", "spread", "fmt_spread",
           "fmt_err"]
