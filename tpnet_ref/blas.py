"""The BLAS under NumPy, seen from tpnet_ref: its threads, and which product shapes it runs fast.

- Threads. One window (or a small batch) runs with a one-thread BLAS (:func:`one_thread`): the
  products of one window are too small to gain from a second thread, and a BLAS thread that
  shares its core with another busy process makes every product wait for it (measured in
  ``docs/performance.md``: with the other core busy a two-thread BLAS made one prediction 3x
  slower). A large batch is split across threads, each with a one-thread BLAS, so NumPy's
  element-wise work uses every core too. Both go through threadpoolctl; without it the BLAS
  keeps its threads.
- Small products. :func:`small_products_pay` measures once per process whether the BLAS runs a
  small product (``M*N*K <=`` :data:`SMALL_PRODUCT`) much faster than the same columns in one
  large product, as OpenBLAS's unpacked small-matrix kernels (SkylakeX and later) do.
- :func:`describe` names the BLAS, its kernel and threads for benchmark reports: OpenBLAS picks
  its kernel when NumPy is imported, from the CPU or from ``OPENBLAS_CORETYPE``.
"""
from __future__ import annotations

import contextlib
import os
import threading
import time
from typing import Any, Iterator

import numpy as np

#: OpenBLAS multiplies a product of M*N*K <= 1e6 multiply-adds without packing its operands
#: first (its "small matrix" kernels, SkylakeX and later); the LSTM input projections of one
#: window (M = m rows) are cut into column blocks that fit (layers.fuse_bilstm)
SMALL_PRODUCT = 1_000_000

_LOCK = threading.Lock()
_STATE: dict[str, Any] = {"controllers": None, "depth": 0, "saved": []}
_SMALL: dict[str, bool] = {}


def cpu_count() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _controllers() -> list[Any]:
    """threadpoolctl's controllers of the loaded BLAS libraries (found once, cached)."""
    if _STATE["controllers"] is None:
        try:
            from threadpoolctl import ThreadpoolController
            ctl = ThreadpoolController()
            _STATE["controllers"] = [c for c in ctl.lib_controllers if c.user_api == "blas"]
        except Exception:   # threadpoolctl missing or unable to inspect: leave the BLAS alone
            _STATE["controllers"] = []
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


#: the name under which earlier versions offered :func:`one_thread`
single_threaded = one_thread


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
        nb = 2048
        while 4 * 512 * nb > SMALL_PRODUCT:
            nb //= 2
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


__all__ = ["SMALL_PRODUCT", "one_thread", "single_threaded", "small_products_pay", "cpu_count",
           "describe"]
