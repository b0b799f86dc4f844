"""Point checks against Box2D quoted in docs/simulator.md.

    PYTHONPATH=. python bench/checks_box2d.py

Prints (both engines in the released convention, impulse at the ring centre): the first step
against Box2D's, when a body dropped from rest falls asleep (sleep=True), how far a
particle that starts inside the wall (start x = 41.9) is pushed out after one step.
"""
from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from box2d_scene import simulate_box2d  # noqa: E402

from tpnet_ref.sim import simulate  # noqa: E402


def last_moving_step(traj: np.ndarray) -> int:
    moved = np.nonzero(np.abs(np.diff(traj, axis=0)).max(axis=(1, 2)) > 0)[0]
    return int(moved.max()) + 1 if len(moved) else 0


def main() -> int:
    case = (1.3, 195.0, 39.5, 29.5)
    d = np.abs(simulate(*case, 1) - simulate_box2d(*case, 1)).max()
    print(f"after the first step, largest difference to Box2D: {d:.2g}")
    drop = (0.0, 270.0, 22.0, 3.3)
    b = simulate_box2d(*drop, 1500, include_initial=True, sleep=True)
    s = simulate(*drop, 1500, include_initial=True, sleep=True)
    diff = np.abs(b[-1] - s[-1]).max()
    print(f"dropped from rest: asleep after {last_moving_step(s)} steps "
          f"(Box2D {last_moving_step(b)}); final positions differ by {diff:.2g}")
    b0 = b1 = s1 = 0.0
    for a in (180.0, 225.0, 270.0):
        for f in (1.0, 1.6):
            b = simulate_box2d(f, a, 41.9, 39.3, 2, include_initial=True)
            b0, b1 = max(b0, b[0].max()), max(b1, b[1].max())
            s1 = max(s1, simulate(f, a, 41.9, 39.3, 1).max())
    print(f"start (41.9, 39.3): largest centre initially {b0:.4f}, after one step "
          f"Box2D {b1:.4f}, tpnet_ref.sim {s1:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
