"""Why the NumPy engine's ReLU takes a row operand: ``np.maximum`` against a scalar 0 and
against an array, on the sizes the feature extractor and the recurrence see.

    python bench/probes/relu_variants.py

Prints the time of ``relu(y + b)`` done as ``y += b; np.maximum(y, 0, out=y)`` (the
scalar form) and as ``np.maximum(y, -b, out=y); y += b`` (the form ``layers.dense`` uses, the
same bits), and of an in-place relu against a scalar 0 and against a zero row, for float32
activations of a B = 1 window (120 points) and of a 2,048-point block.
"""
from __future__ import annotations

import sys
import timeit

import numpy as np


def best(fn, n: int) -> float:
    return min(timeit.repeat(fn, number=n, repeat=7)) / n * 1e6


def main() -> int:
    rng = np.random.default_rng(0)
    print(f"NumPy {np.__version__}; microseconds per call (best of 7 repeats), float32")
    print(f"{'activation':>14s} {'y+=b; max(y,0)':>15s} {'max(y,-b); y+=b':>16s} "
          f"{'max(y,0)':>9s} {'max(y,zero row)':>16s}")
    for rows, cols in ((120, 256), (120, 512), (2048, 256), (2048, 512)):
        y0 = rng.standard_normal((rows, cols)).astype(np.float32)
        b = rng.standard_normal(cols).astype(np.float32)
        y = y0.copy()
        zero = np.zeros(cols, np.float32)
        n = 2000 if rows < 1000 else 200

        def scalar_form():
            np.copyto(y, y0)
            y.__iadd__(b)
            np.maximum(y, 0, out=y)

        def row_form():
            np.copyto(y, y0)
            np.maximum(y, -b, out=y)
            y.__iadd__(b)
        copy = best(lambda: np.copyto(y, y0), n)
        t1, t2 = best(scalar_form, n) - copy, best(row_form, n) - copy
        np.copyto(y, y0)
        t3 = best(lambda: np.maximum(y, 0, out=y), n)
        t4 = best(lambda: np.maximum(y, zero, out=y), n)
        a = y0 + b
        assert np.array_equal(np.maximum(a, 0), np.maximum(y0, -b) + b)
        print(f"{f'({rows}, {cols})':>14s} {t1:15.1f} {t2:16.1f} {t3:9.1f} {t4:16.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
