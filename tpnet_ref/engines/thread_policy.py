"""The thread policy: one thread, or a second one for the parts that may take it, whichever
measures faster.

For one window, only a plan that gives the same bits whichever thread runs what may use a second
thread: the Numba engine's two LSTM directions, and its feature extractor's frames (each number
computed by the same code on one thread). :class:`ThreadPolicy` (:data:`adaptive`) runs it or the
one-thread plan, whichever its recent calls measured faster (a second thread beside a busy core
makes every step wait); both plans run every BLAS product on one thread
(:func:`tpnet_ref.engines.blas.one_thread`), so the policy changes speed, never a result.
"""
from __future__ import annotations

import os
import threading
import time
from collections import deque
from typing import Any, Hashable

from .blas import cpu_count, in_one_thread, one_thread
from .load_monitor import CoreMonitor

#: :class:`ThreadPolicy`: every this many calls of one kind, the choice not currently preferred
PROBE_EVERY = 8
#: :class:`ThreadPolicy`: latencies kept per choice (their median decides)
KEEP = 4
#: :class:`ThreadPolicy`: the two-thread plan is taken only when its median latency is this much
#: below one thread's (beside a busy core a second thread can take twice as long or more) ...
MARGIN = 0.07
#: ... and kept while it stays this much below (a choice that moves only on a change larger
#: than the noise: plans within a few percent of each other do not swap call by call)
HOLD_MARGIN = 0.03

_LOCAL = threading.local()


def two_threads() -> bool:
    """Whether the work the calling thread runs now may take a second thread: True only inside a
    :class:`ThreadPolicy` block that chose the two-thread plan."""
    return getattr(_LOCAL, "two", False)


#: the values of TPNET_THREADS that fix a plan: 1 one thread, 0 two threads
_FIXED = {"1": 1, "2": 0, "all": 0}
#: the environment's own dict where it has one (POSIX: bytes keys), read without the KeyError
#: that ``os.environ.get`` raises and catches for every unset name (a microsecond a call)
_ENV_DATA = getattr(os.environ, "_data", None) if os.name == "posix" else None
if not (isinstance(_ENV_DATA, dict) and all(isinstance(k, bytes) for k in _ENV_DATA)):
    _ENV_DATA = None


def _getenv(name: str, key: bytes) -> str | None:
    """``os.environ.get(name)`` (``key``: ``name`` encoded), cheaply where the name is unset."""
    if _ENV_DATA is not None and key not in _ENV_DATA:
        return None
    return os.environ.get(name)


def _fixed_choice() -> int | None:
    """``TPNET_THREADS=1`` (or the older ``TPNET_BLAS_THREADS=1``) fixes the one-thread plan,
    ``=2`` / ``=all`` the two-thread plan; None: measure."""
    fixed = _getenv("TPNET_THREADS", b"TPNET_THREADS")
    if fixed is None:
        fixed = _getenv("TPNET_BLAS_THREADS", b"TPNET_BLAS_THREADS")
    return _FIXED.get(fixed or "")


class ThreadPolicy:
    """Runs each call of a kind on one thread or with a second thread for the parts that may
    take one (:func:`two_threads`), whichever its recent calls of that kind measured faster. The
    two plans give the same bits, and both run every BLAS product on one thread
    (:func:`one_thread`): the policy changes speed, never a result.

    Per kind (any hashable, e.g. ``("predict", dtype, points)``) it keeps the last :data:`KEEP`
    latencies of each choice; it takes two threads when their median is at least :data:`MARGIN`
    below one thread's and keeps them while it stays :data:`HOLD_MARGIN` below, else one thread,
    and every :data:`PROBE_EVERY` calls the other choice (probes of two threads less often while
    they do not win by the margin; each such probe is two calls, the first, which wakes the
    second thread, not measured), so a change of load (another process taking a core, then
    leaving) moves the choice. Nested inside another
    :func:`one_thread` block (a chunk of a split batch, a caller's block) or on one core it runs
    one thread and measures nothing. ``TPNET_THREADS=1`` or ``=2`` fixes the choice.

    ``monitor`` (a :class:`CoreMonitor`; the process-wide :data:`adaptive` has one): while it
    sees the other core taken by another process, every call runs one thread without a probe;
    when it sees the machine change (taken, or free again), the latencies measured before are
    dropped, so the next few calls measure both plans afresh instead of trusting minutes-old
    figures. Thread-safe.
    """

    def __init__(self, probe_every: int = PROBE_EVERY, keep: int = KEEP,
                 margin: float = MARGIN, monitor: CoreMonitor | None = None,
                 hold: float = HOLD_MARGIN) -> None:
        self.probe_every, self.keep, self.margin, self.hold = probe_every, keep, margin, hold
        self.monitor = monitor
        # per kind: the latencies of each choice, [calls, calls between probes, probing now,
        # a two-thread probe's call due after its warm-up, this call is a warm-up, the choice
        # the latencies favoured last (:meth:`_best`)]
        self._kinds: dict[Hashable, tuple[dict[int, deque], list[int]]] = {}
        self._lock = threading.Lock()
        self._generation = 0

    @staticmethod
    def _median(t: deque) -> float:
        return sorted(t)[len(t) // 2]

    def _wins(self, times: dict[int, deque], margin: float) -> bool:
        """Whether two threads' median latency is at least ``margin`` below one thread's."""
        return self._median(times[0]) < (1 - margin) * self._median(times[1])

    def _best(self, times: dict[int, deque], held: int) -> int:
        """0 (two threads) or 1 from the medians; ``held``: the choice favoured until now."""
        return 0 if self._wins(times, self.hold if held == 0 else self.margin) else 1

    def choose(self, kind: Hashable) -> int:
        """1 (one thread) or 0 (a second thread) for the next call of ``kind``."""
        fixed = _fixed_choice()
        if fixed is not None:
            return fixed
        taken = self.monitor is not None and self.monitor.taken()
        with self._lock:
            if self.monitor is not None and self.monitor.generation != self._generation:
                self._generation = self.monitor.generation
                self._kinds.clear()                 # the machine changed: measure afresh
            if taken:
                return 1
            got = self._kinds.get(kind)
            if got is None:
                if len(self._kinds) >= 256:
                    self._kinds.clear()             # many kinds (ragged windows): start over
                got = self._kinds[kind] = ({1: deque(maxlen=self.keep),
                                            0: deque(maxlen=self.keep)},
                                           [0, self.probe_every, 0, 0, 0, 1])
            times, st = got
            for c in (1, 0):                        # first fill both with a few samples
                if len(times[c]) < 2:
                    return c
            st[0] += 1
            if st[3]:                               # the probe after its warm-up call
                st[2:5] = [1, 0, 0]
                return 0
            best = st[5] = self._best(times, st[5])
            st[2] = int(st[0] % st[1] == 0)
            if st[2] and best == 1:
                # a probe of two threads after a run of one-thread calls: the second thread's
                # workers have gone to sleep, and waking them slows the first call, which would
                # make two threads look slower than they are. That call is not recorded; the next
                # one is the probe.
                st[2:5] = [0, 1, 1]
                return 0
            return 1 - best if st[2] else best

    def record(self, kind: Hashable, choice: int, seconds: float) -> None:
        """Keep one measured latency of ``choice`` for ``kind``. A probe of two threads that
        does not win by the margin doubles the calls until the next probe (up to 1024: beside a
        busy core a second thread can take 10x as long, so losing probes must get rare); any
        other probe resets it."""
        with self._lock:
            if kind not in self._kinds:
                return
            times, st = self._kinds[kind]
            if st[4]:                               # a probe's warm-up call
                st[4] = 0
                return
            if st[2] and len(times[1 - choice]):
                other = self._median(times[1 - choice])
                lost = choice == 0 and not seconds < (1 - self.margin) * other
                st[1] = min(2 * st[1], 1024) if lost else self.probe_every
                st[2] = 0
            times[choice].append(seconds)

    def one_thread_plan(self, kind: Hashable, held: bool = False,
                        margin: float | None = None) -> bool:
        """Whether calls of ``kind`` run on one thread now, with no change of plan in sight:
        nested in another :func:`one_thread` block (unless ``held``, as for :meth:`__call__`),
        one core, ``TPNET_THREADS=1``, the other core taken (the monitor), or one thread
        measured faster (:meth:`preferred`; with ``margin``: unless two threads measure that
        much faster, whichever runs now). Changes nothing."""
        if (in_one_thread() and not held) or cpu_count() < 2:
            return True
        fixed = _fixed_choice()
        if fixed is not None:
            return fixed == 1
        if self.monitor is not None and self.monitor.taken():
            return True
        if margin is None:
            return self.preferred(kind) == 1
        with self._lock:
            times = self._kinds.get(kind, ({1: (), 0: ()},))[0]
            return bool(times[0] and times[1]) and not self._wins(times, margin)

    def preferred(self, kind: Hashable) -> int | None:
        """The choice (1 or 0) the recent calls of ``kind`` measured faster; None before any."""
        with self._lock:
            if kind not in self._kinds:
                return None
            times, st = self._kinds[kind]
            if not (times[0] and times[1]):
                return None
            return self._best(times, st[5])

    def __call__(self, kind: Hashable, held: bool = False,
                 blas_free: bool = False) -> "_Block":
        """A block (``with``) run with a one-thread BLAS and the chosen plan
        (:func:`two_threads` tells the block); it gives the choice (1, 0, or -1 when the policy
        stands aside: nested in another :func:`one_thread` block, or one core) and records the
        block's latency. ``held``: the caller holds a :func:`one_thread` block of its own around
        many such blocks (a rollout's steps) and was not itself nested in one when it took it:
        the policy chooses all the same. ``blas_free``: the block calls no BLAS product (the
        Numba engine's kernels alone), so on one thread it needs no one-thread BLAS block; its
        two-thread plan still takes one."""
        return _Block(self, kind, held, blas_free)


class _Block:
    """:meth:`ThreadPolicy.__call__`'s block (a class, not a generator: a microsecond less a
    call). A failing block records nothing."""

    __slots__ = ("policy", "kind", "held", "blas_free", "choice", "blas", "t")

    def __init__(self, policy: ThreadPolicy, kind: Hashable, held: bool,
                 blas_free: bool) -> None:
        self.policy, self.kind, self.held, self.blas_free = policy, kind, held, blas_free

    def __enter__(self) -> int:
        self.blas = None
        if (in_one_thread() and not self.held) or cpu_count() < 2:
            self.choice = -1
            self.blas = one_thread()
            self.blas.__enter__()
            return -1
        self.choice = choice = self.policy.choose(self.kind)
        self.t = time.perf_counter()             # the plan's latency, its BLAS block included
        _LOCAL.two = choice == 0
        if not (self.held or (self.blas_free and choice == 1)):
            self.blas = one_thread()
            self.blas.__enter__()
        return choice

    def __exit__(self, *exc: Any) -> None:
        if self.blas is not None:
            self.blas.__exit__(*exc)
        if self.choice != -1:
            _LOCAL.two = False
            if exc[0] is None:
                self.policy.record(self.kind, self.choice, time.perf_counter() - self.t)


#: the process-wide policy :mod:`tpnet_ref.model` runs the Numba engine's single windows under;
#: it watches the other cores (:class:`CoreMonitor`)
adaptive = ThreadPolicy(monitor=CoreMonitor())


__all__ = ["PROBE_EVERY", "KEEP", "MARGIN", "HOLD_MARGIN", "two_threads", "ThreadPolicy",
           "adaptive"]
