"""The gate of the Numba engine's two-thread kernels: one such call at a time, only beside a
one-thread BLAS, and (in the short commands) only where numba already has the kernel. Every
two-thread kernel has a one-thread twin that gives the same bits; the gate only says which runs."""
from __future__ import annotations

import threading
from typing import Any

from . import compile_watch
from .blas import in_one_thread

#: one parallel call at a time (another thread asking meanwhile runs the serial kernel)
LOCK = threading.Lock()


def available(kernel: Any, memo: dict[Any, bool], args: tuple[Any, ...],
               key: Any = None) -> bool:
    """Whether the two-thread ``kernel`` may run on ``args``: always where two-thread kernels
    are compiled on demand (:data:`tpnet_ref.engines.compile_watch.TWO_THREAD_KERNELS_ON_DEMAND`, the
    library's default);
    else (``tpnet demo``, ``predict``, ``animate``) only if numba has it for these argument
    types, compiled in this process or in its cache (loaded then), so that a short command never
    stops to compile it -- the one-thread kernel gives the same bits. ``memo``: the caller's
    answers, by ``key``: the kernel where its argument types do not change, else what tells
    them apart."""
    got = compile_watch.may_compile(kernel, kernel if key is None else key, memo, args)
    if not got:
        _SKIPPED.add(kernel.__name__)
    return got


#: the two-thread kernels that :func:`available` found missing in this process
_SKIPPED: set[str] = set()


def two_thread_kernels_skipped() -> tuple[str, ...]:
    """The two-thread kernels that ran on one thread in this process because numba did not have
    them and they are not compiled on demand (:func:`available`), sorted."""
    return tuple(sorted(_SKIPPED))


def take(parallel: bool) -> bool:
    """Whether a call asked to run ``parallel`` takes the two-thread kernels now: only inside a
    :func:`tpnet_ref.engines.blas.one_thread` block (a one-thread BLAS), and one such call at a time.
    Beside a multi-threaded BLAS, whose threads spin between calls, numba's second thread waits
    for a core and costs several times what it saves; beside a one-thread BLAS it pays
    (docs/performance.md). True holds :data:`LOCK`: the caller releases it."""
    return parallel and in_one_thread() and LOCK.acquire(blocking=False)


__all__ = ["LOCK", "available", "take", "two_thread_kernels_skipped"]
