"""The product pages speak of the product: README.md, weights/*.md and docs/*.md name no issue
numbers, lent machines, leases, sessions or "today". How the project was made, and what earlier
versions measured, belongs in docs/history.md (docs/training.md is checked once it is rewritten:
it is left out below)."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

#: pages that may speak of how the project was made
EXEMPT = {"docs/history.md"}

#: words about the making, not the product ("numba issues 4807 and 10128", an upstream bug
#: tracker's numbers, and onnxruntime's InferenceSession are not matched)
PROCESS_WORDS = re.compile(r"\b[Ii]ssue \d+|\b[Tt]his issue\b|\bthe issue's\b|\blent\b|\bleases?\b"
                           r"|\b[Tt]oday\b|\bsessions?\b|\bsitting\b")


def product_pages() -> list[str]:
    pages = ["README.md", *(str(p.relative_to(REPO)) for p in (REPO / "weights").glob("*.md")),
             *(str(p.relative_to(REPO)) for p in (REPO / "docs").glob("*.md"))]
    return sorted(p for p in pages if p not in EXEMPT)


def process_words(text: str, name: str) -> list[str]:
    """Every line of ``text`` with a word about the making, as ``name:line: text``."""
    return [f"{name}:{i}: {m.group(0)!r} in {line.strip()[:120]}"
            for i, line in enumerate(text.splitlines(), 1)
            for m in [PROCESS_WORDS.search(line)] if m]


def test_the_pages_checked_exist():
    pages = product_pages()
    assert "README.md" in pages and "weights/README.md" in pages and "docs/glossary.md" in pages
    assert not EXEMPT & set(pages)


@pytest.mark.parametrize("page", product_pages())
def test_product_pages_name_no_process_words(page):
    hits = process_words((REPO / page).read_text(), page)
    assert not hits, ("words about how the project was made (move history to docs/history.md, "
                      "keep the facts in product words):\n" + "\n".join(hits))


def test_the_check_names_file_and_line():
    n = 47                                  # an issue number, as a page might cite one
    text = f"fine\nmeasured in issue {n}'s run\nnumba issues 4807 and 10128\nGPUs lent for minutes\n" \
           "ort.InferenceSession(path)\na session of training\ntoday's recipe\n"
    hits = process_words(text, "x.md")
    assert [h.split(": ")[0] for h in hits] == ["x.md:2", "x.md:4", "x.md:6", "x.md:7"]
    assert f"'issue {n}'" in hits[0]
