"""Shared by the unit-order and specialisation tests: a small network shape and windows of a
ring drifting through the box (the scene's kind of input, cheap to make); by the 3-D tests: a
window of the 3-D scene's ball thrown in free fall; by the compiled-call tests: fixed windows of
a moving ring."""
from __future__ import annotations

import numpy as np

from tpnet_ref.model import TPNetConfig

SMALL = TPNetConfig(mlp1=(16, 16), mlp2=(16, 32, 48), global_features=24, lstm_units=(32, 16, 16))


def rings(rng: np.random.Generator, n: int, m: int = 4, wobble: float = 0.0) -> np.ndarray:
    """Windows of a ring of radius 2 (30 points) drifting through the box: ``(n, m, 30, 2)``;
    ``wobble`` > 0 adds normal noise of that scale to every point."""
    a = np.arange(30) * 2 * np.pi / 30
    ring = 2 * np.stack([np.sin(a), np.cos(a)], axis=1)
    start = rng.uniform(8, 37, (n, 1, 1, 2))
    vel = rng.uniform(-0.6, 0.6, (n, 1, 1, 2))
    out = start + vel * np.arange(m)[None, :, None, None] + ring
    if wobble:
        out = out + rng.normal(0, wobble, (n, m, 30, 2))
    return out


def ring_windows(batch: int) -> np.ndarray:
    """``batch`` windows ``(batch, 4, 30, 2)`` of a ring of radius 2 moving right and down, the
    windows 2 units apart (fixed: no draw)."""
    a = np.arange(30) * 2 * np.pi / 30
    ring = 2 * np.stack([np.sin(a), np.cos(a)], axis=1)
    return np.stack([np.stack([ring + [15 + 2 * b + 0.5 * i, 25 - 0.2 * i] for i in range(4)])
                     for b in range(batch)])


def thrown_ball(rows_apart: float = 4, centre=(20.0, 22.0, 30.0), v=(6.0, -3.0, 4.0),
                radius: float = 2.0) -> np.ndarray:
    """A window of the 3-D scene's ball (docs/spec.md §8: 42 points, radius 2; here of
    ``radius``) thrown in free fall from ``centre`` at ``v``: frames ``rows_apart`` simulator
    rows apart, world units, ``(4, 42, 3)``."""
    from tpnet_ref import checks as C
    from tpnet_ref.sim.scene3d import ball_positions
    t = np.arange(4) * rows_apart * C.SIM_DT
    c = np.asarray(centre) + np.outer(t, v) + np.outer(0.5 * t ** 2, [0, 0, -C.GRAVITY])
    return np.stack([p + ball_positions(0, 0, 0) * (radius / 2.0) for p in c])
