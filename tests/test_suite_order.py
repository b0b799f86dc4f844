"""The suite's own order of work (tests/conftest.py, tests/background.py, tests/lane.py): late
tests run last, an early job's result, or its failure, reaches its test, and so do the second
lane's results."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import background
import lane


def test_late_tests_run_after_all_the_others(request):
    items = request.session.items
    if lane.wanted(items):              # the second lane's tests run in the child, with their own
        items = [item for item in items if item.get_closest_marker("lane") is None]
    marked = [i for i, item in enumerate(items) if item.get_closest_marker("late")]
    assert marked == list(range(len(items) - len(marked), len(items)))


class _Item:
    """What ``background.start`` reads of a collected test: its id and its markers."""

    def __init__(self, nodeid, job):
        self.nodeid, self._mark = nodeid, background.early(job).mark

    def get_closest_marker(self, name):
        return self._mark if name == "early" else None


def test_an_early_job_runs_in_its_own_folder_and_its_failure_reaches_the_test(tmp_path):
    def writes(folder):
        (folder / "out.txt").write_text("done")
        return folder

    def fails(folder):
        assert False, "the job's own message"

    def folder_for(nodeid):
        d = tmp_path / nodeid.replace("::", "-")
        d.mkdir()
        return d

    assert background.start([_Item("t::writes", writes), _Item("t::fails", fails)],
                            folder_for) == 2
    folder = background.FUTURES["t::writes"].result(timeout=60)
    assert folder == tmp_path / "t-writes" and (folder / "out.txt").read_text() == "done"
    with pytest.raises(AssertionError, match="the job's own message"):
        background.FUTURES["t::fails"].result(timeout=60)


def _job(folder):
    return f"from the job in {folder.name}"


@background.early(_job)
def test_a_test_marked_early_gets_its_job_s_result(early_result):
    assert early_result.startswith("from the job in test_a_test_marked_early")   # its folder


_LANE_TESTS = '''
import os
import pytest
pytestmark = pytest.mark.lane

def test_passes():
    assert os.environ["TPNET_TEST_LANE"] != "off"        # in the child

def test_fails():
    assert 1 == 2, "the child's own message"

def test_skips():
    pytest.skip("the child's skip")

@pytest.mark.xfail(reason="the child's xfail", strict=True)
def test_xfails():
    assert False

@pytest.mark.parametrize("x", ["a b", "c/d", "e::f"])
def test_odd_ids(x):
    pass
'''


def test_the_second_lane_reports_the_child_s_results_as_its_own(tmp_path):
    """A small suite with this conftest: its lane module runs in a child pytest, and each
    outcome (a failure with its message, a skip, an xfail, odd parameter ids) is reported by the
    first process; a module not in the lane runs there."""
    if (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()) < 2:
        pytest.skip("one CPU: the suite runs in one process (tests/lane.py)")
    here = Path(__file__).parent
    for name in ("conftest.py", "background.py", "lane.py"):
        shutil.copy(here / name, tmp_path / name)
    (tmp_path / "pytest.ini").write_text("[pytest]\nmarkers =\n    lane: x\n    late: x\n"
                                         "    early(job): x\n")
    (tmp_path / "test_in_lane.py").write_text(_LANE_TESTS)
    (tmp_path / "test_here.py").write_text(
        "import os\ndef test_here():\n    assert os.environ.get('TPNET_TEST_LANE') is None\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith("TPNET_TEST_LANE")}
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-rA", "-p", "no:cacheprovider"],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    out = run.stdout + run.stderr
    assert run.returncode == 1, out
    assert "1 failed, 5 passed, 1 skipped, 1 xfailed" in out, out
    assert "the child's own message" in out and "the child's skip" in out, out
    assert re.search(r"second lane: 7 tests in child pytests one after another \(lane: 7 tests "
                     r"in \d+ s, exit status 1;", out), out
    assert "ran here instead" not in out, out
