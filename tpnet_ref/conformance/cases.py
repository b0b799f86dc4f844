"""The conformance cases: scene windows, shuffled points, ragged frames, the edges of the
trained range and a short rollout (:func:`make_cases`). A 2-D network's windows come from the
2-D scene (the ``sim`` extra), a 3-D network's from the 3-D scene (the ``sim3d`` extra)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

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
#: the 3-D conformance windows' throws (force, azimuth, elevation in degrees, x, y, z): off the
#: 3-D training grid, inside its ranges (tpnet_ref/sim/cases3d.py)
SCENES3D = ((1.22, 217.0, -32.0, 34.6, 36.1, 33.2), (1.53, 248.0, -58.0, 31.7, 38.4, 37.9))
#: the simulator steps between a window's frames, and where the first window starts
SPACING, START = 4, 60


def _scenes(dim: int) -> tuple[tuple[tuple[float, ...], ...], str, Any]:
    """The scene throws for points of ``dim`` coordinates, their parameters' names and the
    simulator that throws them (its extra checked here, in one line)."""
    from ..extras import require
    if dim == 2:
        require("tpnet_ref.sim", "sim", "tpnet vectors (the scene windows)")
        from ..sim import simulate
        return SCENES, "force, angle, x, y", simulate
    if dim == 3:
        require("mujoco", "sim3d", "tpnet vectors (the 3-D scene windows)")
        from ..sim.scene3d import simulate3d
        return SCENES3D, "force, azimuth, elevation, x, y, z", simulate3d
    raise ValueError(f"conformance cases: the scenes are 2-D and 3-D, the network takes "
                     f"points of dim={dim}")


def _coords(dim: int) -> str:
    """``x and y``, ``x, y and z``: the coordinates an edge case moves."""
    names = list("xyz"[:dim])
    return ", ".join(names[:-1]) + " and " + names[-1]


def make_cases(config: TPNetConfig, params: dict[str, np.ndarray],
               rollout_steps: int = 3, seed: int = 0) -> list[Case]:
    """The conformance cases for a network with ``config.m`` frames of ``config.dim``-D points
    (the 2-D scene, the ``sim`` extra; the 3-D scene, the ``sim3d`` extra): two scene windows,
    one with each frame's points shuffled, one with ragged N, the scene pushed against the low
    and the high edge of the normalisation range (the trained box), and ``rollout_steps`` steps
    of a rollout (each step's window holds the reference's float64 predictions as its newest
    frames)."""
    m = config.m
    rng = np.random.default_rng(seed)
    span = SPACING * (m - 1) + 1
    scenes, labels, simulate = _scenes(config.dim)
    wins = []
    for scene in scenes:
        traj = simulate(*scene, steps=START + span + 1)
        wins.append([traj[START + SPACING * t] for t in range(m)])
    a, b = wins
    cases = [Case("scene1", f"simulated scene {scenes[0]} ({labels}), frames "
                  f"{START}, {START + SPACING}, ... of the trajectory", a),
             Case("scene2", f"simulated scene {scenes[1]}", b),
             Case("shuffled", "scene1 with each frame's points in a random order",
                  [f[rng.permutation(len(f))] for f in a])]
    keep = [max(1, len(f) - 4 * t - 3 * (t % 2)) for t, f in enumerate(b)]
    cases.append(Case("ragged", f"scene2 with frames of {keep} points (random subsets)",
                      [f[np.sort(rng.choice(len(f), k, replace=False))]
                       for f, k in zip(b, keep)]))
    lo, hi = config.norm_lo, config.norm_hi
    allpts = np.concatenate(a)
    coords = _coords(config.dim)
    cases.append(Case("edge_low", "scene1 moved against the low edge of the normalisation "
                      f"range (its smallest {coords} at norm_lo)",
                      [f - allpts.min(axis=0) + lo for f in a]))
    cases.append(Case("edge_high", f"scene1 moved against the high edge (its largest {coords} "
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


__all__ = ["Case", "SCENES", "SCENES3D", "SPACING", "START", "make_cases"]
