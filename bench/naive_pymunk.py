"""A straightforward pymunk port of the scene (for comparison only, not used by the package).

pymunk defaults everywhere: DampedSpring springs of stiffness mu (2 pi f)^2 (explicit), contact
slop 0.1, default collision bias, friction and restitution multiplied, no continuous collision,
no velocity clamps, no sleeping; walls are 1-thick boxes without skin.
"""
from __future__ import annotations

import math

import numpy as np

from tpnet_ref.sim import ring_positions, spring_pairs


def simulate_naive(force: float, angle_deg: float, x: float, y: float, steps: int = 600, *,
                   frequency: float = 1.0, dt: float = 1 / 45) -> np.ndarray:
    import pymunk

    space = pymunk.Space()
    space.gravity = (0.0, -0.5)
    space.iterations = 10
    for x0, y0, x1, y1 in ((0, 0, 45, 1), (0, 44, 45, 45), (0, 0, 1, 45), (44, 0, 45, 45)):
        w = pymunk.Poly(space.static_body, [(x0, y0), (x1, y0), (x1, y1), (x0, y1)])
        w.friction, w.elasticity = 1.0, 0.0
        space.add(w)
    start = ring_positions(x, y)
    bodies = []
    for i in range(30):
        b = pymunk.Body()
        b.position = tuple(start[i])
        s = pymunk.Circle(b, 0.15)
        s.density, s.friction, s.elasticity = 1.0, 1.0, 0.0
        s.filter = pymunk.ShapeFilter(group=1)  # no particle-particle contacts at all
        space.add(b, s)
        bodies.append(b)
    m = bodies[0].mass
    k = 0.5 * m * (2 * math.pi * frequency) ** 2
    for i, j in spring_pairs():
        a, b = bodies[i], bodies[j]
        rest = float(np.linalg.norm(start[i] - start[j]))
        space.add(pymunk.DampedSpring(a, b, (0, 0), (0, 0), rest, k, 0.0))
    for b in bodies:
        b.apply_impulse_at_local_point((force * math.cos(math.radians(angle_deg)),
                                        force * math.sin(math.radians(angle_deg))))
    out = np.empty((steps, 30, 2))
    for t in range(steps):      # row t: after t + 1 steps, as tpnet_ref.sim
        space.step(dt)
        out[t] = [tuple(b.position) for b in bodies]
    return out
