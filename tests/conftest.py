"""Suite-wide settings: bounded hypothesis runs, a memory guard, and the order of the work.

- hypothesis: no example database written into the checkout, one bug reported per test (it then
  keeps one failing example, not one per distinct failure), and a deadline off (the first call of
  a model may compile numba kernels). Each test keeps its own ``max_examples``.
- The memory guard: a thread reads the test process's resident memory every 0.2 s; above
  ``TPNET_TEST_MAX_RSS_GB`` (default 4) it prints which test was running and ends the run with
  exit status 3 -- a runaway test fails with that line instead of taking the machine down (a
  hypothesis test that built a new 170 MB model per example kept every failing example's
  traceback, and with it the model, while shrinking: 15 GB in 50 s).
- Early jobs (``tests/background.py``): the work of tests that only wait for child processes
  starts when collection ends, in a background thread, beside the in-process tests.
- Late tests (``@pytest.mark.late``): tests whose child processes load the kernels this process
  compiled run last, when numba's on-disk cache holds them; before, each child compiled them again.
- The second lane (``tests/lane.py``): the tests marked ``lane`` run in child pytests on the
  second core, one per group; their results are reported here.
- HDF5's file locks are off (``HDF5_USE_FILE_LOCKING``): a child process forked by a background
  thread holds copies of this process's open files until it closes them, and with them the lock
  of a file a test has just written, so the test's next open of it failed now and then (errno 11).
"""
from __future__ import annotations

import os
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

os.environ["HDF5_USE_FILE_LOCKING"] = "FALSE"   # before h5py opens a file (see above)

import pytest  # noqa: E402
from hypothesis import settings  # noqa: E402

import background  # noqa: E402
import lane  # noqa: E402

settings.register_profile("tpnet", database=None, report_multiple_bugs=False, deadline=None)
settings.load_profile("tpnet")

_LIMIT_GB = float(os.environ.get("TPNET_TEST_MAX_RSS_GB", "4"))
_CURRENT = {"test": "(collection)"}
_PEAK = {"bytes": 0, "together": 0}
_LANE: list[lane.Lane] = []


def _rss_bytes(pid: int | str = "self") -> int:
    try:
        with open(f"/proc/{pid}/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, IndexError):                   # the child ended
        return 0


def _tree_rss_bytes() -> int:
    """The resident memory of this process and all its descendants (the second lane, the early
    jobs' children, the children of tests)."""
    parent = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    parent[int(entry)] = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):    # ended meanwhile
                pass
    children: dict[int, list[int]] = {}
    for pid, ppid in parent.items():
        children.setdefault(ppid, []).append(pid)
    mine, todo = [], [os.getpid()]
    while todo:
        mine.append(todo.pop())
        todo += children.get(mine[-1], [])
    return sum(_rss_bytes(pid) for pid in mine)


_TREE_LOG = os.environ.get("TPNET_TEST_TREE_LOG")


def _guard() -> None:
    limit = _LIMIT_GB * 2**30
    t0, tick = time.monotonic(), 0
    while True:
        rss = _rss_bytes()
        _PEAK["bytes"] = max(_PEAK["bytes"], rss)
        tick += 1
        if tick % 5 == 0 and not lane.in_child():   # once a second: the whole process tree
            tree = _tree_rss_bytes()
            _PEAK["together"] = max(_PEAK["together"], tree)
            if _TREE_LOG:
                with open(_TREE_LOG, "a") as f:
                    f.write(f"{time.monotonic() - t0:.0f} {rss / 2**20:.0f} {tree / 2**20:.0f} "
                            f"{_CURRENT['test']}\n")
        if rss > limit:
            sys.stderr.write(f"\nmemory guard: the test process reached {rss / 2**30:.1f} GB "
                             f"(limit {_LIMIT_GB:g} GB, TPNET_TEST_MAX_RSS_GB) while running "
                             f"{_CURRENT['test']}; stopping the run\n")
            sys.stderr.flush()
            os._exit(3)
        time.sleep(0.2)


if os.path.exists("/proc/self/statm"):
    threading.Thread(target=_guard, name="memory-guard", daemon=True).start()


@pytest.fixture(scope="session")
def released_random64():
    """A random TP-Net of the released shape in float64 (``init_random(seed=3)``), built once for
    the suite: the unit tests' reference network (tests copy it before changing anything)."""
    from tpnet_ref.model import init_random
    return init_random(seed=3, dtype="float64")


def _release_freed_memory() -> None:
    """Collect cycles and hand freed heap pages back to the OS (glibc ``malloc_trim``): the
    released-shape models a module builds are freed with it, but without the trim the process
    keeps their pages and the resident memory the guard reads only grows."""
    import ctypes
    import gc
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):               # not glibc: nothing to trim
        pass


def pytest_collection_modifyitems(config, items):
    """The tests marked ``late`` after all others, each group in its own order; with a second
    lane, its tests before the late ones and the early jobs' tests before the lane's (in the
    child: only the tests it was given)."""
    if lane.in_child():
        lane.keep_listed(config, items)
    use_lane = lane.wanted(items)

    def rank(item) -> int:
        if use_lane and item.get_closest_marker("lane") is not None:
            return 2
        if item.get_closest_marker("late") is not None:
            return 3
        return 1 if use_lane and item.get_closest_marker("early") is not None else 0
    items.sort(key=rank)                                                  # a stable sort


_EARLY_FOLDER: list = []


def pytest_collection_finish(session):
    if session.config.option.collectonly or not session.items or session.testsfailed:
        return                          # nothing will run (a collection error stops the run)
    def folder_for(nodeid: str) -> Path:
        if not _EARLY_FOLDER:
            _EARLY_FOLDER.append(Path(tempfile.mkdtemp(prefix="tpnet-early-jobs-")))
        name = nodeid.rsplit("::", 1)[-1][:40]
        return Path(tempfile.mkdtemp(prefix=f"{name}-", dir=_EARLY_FOLDER[0]))
    items = session.items
    if lane.wanted(items):
        theirs = [item for item in items if item.get_closest_marker("lane") is not None]
        _LANE.append(lane.Lane(theirs, session.config.rootpath, folder_for("second-lane")))
        items = [item for item in items if item.get_closest_marker("lane") is None]
    if _LANE:                           # the lane first: its child runs while this process is
        _LANE[0].start()                # small; the early jobs after it, before their tests
    background.start(items, folder_for, after=_LANE[0].future if _LANE else None)


def pytest_sessionfinish(session, exitstatus):
    if lane.in_child():
        lane.write_peak(_PEAK["bytes"])
    for child in _LANE:
        child.stop()
    background.stop()
    if exitstatus == 0:                 # a failed job's folder stays for a look
        for base in _EARLY_FOLDER:
            shutil.rmtree(base, ignore_errors=True)


@pytest.fixture
def early_result(request):
    """The return value of this test's early job (``tests/background.py``), once it ended."""
    future = background.FUTURES.get(request.node.nodeid)
    if future is None:
        pytest.fail("no early job started for this test (mark it with background.early)")
    return future.result()


def pytest_runtest_protocol(item, nextitem):
    _CURRENT["test"] = item.nodeid
    if _LANE and item.get_closest_marker("lane") is not None:
        reports = _LANE[0].reports_for(item.nodeid)
        if reports:                     # else the child left it: it runs here
            lane.replay(item, reports)
            return True
    return None


def pytest_runtest_logreport(report):
    if lane.in_child():
        lane.write_report(_CONFIG[0], report)


_CONFIG: list = []


def pytest_configure(config):
    _CONFIG.append(config)


@pytest.hookimpl(trylast=True)        # after pytest's own teardown has ended the module's fixtures
def pytest_runtest_teardown(item, nextitem):
    if nextitem is None or nextitem.module is not item.module:    # after each test module
        _release_freed_memory()


_RSS_LOG = os.environ.get("TPNET_TEST_RSS_LOG")


def pytest_runtest_logfinish(nodeid, location):
    """With ``TPNET_TEST_RSS_LOG=path``: each test's resident memory after it ran, one line each
    (to find which tests hold memory)."""
    if _RSS_LOG and os.path.exists("/proc/self/statm"):
        with open(_RSS_LOG, "a") as f:
            f.write(f"{_rss_bytes() / 2**20:.0f} MiB {nodeid}\n")


def pytest_terminal_summary(terminalreporter):
    if _PEAK["bytes"]:
        terminalreporter.write_line(f"peak resident memory of the test process: "
                                    f"{_PEAK['bytes'] / 2**30:.2f} GB (guard at {_LIMIT_GB:g} GB)")
    for child in _LANE:
        terminalreporter.write_line(child.summary())
    if _PEAK["together"]:
        terminalreporter.write_line(f"peak resident memory of the test process and its children "
                                    f"together: {_PEAK['together'] / 2**30:.2f} GB")
