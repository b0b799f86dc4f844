"""A large batch cut into chunks of a fixed number of windows, run on a pool of threads: the
cut depends on the batch size alone, so neither the thread count nor the load changes a bit."""
from __future__ import annotations

from typing import Any

from .blas import cpu_count, one_thread

#: batches of this many windows or more are cut into chunks of ``SPLIT_CHUNK`` windows (the last
#: one shorter) that run on threads; the cut depends on the batch size alone, never on the
#: thread count, so neither changes a bit (docs/architecture.md, "Determinism")
SPLIT_MIN_BATCH = 64
SPLIT_CHUNK = 64
_POOLS: dict[int, Any] = {}


def split_batch(fn: Any, frames: list, batch: int, m: int, threads: int | None,
                *args: Any) -> Any:
    """``fn(frames, batch, *args)`` (``batch * m`` frames, window after window) with a one-thread
    BLAS: a batch of fewer than ``SPLIT_MIN_BATCH`` windows as it is (``fn`` sets its own BLAS
    block), a larger one in chunks of ``SPLIT_CHUNK`` consecutive windows joined along the batch
    axis, on ``threads`` threads (None: every core; 1: one after another). The chunks depend on
    ``batch`` alone, so the thread count changes no bit."""
    if batch < SPLIT_MIN_BATCH:
        return fn(frames, batch, *args)
    import numpy as np
    from concurrent.futures import ThreadPoolExecutor
    parts = [(frames[b0 * m:(b0 + SPLIT_CHUNK) * m], min(SPLIT_CHUNK, batch - b0))
             for b0 in range(0, batch, SPLIT_CHUNK)]
    n = min(threads or cpu_count(), len(parts))
    with one_thread():
        if n < 2:
            return np.concatenate([fn(f, b, *args) for f, b in parts])
        if n not in _POOLS:                  # a process-wide pool per size, made on first use
            _POOLS[n] = ThreadPoolExecutor(max_workers=n, thread_name_prefix="tpnet")
        return np.concatenate(list(_POOLS[n].map(lambda p: fn(p[0], p[1], *args), parts)))


__all__ = ["SPLIT_MIN_BATCH", "SPLIT_CHUNK", "split_batch"]
