"""The suite's own order of work (tests/conftest.py, tests/background.py): late tests run last,
and an early job's result, or its failure, reaches its test."""
from __future__ import annotations

import pytest

import background


def test_late_tests_run_after_all_the_others(request):
    marked = [i for i, item in enumerate(request.session.items) if item.get_closest_marker("late")]
    n = len(request.session.items)
    assert marked == list(range(n - len(marked), n))


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
