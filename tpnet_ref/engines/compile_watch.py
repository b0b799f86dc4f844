"""The Numba compilations inside a block of code: announced when the first one starts, timed;
and whether a call compiles the two-thread kernels it lacks.

Numba compiles a kernel the first time it is called with new argument types, unless its cache
(``__pycache__/*.nbi``, ``*.nbc`` beside the module, or ``NUMBA_CACHE_DIR``) holds it: the first
run after install compiles, later runs load. ``with CompileWatch(announce) as w:`` calls
``announce()`` once, when the first compilation inside the block starts (so a command can say
why it is silent), and ``w.seconds`` is then the wall time spent compiling (nested compilations
counted once), ``w.count`` the kernels compiled. Loads from the cache are not compilations.
numba is imported only if it is installed; without it the block runs unwatched (0 s).

The Numba engine has each kernel in two versions, one thread and two (the same bits); the thread
policy (:mod:`tpnet_ref.engines.thread_policy`) tries the two-thread plan whenever a second core looks free, in
any run. :data:`TWO_THREAD_KERNELS_ON_DEMAND` True (the library's default: a long-lived process
gains from them) compiles a two-thread kernel when that plan first runs; ``tpnet demo``,
``predict`` and ``animate`` set it False: the two-thread kernels run only where numba already has
them (compiled in the process, or in its cache), so a later run never stops to compile them.
"""
from __future__ import annotations

import importlib.util
import threading
import time
from collections.abc import Callable
from typing import Any

#: the event numba triggers around each compilation (not around a load from its cache)
EVENT = "numba:compile"
#: whether a call that may run one of the Numba engine's optional kernels compiles it when
#: lacking (the module docstring): the two-thread kernels (the one-thread kernel runs otherwise),
#: the input checks' compiled first pass and sort (the NumPy checks run otherwise) and a
#: rollout's fused steps (the step-by-step loop runs otherwise) -- the same results either way
TWO_THREAD_KERNELS_ON_DEMAND = True


class CompileWatch:
    """A context manager: see the module. ``announce`` is called in the compiling thread."""

    def __init__(self, announce: Callable[[], None] | None = None) -> None:
        self.announce = announce
        self.seconds = 0.0
        self.count = 0
        self._announced = False
        self._local = threading.local()
        self._lock = threading.Lock()
        self._listener: Any = None

    def __enter__(self) -> "CompileWatch":
        if importlib.util.find_spec("numba") is None:
            return self
        from numba.core import event

        watch = self

        class _Listener(event.Listener):
            def on_start(self, ev: Any) -> None:
                watch._started()

            def on_end(self, ev: Any) -> None:
                watch._ended()

        self._listener = _Listener()
        event.register(EVENT, self._listener)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._listener is not None:
            from numba.core import event
            event.unregister(EVENT, self._listener)
            self._listener = None

    def _started(self) -> None:
        depth = getattr(self._local, "depth", 0)
        self._local.depth = depth + 1
        if depth:
            return
        self._local.t0 = time.perf_counter()
        with self._lock:
            first = not self._announced
            self._announced = True
        if first and self.announce is not None:
            self.announce()

    def _ended(self) -> None:
        self._local.depth -= 1
        if self._local.depth == 0:
            with self._lock:
                self.seconds += time.perf_counter() - self._local.t0
                self.count += 1

    def report(self) -> str:
        """One line for a timing report: what was compiled and in how long, or that nothing was."""
        if not self.count:
            return ("Numba kernels: none compiled (loaded from numba's cache, or not used)")
        return (f"Numba kernels: {self.count} compiled in {self.seconds:.1f} s (once: later runs "
                "load them from numba's cache)")


#: the line a command prints when its first compilation starts
COMPILING = "compiling the Numba kernels (once; cached for later runs)..."


def compiled_or_cached(kernel: Any, args: tuple[Any, ...]) -> bool:
    """Whether ``kernel`` (a numba dispatcher) has a version for ``args``' types, compiled or
    loaded now from numba's cache (as its ``compile`` does before compiling); never compiles.
    False where numba's internals differ from those of numba 0.68 that this reads (then the
    one-thread kernel runs: the same bits)."""
    from numba.core.compiler_lock import global_compiler_lock
    try:
        sig = tuple(kernel.typeof_pyval(a) for a in args)
        if sig in kernel.overloads:
            return True
        with global_compiler_lock:
            cres = kernel._cache.load_overload(sig, kernel.targetctx)
            if cres is None:
                return False
            kernel.targetctx.insert_user_function(cres.entry_point, cres.fndesc, [cres.library])
            kernel.add_overload(cres)
        return True
    except Exception:                   # noqa: BLE001 -- numba's internals changed: one thread
        return False


def entry_point(kernel: Any, args: tuple[Any, ...]) -> Callable[..., Any] | None:
    """The code numba compiled for ``args``' types, to be called on arguments of those very types
    without the dispatcher, which types every argument again on each call (3 us a call for the
    Numba engine's network, whose arguments are tuples of arrays); None where numba has no version
    for them (call ``kernel`` first) or where its internals differ from those of numba 0.68 that
    this reads (the caller then calls ``kernel``)."""
    try:
        cres = kernel.overloads.get(tuple(kernel.typeof_pyval(a) for a in args))
        return None if cres is None else cres.entry_point
    except Exception:                   # noqa: BLE001 -- numba's internals changed: the dispatcher
        return None


def may_compile(kernel, key, memo: dict, args: tuple) -> bool:
    """Whether the optional ``kernel`` (the same results exist without it) may run on ``args``:
    always where the library compiles such kernels on demand
    (:data:`TWO_THREAD_KERNELS_ON_DEMAND`, its default); in the short
    commands (``tpnet demo``, ``predict``, ``animate``) only when numba already has it, compiled
    in this process or in its cache, so that they never stop to compile it. ``memo``: the
    answers by ``key`` (the argument types)."""
    if TWO_THREAD_KERNELS_ON_DEMAND:
        return True
    got = memo.get(key)
    if got is None:
        got = memo[key] = compiled_or_cached(kernel, args)
    return got


__all__ = ["CompileWatch", "COMPILING", "EVENT", "TWO_THREAD_KERNELS_ON_DEMAND", "compiled_or_cached",
           "entry_point", "may_compile"]
