"""The BLAS under NumPy, seen from tpnet_ref: always one thread, and which product shapes it runs fast.

- Determinism. A multi-threaded BLAS cuts a product differently for different thread counts,
  and some kernels (OpenBLAS's Haswell kernel, on AMD and Intel alike) then round it
  differently: the same window gave two outputs within ten calls while a policy switched the
  BLAS between one and two threads. So every product the model computes runs on a one-thread
  BLAS (:func:`one_thread`), and the work is cut into BLAS calls by the input's shapes alone
  (a large batch in chunks of a fixed number of windows, :data:`SPLIT_CHUNK`).
  Threads only schedule calls that are fixed beforehand, so no thread count, load or policy can
  change a bit (docs/architecture.md, "Determinism").
- The second core. A large batch's chunks run on threads, each with the one-thread BLAS. For
  one window, only a plan that gives the same bits whichever thread runs what may use a second
  thread: the Numba engine's two LSTM directions (each number computed by the same code on one
  thread). :class:`ThreadPolicy` (:data:`adaptive`) runs it or the one-thread plan, whichever
  its recent calls measured faster (a second thread beside a busy core makes every step wait).
- Small products. The LSTMs' input projections are computed as a stack of column blocks of at
  most :data:`SMALL_PRODUCT` multiply-adds each, always: OpenBLAS multiplies such blocks without
  packing them first (SkylakeX and later) and they are no slower elsewhere. This used to be
  measured once per process, and a timing that decides how the work is cut decides its
  rounding: on the Haswell kernel two processes cut it differently and disagreed.
- :func:`describe` names the BLAS, its kernel and threads for benchmark reports: OpenBLAS picks
  its kernel when NumPy is imported, from the CPU or from ``OPENBLAS_CORETYPE``.
"""
from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections import deque
from typing import Any, Hashable, Iterator


#: OpenBLAS multiplies a product of M*N*K <= 1e6 multiply-adds without packing its operands
#: first (its "small matrix" kernels, SkylakeX and later); the LSTM input projections of one
#: window (M = m rows) are cut into column blocks that fit (layers.fuse_bilstm)
SMALL_PRODUCT = 1_000_000

#: and the blocks are at most this many columns wide: then each block's rows are 4 cache lines
#: and the small kernel streams the weights from memory at about twice the rate it reaches on
#: wider blocks (measured one thread, weights not in cache, 4 rows: 1024 x 2048 818 -> 426 us,
#: 512 x 2048 488 -> 210 us, 128 x 4096 264 -> 149 us; in cache no slower)
BLOCK_COLUMNS = 64

_LOCK = threading.Lock()
_STATE: dict[str, Any] = {"controllers": None, "modules": 0, "depth": 0, "saved": []}


def cpu_count() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _controllers() -> list[Any]:
    """threadpoolctl's controllers of the loaded BLAS libraries, cached, and found again
    (outside any :func:`one_thread` block) whenever modules were imported since the last look:
    an import may load another BLAS, as numba does with SciPy's, which the thread limits must
    cover too. In a steady state this is one ``len(sys.modules)``."""
    n = len(sys.modules)
    if _STATE["controllers"] is None or (_STATE["modules"] != n and _STATE["depth"] == 0):
        try:
            from threadpoolctl import ThreadpoolController
            ctl = ThreadpoolController()
            _STATE["controllers"] = [c for c in ctl.lib_controllers if c.user_api == "blas"]
        except Exception:   # threadpoolctl missing or unable to inspect: leave the BLAS alone
            _STATE["controllers"] = []
        _STATE["modules"] = len(sys.modules)
    return _STATE["controllers"]


def _set_threads(ctl: Any, n: int) -> None:
    """Set a BLAS library's thread count from whichever thread calls. threadpoolctl (3.x)
    lets only the first Python thread that set OpenBLAS's count (while it lives) change it and
    silently ignores the others, so a prediction called from a worker thread left the
    split-batch pool's products on two threads: 27 of 96 calls from 8 threads differed from
    the serial bits by up to 1e-5 (issue 37, tests/test_concurrency.py). OpenBLAS's own setter
    is process-wide, and :func:`one_thread` serialises every change under its lock."""
    getattr(ctl, "_real_set_num_threads", ctl.set_num_threads)(n)


@contextlib.contextmanager
def one_thread() -> Iterator[None]:
    """A one-thread BLAS inside the block (process-wide; the previous thread counts come back
    when the last of any nested or concurrent blocks ends). About 1 us per block."""
    ctls = _controllers()
    with _LOCK:
        if _STATE["depth"] == 0:
            _STATE["saved"] = [c.get_num_threads() for c in ctls]
            for c in ctls:
                _set_threads(c, 1)
        _STATE["depth"] += 1
    try:
        yield
    finally:
        with _LOCK:
            _STATE["depth"] -= 1
            if _STATE["depth"] == 0:
                for c, n in zip(ctls, _STATE["saved"]):
                    _set_threads(c, n)


def in_one_thread() -> bool:
    """Whether the calling code runs inside a :func:`one_thread` block (the numba engine then
    runs its serial kernels too; outside, its directions in parallel)."""
    return _STATE["depth"] > 0


#: :class:`ThreadPolicy`: every this many calls of one kind, the choice not currently preferred
PROBE_EVERY = 8
#: :class:`ThreadPolicy`: latencies kept per choice (their median decides)
KEEP = 4
#: :class:`ThreadPolicy`: the two-thread plan runs only when its median latency is this much
#: below one thread's (beside a busy core a second thread can take twice as long or more)
MARGIN = 0.1

_LOCAL = threading.local()


def two_threads() -> bool:
    """Whether the work the calling thread runs now may take a second thread: True only inside a
    :class:`ThreadPolicy` block that chose the two-thread plan."""
    return getattr(_LOCAL, "two", False)


def _fixed_choice() -> int | None:
    """``TPNET_THREADS=1`` (or the older ``TPNET_BLAS_THREADS=1``) fixes the one-thread plan,
    ``=2`` / ``=all`` the two-thread plan; None: measure."""
    fixed = os.environ.get("TPNET_THREADS", os.environ.get("TPNET_BLAS_THREADS"))
    return {"1": 1, "2": 0, "all": 0}.get(fixed or "")


#: :class:`CoreMonitor`: seconds between two looks at /proc/stat (jiffies are 10 ms, so a
#: shorter window could not tell a spinning core from noise)
SAMPLE_S = 0.05
#: :class:`CoreMonitor`: the other core counts as taken above this many cores' worth of other
#: processes' time at normal priority, and as free again below the second figure (hysteresis)
TAKEN_CORES, FREE_CORES = 0.6, 0.35


def _read_proc_stat() -> tuple[float, float] | None:
    """Seconds all cores spent busy at normal priority (user, system, irq, softirq, steal) and at
    a lower one (nice), from the first line of /proc/stat; None where there is none."""
    try:
        with open("/proc/stat", "rb") as f:
            v = f.readline().split()
    except OSError:
        return None
    if len(v) < 9 or v[0] != b"cpu":
        return None
    user, nice, system, _idle, _io, irq, softirq, steal = (int(x) for x in v[1:9])
    tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    return (user + system + irq + softirq + steal) / tick, nice / tick


def _nice_counts() -> bool:
    """Whether niced processes take cores from this one: when it is niced itself, or when Linux
    groups processes by session (``sched_autogroup_enabled``), where nice only orders the
    processes of one session and another session's ``nice 19`` job gets its share all the same."""
    if hasattr(os, "nice") and os.nice(0) > 0:
        return True
    try:
        with open("/proc/sys/kernel/sched_autogroup_enabled", "rb") as f:
            return f.read().strip() == b"1"
    except OSError:
        return False


class CoreMonitor:
    """How many cores other processes take now, from /proc/stat, read at most every
    :data:`SAMPLE_S` seconds (one ``time.monotonic()`` per call in between; the read itself is
    about 20 us). Other processes' time at normal priority is the busy time of all cores less
    this process's own (``os.times``); time of niced processes (a background job at ``nice 19``)
    does not count, since they yield the core to this one -- unless this process is niced itself
    or the kernel groups processes by session (autogroup), where they do not yield
    (:func:`_nice_counts`; ``count_nice`` overrides).
    :meth:`taken` says whether fewer than two cores are free for a call's two threads;
    :attr:`generation` counts the changes, so that a policy can drop latencies measured before
    one. Where /proc/stat cannot be read it says "free" and never changes."""

    def __init__(self, read: Any = _read_proc_stat, clock: Any = time.monotonic,
                 own: Any = None, sample_s: float = SAMPLE_S,
                 count_nice: bool | None = None) -> None:
        self._read, self._clock, self.sample_s = read, clock, sample_s
        self._own = own or (lambda: sum(os.times()[:2]))
        self._niced = _nice_counts() if count_nice is None else bool(count_nice)
        self._last: tuple[float, float, float] | None = None
        self._lock = threading.Lock()
        self.others = 0.0        #: other processes' cores, over the last window
        self.is_taken = False
        self.generation = 0

    def taken(self) -> bool:
        """Whether other processes take so much of the machine that a second thread would wait
        (looked at again when :data:`SAMPLE_S` has passed since the last look)."""
        now = self._clock()
        last = self._last
        if last is not None and now - last[0] < self.sample_s:
            return self.is_taken
        with self._lock:
            if self._last is not last:                  # another thread looked meanwhile
                return self.is_taken
            stat = self._read()
            if stat is None:
                self._last = (now, 0.0, 0.0)
                return self.is_taken
            busy = stat[0] + (stat[1] if self._niced else 0.0)
            own = self._own()
            if last is not None and now > last[0]:
                self.others = max(0.0, (busy - last[1]) - (own - last[2])) / (now - last[0])
                free = cpu_count() - self.others
                taken = free < 2 - TAKEN_CORES if not self.is_taken else free < 2 - FREE_CORES
                if taken != self.is_taken:
                    self.is_taken, self.generation = taken, self.generation + 1
            self._last = (now, busy, own)
            return self.is_taken


class ThreadPolicy:
    """Runs each call of a kind on one thread or with a second thread for the parts that may
    take one (:func:`two_threads`), whichever its recent calls of that kind measured faster. The
    two plans give the same bits, and both run every BLAS product on one thread
    (:func:`one_thread`): the policy changes speed, never a result.

    Per kind (any hashable, e.g. ``("predict", dtype, points)``) it keeps the last :data:`KEEP`
    latencies of each choice; it runs two threads when their median is at least :data:`MARGIN`
    below one thread's, else one thread, and every :data:`PROBE_EVERY` calls the other choice
    (probes of two threads less often while they do not win by the margin; each such probe is
    two calls, the first, which wakes the second thread, not measured), so a change of load
    (another process taking a core, then leaving) moves the choice. Nested inside another
    :func:`one_thread` block (a chunk of a split batch, a caller's block) or on one core it runs
    one thread and measures nothing. ``TPNET_THREADS=1`` or ``=2`` fixes the choice.

    ``monitor`` (a :class:`CoreMonitor`; the process-wide :data:`adaptive` has one): while it
    sees the other core taken by another process, every call runs one thread without a probe;
    when it sees the machine change (taken, or free again), the latencies measured before are
    dropped, so the next few calls measure both plans afresh instead of trusting minutes-old
    figures. Thread-safe; about 2 us per call.
    """

    def __init__(self, probe_every: int = PROBE_EVERY, keep: int = KEEP,
                 margin: float = MARGIN, monitor: CoreMonitor | None = None) -> None:
        self.probe_every, self.keep, self.margin = probe_every, keep, margin
        self.monitor = monitor
        # per kind: the latencies of each choice, [calls, calls between probes, probing now,
        # a two-thread probe's call due after its warm-up, this call is a warm-up]
        self._kinds: dict[Hashable, tuple[dict[int, deque], list[int]]] = {}
        self._lock = threading.Lock()
        self._generation = 0

    @staticmethod
    def _median(t: deque) -> float:
        return sorted(t)[len(t) // 2]

    def _best(self, times: dict[int, deque]) -> int:
        return 0 if self._median(times[0]) < (1 - self.margin) * self._median(times[1]) else 1

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
            if kind not in self._kinds and len(self._kinds) >= 256:
                self._kinds.clear()                 # many kinds (ragged windows): start over
            times, st = self._kinds.setdefault(
                kind, ({1: deque(maxlen=self.keep), 0: deque(maxlen=self.keep)},
                       [0, self.probe_every, 0, 0, 0]))
            for c in (1, 0):                        # first fill both with a few samples
                if len(times[c]) < 2:
                    return c
            st[0] += 1
            if st[3]:                               # the probe after its warm-up call
                st[2:5] = [1, 0, 0]
                return 0
            best = self._best(times)
            st[2] = int(st[0] % st[1] == 0)
            if st[2] and best == 1:
                # a probe of two threads after a run of one-thread calls: the second thread's
                # workers have gone to sleep, and waking them costs the first call ~25 %
                # (measured: 1.43 against 1.15 ms warm on this 2-core VM), which would make
                # two threads look slower than they are. That call is not recorded; the next
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

    def preferred(self, kind: Hashable) -> int | None:
        """The choice (1 or 0) the recent calls of ``kind`` measured faster; None before any."""
        with self._lock:
            if kind not in self._kinds:
                return None
            times = self._kinds[kind][0]
            if not (times[0] and times[1]):
                return None
            return self._best(times)

    @contextlib.contextmanager
    def __call__(self, kind: Hashable, held: bool = False) -> Iterator[int]:
        """Run the block with a one-thread BLAS and the chosen plan (:func:`two_threads` tells
        the block); yields the choice (1, 0, or -1 when the policy stands aside: nested in
        another :func:`one_thread` block, or one core) and records the block's latency.
        ``held``: the caller holds a :func:`one_thread` block of its own around many such
        blocks (a rollout's steps, ~30 us each saved) and was not itself nested in one when it
        took it: the policy chooses all the same."""
        if (in_one_thread() and not held) or cpu_count() < 2:
            with one_thread():
                yield -1
            return
        choice = self.choose(kind)
        t = time.perf_counter()
        _LOCAL.two = choice == 0
        try:
            if held:
                yield choice
            else:
                with one_thread():
                    yield choice
        finally:
            _LOCAL.two = False
        self.record(kind, choice, time.perf_counter() - t)


#: the process-wide policy :mod:`tpnet_ref.model` runs the Numba engine's single windows under;
#: it watches the other cores (:class:`CoreMonitor`)
adaptive = ThreadPolicy(monitor=CoreMonitor())



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

def describe() -> str:
    """The BLAS NumPy uses, its kernel and threads (threadpoolctl's view), one line."""
    try:
        from threadpoolctl import threadpool_info
        info = [d for d in threadpool_info() if d.get("user_api") == "blas"]
    except ImportError:
        return "threadpoolctl not installed"
    return "; ".join(f"{d.get('internal_api')} {d.get('version')} kernel "
                     f"{d.get('architecture')} threads {d.get('num_threads')}" for d in info)


__all__ = ["SMALL_PRODUCT", "BLOCK_COLUMNS", "one_thread", "in_one_thread", "two_threads",
           "ThreadPolicy", "CoreMonitor", "adaptive", "PROBE_EVERY", "cpu_count", "describe"]
