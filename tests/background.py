"""Tests whose work runs in other processes start it when the session starts, beside the rest.

The suite runs in one process, on one core; a test that only waits for child processes (a
training script end to end, kernels compiled in an empty cache) leaves the second core idle for
minutes. Such a test hands its work to :func:`early`: ``tests/conftest.py`` starts every
selected test's job, one after another in a background thread, when collection ends (after the
second lane's child, ``tests/lane.py``, where there is one), and the test itself waits for its
job and asserts on what it returns. An exception inside the job (a failed ``assert`` included)
fails the test with the job's traceback.

A job gets a fresh folder of its own and nothing else (no fixtures: they are the main thread's).
It must not share a Numba cache with the test process: two processes compiling different
signatures of one function into one cache can give both the same cache file name (numba's
``IndexDataCacheFile.save``), so a job's child processes set ``NUMBA_CACHE_DIR`` under that
folder (:func:`private_cache`, or :func:`seeded_cache` to start from a copy of this
process's). The jobs run one at a time, so the session holds at most one more process tree
than before.
"""
from __future__ import annotations

import os
import shutil
from concurrent.futures import Future, ThreadPoolExecutor, wait
from pathlib import Path
from typing import Callable

import pytest

Job = Callable[[Path], object]

#: test node id -> its job's future, filled when collection ends
FUTURES: dict[str, Future] = {}
_POOL: list[ThreadPoolExecutor] = []


def early(job: Job):
    """Mark a test whose work is ``job(folder)``: started when the session starts; the test
    reads the job's return value from the ``early_result`` fixture."""
    return pytest.mark.early.with_args(job)    # a lone callable would be decorated instead


def private_cache(folder: Path, env: dict | None = None) -> dict:
    """``env`` (default: this process's) with ``NUMBA_CACHE_DIR`` in ``folder``."""
    return {**(os.environ if env is None else env), "NUMBA_CACHE_DIR": str(folder / "numba-cache")}


def seeded_cache(folder: Path, env: dict | None = None) -> dict:
    """:func:`private_cache`, holding a copy of the package's kernels in this process's Numba
    cache as it is now: a child loads what this process compiled before it started instead of
    compiling it again (a copy, not a share: the two then write to caches of their own)."""
    env = private_cache(folder, env)
    copy_numba_cache(Path(env["NUMBA_CACHE_DIR"]))
    return env


def copy_numba_cache(dest: Path) -> None:
    """Copy the index and data files of this process's Numba cache for ``tpnet_ref``'s modules
    (``NUMBA_CACHE_DIR``'s, or the package's ``__pycache__`` folders) into the cache folder
    ``dest``, laid out as numba lays out a ``NUMBA_CACHE_DIR``. A file
    written meanwhile is copied whole or not at all (numba replaces its files atomically); an
    index naming a data file not copied makes numba compile that signature again."""
    from numba.core.caching import UserProvidedCacheLocator
    import tpnet_ref
    own = os.environ.get("NUMBA_CACHE_DIR")
    for init in Path(tpnet_ref.__file__).parent.rglob("__init__.py"):
        sub = UserProvidedCacheLocator.get_suitable_cache_subpath(str(init))
        src = Path(own) / sub if own else init.parent / "__pycache__"
        if not src.is_dir():
            continue
        names = sorted(src.glob("*.nbi")) + sorted(src.glob("*.nbc"))   # indexes first
        if names:
            (dest / sub).mkdir(parents=True, exist_ok=True)
        for path in names:
            try:
                shutil.copy2(path, dest / sub / path.name)
            except FileNotFoundError:                   # replaced meanwhile
                pass


def start(items, folder_for: Callable[[str], Path], after: Future | None = None) -> int:
    """Submit the job of every item marked :func:`early`, in the items' order, once ``after``
    (the second lane's run, ``tests/lane.py``) ended; returns how many."""
    jobs = [(item.nodeid, m.args[0]) for item in items
            if (m := item.get_closest_marker("early")) is not None]
    if not jobs:
        return 0
    pool = ThreadPoolExecutor(1, thread_name_prefix="early-job")
    _POOL.append(pool)
    if after is not None:
        pool.submit(wait, [after])
    for nodeid, job in jobs:
        FUTURES[nodeid] = pool.submit(job, folder_for(nodeid))
    return len(jobs)


def stop() -> None:
    """Drop the jobs not started yet; wait for the one running (its children have timeouts)."""
    for pool in _POOL:
        pool.shutdown(wait=True, cancel_futures=True)
    _POOL.clear()
    FUTURES.clear()
