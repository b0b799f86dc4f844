"""The 3-D scene's training grid and its 60 held-out test cases (docs/spec.md §8), as constants.

Kept as ``tests/fixtures/train_grid3d.csv`` and ``tests/fixtures/test_cases3d.csv`` too, which
``tests/test_sim_cases3d.py`` checks these against. Units: force per particle, angles in degrees
(azimuth from +x towards +y, elevation above the horizontal), centre in world units.

The grid has the 2-D grid's spacing in every dimension (:mod:`tpnet_ref.sim.cases`): the same five
forces, directions 5 degrees apart in azimuth (180..270, the 2-D angles) and in elevation (0 down
to -85: from the horizontal to nearly straight down, as the 2-D angles run from 180 to 270), and
75 start centres drawn once (seeded, rounded to 0.1) from [28.5, 41.5]^3, the 2-D positions' range
in every coordinate. :func:`train_grid3d` combines them. The 60 test cases were
drawn once from the same forces and directions with start centres that no training position has,
so no test case is a grid row.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .cases import TRAIN_FORCES

#: the 2-D grid's forces
TRAIN_FORCES3D: tuple[float, ...] = TRAIN_FORCES
TRAIN_AZIMUTHS_DEG: tuple[float, ...] = tuple(180.0 + 5.0 * k for k in range(19))
TRAIN_ELEVATIONS_DEG: tuple[float, ...] = tuple(0.0 - 5.0 * k for k in range(18))

#: 75 start centres (x, y, z)
TRAIN_POSITIONS3D: tuple[tuple[float, float, float], ...] = (
    (36.1, 39.2, 30.0), (33.4, 30.9, 30.6), (28.6, 41.1, 29.8), (40.6, 34.0, 37.7),
    (29.9, 35.1, 38.9), (29.8, 31.7, 29.9), (33.0, 33.1, 31.0), (30.1, 40.1, 38.7),
    (37.0, 31.6, 29.3), (36.8, 40.8, 40.9), (38.7, 41.4, 28.8), (32.3, 41.1, 30.5),
    (35.3, 40.4, 36.7), (33.8, 31.0, 32.4), (31.6, 28.5, 31.5), (36.6, 37.9, 38.4),
    (34.2, 29.8, 32.8), (31.4, 35.7, 33.2), (34.0, 35.4, 38.2), (32.2, 29.3, 34.6),
    (38.6, 29.6, 35.1), (40.8, 30.4, 28.6), (35.4, 36.9, 36.6), (33.7, 38.4, 37.8),
    (31.9, 35.1, 33.5), (40.2, 34.1, 28.6), (33.1, 37.0, 32.3), (41.0, 35.8, 29.5),
    (29.9, 29.4, 29.6), (41.5, 28.7, 39.6), (35.2, 41.4, 33.8), (33.6, 39.8, 33.2),
    (28.7, 29.3, 35.2), (35.4, 34.5, 36.5), (41.0, 34.4, 41.5), (32.6, 31.3, 40.3),
    (33.1, 41.5, 39.0), (38.7, 38.1, 34.2), (30.9, 36.8, 29.1), (34.4, 35.0, 40.5),
    (32.2, 32.0, 31.8), (40.1, 34.8, 39.6), (29.1, 38.6, 31.6), (30.9, 37.4, 40.3),
    (35.7, 30.8, 32.4), (36.9, 40.0, 29.3), (31.0, 40.2, 35.9), (29.0, 35.5, 41.5),
    (35.8, 38.3, 28.6), (28.8, 31.9, 30.3), (28.6, 28.5, 30.3), (39.2, 39.6, 34.1),
    (39.8, 35.8, 28.8), (29.2, 36.5, 38.2), (31.8, 40.3, 35.9), (35.8, 40.9, 30.1),
    (31.3, 29.4, 35.8), (35.9, 38.9, 29.1), (33.9, 35.5, 37.3), (39.9, 38.9, 37.7),
    (32.9, 34.1, 33.8), (33.1, 39.2, 31.1), (40.3, 32.9, 38.6), (40.3, 33.0, 29.1),
    (32.6, 29.5, 36.7), (36.5, 29.8, 36.0), (40.1, 35.4, 31.9), (38.4, 38.3, 31.4),
    (28.8, 30.2, 33.9), (35.6, 32.3, 39.1), (40.7, 30.5, 34.5), (33.0, 31.8, 30.4),
    (31.1, 39.7, 32.8), (29.6, 36.5, 33.9), (31.1, 30.8, 35.8),
)

#: 60 held-out cases (force, azimuth_deg, elevation_deg, x, y, z); never trained on
TEST_CASES3D: tuple[tuple[float, float, float, float, float, float], ...] = (
    (1.3, 200.0, -70.0, 37.6, 33.8, 31.7), (1.6, 200.0, -65.0, 33.8, 37.8, 32.2),
    (1.0, 215.0, -45.0, 37.2, 35.5, 35.1), (1.45, 230.0, -75.0, 34.0, 30.8, 38.3),
    (1.15, 200.0, -75.0, 39.7, 28.8, 30.7), (1.3, 220.0, -75.0, 37.7, 33.5, 36.2),
    (1.15, 245.0, -5.0, 35.9, 35.7, 38.9), (1.45, 200.0, -25.0, 29.9, 38.7, 40.4),
    (1.15, 230.0, -35.0, 33.5, 34.3, 29.3), (1.45, 260.0, -5.0, 37.3, 36.0, 35.5),
    (1.15, 240.0, -30.0, 39.0, 41.1, 36.0), (1.15, 270.0, -80.0, 38.8, 33.2, 29.8),
    (1.6, 255.0, -55.0, 37.9, 41.2, 34.7), (1.45, 200.0, -45.0, 39.0, 39.4, 40.4),
    (1.0, 255.0, -10.0, 34.3, 34.3, 39.7), (1.0, 205.0, -85.0, 41.0, 37.8, 32.5),
    (1.0, 245.0, -20.0, 39.4, 30.5, 41.1), (1.6, 260.0, -15.0, 39.5, 39.5, 35.3),
    (1.45, 240.0, -55.0, 33.8, 37.1, 34.3), (1.0, 215.0, -10.0, 38.3, 35.1, 31.1),
    (1.45, 260.0, -40.0, 36.5, 35.8, 29.1), (1.0, 255.0, -65.0, 30.1, 37.0, 31.7),
    (1.15, 200.0, -25.0, 41.0, 39.9, 29.3), (1.6, 210.0, 0.0, 28.9, 33.9, 40.3),
    (1.0, 195.0, -20.0, 29.4, 37.1, 40.1), (1.45, 215.0, -20.0, 39.4, 29.1, 29.6),
    (1.15, 235.0, -40.0, 29.0, 33.1, 32.7), (1.3, 220.0, -5.0, 38.6, 29.1, 29.7),
    (1.15, 195.0, -25.0, 31.0, 40.8, 29.0), (1.0, 205.0, -50.0, 41.3, 41.2, 41.3),
    (1.3, 215.0, -30.0, 34.9, 36.6, 32.0), (1.3, 235.0, -40.0, 39.0, 31.6, 32.1),
    (1.6, 255.0, -25.0, 37.3, 34.5, 37.9), (1.0, 270.0, -5.0, 29.0, 38.3, 40.7),
    (1.15, 235.0, -25.0, 33.5, 37.6, 32.9), (1.3, 265.0, -70.0, 32.1, 32.5, 37.5),
    (1.3, 185.0, -80.0, 33.2, 31.9, 33.4), (1.3, 190.0, -40.0, 35.7, 33.1, 39.6),
    (1.0, 225.0, -30.0, 29.6, 35.6, 32.8), (1.15, 230.0, -25.0, 36.8, 29.5, 32.6),
    (1.15, 245.0, -45.0, 39.5, 38.8, 37.4), (1.15, 205.0, -20.0, 32.0, 33.6, 40.6),
    (1.3, 190.0, -35.0, 30.5, 37.7, 29.8), (1.3, 195.0, -35.0, 30.2, 39.1, 28.7),
    (1.45, 245.0, -85.0, 37.5, 33.7, 36.9), (1.3, 225.0, -20.0, 36.2, 32.2, 32.6),
    (1.0, 250.0, -15.0, 30.6, 29.9, 28.6), (1.0, 265.0, -65.0, 30.8, 32.5, 30.9),
    (1.3, 270.0, -50.0, 29.1, 34.4, 39.9), (1.6, 235.0, -70.0, 34.2, 38.8, 29.5),
    (1.15, 220.0, -85.0, 41.3, 38.0, 39.7), (1.3, 215.0, -5.0, 38.0, 32.1, 33.3),
    (1.15, 190.0, -35.0, 35.7, 34.8, 35.6), (1.0, 265.0, -75.0, 33.5, 34.0, 33.3),
    (1.15, 245.0, -50.0, 35.9, 38.9, 35.8), (1.0, 240.0, -75.0, 36.2, 30.1, 33.6),
    (1.45, 225.0, -75.0, 34.9, 35.5, 41.1), (1.3, 210.0, -35.0, 34.2, 35.9, 40.4),
    (1.15, 210.0, -60.0, 37.1, 30.5, 30.5), (1.15, 220.0, -85.0, 33.9, 39.5, 38.0),
)


def train_grid3d(forces: Sequence[float] = TRAIN_FORCES3D,
                 azimuths: Sequence[float] = TRAIN_AZIMUTHS_DEG,
                 elevations: Sequence[float] = TRAIN_ELEVATIONS_DEG,
                 positions: int | None = None, per_direction: int = 1) -> np.ndarray:
    """``(T, 6)`` (force, azimuth_deg, elevation_deg, x, y, z) of the 3-D training grid
    (docs/spec.md §8): every direction (elevations outermost, then azimuths) ``per_direction``
    times, ``T = len(elevations) * len(azimuths) * per_direction``. The ``c``-th throw towards
    the direction ``(azimuths[a], elevations[e])`` has the force ``forces[(a + e + c) % F]``, so
    each force meets every azimuth and every elevation (``per_direction = F``: every force in
    every direction, the full product), and throw ``t`` starts at position ``t % P`` of the first
    ``positions`` of the 75 (all by default). The default grid: 342 throws, the 2-D grid's
    spacing in every dimension."""
    pos = np.asarray(TRAIN_POSITIONS3D, dtype=float)
    if positions is not None:
        if isinstance(positions, bool) or not 1 <= int(positions) <= len(pos):
            raise ValueError(f"positions: must be in 1..{len(pos)}, got {positions}")
        pos = pos[:int(positions)]
    if isinstance(per_direction, bool) or int(per_direction) < 1:
        raise ValueError(f"per_direction: must be >= 1, got {per_direction}")
    f = [float(v) for v in forces]
    for name, values in (("forces", f), ("azimuths", azimuths), ("elevations", elevations)):
        if len(values) == 0:
            raise ValueError(f"{name}: need at least one value")
    out = []
    for ie, e in enumerate(elevations):
        for ia, a in enumerate(azimuths):
            for c in range(int(per_direction)):
                x, y, z = pos[len(out) % len(pos)]
                out.append((f[(ia + ie + c) % len(f)], float(a), float(e), x, y, z))
    return np.asarray(out, dtype=float).reshape(-1, 6)


__all__ = ["train_grid3d", "TRAIN_FORCES3D", "TRAIN_AZIMUTHS_DEG", "TRAIN_ELEVATIONS_DEG",
           "TRAIN_POSITIONS3D", "TEST_CASES3D"]
