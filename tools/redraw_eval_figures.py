"""Redraw the evaluation figures from the numbers a ``tpnet eval`` run wrote, without rerunning it.

``python tools/redraw_eval_figures.py docs`` reads ``docs/eval_curves.csv`` (per-step means of
every curve), ``docs/eval_cases.csv`` (every case's errors at 40 and 80 predictions) and the
"Error against run time" table of ``docs/results.md``, and draws ``eval_error_vs_frame.png``,
``eval_spread.png`` and ``eval_error_vs_time.png`` into the same folder (``--out``: another
one) with :mod:`tpnet_ref.evaluation.plots`. The figures show means over the cases, which is what
the files hold (the CSV to 4 significant digits, the table to the digits printed), so a change of
the plotting code can be seen on the published numbers in seconds; the numbers themselves come
only from ``tpnet eval`` (the command at the top of ``results.md``).
"""
from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from tpnet_ref.evaluation.plots import plot_models, plot_spread, plot_timing
from tpnet_ref.evaluation.run import HEADLINE, Curve
from tpnet_ref.evaluation.timing import TimingRow

TIMING_HEADING = "## Error against run time"


def read_curves(path: str | Path, group: str = "test") -> list[Curve]:
    """The curves of ``group`` in an ``eval_curves.csv``, each error a ``(1, H)`` array of the
    per-step means (so ``Curve.mean`` gives them back)."""
    rows: dict[tuple[str, int, str], list[dict[str, str]]] = {}
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            if r["group"] == group:
                rows.setdefault((r["method"], int(r["m"]), r["ordering"]), []).append(r)
    if not rows:
        raise ValueError(f"{path}: no curves of group {group!r}")
    out = []
    for (name, m, ordering), rs in rows.items():
        rs.sort(key=lambda r: int(r["step"]))
        keys = [k for k in rs[0] if k.startswith(("Ep_", "Es_"))]
        out.append(Curve(name, m, ordering,
                         {k: np.array([[float(r[k]) for r in rs]]) for k in keys}, group))
    return out


def read_cases(path: str | Path, group: str = "test") -> list[Curve]:
    """The curves of ``group`` in an ``eval_cases.csv``, each error a ``(cases, H)`` array holding
    every case's errors at the steps the file has (zero elsewhere; the spread figure reads only
    those)."""
    rows: dict[tuple[str, int, str], dict[tuple[int, int], dict[str, str]]] = {}
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            if r["group"] == group:
                key = (r["method"], int(r["m"]), r["ordering"])
                rows.setdefault(key, {})[(int(r["case"]), int(r["step"]))] = r
    if not rows:
        raise ValueError(f"{path}: no cases of group {group!r}")
    out = []
    for (name, m, ordering), cells in rows.items():
        n_cases = max(c for c, _ in cells)
        n_steps = max(h for _, h in cells)
        keys = [k for k in next(iter(cells.values())) if k.startswith(("Ep_", "Es_"))]
        err = {k: np.zeros((n_cases, n_steps)) for k in keys}
        for (c, h), r in cells.items():
            for k in keys:
                err[k][c - 1, h - 1] = float(r[k])
        out.append(Curve(name, m, ordering, err, group))
    return out


def _number(cell: str) -> float | None:
    """A table cell's number: the cell itself, or the mean that leads an error cell
    (``mean [lo, hi] med median``)."""
    cell = cell.strip().split(" ")[0] if cell.strip() else ""
    return None if cell in ("", "–", "-") else float(cell)


def read_timing(path: str | Path) -> list[TimingRow]:
    """The rows of the "Error against run time" table of a ``results.md``; each row's E_p and
    E_s a ``(1, H)`` array holding the table's means at its horizons (zero elsewhere; the
    figure reads only those)."""
    lines = Path(path).read_text().splitlines()
    try:
        start = lines.index(TIMING_HEADING)
    except ValueError:
        raise ValueError(f"{path}: no {TIMING_HEADING!r} section") from None
    end = next((i for i, s in enumerate(lines[start:]) if s.startswith("|")), None)
    if end is None:
        raise ValueError(f"{path}: the {TIMING_HEADING!r} section has no table")
    table = []
    for s in lines[start + end:]:
        if not s.startswith("|"):
            break
        table.append([c.strip() for c in s.strip().strip("|").split("|")])
    header, body = table[0], table[2:]
    cols = {h: i for i, h in enumerate(header)}
    hs = sorted({int(h.split("@")[1]) for h in header if h.startswith("E_p @")})
    if not hs:
        raise ValueError(f"{path}: the timing table has no E_p @h column")
    out = []
    for cells in body:
        err = {}
        for k, label in (("Ep", "E_p"), ("Es", "E_s")):
            e = np.zeros((1, hs[-1]))
            for h in hs:
                e[0, h - 1] = _number(cells[cols[f"{label} @{h}"]]) or 0.0
            err[f"{k}_{HEADLINE}"] = e
        ms_batch = next(i for h, i in cols.items() if h.startswith("ms/frame (batch"))
        out.append(TimingRow(cells[0], _number(cells[ms_batch]),
                             _number(cells[cols["ms/frame (one rollout)"]]), err,
                             cells[cols["note"]]))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folder", help="folder of a `tpnet eval --out` run (results.md, "
                                  "eval_curves.csv)")
    p.add_argument("--out", default=None, help="write the figures here (default: the folder)")
    args = p.parse_args(argv)
    src = Path(args.folder)
    out = Path(args.out) if args.out else src
    out.mkdir(parents=True, exist_ok=True)
    written = [plot_models(read_curves(src / "eval_curves.csv"), out / "eval_error_vs_frame.png")]
    if (src / "eval_cases.csv").is_file():
        written.append(plot_spread(read_cases(src / "eval_cases.csv"), out / "eval_spread.png"))
    if TIMING_HEADING in (src / "results.md").read_text().splitlines():
        written.append(plot_timing(read_timing(src / "results.md"),
                                   out / "eval_error_vs_time.png"))
    for w in written:
        print(f"wrote {w}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
