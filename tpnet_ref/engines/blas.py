"""The BLAS under NumPy, seen from tpnet_ref: always one thread, and which product shapes it runs fast.

- Determinism. A multi-threaded BLAS cuts a product differently for different thread counts,
  and some kernels (OpenBLAS's Haswell kernel) then round it differently: a policy that
  switched the BLAS between one and two threads would switch the bits of a result. So every
  product the model computes runs on a one-thread
  BLAS (:func:`one_thread`), and the work is cut into BLAS calls by the input's shapes alone
  (a large batch in chunks of a fixed number of windows,
  :data:`tpnet_ref.engines.batch_split.SPLIT_CHUNK`). Threads only schedule calls that are
  fixed beforehand, so no thread count, load or policy can change a bit
  (docs/architecture.md, "Determinism").
- The second core: :mod:`tpnet_ref.engines.thread_policy` (which plan a call runs) and
  :mod:`tpnet_ref.engines.load_monitor` (whether other processes take the other core).
- Small products. The LSTMs' input projections are computed as a stack of column blocks of at
  most :data:`SMALL_PRODUCT` multiply-adds each, always: OpenBLAS multiplies such blocks without
  packing them first (SkylakeX and later) and they are no slower elsewhere. No timing chooses
  it: whatever decides how the work is cut decides its rounding, and a timing would differ
  between processes.
- :func:`describe` names the BLAS, its kernel and threads for benchmark reports: OpenBLAS picks
  its kernel when NumPy is imported, from the CPU or from ``OPENBLAS_CORETYPE``.
"""
from __future__ import annotations

import os
import sys
import threading
import time
from typing import Any

#: OpenBLAS multiplies a product of M*N*K <= 1e6 multiply-adds without packing its operands
#: first (its "small matrix" kernels, SkylakeX and later); the LSTM input projections of one
#: window (M = m rows) are cut into column blocks that fit (layers.fuse_bilstm)
SMALL_PRODUCT = 1_000_000

#: and the blocks are at most this many columns wide: then each block's rows are 4 cache lines
#: and the small kernel streams the weights from memory at about twice the rate it reaches on
#: wider blocks (weights not in cache; in cache no slower)
BLOCK_COLUMNS = 64

_LOCK = threading.Lock()
_STATE: dict[str, Any] = {"controllers": None, "modules": 0, "depth": 0, "saved": [],
                          "calls": {}}


#: :func:`cpu_count`: seconds its answer is kept (the affinity rarely changes; reading it is
#: half a microsecond, a share of a small network's call)
CPU_COUNT_KEEP_S = 1.0
_CPUS = [-CPU_COUNT_KEEP_S, 1]               # when last read (time.monotonic), the count


def cpu_count() -> int:
    """Cores this process may run on (read at most every :data:`CPU_COUNT_KEEP_S` seconds)."""
    now = time.monotonic()
    if now - _CPUS[0] < CPU_COUNT_KEEP_S:
        return _CPUS[1]
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        n = os.cpu_count() or 1
    _CPUS[:] = [now, n]
    return n


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


def _calls(ctl: Any) -> tuple[Any, Any]:
    """``(get, set)`` of a controller's thread count, found once per controller: the library's
    own C functions where threadpoolctl's OpenBLAS controller names them (a ctypes call each,
    ~0.2 us, where threadpoolctl's methods look the symbol up on every call, ~1 us), else
    :meth:`get_num_threads` and :func:`_set_threads`."""
    got = _STATE["calls"].get(id(ctl))
    if got is None or got[0] is not ctl:
        get = lambda: ctl.get_num_threads()  # noqa: E731
        put = lambda n: _set_threads(ctl, n)  # noqa: E731
        try:
            omp = getattr(ctl, "threading_layer", None) == "openmp"
            g = ctl._get_symbol("omp_get_max_threads" if omp else "openblas_get_num_threads")
            p = ctl._get_symbol("omp_set_num_threads" if omp else "openblas_set_num_threads")
            if g is not None and p is not None and hasattr(ctl, "_real_set_num_threads"):
                get, put = g, p
        except Exception:   # another threadpoolctl: its public methods
            pass
        got = _STATE["calls"][id(ctl)] = (ctl, get, put)
    return got[1], got[2]


def _set_threads(ctl: Any, n: int) -> None:
    """Set a BLAS library's thread count from whichever thread calls. threadpoolctl (3.x)
    lets only the first Python thread that set OpenBLAS's count (while it lives) change it and
    silently ignores the others, so a prediction called from a worker thread would leave the
    split-batch pool's products on two threads, and their bits would differ from the serial
    ones (tests/test_concurrency.py). OpenBLAS's own setter
    is process-wide, and :func:`one_thread` serialises every change under its lock."""
    getattr(ctl, "_real_set_num_threads", ctl.set_num_threads)(n)


class one_thread:  # noqa: N801 -- used as a function: ``with one_thread():``
    """A one-thread BLAS inside the block (process-wide; the previous thread counts come back
    when the last of any nested or concurrent blocks ends). A class, not a generator: a
    prediction enters one, and a generator's block cost 3.4 us against the class's 2.6."""

    __slots__ = ("calls",)

    def __enter__(self) -> None:
        self.calls = calls = [_calls(c) for c in _controllers()]
        with _LOCK:
            if _STATE["depth"] == 0:
                _STATE["saved"] = [get() for get, _ in calls]
                for (_, put), n in zip(calls, _STATE["saved"]):
                    if n != 1:
                        put(1)
            _STATE["depth"] += 1

    def __exit__(self, *exc: Any) -> None:
        with _LOCK:
            _STATE["depth"] -= 1
            if _STATE["depth"] == 0:
                for (_, put), n in zip(self.calls, _STATE["saved"]):
                    if n != 1:
                        put(n)


def in_one_thread() -> bool:
    """Whether the calling code runs inside a :func:`one_thread` block (the numba engine then
    runs its serial kernels too; outside, its directions in parallel)."""
    return _STATE["depth"] > 0


def describe() -> str:
    """The BLAS NumPy uses, its kernel and threads (threadpoolctl's view), one line."""
    try:
        from threadpoolctl import threadpool_info
        info = [d for d in threadpool_info() if d.get("user_api") == "blas"]
    except ImportError:
        return "threadpoolctl not installed"
    return "; ".join(f"{d.get('internal_api')} {d.get('version')} kernel "
                     f"{d.get('architecture')} threads {d.get('num_threads')}" for d in info)


__all__ = ["SMALL_PRODUCT", "BLOCK_COLUMNS", "cpu_count", "one_thread", "in_one_thread",
           "describe"]
