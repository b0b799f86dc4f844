"""The paper's soft-body scene in Box2D 2.3 (pybox2d), used only to validate ``tpnet_ref.sim``.

Needs pybox2d (the ``box2d`` extra, ``box2d==2.3.10``, the engine version of the paper), imported on
first use; used by ``bench/compare_box2d.py``, ``bench/stability.py`` and skip-if-missing tests,
never by the rest of the package.

Built from docs/spec.md §5 and the Box2D 2.3 manual: static box walls (fixtures with friction and
restitution), dynamic circle particles (density 1, friction 1, restitution 0), soft distance joints
between every pair within index reach 12 (``frequencyHz``, ``dampingRatio``; ``collideConnected``
False), an impulse ``F (cos a, sin a)`` on every particle at t = 0, ``world.Step(dt, 10, 10)``.
Everything else is Box2D's default (warm starting, continuous collision, sleeping allowed).

Row k of the result is the state after k + 1 steps, or after k steps with ``include_initial``
(row 0 then the initial state), as in ``tpnet_ref.sim``.
"""
from __future__ import annotations

import math

import numpy as np

from ..extras import require


def simulate_box2d(force: float, angle_deg: float, x: float, y: float, steps: int = 600, *,
                   n_particles: int = 30, ring_radius: float = 2.0, particle_radius: float = 0.15,
                   density: float = 1.0, gravity: tuple[float, float] = (0.0, -0.5),
                   frequency: float = 1.0, damping_ratio: float = 0.0, spring_reach: int = 12,
                   particle_friction: float = 1.0, wall_friction: float = 1.0,
                   particle_restitution: float = 0.0, wall_restitution: float = 0.0,
                   dt: float = 1.0 / 45.0, velocity_iterations: int = 10,
                   position_iterations: int = 10, box_size: float = 45.0,
                   wall_thickness: float = 1.0, walls: bool = True,
                   impulse_point: str = "ring_centre", sleep: bool = False,
                   include_initial: bool = False) -> np.ndarray:
    """Positions ``(steps, n_particles, 2)`` in world units of the Box2D scene."""
    B = require("Box2D", "box2d")

    world = B.b2World(gravity=gravity, doSleep=sleep)
    if walls:
        ht = wall_thickness / 2.0
        hs = box_size / 2.0
        for cx, cy, hx, hy in ((hs, ht, hs, ht), (hs, box_size - ht, hs, ht),
                               (ht, hs, ht, hs), (box_size - ht, hs, ht, hs)):
            body = world.CreateStaticBody(position=(cx, cy))
            body.CreateFixture(B.b2FixtureDef(shape=B.b2PolygonShape(box=(hx, hy)),
                                              friction=wall_friction,
                                              restitution=wall_restitution))
    bodies = []
    for i in range(n_particles):
        a = i * 2.0 * math.pi / n_particles
        body = world.CreateDynamicBody(position=(x + ring_radius * math.sin(a),
                                                 y + ring_radius * math.cos(a)))
        body.CreateFixture(B.b2FixtureDef(shape=B.b2CircleShape(radius=particle_radius),
                                          density=density, friction=particle_friction,
                                          restitution=particle_restitution))
        bodies.append(body)
    for i in range(n_particles):
        for d in range(1, spring_reach + 1):
            j = (i + d) % n_particles
            if d > n_particles // 2 or (2 * d == n_particles and j < i):
                continue
            a, b = bodies[i], bodies[j]
            world.CreateDistanceJoint(bodyA=a, bodyB=b, anchorA=a.position, anchorB=b.position,
                                      frequencyHz=frequency, dampingRatio=damping_ratio,
                                      collideConnected=False)
    ix = force * math.cos(math.radians(angle_deg))
    iy = force * math.sin(math.radians(angle_deg))
    if impulse_point not in ("ring_centre", "particle_centre"):
        raise ValueError(f"impulse_point: 'ring_centre' or 'particle_centre', got {impulse_point!r}")
    for body in bodies:
        # released code: ApplyLinearImpulse(impulse, point=soft_body_center, wake=True)
        point = (x, y) if impulse_point == "ring_centre" else body.worldCenter
        body.ApplyLinearImpulse((ix, iy), point, True)
    out = np.empty((steps, n_particles, 2))
    for k in range(steps):
        if k or not include_initial:
            world.Step(dt, velocity_iterations, position_iterations)
        out[k] = [tuple(b.worldCenter) for b in bodies]
    return out


def n_springs(n_particles: int = 30, spring_reach: int = 12) -> int:
    """Number of distinct pairs within circular index distance ``1..spring_reach``."""
    return len({tuple(sorted((i, (i + d) % n_particles)))
                for i in range(n_particles) for d in range(1, spring_reach + 1)})
