"""The training grid and the 60 held-out test cases (tpnet_ref.sim.cases) against the CSV lists
they were typed from (tests/fixtures/test_cases.csv and train_grid.csv: the paper's cases, 2 KB)."""
from __future__ import annotations

import csv
from pathlib import Path

from tpnet_ref.sim.cases import TEST_CASES, TRAIN_ANGLES_DEG, TRAIN_FORCES, TRAIN_POSITIONS

FIX = Path(__file__).resolve().parent / "fixtures"


def test_sizes_and_ranges():
    assert len(TRAIN_POSITIONS) == 75 and len(set(TRAIN_POSITIONS)) == 75
    assert len(TEST_CASES) == 60
    assert TRAIN_FORCES == (1.0, 1.15, 1.3, 1.45, 1.6)
    assert TRAIN_ANGLES_DEG == tuple(180.0 + 5 * k for k in range(19))
    for f, a, x, y in TEST_CASES:
        assert 1.0 <= f <= 1.6 and 180.0 <= a <= 270.0
        assert 2.85 <= x <= 42.15 and 2.85 <= y <= 42.15


def test_test_cases_match_their_csv():
    with open(FIX / "test_cases.csv") as f:
        rows = [(float(r["force"]), float(r["angle_deg"]), float(r["x"]), float(r["y"]))
                for r in csv.DictReader(f)]
    assert rows == list(TEST_CASES)


def test_train_positions_match_their_csv():
    with open(FIX / "train_grid.csv") as f:
        lines = f.read().splitlines()
    header = {ln[2:].split(":")[0]: ln.split(":")[1].split() for ln in lines if ln.startswith("#")}
    assert tuple(float(v) for v in header["forces"]) == TRAIN_FORCES
    assert tuple(float(v) for v in header["angles_deg"]) == TRAIN_ANGLES_DEG
    rows = list(csv.DictReader(ln for ln in lines if not ln.startswith("#")))
    assert [(float(r["x"]), float(r["y"])) for r in rows] == list(TRAIN_POSITIONS)
