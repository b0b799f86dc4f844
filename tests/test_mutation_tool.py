"""tools/mutation.py, the mutation score of the inference core (docs/testing.md, "Mutation
score"), stays runnable: its modules are the core's, every test file it runs exists, its triage
file names real lines, and it tells a mutant inside an annotation. It is not run here (hours on
two cores; cosmic-ray is the ``mutation`` extra, not CI's)."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from types import SimpleNamespace

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _tool():
    spec = importlib.util.spec_from_file_location("mutation_tool", ROOT / "tools" / "mutation.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_modules_and_their_tests():
    m = _tool()
    assert set(m.MODULES) == {"reference", "layers", "checks", "native", "hdf5", "testing",
                              "onnx_peer"}
    for module, tests in m.MODULES.items():
        assert (ROOT / m.source(module)).is_file()
        assert tests and all((ROOT / t.split("::")[0]).is_file() for t in tests), (module, tests)


def test_the_triage_entries_are_complete():
    """Each entry: the module, the mutated line before and after, the kind and the reason. (An
    entry whose line has since changed matches no mutant any more: harmless, and the next run
    lists the new line's survivors to triage.)"""
    m = _tool()
    triage = json.loads(m.TRIAGE.read_text())
    assert triage
    for t in triage:
        assert set(t) >= {"module", "line", "operator", "before", "after", "reason", "kind"}, t
        assert t["module"] in m.MODULES and t["before"] != t["after"], t
        assert t["kind"] in ("equivalent", "accepted") and t["reason"], t


def test_a_mutant_inside_an_annotation_is_recognised():
    m = _tool()
    spans = m.annotation_spans("layers")
    lines = (ROOT / m.source("layers")).read_text().splitlines()
    row = next(i for i, s in enumerate(lines, 1) if s.startswith("def dense("))
    head = "\n".join(lines[row - 1:row + 2])
    col = lines[row].index("str | None")                      # the activation's annotation
    inside = SimpleNamespace(start_pos=(row + 1, col + 4), end_pos=(row + 1, col + 5))
    body = SimpleNamespace(start_pos=(row + 3, 4), end_pos=(row + 3, 5))
    assert "activation: str | None" in head
    assert m.in_annotation(inside, spans) and not m.in_annotation(body, spans)


def test_a_fresh_seed_is_drawn_from_the_clock_printed_first_and_starts_over(monkeypatch, capsys,
                                                                            tmp_path):
    """``--fresh-seed``: the seed comes from the clock, is printed before any mutant runs, chooses
    the sample and starts the session over; without ``--sample`` or beside ``--seed`` it is an
    error. (cosmic-ray itself is stubbed out: only the tool's own choices are seen here.)"""
    import sys
    m = _tool()
    monkeypatch.setitem(sys.modules, "cosmic_ray", SimpleNamespace())
    calls = []
    monkeypatch.setattr(m.time, "time_ns", lambda: 1_234_567_890_123)
    monkeypatch.setattr(m.os, "nice", lambda n: None)
    monkeypatch.setattr(m, "prepare", lambda module, work, timeout, sample, seed, fresh: calls.append(
        (module, sample, seed, fresh, capsys.readouterr().out)))
    monkeypatch.setattr(m, "run", lambda module, work: None)
    monkeypatch.setattr(m, "report", lambda modules, work: {"checks": {}})
    seed = 1_234_567_890_123 % 1_000_000_007
    assert m.main(["checks", "--sample", "40", "--fresh-seed", "--workdir", str(tmp_path)]) == 0
    [(module, sample, got, fresh, printed)] = calls
    assert (module, sample, got, fresh) == ("checks", 40, seed, True)
    assert f"fresh seed: {seed}" in printed                   # printed before the module ran
    monkeypatch.setattr(m.time, "time_ns", lambda: 1_234_567_890_124)
    m.main(["checks", "--sample", "40", "--fresh-seed", "--workdir", str(tmp_path)])
    assert calls[1][2] == seed + 1                             # another moment, another sample
    for bad in (["checks", "--fresh-seed"], ["checks", "--sample", "40", "--seed", "3",
                                             "--fresh-seed"]):
        with pytest.raises(SystemExit):
            m.main(bad + ["--workdir", str(tmp_path)])


def test_the_report_names_each_sample_by_its_seed(tmp_path):
    m = _tool()
    assert m.sample_seed("checks", tmp_path) == "?"
    (tmp_path / "checks").mkdir()
    (tmp_path / "checks" / "seed").write_text("777\n")
    assert m.sample_seed("checks", tmp_path) == "777"
