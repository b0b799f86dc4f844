"""The BLAS under NumPy, seen from tpnet_ref: its threads, and which product shapes it runs fast.

- Threads. A single window runs under :class:`ThreadPolicy` (:func:`adaptive`): on an idle
  machine the BLAS's own threads make one prediction about 25 % faster (its weight-streaming
  products use both cores' bandwidth), but a BLAS thread that shares its core with another busy
  process makes every product wait for it (a two-thread BLAS made one prediction 3x slower).
  So the policy measures: it keeps the latest latencies of each choice, runs the faster one and
  tries the other every :data:`PROBE_EVERY` calls. The BLAS's thread count does not change a
  single window's result (``tests/test_blas.py`` compares them bit for bit). A small batch
  runs with a one-thread BLAS (:func:`one_thread`); a large batch is split across threads, each
  with a one-thread BLAS, so NumPy's element-wise work uses every core too. All go through
  threadpoolctl; without it the BLAS keeps its threads.
- Small products. :func:`small_products_pay` measures once per process whether the BLAS runs a
  small product (``M*N*K <=`` :data:`SMALL_PRODUCT`) much faster than the same columns in one
  large product, as OpenBLAS's unpacked small-matrix kernels (SkylakeX and later) do.
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

import numpy as np

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
_SMALL: dict[str, bool] = {}


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


@contextlib.contextmanager
def one_thread() -> Iterator[None]:
    """A one-thread BLAS inside the block (process-wide; the previous thread counts come back
    when the last of any nested or concurrent blocks ends). About 1 us per block."""
    ctls = _controllers()
    with _LOCK:
        if _STATE["depth"] == 0:
            _STATE["saved"] = [c.get_num_threads() for c in ctls]
            for c in ctls:
                c.set_num_threads(1)
        _STATE["depth"] += 1
    try:
        yield
    finally:
        with _LOCK:
            _STATE["depth"] -= 1
            if _STATE["depth"] == 0:
                for c, n in zip(ctls, _STATE["saved"]):
                    c.set_num_threads(n)


def in_one_thread() -> bool:
    """Whether the calling code runs inside a :func:`one_thread` block (the numba engine then
    runs its serial kernels too; outside, its directions in parallel)."""
    return _STATE["depth"] > 0


#: :class:`ThreadPolicy`: every this many calls of one kind, the choice not currently preferred
PROBE_EVERY = 8
#: :class:`ThreadPolicy`: latencies kept per choice (their median decides)
KEEP = 4
#: :class:`ThreadPolicy`: the BLAS's own threads run only when their median latency is this much
#: below one thread's (a two-thread BLAS beside a busy core can take twice as long or more, and
#: after each two-thread call its worker spins for a while, slowing what runs beside it)
MARGIN = 0.1


class ThreadPolicy:
    """Runs each call of a kind with a one-thread BLAS or with the BLAS's own threads, whichever
    its recent calls of that kind measured faster.

    Per kind (any hashable, e.g. ``("predict", dtype, points)``) it keeps the last :data:`KEEP`
    latencies of each choice; it runs the BLAS's own threads when their median is at least
    :data:`MARGIN` below one thread's, else one thread, and every :data:`PROBE_EVERY` calls the
    other choice (probes of the BLAS's threads less often while they do not win by the margin),
    so a change of load (another process taking a core, then leaving) moves the choice. Inside an
    enclosing :func:`one_thread` block, or when the BLAS has one thread anyway, it changes
    nothing. ``TPNET_BLAS_THREADS=1``
    or ``=all`` fixes the choice. Thread-safe; about 2 us per call.
    """

    def __init__(self, probe_every: int = PROBE_EVERY, keep: int = KEEP,
                 margin: float = MARGIN) -> None:
        self.probe_every, self.keep, self.margin = probe_every, keep, margin
        # per kind: the latencies of each choice, [calls, calls between probes, probing now]
        self._kinds: dict[Hashable, tuple[dict[int, deque], list[int]]] = {}
        self._lock = threading.Lock()

    @staticmethod
    def _median(t: deque) -> float:
        return sorted(t)[len(t) // 2]

    def _best(self, times: dict[int, deque]) -> int:
        return 0 if self._median(times[0]) < (1 - self.margin) * self._median(times[1]) else 1

    def choose(self, kind: Hashable) -> int:
        """1 (one thread) or 0 (the BLAS's own threads) for the next call of ``kind``."""
        fixed = os.environ.get("TPNET_BLAS_THREADS")
        if fixed == "1":
            return 1
        if fixed == "all":
            return 0
        with self._lock:
            if kind not in self._kinds and len(self._kinds) >= 256:
                self._kinds.clear()                 # many kinds (ragged windows): start over
            times, st = self._kinds.setdefault(
                kind, ({1: deque(maxlen=self.keep), 0: deque(maxlen=self.keep)},
                       [0, self.probe_every, 0]))
            for c in (1, 0):                        # first fill both with a few samples
                if len(times[c]) < 2:
                    return c
            st[0] += 1
            best = self._best(times)
            st[2] = int(st[0] % st[1] == 0)
            return 1 - best if st[2] else best

    def record(self, kind: Hashable, choice: int, seconds: float) -> None:
        """Keep one measured latency of ``choice`` for ``kind``. A probe of the BLAS's threads
        that does not win by the margin doubles the calls until the next probe (up to 1024: a
        two-thread BLAS beside a busy core can take 10x as long, so losing probes must get rare);
        any other probe resets it."""
        with self._lock:
            if kind not in self._kinds:
                return
            times, st = self._kinds[kind]
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
    def __call__(self, kind: Hashable) -> Iterator[int]:
        """Run the block with the chosen thread count; yields the choice (1, 0, or -1 when the
        policy stands aside) and records the block's latency."""
        ctls = _controllers()
        with _LOCK:
            active = _STATE["depth"] == 0 and any(c.get_num_threads() > 1 for c in ctls)
        if not active:
            yield -1
            return
        choice = self.choose(kind)
        t = time.perf_counter()
        if choice == 1:
            with one_thread():
                yield 1
        else:
            yield 0
        self.record(kind, choice, time.perf_counter() - t)


#: the process-wide policy :mod:`tpnet_ref.model` runs single windows under
adaptive = ThreadPolicy()


def small_products_pay(dtype: Any = np.float32) -> bool:
    """Whether a product of 4 rows runs clearly faster (< 0.8x the time) as column blocks of
    at most :data:`SMALL_PRODUCT` multiply-adds each than as one product, measured once per
    process and dtype on a 512 x 2048 matrix (about 10 ms). ``TPNET_SMALL_PRODUCTS=0`` or ``1``
    decides without measuring. Both ways give the same products up to rounding."""
    name = np.dtype(dtype).name
    env = os.environ.get("TPNET_SMALL_PRODUCTS")
    if env in ("0", "1"):
        return env == "1"
    if name not in _SMALL:
        rng = np.random.default_rng(0)
        k = rng.standard_normal((512, 2048)).astype(dtype)
        nb = BLOCK_COLUMNS
        blocks = np.ascontiguousarray(k.reshape(512, -1, nb).transpose(1, 0, 2))
        x = rng.standard_normal((4, 512)).astype(dtype)
        full, small = [], []
        with one_thread():
            for _ in range(8):
                t = time.perf_counter()
                x @ k
                full.append(time.perf_counter() - t)
                t = time.perf_counter()
                np.matmul(x, blocks)
                small.append(time.perf_counter() - t)
        _SMALL[name] = float(np.median(small[2:])) < 0.8 * float(np.median(full[2:]))
    return _SMALL[name]


def describe() -> str:
    """The BLAS NumPy uses, its kernel and threads (threadpoolctl's view), one line."""
    try:
        from threadpoolctl import threadpool_info
        info = [d for d in threadpool_info() if d.get("user_api") == "blas"]
    except ImportError:
        return "threadpoolctl not installed"
    return "; ".join(f"{d.get('internal_api')} {d.get('version')} kernel "
                     f"{d.get('architecture')} threads {d.get('num_threads')}" for d in info)


__all__ = ["SMALL_PRODUCT", "BLOCK_COLUMNS", "one_thread", "in_one_thread",
           "ThreadPolicy", "adaptive", "PROBE_EVERY", "small_products_pay", "cpu_count", "describe"]
