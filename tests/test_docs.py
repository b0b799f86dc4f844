"""The README and the docs: the quoted headline table matches docs/results.md, the README's
commands and API lines are the ones that run, every relative link resolves, the length limits."""
from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = (REPO / "README.md").read_text()


def _tool():
    spec = importlib.util.spec_from_file_location("headline_tables",
                                                  REPO / "tools" / "headline_tables.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_headline_blocks_quote_docs_results():
    """README.md and the model card quote the m = 4 rows of docs/results.md as they are
    (`python tools/headline_tables.py` copies them after `tpnet eval`)."""
    assert _tool().main(["--check"]) == 0


def test_headline_table_is_taken_from_the_paper_table(tmp_path):
    tool = _tool()
    results = ("# r\n\n## The paper's table, side by side\n\ntext\n\n"
               "| m | method | E_p @40 | E_s @40 |\n|---|---|---|---|\n"
               "| 3 | a | 1 [0, 2] med 1 | 2 |\n| 4 | **TP-Net, paper** | 0.071 | 0.007 |\n"
               "| 4 | b | 3 [2, 4] med 3 | 4 |\n\n## Next\n\n| 4 | c | 9 | 9 |\n")
    table = tool.headline_table(results)
    assert table.splitlines() == ["| m = 4, squared reading | E_p @40 | E_s @40 |", "|---|---|---|",
                                  "| **TP-Net, paper** | 0.071 | 0.007 |",
                                  "| b | 3 [2, 4] med 3 | 4 |"]
    page = "x\n<!-- headline: m4 -->\nold\n<!-- /headline: m4 -->\ny\n"
    assert tool.update(page, table) == page.replace("old", table)
    with pytest.raises(ValueError, match="no rows for m = 4"):
        tool.headline_table(results.replace("| 4 |", "| 5 |"))
    with pytest.raises(ValueError, match="headline"):
        tool.update("no block", table)


def test_readme_test_command_is_what_ci_runs():
    ci = (REPO / ".ci" / "run").read_text()
    assert 'pip install -q -e ".[test,crosscheck]"' in ci
    last = [ln for ln in ci.splitlines() if ln.strip() and not ln.startswith("#")][-1]
    assert last == "python -m pytest -q"
    cmd = ('python3 -m venv .venv && . .venv/bin/activate && pip install -e ".[test,crosscheck]" '
           '&& python -m pytest -q')
    assert cmd in README
    assert ('python3 -m venv .venv && . .venv/bin/activate && pip install -e ".[eval]" '
            '&& tpnet demo') in README


def test_readme_api_lines_run(tmp_path, monkeypatch):
    pytest.importorskip("pymunk")
    pytest.importorskip("numba")
    block = README[README.index("## API"):]
    code = block[block.index("```python") + len("```python"):]
    code = code[:code.index("```")]
    assert len(code.strip().splitlines()) <= 10
    monkeypatch.chdir(tmp_path)                        # model.save writes here
    ns: dict = {}
    exec(compile(code, "README.md (API)", "exec"), ns)
    assert ns["nxt"].shape == (30, 2) and ns["future"].shape == (80, 30, 2)
    assert ns["batch"].shape == (2, 30, 2) and (tmp_path / "my-weights.h5").is_file()


_LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


@pytest.mark.parametrize("page", ["README.md", "weights/MODEL_CARD.md",
                                  *sorted(str(p.relative_to(REPO))
                                          for p in (REPO / "docs").glob("*.md"))])
def test_relative_links_resolve(page):
    text = (REPO / page).read_text()
    base = (REPO / page).parent
    missing = [t for t in _LINK.findall(text)
               if not t.startswith(("http://", "https://", "mailto:"))
               and not (base / t).exists()]
    assert not missing, f"{page}: {missing}"


@pytest.mark.parametrize("page, limit", [("README.md", 200), ("docs/performance.md", 300),
                                         ("docs/training.md", 300),
                                         ("weights/MODEL_CARD.md", 200)])
def test_reference_pages_stay_short(page, limit):
    """Reference pages state the present; the past goes to docs/history.md."""
    n = len((REPO / page).read_text().splitlines())
    assert n <= limit, f"{page}: {n} lines (limit {limit}); move history to docs/history.md"


def test_readme_shows_the_animation_and_the_spread():
    assert "![" in README and "(docs/rollout.gif)" in README
    assert (REPO / "docs" / "rollout.gif").stat().st_size < 1_500_000
    assert "(docs/eval_spread.png)" in README and "bootstrap interval" in README
