"""The paper's soft-body scene (docs/spec.md §5) in pymunk, made to behave like Box2D 2.3.

``simulate(force, angle_deg, x, y)`` returns the ``(steps, 30, 2)`` particle centres in world
units. Row ``k`` is the state after ``k + 1`` steps of ``dt`` (a Box2D script that steps, then
records), so 600 rows are 600 steps; ``include_initial=True`` puts the initial state (the
undeformed ring) first instead. A model frame is every 4th row: model frame ``j`` is row
``4 j``, and "inputs are frames 0, 4, ..., 4(m-1)" means rows 0, 4, ..., 4(m-1).

Division of labour per step (see docs/simulator.md for why each piece is there):

* pymunk (Chipmunk2D) holds the 30 particle bodies, integrates their positions, applies gravity
  and solves the particle-particle contacts (except spring-connected pairs) with Box2D's contact
  slop (0.005) and mixing rules.
* a Numba kernel does what Box2D's island solver does with the springs and the walls, in
  Box2D's order: soft distance joints (implicit soft constraint, gamma/bias from frequency and
  damping ratio; stable at any stiffness, loses energy even with damping ratio 0, as Box2D
  does) and the wall contacts (friction then normal, restitution above 1 unit/s), warm-started,
  ``iterations`` passes; then Box2D's velocity clamps (translation 2 and rotation pi/2 per
  step), the walls' continuous collision (a particle stops at core distance
  ``radius + skin - 3 slop`` = 0.145 from a wall instead of tunnelling), and the walls'
  position correction. The four walls are axis-aligned half-planes in the kernel, not pymunk
  shapes, so no particle can leave the box at any speed.
* Box2D's island sleeping (all bodies slower than 0.01 units/s and 2 deg/s for 0.5 s) freezes the
  body when ``sleep=True``; the released world runs with ``doSleep=False``, the default here.

The start impulse acts where the released code applies it, at the ring centre
(``impulse_point="ring_centre"``): each particle also receives the angular impulse
``(c - p) x J`` (thousands of rad/s), which Box2D's solver clamps to ``max_rotation`` (pi/2)
per step; the spinning particles then roll and slide at every wall contact (friction 1).
``impulse_point="particle_centre"`` is the centre-of-mass convention (no spin).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..extras import require
from .params import check_fields, check_number, check_positive

# Box2D 2.3 constants (b2Settings.h) that shape the original data
B2_LINEAR_SLOP = 0.005
B2_POLYGON_RADIUS = 2.0 * B2_LINEAR_SLOP          # skin of every Box2D polygon (the walls)
B2_MAX_TRANSLATION = 2.0                           # per step
B2_MAX_ROTATION = 0.5 * math.pi                    # per step
B2_VELOCITY_THRESHOLD = 1.0                        # restitution only above this approach speed
B2_LINEAR_SLEEP_TOLERANCE = 0.01
B2_ANGULAR_SLEEP_TOLERANCE = 2.0 / 180.0 * math.pi
B2_TIME_TO_SLEEP = 0.5


@dataclass(frozen=True)
class SceneParams:
    """Every parameter of the scene; defaults are the paper's / Box2D's values (docs/spec.md §5).

    Lengths in world units, times in seconds, angles in degrees unless named ``*_rad``.
    """

    n_particles: int = 30
    ring_radius: float = 2.0
    particle_radius: float = 0.15
    density: float = 1.0
    gravity: tuple[float, float] = (0.0, -0.5)
    frequency: float = 1.0               # spring frequency, Hz
    damping_ratio: float = 0.0
    spring_reach: int = 12               # springs join particles whose index distance is 1..reach
    particle_friction: float = 1.0
    wall_friction: float = 1.0
    particle_restitution: float = 0.0
    wall_restitution: float = 0.0        # what the released code's Box2D ran with (paper lists 1)
    dt: float = 1.0 / 45.0
    iterations: int = 10                 # velocity iterations (contacts in pymunk, springs here)
    box_size: float = 45.0               # outer size of the square; free area [t, size - t]^2
    wall_thickness: float = 1.0         # sets the free area; walls are half-planes
    walls: bool = True
    wall_skin: float = B2_POLYGON_RADIUS
    contact_slop: float = B2_LINEAR_SLOP
    contact_bias: float = 0.2            # fraction of penetration (beyond slop) removed per step
    restitution_threshold: float = B2_VELOCITY_THRESHOLD
    max_translation: float | None = B2_MAX_TRANSLATION   # per step; None: no clamp
    max_rotation: float | None = B2_MAX_ROTATION         # radians per step; None: no clamp
    continuous: bool = True              # time-of-impact handling against the walls
    sleep: bool = False                  # Box2D island sleeping (the released world: off)
    impulse_point: str = "ring_centre"   # where the start impulse acts (see IMPULSE_POINTS)

    @property
    def mass(self) -> float:
        return self.density * math.pi * self.particle_radius ** 2

    @property
    def inertia(self) -> float:
        return 0.5 * self.mass * self.particle_radius ** 2

    @property
    def free_lo(self) -> float:
        """Inner face of the left / bottom wall."""
        return self.wall_thickness

    @property
    def free_hi(self) -> float:
        """Inner face of the right / top wall."""
        return self.box_size - self.wall_thickness

    @property
    def toi_distance(self) -> float:
        """Centre-to-wall distance at which Box2D's continuous collision stops a particle."""
        return max(self.contact_slop,
                   self.particle_radius + self.wall_skin - 3.0 * self.contact_slop)

    @property
    def toi_stop(self) -> float:
        """Centre-to-wall distance where a time-of-impact event leaves a particle: Box2D's TOI
        position solve (baumgarte 0.75, done once the separation was >= -1.5 slop) from
        ``toi_distance``; 0.154375 with the default values."""
        touch = self.particle_radius + self.wall_skin
        sep = self.toi_distance - touch
        for _ in range(20):
            before = sep
            sep -= min(max(0.75 * (sep + self.contact_slop), -0.2), 0.0)
            if before >= -1.5 * self.contact_slop:
                break
        return touch + sep


#: where each particle's start impulse is applied: "ring_centre" (the released code,
#: ``ApplyLinearImpulse(J, point=soft_body_center)``: the particle also gets the angular impulse
#: ``(c - p) x J``, clamped by Box2D to ``max_rotation`` per step) or "particle_centre" (the
#: centre of mass: no spin; this project's convention before the released code was read)
IMPULSE_POINTS = ("ring_centre", "particle_centre")
_INT_FIELDS = ("n_particles", "spring_reach", "iterations")
_BOOL_FIELDS = ("walls", "continuous", "sleep")
#: pymunk stores the iteration count in a C int
_MAX_ITERATIONS = 1_000_000
#: coordinates must resolve a particle radius to this many parts (float64 resolution)
_RESOLUTION = 1000.0
_POS_FIELDS = ("ring_radius", "particle_radius", "density", "frequency", "dt", "box_size",
               "wall_thickness")
_NONNEG_FIELDS = ("damping_ratio", "particle_friction", "wall_friction", "particle_restitution",
                  "wall_restitution", "wall_skin", "contact_slop", "restitution_threshold")


def validate_params(p: SceneParams) -> None:
    """Raise ``ValueError``/``TypeError`` naming the first parameter the simulator cannot handle."""
    if not isinstance(p, SceneParams):
        raise TypeError(f"params: expected a SceneParams, got {type(p).__name__}")
    check_fields(p, _INT_FIELDS, _BOOL_FIELDS)
    if not isinstance(p.impulse_point, str) or p.impulse_point not in IMPULSE_POINTS:
        raise ValueError(f"impulse_point: must be one of {', '.join(IMPULSE_POINTS)}, got "
                         f"{p.impulse_point!r}")
    if p.iterations > _MAX_ITERATIONS:
        raise ValueError(f"iterations: must be <= {_MAX_ITERATIONS}, got {p.iterations}")
    if p.n_particles < 3:
        raise ValueError(f"n_particles: need at least 3, got {p.n_particles}")
    if not 1 <= p.spring_reach <= p.n_particles // 2:
        raise ValueError(f"spring_reach: must be in 1..{p.n_particles // 2}, got {p.spring_reach}")
    if p.iterations < 1:
        raise ValueError(f"iterations: must be >= 1, got {p.iterations}")
    check_positive(p, _POS_FIELDS)
    mass = p.mass
    if not (math.isfinite(mass) and mass > 0 and math.isfinite(1.0 / mass)
            and 0 < p.inertia < math.inf and math.isfinite(1.0 / p.inertia)):
        raise ValueError(f"density, particle_radius: {p.density}, {p.particle_radius} give a "
                         f"particle mass {mass:g} (inertia {p.inertia:g}) that float64 cannot "
                         "invert")
    for name in _NONNEG_FIELDS:
        if check_number(getattr(p, name), name) < 0:
            raise ValueError(f"{name}: must be >= 0, got {getattr(p, name)}")
    for name in ("particle_restitution", "wall_restitution"):
        if getattr(p, name) > 1:
            raise ValueError(f"{name}: must be <= 1 (energy would grow), got {getattr(p, name)}")
    if not 0 < check_number(p.contact_bias, "contact_bias") <= 1:
        raise ValueError(f"contact_bias: must be in (0, 1], got {p.contact_bias}")
    for name in ("max_translation", "max_rotation"):
        v = getattr(p, name)
        if v is not None and check_number(v, name) <= 0:
            raise ValueError(f"{name}: must be > 0 or None, got {v}")
    g = p.gravity
    if not isinstance(g, (tuple, list, np.ndarray)) or len(g) != 2:
        raise ValueError(f"gravity: expected a pair (gx, gy), got {g!r}")
    for k, gi in enumerate(g):
        if abs(check_number(gi, f"gravity[{k}]")) * p.dt ** 2 > 1e6:
            raise ValueError(f"gravity[{k}]: {gi} moves a particle more than 1e6 per step")
    if not 1e-12 <= p.mass <= 1e12:
        raise ValueError(f"density: gives a particle mass of {p.mass:g}; it must be within "
                         "1e-12..1e12")
    if p.walls and p.box_size <= 2 * p.wall_thickness + 2 * (p.ring_radius + p.particle_radius):
        raise ValueError(f"box_size: {p.box_size} leaves no room for the body "
                         f"(wall_thickness {p.wall_thickness}, ring_radius {p.ring_radius})")
    # neighbouring particles must not overlap at rest (Box2D would push the ring apart)
    gap = 2 * p.ring_radius * math.sin(math.pi / p.n_particles)
    if gap <= 2 * p.particle_radius:
        raise ValueError(f"particle_radius: {p.particle_radius} makes neighbouring particles "
                         f"overlap on a ring of radius {p.ring_radius} with "
                         f"{p.n_particles} particles")
    if p.frequency * p.dt > 1e4:
        raise ValueError(f"frequency: {p.frequency} Hz is beyond what the soft-constraint "
                         f"solver resolves at dt={p.dt} (frequency*dt must be <= 1e4)")


# --------------------------------------------------------------------------- geometry
def ring_positions(x: float, y: float, n_particles: int = 30,
                   ring_radius: float = 2.0) -> np.ndarray:
    """``(n, 2)`` start positions: particle i at angle ``2 pi i / n`` from +y towards +x."""
    a = np.arange(n_particles) * (2.0 * np.pi / n_particles)
    return np.stack([x + ring_radius * np.sin(a), y + ring_radius * np.cos(a)], axis=1)


def spring_pairs(n_particles: int = 30, spring_reach: int = 12) -> np.ndarray:
    """``(S, 2)`` int index pairs ``(i, j)`` with circular index distance 1..reach (S = n*reach,
    or fewer when ``2 reach >= n``), in the order the springs are created."""
    pairs = []
    seen = set()
    for i in range(n_particles):
        for d in range(1, spring_reach + 1):
            j = (i + d) % n_particles
            key = (min(i, j), max(i, j))
            if key not in seen:
                seen.add(key)
                pairs.append((i, j))
    return np.asarray(pairs, dtype=np.int64)


def connected_matrix(n_particles: int = 30, spring_reach: int = 12) -> np.ndarray:
    """``(n, n)`` bool: True where two particles share a spring (they do not collide)."""
    pairs = spring_pairs(n_particles, spring_reach)
    c = np.zeros((n_particles, n_particles), dtype=bool)
    c[pairs[:, 0], pairs[:, 1]] = True
    c[pairs[:, 1], pairs[:, 0]] = True
    return c



# --------------------------------------------------------------------------- the scene
def _advance() -> Any:
    """The Numba step kernel (:func:`tpnet_ref.sim.kernel.advance`), imported on first use so
    that a missing numba is one line naming the ``sim`` extra."""
    require("numba", "sim")
    from .kernel import advance  # imports numba; compiled code is cached on disk
    return advance


@dataclass
class Scene:
    """A built scene: the pymunk space, its particle bodies (in index order) and spring state."""

    params: SceneParams
    space: Any
    bodies: list
    pairs: np.ndarray            # (S, 2) spring index pairs
    rest: np.ndarray             # (S,) rest lengths
    lam: np.ndarray              # (S,) accumulated spring impulses (warm starting)
    inv_mass: np.ndarray         # (N,)
    buf: np.ndarray              # ((N + n_static), 5) pymunk batch layout: x, y, vx, vy, w
    wall_ln: np.ndarray          # (N, 4) accumulated wall normal impulses (left, right, bottom,
    wall_lt: np.ndarray          # (N, 4) top) and friction impulses, for warm starting
    sleep_time: float = 0.0
    asleep: bool = False
    stepped: bool = False        # the initial state is returned as built
    _batch: Any = field(default=None, repr=False)
    _const: tuple = field(default=(), repr=False)

    @property
    def n(self) -> int:
        return self.params.n_particles

    def __post_init__(self) -> None:
        # the kernel's constant arguments, computed once
        p = self.params
        self._const = (
            np.ascontiguousarray(self.pairs[:, 0]), np.ascontiguousarray(self.pairs[:, 1]),
            self.rest, self.inv_mass, p.dt, 2.0 * math.pi * p.frequency, p.damping_ratio,
            p.iterations, p.contact_slop, p.max_translation or 0.0, p.max_rotation or 0.0,
            p.walls, p.walls and p.continuous, p.free_lo + p.toi_distance,
            p.free_hi - p.toi_distance, p.free_lo, p.free_hi, p.particle_radius + p.wall_skin,
            p.particle_radius, p.toi_stop, p.mass, p.inertia,
            math.sqrt(p.particle_friction * p.wall_friction),
            max(p.particle_restitution, p.wall_restitution), p.restitution_threshold)

    def read(self) -> np.ndarray:
        """Pull positions/velocities of all bodies into ``buf`` (one pymunk batch call).

        pymunk's particle-particle position correction is applied after the kernel's wall
        handling; where it has pushed a centre past the walls' time-of-impact distance, the
        particle is put back where Box2D's continuous collision would have stopped it (its
        velocity into the wall removed). Rare: crushed bodies at high speed."""
        pb, fields, getbuf, setbuf = self._batch
        getbuf.clear()
        pb.get_space_bodies(self.space, fields, getbuf)
        b = self.buf
        b[...] = np.frombuffer(getbuf.float_buf()).reshape(b.shape)
        p = self.params
        if p.walls and p.continuous and self.stepped:
            n = self.n
            pos = b[:n, 0:2]
            lo = p.free_lo + p.toi_distance
            hi = p.free_hi - p.toi_distance
            if pos.min() < lo or pos.max() > hi:
                stop = p.toi_stop
                vel = b[:n, 2:4]
                low = pos < lo
                high = pos > hi
                pos[low] = p.free_lo + stop
                pos[high] = p.free_hi - stop
                vel[low & (vel < 0)] = 0.0
                vel[high & (vel > 0)] = 0.0
                pb.set_space_bodies(self.space, fields, setbuf)
        return b

    def positions(self) -> np.ndarray:
        """``(N, 2)`` current particle centres (a copy)."""
        return self.read()[: self.n, 0:2].copy()

    def energy(self, springs: bool = True) -> float:
        """Mechanical energy now (from ``buf``; call ``read`` first): linear and rotational
        kinetic and gravitational energy, plus (``springs``) the springs' potential energy as
        ideal springs of stiffness ``mu (2 pi f)^2``."""
        p = self.params
        n = self.n
        b = self.buf
        # pymunk's stored velocity already holds the next step's gravity kick; remove it
        v = b[:n, 2:4] - p.dt * np.asarray(p.gravity, dtype=float)
        ke = 0.5 * p.mass * float((v ** 2).sum()) + 0.5 * p.inertia * float((b[:n, 4] ** 2).sum())
        pe = -p.mass * float((b[:n, 0:2] @ np.asarray(p.gravity, dtype=float)).sum())
        if not springs:
            return ke + pe
        d = b[self.pairs[:, 1], 0:2] - b[self.pairs[:, 0], 0:2]
        stretch = np.sqrt((d ** 2).sum(1)) - self.rest
        return ke + pe + 0.5 * spring_energy_k(p) * float((stretch ** 2).sum())

    def step(self) -> None:
        """Advance one ``dt`` (velocities in ``buf`` must be current: call ``read`` first)."""
        p = self.params
        if self.asleep:
            return
        n = self.n
        b = self.buf
        pos = np.ascontiguousarray(b[:n, 0:2])
        vel = np.ascontiguousarray(b[:n, 2:4])
        ang = np.ascontiguousarray(b[:n, 4])
        out = np.empty_like(pos)
        vmax2, wmax2 = _advance()(pos, vel, ang, out, self.lam, self.wall_ln, self.wall_lt,
                                  *self._const)
        if p.sleep:
            if (vmax2 > B2_LINEAR_SLEEP_TOLERANCE ** 2
                    or wmax2 > B2_ANGULAR_SLEEP_TOLERANCE ** 2):
                self.sleep_time = 0.0
            else:
                self.sleep_time += p.dt
                if self.sleep_time >= B2_TIME_TO_SLEEP:
                    self.asleep = True
        # pymunk integrates x += dt v first: start it where that lands on the end position
        b[:n, 0:2] = out - p.dt * vel
        b[:n, 2:4] = vel
        b[:n, 4] = ang
        pb, fields, _, setbuf = self._batch
        pb.set_space_bodies(self.space, fields, setbuf)
        self.space.step(p.dt)
        self.stepped = True
        if self.asleep:  # Box2D zeroes the velocities of a sleeping island
            self.read()
            b[:n, 2:5] = 0.0
            pb.set_space_bodies(self.space, fields, setbuf)


def build_scene(x: float, y: float, force: float = 0.0, angle_deg: float = 0.0,
                params: SceneParams | None = None) -> Scene:
    """Build the pymunk space for a body centred at ``(x, y)`` that has received the impulse
    ``force (cos a, sin a)`` per particle (validated: finite, body inside the free area)."""
    pymunk = require("pymunk", "sim")
    pb = require("pymunk.batch", "sim")

    p = params or SceneParams()
    validate_params(p)
    x = check_number(x, "x")
    y = check_number(y, "y")
    force = check_number(force, "force")
    angle_deg = check_number(angle_deg, "angle_deg")
    if force < 0:
        raise ValueError(f"force: must be >= 0 (use angle_deg for the direction), got {force}")
    extent = max(abs(x), abs(y), p.box_size if p.walls else 0.0) + p.ring_radius
    if extent * np.finfo(float).eps * _RESOLUTION > p.particle_radius:
        raise ValueError(f"x, y, ring_radius, box_size: coordinates up to {extent:g} cannot "
                         f"resolve particles of radius {p.particle_radius:g} in float64")
    if not math.isfinite(force / p.mass * max(1.0, p.dt)):
        raise ValueError(f"force: {force:g} gives a non-finite velocity for particles of mass "
                         f"{p.mass:g}")
    if force / p.mass * p.dt > 1e6:
        raise ValueError(f"force: {force} moves a particle more than 1e6 per step; "
                         "beyond what the simulator resolves")
    if p.walls:
        # the paper draws centres from [2.9, 42.1]: particle centres may start up to one
        # particle radius inside a wall (contacts push them out, as in Box2D)
        reach = p.ring_radius - p.particle_radius
        lo, hi = p.free_lo + reach, p.free_hi - reach
        for name, v in (("x", x), ("y", y)):
            if not lo <= v <= hi:
                raise ValueError(f"{name}: start centre {v} puts the body outside the box; "
                                 f"must be in [{lo:g}, {hi:g}]")

    space = pymunk.Space()
    space.gravity = (float(p.gravity[0]), float(p.gravity[1]))
    space.iterations = p.iterations
    space.collision_slop = p.contact_slop
    # pymunk removes the fraction 1 - bias**dt of the penetration per step
    space.collision_bias = (1.0 - p.contact_bias) ** (1.0 / p.dt)
    space.damping = 1.0
    # The walls are not pymunk shapes: they are four axis-aligned half-planes handled in the
    # kernel (contacts solved with the springs, time of impact, position correction). pymunk
    # handles the particle-particle contacts. Box2D mixes friction by geometric mean and
    # restitution by max; pymunk multiplies: sqrt(mu) and sqrt(e) per shape give mu and e for
    # a pair, and a pre_solve handler adds Box2D's restitution threshold when e > 0.
    e_p = p.particle_restitution
    start = ring_positions(x, y, p.n_particles, p.ring_radius)
    v0 = force / p.mass * np.array([math.cos(math.radians(angle_deg)),
                                    math.sin(math.radians(angle_deg))])
    # pymunk's stored velocity after a step already holds gravity for the next one (it
    # integrates positions first): the first step of Box2D sees v0 + g dt
    v0 = v0 + p.dt * np.asarray(p.gravity, dtype=float)
    w0 = start_spin(start, x, y, force, angle_deg, p)
    bodies = []
    index: dict[Any, int] = {}
    for i in range(p.n_particles):
        body = pymunk.Body()
        body.position = (float(start[i, 0]), float(start[i, 1]))
        body.velocity = (float(v0[0]), float(v0[1]))
        body.angular_velocity = float(w0[i])
        shape = pymunk.Circle(body, p.particle_radius)
        shape.density = p.density
        shape.friction = math.sqrt(p.particle_friction)
        shape.elasticity = math.sqrt(e_p)
        shape.collision_type = 1
        space.add(body, shape)
        bodies.append(body)
        index[shape] = i
    connected = connected_matrix(p.n_particles, p.spring_reach)

    def begin(arbiter: Any, _space: Any, _data: Any) -> None:
        a, b = arbiter.shapes
        if connected[index[a], index[b]]:
            arbiter.process_collision = False   # Box2D: collideConnected = False

    def particle_pre_solve(arbiter: Any, _space: Any, _data: Any) -> None:
        # Box2D: max(e_p, e_p) = e_p, and only above the restitution threshold
        a, b = arbiter.bodies
        vrel = (b.velocity - a.velocity).dot(arbiter.normal)
        arbiter.restitution = e_p if abs(vrel) > p.restitution_threshold else 0.0

    space.on_collision(1, 1, begin=begin, pre_solve=particle_pre_solve if e_p > 0 else None)

    pairs = spring_pairs(p.n_particles, p.spring_reach)
    rest = np.linalg.norm(start[pairs[:, 1]] - start[pairs[:, 0]], axis=1)
    inv_mass = np.array([1.0 / bd.mass for bd in bodies])
    fields = pb.BodyFields.POSITION | pb.BodyFields.VELOCITY | pb.BodyFields.ANGULAR_VELOCITY
    getbuf = pb.Buffer()
    pb.get_space_bodies(space, fields, getbuf)
    raw = np.frombuffer(getbuf.float_buf())
    buf = raw.copy().reshape(-1, 5)
    setbuf = pb.Buffer()
    setbuf.set_float_buf(buf)
    scene = Scene(params=p, space=space, bodies=bodies, pairs=pairs, rest=rest,
                  lam=np.zeros(len(pairs)), inv_mass=inv_mass, buf=buf,
                  wall_ln=np.zeros((p.n_particles, 4)), wall_lt=np.zeros((p.n_particles, 4)))
    scene._batch = (pb, fields, getbuf, setbuf)
    return scene


def start_spin(start: np.ndarray, x: float, y: float, force: float, angle_deg: float,
                params: SceneParams) -> np.ndarray:
    """``(N,)`` angular velocity (rad/s) each particle starts with: ``(c - p_i) x J / I`` for an
    impulse ``J = force (cos a, sin a)`` applied at the ring centre ``c = (x, y)`` (Box2D's
    ``ApplyLinearImpulse``), zero for ``impulse_point="particle_centre"``. With the paper's values
    the lever arm is the ring radius, so up to ~4,000 rad/s at F = 1.6 (bench/stability.py
    --first-step: 4,019); Box2D's solver then limits the
    rotation to ``max_rotation`` per step (pi/2, i.e. 70.7 rad/s at dt = 1/45) after the first
    step's velocity solve."""
    if params.impulse_point == "particle_centre":
        return np.zeros(len(start))
    a = math.radians(angle_deg)
    jx, jy = force * math.cos(a), force * math.sin(a)
    rx, ry = x - start[:, 0], y - start[:, 1]
    return (rx * jy - ry * jx) / params.inertia


def simulate(force: float, angle_deg: float, x: float, y: float, steps: int = 600, *,
             params: SceneParams | None = None, include_initial: bool = False,
             return_energy: bool = False,
             **kwargs: Any) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Particle centres ``(steps, n_particles, 2)`` (float64, world units) of one trajectory.

    ``force``: impulse magnitude per particle; ``angle_deg``: its direction (0 = +x, 90 = +y);
    ``(x, y)``: start centre of the ring; the impulse acts at the ring centre (``impulse_point=
    "ring_centre"``, the released code: every particle also spins) or at each particle's centre
    (``impulse_point="particle_centre"``). Row ``k`` is the state after ``k + 1`` steps of ``dt``
    (row 0: after the first step), the paper's convention (docs/simulator.md); with
    ``include_initial`` row 0 is the initial state and row ``k`` the state after ``k`` steps.
    Any ``SceneParams`` field can be given as a keyword (e.g. ``frequency=4``,
    ``walls=False``); unknown keywords raise ``TypeError``. With ``return_energy`` also the
    ``(steps,)`` mechanical energy per row (``Scene.energy``).
    """
    if isinstance(steps, (bool, np.bool_)) or not isinstance(steps, (int, np.integer)):
        raise TypeError(f"steps: expected an integer, got {type(steps).__name__}")
    if steps < 1:
        raise ValueError(f"steps: must be >= 1, got {steps}")
    if not isinstance(return_energy, (bool, np.bool_)):
        raise TypeError(f"return_energy: expected a bool, got {type(return_energy).__name__}")
    p = SceneParams() if params is None else params
    if not isinstance(p, SceneParams):
        raise TypeError(f"params: expected a SceneParams, got {type(p).__name__}")
    if kwargs:
        p = _replace(p, kwargs)
    scene = build_scene(x, y, force, angle_deg, p)
    n = p.n_particles
    try:
        out = np.empty((steps, n, 2))
        en = np.empty(steps) if return_energy else None
    except MemoryError:
        raise ValueError(f"steps: {steps} rows of {n} particles do not fit in memory") from None
    buf = scene.read()
    for k in range(steps):
        if k or not include_initial:
            if scene.asleep:        # nothing moves any more: repeat the last row
                out[k:] = out[k - 1]
                if en is not None:
                    en[k:] = en[k - 1]
                break
            scene.step()
            buf = scene.read()
        out[k] = buf[:n, 0:2]
        if en is not None:
            en[k] = scene.energy()
    if not np.isfinite(out).all():  # pragma: no cover - guarded by validation and the solver
        raise FloatingPointError("simulate: non-finite positions; parameters beyond the solver")
    return (out, en) if en is not None else out


def _replace(p: SceneParams, kwargs: dict[str, Any]) -> SceneParams:
    names = {f.name for f in dataclasses.fields(SceneParams)}
    bad = sorted(set(kwargs) - names)
    if bad:
        raise TypeError(f"simulate: unknown parameter(s) {', '.join(bad)}")
    if "gravity" in kwargs:
        g = kwargs["gravity"]
        if not isinstance(g, (tuple, list, np.ndarray)):
            raise TypeError(f"gravity: expected a pair (gx, gy), got {type(g).__name__}")
        kwargs = dict(kwargs, gravity=tuple(g))
    return dataclasses.replace(p, **kwargs)


def spring_energy_k(params: SceneParams) -> float:
    """Stiffness of one spring, ``mu (2 pi f)^2`` with the pair's reduced mass ``mu = m/2``."""
    return 0.5 * params.mass * (2.0 * math.pi * params.frequency) ** 2


__all__ = ["SceneParams", "Scene", "simulate", "build_scene", "ring_positions", "spring_pairs",
           "connected_matrix", "validate_params", "spring_energy_k", "start_spin",
           "IMPULSE_POINTS"]
