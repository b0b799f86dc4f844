"""The BLAS under NumPy, seen from tpnet_ref: its thread count while a batch is split.

NumPy's element-wise work (the LSTM gates) runs on one core while the BLAS uses all of them; a
large batch split across threads, each with a one-thread BLAS, uses every core for both
(:func:`single_threaded`, through threadpoolctl; measured in ``docs/performance.md``).
:func:`describe` names the BLAS, its kernel and threads for benchmark reports: OpenBLAS picks
its kernel when NumPy is imported, from the CPU or from ``OPENBLAS_CORETYPE``.
"""
from __future__ import annotations

import contextlib
import os
from typing import Iterator


def cpu_count() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


@contextlib.contextmanager
def single_threaded() -> Iterator[None]:
    """A one-thread BLAS inside the block (process-wide, restored after it). Without
    threadpoolctl the BLAS keeps its threads."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        yield
        return
    with threadpool_limits(1, user_api="blas"):
        yield


def describe() -> str:
    """The BLAS NumPy uses, its kernel and threads (threadpoolctl's view), one line."""
    try:
        from threadpoolctl import threadpool_info
        info = [d for d in threadpool_info() if d.get("user_api") == "blas"]
    except ImportError:
        return "threadpoolctl not installed"
    return "; ".join(f"{d.get('internal_api')} {d.get('version')} kernel "
                     f"{d.get('architecture')} threads {d.get('num_threads')}" for d in info)


__all__ = ["single_threaded", "cpu_count", "describe"]
