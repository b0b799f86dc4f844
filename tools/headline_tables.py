"""Copy the m = 4 headline table of ``docs/results.md`` into README.md and weights/MODEL_CARD.md.

    python tools/headline_tables.py            # rewrite the marked blocks
    python tools/headline_tables.py --check    # exit 1 if a block differs from docs/results.md

``tpnet eval`` writes ``docs/results.md``; the README and the model card quote its m = 4 rows
(the paper, the shipped model, copy last, constant velocity; each cell with its spread) between
``<!-- headline: m4 -->`` and ``<!-- /headline: m4 -->``. This copies them, so that rerunning the
evaluation (``bash tools/refresh_docs.sh``) refreshes every page that shows them.
"""
from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PAGES = ("README.md", "weights/MODEL_CARD.md")
BLOCK = re.compile(r"(<!-- headline: m4 -->\n).*?(<!-- /headline: m4 -->)", re.S)
SECTION = "## The paper's table"


def headline_table(results: str, m: int = 4) -> str:
    """The rows of window length ``m`` of the first table under "The paper's table", without
    the m column, under a header that names the reading."""
    lines = results.splitlines()
    try:
        start = next(i for i, s in enumerate(lines) if s.startswith(SECTION))
    except StopIteration:
        raise ValueError(f"results.md: no {SECTION!r} section") from None
    table = []
    for s in lines[start + 1:]:
        if s.startswith("|"):
            table.append(s)
        elif table:
            break
    if len(table) < 3:
        raise ValueError("results.md: the paper's table has no rows")
    header = [c.strip() for c in table[0].strip().strip("|").split("|")]
    rows = [[c.strip() for c in s.strip().strip("|").split("|")] for s in table[2:]]
    mine = [r for r in rows if r[0] == str(m)]
    if not mine:
        raise ValueError(f"results.md: no rows for m = {m}")
    out = [f"| m = {m}, squared reading | " + " | ".join(header[2:]) + " |",
           "|" + "---|" * (len(header) - 1)]
    out += ["| " + " | ".join(r[1:]) + " |" for r in mine]
    return "\n".join(out)


def update(page: str, table: str) -> str:
    """``page`` with its marked block replaced by ``table``."""
    if not BLOCK.search(page):
        raise ValueError("no <!-- headline: m4 --> ... <!-- /headline: m4 --> block")
    return BLOCK.sub(lambda mt: mt[1] + table + "\n" + mt[2], page, count=1)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", default=str(REPO / "docs" / "results.md"))
    ap.add_argument("--check", action="store_true", help="only compare; exit 1 if stale")
    args = ap.parse_args(argv)
    table = headline_table(Path(args.results).read_text())
    stale = []
    for name in PAGES:
        path = REPO / name
        text = path.read_text()
        new = update(text, table)
        if new != text:
            stale.append(name)
            if not args.check:
                path.write_text(new)
    verb = "differs from" if args.check else "updated from"
    for name in stale:
        print(f"{name}: {verb} {args.results}")
    return 1 if (args.check and stale) else 0


if __name__ == "__main__":
    sys.exit(main())
