"""The conformance cases: scene windows, shuffled points, ragged frames, the edges of the
trained range and a short rollout (:func:`make_cases`; the simulator needs the ``sim`` extra)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import TPNetConfig
from ..engines import reference


@dataclass
class Case:
    name: str
    description: str
    frames: list[np.ndarray]

    @property
    def counts(self) -> list[int]:
        return [len(f) for f in self.frames]


#: scene parameters of the conformance windows (force, angle in degrees, x, y): off the
#: training grid, inside its ranges (tpnet_ref/sim/cases.py)
SCENES = ((1.22, 58.0, 17.3, 23.9), (1.53, 121.0, 30.6, 18.2))
#: the simulator steps between a window's frames, and where the first window starts
SPACING, START = 4, 60


def make_cases(config: TPNetConfig, params: dict[str, np.ndarray],
               rollout_steps: int = 3, seed: int = 0) -> list[Case]:
    """The conformance cases for a network with ``config.m`` frames (needs the ``sim`` extra):
    two scene windows, one with each frame's points shuffled, one with ragged N, the scene
    pushed against the low and the high edge of the normalisation range (the trained box), and
    ``rollout_steps`` steps of a rollout (each step's window holds the reference's float64
    predictions as its newest frames)."""
    from ..extras import require
    require("tpnet_ref.sim", "sim", "tpnet vectors (the scene windows)")
    from ..sim import simulate

    m = config.m
    rng = np.random.default_rng(seed)
    span = SPACING * (m - 1) + 1
    wins = []
    for force, angle, x, y in SCENES:
        traj = simulate(force, angle, x, y, steps=START + span + 1)
        wins.append([traj[START + SPACING * t] for t in range(m)])
    a, b = wins
    cases = [Case("scene1", f"simulated scene {SCENES[0]} (force, angle, x, y), frames "
                  f"{START}, {START + SPACING}, ... of the trajectory", a),
             Case("scene2", f"simulated scene {SCENES[1]}", b),
             Case("shuffled", "scene1 with each frame's points in a random order",
                  [f[rng.permutation(len(f))] for f in a])]
    keep = [max(1, len(f) - 4 * t - 3 * (t % 2)) for t, f in enumerate(b)]
    cases.append(Case("ragged", f"scene2 with frames of {keep} points (random subsets)",
                      [f[np.sort(rng.choice(len(f), k, replace=False))]
                       for f, k in zip(b, keep)]))
    lo, hi = config.norm_lo, config.norm_hi
    allpts = np.concatenate(a)
    cases.append(Case("edge_low", "scene1 moved against the low edge of the normalisation "
                      "range (its smallest x and y at norm_lo)",
                      [f - allpts.min(axis=0) + lo for f in a]))
    cases.append(Case("edge_high", "scene1 moved against the high edge (its largest x and y "
                      "at norm_hi)", [f - allpts.max(axis=0) + hi for f in a]))
    frames = list(b)
    for s in range(1, rollout_steps + 1):
        nxt = reference.forward(config, {k: np.asarray(v, np.float64) for k, v in params.items()},
                                frames[-m:])
        frames.append(nxt)
        cases.append(Case(f"rollout{s}", f"step {s} of a rollout from scene2: its newest "
                          f"{min(s, m)} frame(s) the reference's float64 predictions",
                          frames[-m:]))
    return cases


__all__ = ["Case", "SCENES", "SPACING", "START", "make_cases"]
