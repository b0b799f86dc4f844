"""Why the NumPy engine orders units: reading a prefix of a kernel's rows against other ways.

    python bench/probes/profile_spans.py

For a 1024 x 2048 float32 kernel in blocks of 64 columns (BiLSTM 2's input projection, 4 rows
of input, one BLAS thread), the median time with the weights in cache ("hot") and after a 48 MB
sweep has evicted them ("cold"): all rows, the first 42 % (one span), the same number of rows in
two spans, and gathering 42 % of the rows with ``np.take`` first.
"""
from __future__ import annotations

import sys
import time

import numpy as np

from tpnet_ref.engines.blas import one_thread


def timed(fn, flush: np.ndarray | None, n: int = 100) -> float:
    for _ in range(5):
        fn()
    ts = []
    for _ in range(n):
        if flush is not None:
            flush[::16].sum()
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return 1e6 * float(np.median(ts))


def main() -> int:
    rng = np.random.default_rng(0)
    sweep = np.ones(48 * 2 ** 20 // 4, np.float32)
    c, n, nb, k = 1024, 2048, 64, 430
    kernel = rng.standard_normal((c, n)).astype(np.float32)
    blocks = np.ascontiguousarray(kernel.reshape(c, n // nb, nb).transpose(1, 0, 2))
    x = rng.standard_normal((4, c)).astype(np.float32)
    rows = np.sort(rng.choice(c, k, replace=False))
    buf = np.empty_like(kernel)
    ways = {
        "all 1024 rows": lambda: np.matmul(x, blocks),
        f"first {k} rows (one span)": lambda: np.matmul(x[:, :k], blocks[:, :k]),
        f"{k} rows in two spans": lambda: (np.matmul(x[:, :180], blocks[:, :180])
                                          + np.matmul(x[:, 512:762], blocks[:, 512:762])),
        f"np.take of {k} scattered rows, then product": lambda: (
            x[:, rows] @ np.take(kernel, rows, axis=0, out=buf[:k])),
    }
    print(f"{c} x {n} float32 kernel, 4 input rows, blocks of {nb} columns, one BLAS thread (us):")
    with one_thread():
        for label, fn in ways.items():
            print(f"  {label:46s} hot {timed(fn, None):7.0f}   cold {timed(fn, sweep):7.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
