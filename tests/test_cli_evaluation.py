"""``tpnet demo`` and ``tpnet eval`` (tpnet_ref.cli.evaluation): the flags reach the library, the
defaults shown in --help are the library's, a missing extra is named before any work, and eval
prints its headline table. End-to-end runs: test_evaluation_demo.py, test_evaluation_suite.py."""
from __future__ import annotations

import importlib.util

import pytest

pytest.importorskip("h5py")

from tpnet_ref import evaluation as E  # noqa: E402
from tpnet_ref.cli import build_parser, main  # noqa: E402
from tpnet_ref.cli import evaluation as CE  # noqa: E402
from tpnet_ref.evaluation import timing as T  # noqa: E402


def test_defaults_spelled_in_the_parser_are_the_librarys():
    """The parser spells them to import no library module; they must not drift."""
    assert CE._DEMO_HORIZONS == E.DEMO_HORIZONS
    assert CE._ORDERINGS == E.ORDERINGS
    assert CE._CALIBRATION_TRAJECTORIES == T.CALIBRATION_TRAJECTORIES


@pytest.mark.parametrize("argv", [["demo", "--no-png"], ["eval", "--baselines-only"]])
def test_a_missing_module_of_the_eval_extra_is_named_before_any_work(
        tmp_path, monkeypatch, capsys, argv):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name in ("pymunk", "tqdm") else real(name, *a))
    monkeypatch.setattr(E, "demo", lambda *a, **k: pytest.fail("demo ran"))
    monkeypatch.setattr(E, "run_eval", lambda *a, **k: pytest.fail("eval ran"))
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pymunk, tqdm" in err[0] and "tpnet-ref[eval]" in err[0]
    assert not list(tmp_path.iterdir())


def test_demo_flags_reach_the_library(monkeypatch):
    got = []
    monkeypatch.setattr(E, "demo", lambda w, **kw: got.append((w, kw)))
    assert main(["demo", "--weights", "w.h5", "--case", "1.2", "200", "20", "22", "--steps", "9",
                 "--horizons", "1", "5", "-o", "x.png", "--seed", "3", "--dtype", "float64"]) == 0
    assert main(["demo", "--no-png"]) == 0
    (w, kw), (w0, kw0) = got
    assert w == "w.h5" and kw == dict(case=[1.2, 200.0, 20.0, 22.0], steps=9, horizons=[1, 5],
                                      png="x.png", seed=3, dtype="float64")
    assert w0 is None and kw0 == dict(case=E.DEMO_CASE, steps=None,
                                      horizons=list(E.DEMO_HORIZONS), png=None, seed=0,
                                      dtype="float32")


def test_eval_prints_the_headline_tables_and_where_it_wrote(tmp_path, monkeypatch, capsys):
    seen = []

    def fake_run_eval(args):
        seen.append(args)
        path = tmp_path / "results.md"
        path.write_text("# Evaluation results\n\nMade by ...\n\n## The paper's table, side by "
                        "side\n\n| m | x |\n\n## Which reading\n\ntext\n\n## Protocol\n\nlong\n")
        return path
    monkeypatch.setattr(E, "run_eval", fake_run_eval)
    assert main(["eval", "--weights", "a.h5", "--weights", "b.h5", "--cases", "2",
                 "--orderings", "given", "shuffle", "--no-timing"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("## The paper's table, side by side") and "## Which reading" in out
    assert "## Protocol" not in out and "Made by" not in out
    assert out.rstrip().endswith(f"wrote {tmp_path / 'results.md'} (and eval_curves.csv, "
                                 f"figures) in {tmp_path}/")
    (a,) = seen
    assert a.weights == ["a.h5", "b.h5"] and a.cases == 2 and a.no_timing
    assert a.orderings == ["given", "shuffle"] and a.repeats == 3 and a.workers == 0


def test_eval_parser_defaults_and_usage_errors(capsys):
    a = build_parser().parse_args(["eval"])
    assert (a.weights, a.orderings, a.gen_cases, a.calibration_trajectories) == (
        [], list(E.ORDERINGS), 20, None)
    for argv, says in ((["eval", "--orderings", "sorted"], "invalid choice: 'sorted'"),
                       (["demo", "--case", "1", "2"], "expected 4 arguments"),
                       (["demo", "--dtype", "float16"], "invalid choice: 'float16'")):
        with pytest.raises(SystemExit) as info:
            main(argv)
        assert info.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and says in err[0], err
