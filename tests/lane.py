"""A second lane: the tests marked ``lane`` run in child pytests, beside this one.

The suite's test process runs on one core. Much of its time is Numba compiling kernels that only
some tests use (bf16 and int8 weights, 3-D networks), so those tests (a module's ``pytestmark =
pytest.mark.lane("group")``, or a test's or a parameter's mark) run in child pytests on the
second core, one per group and one after another (a child holds what it compiled, 1-1.5 GB:
two at once would double that), each with a Numba cache of its own that starts as a copy of
this process's (``background.seeded_cache``: what this process compiled before the child
started, the child loads). ``tests/conftest.py`` starts
them when collection ends, in a thread of their own (the early jobs of ``tests/background.py``
start when they ended). It puts the lane's tests after all the others but the late ones, and the
early jobs' tests just before them. When the test process reaches the lane's tests it waits for
the children and reports each test's result as its child wrote it (the reports pytest itself
serialises, as pytest-xdist sends them): passes, failures with their tracebacks, skips and
xfails appear as if run here.

A child writes one report per line to the file named in ``TPNET_TEST_LANE`` and runs only the
node ids listed in ``TPNET_TEST_LANE_IDS``. A test a child left without a report (it crashed, or
was stopped) runs in this process instead. ``TPNET_TEST_LANE=off`` runs everything here; so does
a machine of one CPU, or a selection that is all lane or has no lane test.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import background

REPORTS_ENV, IDS_ENV = "TPNET_TEST_LANE", "TPNET_TEST_LANE_IDS"
#: the child's wall-clock limit (s); past it the child is stopped and its tests run here
TIMEOUT_S = 3600


def in_child() -> bool:
    return os.environ.get(REPORTS_ENV, "off") != "off"


def wanted(items) -> bool:
    """Whether this process hands the ``lane`` tests among ``items`` to a child."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    if REPORTS_ENV in os.environ or (cpus or 1) < 2:      # "off", or this is a child
        return False
    marked = sum(item.get_closest_marker("lane") is not None for item in items)
    return 0 < marked < len(items)


def keep_listed(config, items) -> None:
    """In the child: drop the items not listed in ``TPNET_TEST_LANE_IDS``."""
    ids = set(Path(os.environ[IDS_ENV]).read_text().splitlines())
    dropped = [item for item in items if item.nodeid not in ids]
    if dropped:
        items[:] = [item for item in items if item.nodeid in ids]
        config.hook.pytest_deselected(items=dropped)


def write_report(config, report) -> None:
    """In the child: one test report, serialised, appended to the lane's file."""
    data = config.hook.pytest_report_to_serializable(config=config, report=report)
    with open(os.environ[REPORTS_ENV], "a") as f:
        f.write(json.dumps(data) + "\n")


def write_peak(peak_bytes: int) -> None:
    with open(os.environ[REPORTS_ENV], "a") as f:
        f.write(json.dumps({"lane_peak_bytes": peak_bytes}) + "\n")


def group(item) -> str:
    """The child a ``lane`` test runs in: ``pytest.mark.lane("name")``'s name."""
    mark = item.get_closest_marker("lane")
    return mark.args[0] if mark.args else "lane"


class Lane:
    """The child pytests of the ``lane`` tests, one per group (:func:`group`), one after another
    (so that one child's compiled kernels are held at a time): started by :meth:`start`, their
    reports by node id from :meth:`reports_for` once the last ended."""

    def __init__(self, items, rootdir: Path, folder: Path):
        self.groups: dict[str, list[str]] = {}
        for item in items:
            self.groups.setdefault(group(item), []).append(item.nodeid)
        self.rootdir, self.folder = rootdir, folder
        self.proc: subprocess.Popen | None = None
        self.future: Future | None = None
        self.status: dict[str, int] = {}        # group -> its child's exit status
        self.took: dict[str, float] = {}        # group -> its child's wall-clock seconds
        self.peak_bytes = 0                     # the largest child's peak
        self.waited_s = 0.0             # how long this process waited for the children's end
        self._reports: dict[str, list[dict]] = {}
        self._stopped = False

    def start(self) -> None:
        pool = ThreadPoolExecutor(1, thread_name_prefix="lane")
        self.future = pool.submit(self._run)
        pool.shutdown(wait=False)

    def _run(self) -> None:
        for name, nodeids in self.groups.items():
            if not self._stopped:
                self._run_child(name, nodeids)

    def _run_child(self, name: str, nodeids: list[str]) -> None:
        folder = self.folder / name
        folder.mkdir()
        ids, out = folder / "ids.txt", folder / "reports.jsonl"
        ids.write_text("\n".join(nodeids) + "\n")
        env = background.seeded_cache(folder, {**os.environ, REPORTS_ENV: str(out),
                                                IDS_ENV: str(ids)})
        files = sorted({nodeid.split("::")[0] for nodeid in nodeids})
        cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *files]
        t0 = time.perf_counter()
        with open(folder / "output.txt", "w") as log:
            self.proc = subprocess.Popen(cmd, cwd=self.rootdir, env=env, stdout=log,
                                         stderr=subprocess.STDOUT)
            try:
                self.status[name] = self.proc.wait(timeout=TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.status[name] = self.proc.wait()
        self.took[name] = time.perf_counter() - t0
        if out.exists():
            for line in out.read_text().splitlines():
                data = json.loads(line)
                if "lane_peak_bytes" in data:
                    self.peak_bytes = max(self.peak_bytes, data["lane_peak_bytes"])
                else:
                    self._reports.setdefault(data["nodeid"], []).append(data)

    def reports_for(self, nodeid: str) -> list[dict]:
        """The child's reports of one test (setup, call, teardown), after the child ended;
        empty when it left the test without a teardown's report."""
        if not self.future.done():
            t0 = time.perf_counter()
            self.future.result()
            self.waited_s += time.perf_counter() - t0
        reports = self._reports.get(nodeid, [])
        return reports if any(r.get("when") == "teardown" for r in reports) else []

    def stop(self) -> None:
        """End the children (this process stopped first)."""
        self._stopped = True
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()

    def summary(self) -> str:
        every = [nodeid for nodeids in self.groups.values() for nodeid in nodeids]
        ran_here = sum(not self.reports_for(nodeid) for nodeid in every)
        return (f"second lane: {len(every)} tests in child pytests one after another ("
                + ", ".join(f"{name}: {len(ids)} tests in {self.took.get(name, 0):.0f} s, exit"
                            f" status {self.status.get(name)}" for name, ids in self.groups.items())
                + f"; the largest child's peak resident memory {self.peak_bytes / 2**30:.2f} GB;"
                f" this process waited {self.waited_s:.0f} s for them)"
                + (f"; {ran_here} of them ran here instead" if ran_here else ""))


def replay(item, reports: list[dict]) -> None:
    """Report ``item``'s results as the child serialised them, through this session's hooks."""
    hook, ihook = item.config.hook, item.ihook
    ihook.pytest_runtest_logstart(nodeid=item.nodeid, location=item.location)
    for data in reports:
        if isinstance(data.get("longrepr"), list):     # a skip's (path, line, reason): JSON
            data = {**data, "longrepr": tuple(data["longrepr"])}    # gave a list back
        ihook.pytest_runtest_logreport(
            report=hook.pytest_report_from_serializable(config=item.config, data=data))
    ihook.pytest_runtest_logfinish(nodeid=item.nodeid, location=item.location)
