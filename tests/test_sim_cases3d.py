"""The 3-D training grid's values and the 60 held-out 3-D test cases (tpnet_ref.sim.cases3d)
against their CSV files (tests/fixtures/train_grid3d.csv and test_cases3d.csv), and the grid
built from them (train_grid3d): the 2-D grid's spacing in every dimension, and no
test case ever a grid row."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from tpnet_ref.sim.cases import TRAIN_ANGLES_DEG, TRAIN_FORCES
from tpnet_ref.sim.cases3d import (TEST_CASES3D, TRAIN_AZIMUTHS_DEG, TRAIN_ELEVATIONS_DEG,
                                   TRAIN_FORCES3D, TRAIN_POSITIONS3D)
from tpnet_ref.sim.scene3d import SceneParams3D, check_throw

pytestmark = pytest.mark.lane("3-D")   # in a second test process (tests/lane.py)

FIX = Path(__file__).resolve().parent / "fixtures"


def test_sizes_ranges_and_the_2d_spacing():
    assert TRAIN_FORCES3D == TRAIN_FORCES
    # 5 degrees apart in azimuth (the 2-D angles) and in elevation, as the 2-D angles are
    assert TRAIN_AZIMUTHS_DEG == TRAIN_ANGLES_DEG
    assert np.diff(TRAIN_ELEVATIONS_DEG).tolist() == [-5.0] * 17
    assert TRAIN_ELEVATIONS_DEG[0] == 0.0 and TRAIN_ELEVATIONS_DEG[-1] == -85.0
    assert len(TRAIN_POSITIONS3D) == 75 and len(set(TRAIN_POSITIONS3D)) == 75
    assert len(TEST_CASES3D) == 60 and len(set(TEST_CASES3D)) == 60
    pos = np.asarray(TRAIN_POSITIONS3D)
    assert pos.min() >= 28.5 and pos.max() <= 41.5
    p = SceneParams3D()
    for case in TEST_CASES3D:
        f, az, el = case[:3]
        assert f in TRAIN_FORCES3D and az in TRAIN_AZIMUTHS_DEG and el in TRAIN_ELEVATIONS_DEG
        check_throw(*case, p)                     # a valid throw, inside the box


def test_test_cases_match_their_csv():
    with open(FIX / "test_cases3d.csv") as f:
        rows = [tuple(float(r[k]) for k in ("force", "azimuth_deg", "elevation_deg", "x", "y", "z"))
                for r in csv.DictReader(f)]
    assert rows == list(TEST_CASES3D)


def test_train_values_match_their_csv():
    with open(FIX / "train_grid3d.csv") as f:
        lines = f.read().splitlines()
    header = {ln[2:].split(":")[0]: ln.split(":")[1].split() for ln in lines if ln.startswith("#")}
    assert tuple(float(v) for v in header["forces"]) == TRAIN_FORCES3D
    assert tuple(float(v) for v in header["azimuths_deg"]) == TRAIN_AZIMUTHS_DEG
    assert tuple(float(v) for v in header["elevations_deg"]) == TRAIN_ELEVATIONS_DEG
    rows = list(csv.DictReader(ln for ln in lines if not ln.startswith("#")))
    assert [(float(r["x"]), float(r["y"]), float(r["z"])) for r in rows] == list(TRAIN_POSITIONS3D)


def test_no_test_case_starts_where_a_training_throw_does():
    train = {tuple(p) for p in TRAIN_POSITIONS3D}
    assert not train & {case[3:] for case in TEST_CASES3D}


@pytest.mark.parametrize("per_direction", [1, 2, 5])
def test_the_grid_covers_every_value_and_never_a_test_case(per_direction):
    from tpnet_ref.sim.cases3d import train_grid3d
    g = train_grid3d(per_direction=per_direction)
    n_dir = len(TRAIN_AZIMUTHS_DEG) * len(TRAIN_ELEVATIONS_DEG)
    assert g.shape == (n_dir * per_direction, 6)
    # every direction of the 5-degree grid, each force with every azimuth and every elevation
    assert len({(a, e) for a, e in g[:, 1:3]}) == n_dir
    for col, values in ((1, TRAIN_AZIMUTHS_DEG), (2, TRAIN_ELEVATIONS_DEG)):
        for v in values:
            assert set(g[g[:, col] == v, 0]) == set(TRAIN_FORCES3D)
    assert {tuple(r) for r in g[:, 3:]} <= set(TRAIN_POSITIONS3D)
    assert len({tuple(r) for r in g[:, 3:]}) == min(75, len(g))
    assert len({tuple(r) for r in g}) == len(g)
    assert not {tuple(r) for r in g} & set(TEST_CASES3D)
    if per_direction == 5:          # every (force, direction) pair: the full product
        assert len({(f, a, e) for f, a, e in g[:, :3]}) == 5 * n_dir


def test_grid_options():
    from tpnet_ref.sim.cases3d import train_grid3d
    g = train_grid3d([1.0], [200.0, 210.0], [-10.0], positions=2)
    np.testing.assert_array_equal(g, [[1.0, 200.0, -10.0, *TRAIN_POSITIONS3D[0]],
                                      [1.0, 210.0, -10.0, *TRAIN_POSITIONS3D[1]]])
    for bad, says in (({"positions": 0}, "positions"), ({"positions": 76}, "positions"),
                      ({"per_direction": 0}, "per_direction"), ({"forces": []}, "forces")):
        with pytest.raises(ValueError, match=says):
            train_grid3d(**bad)
