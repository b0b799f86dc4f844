"""The paper's soft-body scene (SPEC section 5) in pymunk, made to behave like Box2D 2.3.

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
  body, as it does in Box2D.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

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
    """Every parameter of the scene; defaults are the paper's / Box2D's values (SPEC section 5).

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
    sleep: bool = True                   # Box2D island sleeping

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


def _check_number(value: Any, name: str) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer,
                                                                      np.floating)):
        raise TypeError(f"{name}: expected a real number, got {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name}: must be finite, got {v}")
    return v


def validate_params(p: SceneParams) -> None:
    """Raise ``ValueError``/``TypeError`` naming the first parameter the simulator cannot handle."""
    if not isinstance(p, SceneParams):
        raise TypeError(f"params: expected a SceneParams, got {type(p).__name__}")
    for name in _INT_FIELDS:
        v = getattr(p, name)
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
            raise TypeError(f"{name}: expected an integer, got {type(v).__name__}")
    for name in _BOOL_FIELDS:
        if not isinstance(getattr(p, name), (bool, np.bool_)):
            raise TypeError(f"{name}: expected a bool, got {type(getattr(p, name)).__name__}")
    if p.iterations > _MAX_ITERATIONS:
        raise ValueError(f"iterations: must be <= {_MAX_ITERATIONS}, got {p.iterations}")
    if p.n_particles < 3:
        raise ValueError(f"n_particles: need at least 3, got {p.n_particles}")
    if not 1 <= p.spring_reach <= p.n_particles // 2:
        raise ValueError(f"spring_reach: must be in 1..{p.n_particles // 2}, got {p.spring_reach}")
    if p.iterations < 1:
        raise ValueError(f"iterations: must be >= 1, got {p.iterations}")
    for name in _POS_FIELDS:
        if _check_number(getattr(p, name), name) <= 0:
            raise ValueError(f"{name}: must be > 0, got {getattr(p, name)}")
    mass = p.mass
    if not (math.isfinite(mass) and mass > 0 and math.isfinite(1.0 / mass)
            and 0 < p.inertia < math.inf and math.isfinite(1.0 / p.inertia)):
        raise ValueError(f"density, particle_radius: {p.density}, {p.particle_radius} give a "
                         f"particle mass {mass:g} (inertia {p.inertia:g}) that float64 cannot "
                         "invert")
    for name in _NONNEG_FIELDS:
        if _check_number(getattr(p, name), name) < 0:
            raise ValueError(f"{name}: must be >= 0, got {getattr(p, name)}")
    for name in ("particle_restitution", "wall_restitution"):
        if getattr(p, name) > 1:
            raise ValueError(f"{name}: must be <= 1 (energy would grow), got {getattr(p, name)}")
    if not 0 < _check_number(p.contact_bias, "contact_bias") <= 1:
        raise ValueError(f"contact_bias: must be in (0, 1], got {p.contact_bias}")
    for name in ("max_translation", "max_rotation"):
        v = getattr(p, name)
        if v is not None and _check_number(v, name) <= 0:
            raise ValueError(f"{name}: must be > 0 or None, got {v}")
    g = p.gravity
    if not isinstance(g, (tuple, list, np.ndarray)) or len(g) != 2:
        raise ValueError(f"gravity: expected a pair (gx, gy), got {g!r}")
    for k, gi in enumerate(g):
        if abs(_check_number(gi, f"gravity[{k}]")) * p.dt ** 2 > 1e6:
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


# --------------------------------------------------------------------------- numba kernels
_KERNELS: dict[str, Any] = {}


def _kernels() -> Any:
    """Compile (or load from cache) the per-step kernel; numba is imported only here."""
    if "advance" in _KERNELS:
        return _KERNELS["advance"]
    from numba import njit

    @njit(cache=True, fastmath=False)
    def advance(pos, vel, ang, out_pos, lam, wl_n, wl_t, ia, ib, rest, inv_mass, h, omega,
                zeta, iters, slop, max_tr, max_rot, walls, toi, lo, hi, face_lo, face_hi, touch,
                radius, toi_stop, mass, inertia, mu, e_wall, v_thresh):  # pragma: no cover
        """One Box2D island step for the springs and walls, in place.

        Springs (soft distance joints) and wall contacts solved together, velocity clamps,
        walls' time of impact, walls' position correction. pos (N, 2) positions now; vel (N, 2),
        ang (N,) velocities after gravity and pymunk's particle-pair contacts, updated to the
        velocities of the step; out_pos (N, 2) receives the positions at the end of the step.
        lam (S,), wl_n / wl_t (N, 4): accumulated spring and wall impulses (warm starting),
        updated. Returns the largest squared linear and angular speeds (for sleeping).
        """
        n = pos.shape[0]
        s = ia.shape[0]
        ux = np.empty(s)
        uy = np.empty(s)
        bias = np.empty(s)
        gam = np.empty(s)
        meff = np.empty(s)
        # -- wall contacts (b2ContactSolver): a particle touches a wall when its centre is
        #    closer than radius + skin to the face. Restitution bias from the approach
        #    speed before warm starting, then warm start with last step's impulses.
        skin = touch - radius
        nc = 0
        c_i = np.empty(4 * n, np.int64)
        c_k = np.empty(4 * n, np.int64)
        c_nx = np.empty(4 * n)
        c_ny = np.empty(4 * n)
        c_r = np.empty(4 * n)
        c_b = np.empty(4 * n)
        for i in range(n):
            for k in range(4):
                ax = k // 2
                side = k % 2
                gap = pos[i, ax] - face_lo if side == 0 else face_hi - pos[i, ax]
                if walls and gap < touch:
                    sg = 1.0 if side == 0 else -1.0
                    nx = sg if ax == 0 else 0.0
                    ny = sg if ax == 1 else 0.0
                    c_i[nc] = i
                    c_k[nc] = k
                    c_nx[nc] = nx
                    c_ny[nc] = ny
                    # contact point midway between the surfaces (b2WorldManifold)
                    c_r[nc] = 0.5 * (radius + gap - skin)
                    vn = vel[i, 0] * nx + vel[i, 1] * ny
                    c_b[nc] = -e_wall * vn if vn < -v_thresh else 0.0
                    nc += 1
                else:
                    wl_n[i, k] = 0.0
                    wl_t[i, k] = 0.0
        for c in range(nc):
            i = c_i[c]
            k = c_k[c]
            ln = wl_n[i, k]
            lt = wl_t[i, k]
            vel[i, 0] += (ln * c_nx[c] + lt * c_ny[c]) / mass
            vel[i, 1] += (ln * c_ny[c] - lt * c_nx[c]) / mass
            ang[i] += c_r[c] * lt / inertia
        # -- init velocity constraints + warm start (b2DistanceJoint::InitVelocityConstraints)
        for j in range(s):
            a = ia[j]
            b = ib[j]
            dx = pos[b, 0] - pos[a, 0]
            dy = pos[b, 1] - pos[a, 1]
            length = math.sqrt(dx * dx + dy * dy)
            if length > slop:
                ux[j] = dx / length
                uy[j] = dy / length
            else:
                ux[j] = 0.0
                uy[j] = 0.0
            im = inv_mass[a] + inv_mass[b]
            m = 1.0 / im
            c = length - rest[j]
            d = 2.0 * m * zeta * omega
            k = m * omega * omega
            g = h * (d + h * k)
            g = 1.0 / g if g != 0.0 else 0.0
            gam[j] = g
            bias[j] = c * h * k * g
            meff[j] = 1.0 / (im + g)
            px = lam[j] * ux[j]
            py = lam[j] * uy[j]
            vel[a, 0] -= inv_mass[a] * px
            vel[a, 1] -= inv_mass[a] * py
            vel[b, 0] += inv_mass[b] * px
            vel[b, 1] += inv_mass[b] * py
        # -- sequential impulses: joints, then contacts (b2Island::Solve)
        for _ in range(iters):
            for j in range(s):
                a = ia[j]
                b = ib[j]
                cdot = ux[j] * (vel[b, 0] - vel[a, 0]) + uy[j] * (vel[b, 1] - vel[a, 1])
                imp = -meff[j] * (cdot + bias[j] + gam[j] * lam[j])
                lam[j] += imp
                px = imp * ux[j]
                py = imp * uy[j]
                vel[a, 0] -= inv_mass[a] * px
                vel[a, 1] -= inv_mass[a] * py
                vel[b, 0] += inv_mass[b] * px
                vel[b, 1] += inv_mass[b] * py
            for c in range(nc):
                i = c_i[c]
                k = c_k[c]
                nx = c_nx[c]
                ny = c_ny[c]
                rc = c_r[c]
                tx = ny
                ty = -nx
                # friction first: velocity of the contact point v + w x r, r = -rc n
                vt = (vel[i, 0] + ang[i] * rc * ny) * tx + (vel[i, 1] - ang[i] * rc * nx) * ty
                mt = 1.0 / (1.0 / mass + rc * rc / inertia)
                lim = mu * wl_n[i, k]
                old = wl_t[i, k]
                new = min(max(old - mt * vt, -lim), lim)
                wl_t[i, k] = new
                dl = new - old
                vel[i, 0] += dl * tx / mass
                vel[i, 1] += dl * ty / mass
                ang[i] += rc * dl / inertia
                # then the normal impulse (accumulated >= 0)
                vn = vel[i, 0] * nx + vel[i, 1] * ny
                old = wl_n[i, k]
                new = max(old - mass * (vn - c_b[c]), 0.0)
                wl_n[i, k] = new
                dl = new - old
                vel[i, 0] += dl * nx / mass
                vel[i, 1] += dl * ny / mass
        vmax2 = 0.0
        wmax2 = 0.0
        for i in range(n):
            # -- b2Island::Solve velocity clamps (they change the stored velocity)
            tx = h * vel[i, 0]
            ty = h * vel[i, 1]
            t2 = tx * tx + ty * ty
            if max_tr > 0.0 and t2 > max_tr * max_tr:
                r = max_tr / math.sqrt(t2)
                vel[i, 0] *= r
                vel[i, 1] *= r
            rot = h * ang[i]
            if max_rot > 0.0 and rot * rot > max_rot * max_rot:
                ang[i] *= max_rot / abs(rot)
            v2 = vel[i, 0] * vel[i, 0] + vel[i, 1] * vel[i, 1]
            if v2 > vmax2:
                vmax2 = v2
            if ang[i] * ang[i] > wmax2:
                wmax2 = ang[i] * ang[i]
            # -- move, stopping at the walls' time of impact (b2World::SolveTOI)
            px = pos[i, 0]
            py = pos[i, 1]
            rem = 1.0
            if toi:
                for _ev in range(4):
                    best = 2.0
                    axis = -1
                    sgn = 0.0
                    for ax in range(2):
                        p = px if ax == 0 else py
                        v = vel[i, ax]
                        q = p + rem * h * v
                        if v < 0.0 and q < lo:
                            alpha = (p - lo) / (p - q) if p > lo else 0.0
                            if alpha < best:
                                best, axis, sgn = alpha, ax, 1.0
                        elif v > 0.0 and q > hi:
                            alpha = (hi - p) / (q - p) if p < hi else 0.0
                            if alpha < best:
                                best, axis, sgn = alpha, ax, -1.0
                    if axis < 0:
                        break
                    # advance to the impact
                    px += best * rem * h * vel[i, 0]
                    py += best * rem * h * vel[i, 1]
                    rem *= 1.0 - best
                    # Box2D's TOI position solve leaves the particle at toi_stop from the face
                    dist = toi_stop
                    # contact at the impact: normal n (into the free area), tangent t = (n.y, -n.x)
                    nx = sgn if axis == 0 else 0.0
                    ny = sgn if axis == 1 else 0.0
                    tx = ny
                    ty = -nx
                    vn = vel[i, 0] * nx + vel[i, 1] * ny
                    target = -e_wall * vn if vn < -v_thresh else 0.0
                    jn = mass * (target - vn)
                    # contact point midway between the two surfaces (b2WorldManifold):
                    # r = -(radius + dist - skin) / 2 n; velocity there v + w x r
                    rc = 0.5 * (radius + dist - (touch - radius))
                    rx = -rc * nx
                    ry = -rc * ny
                    vcx = vel[i, 0] - ang[i] * ry
                    vcy = vel[i, 1] + ang[i] * rx
                    vt = vcx * tx + vcy * ty
                    rt = rx * ty - ry * tx
                    mt = 1.0 / (1.0 / mass + rt * rt / inertia)
                    jt = -mt * vt
                    lim = mu * jn
                    if jt > lim:
                        jt = lim
                    elif jt < -lim:
                        jt = -lim
                    vel[i, 0] += (jn * nx + jt * tx) / mass
                    vel[i, 1] += (jn * ny + jt * ty) / mass
                    ang[i] += rt * jt / inertia
                    if axis == 0:
                        px = face_lo + dist if sgn > 0 else face_hi - dist
                    else:
                        py = face_lo + dist if sgn > 0 else face_hi - dist
                    if rem <= 0.0:
                        break
            out_pos[i, 0] = px + rem * h * vel[i, 0]
            out_pos[i, 1] = py + rem * h * vel[i, 1]
            # -- wall position correction (b2ContactSolver::SolvePositionConstraints:
            #    10 iterations, baumgarte 0.2, at most 0.2 per iteration, slop kept)
            if walls:
                for ax in range(2):
                    for side in range(2):
                        q = out_pos[i, ax]
                        sep = (q - face_lo if side == 0 else face_hi - q) - touch
                        if sep < -slop:
                            s0 = sep
                            for _it in range(10):
                                corr = 0.2 * (sep + slop)
                                if corr < -0.2:
                                    corr = -0.2
                                if corr < 0.0:
                                    sep -= corr
                            out_pos[i, ax] = q + (sep - s0 if side == 0 else s0 - sep)
        return vmax2, wmax2

    _KERNELS["advance"] = advance
    return advance


# --------------------------------------------------------------------------- the scene
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
        vmax2, wmax2 = _kernels()(pos, vel, ang, out, self.lam, self.wall_ln, self.wall_lt,
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
    import pymunk
    import pymunk.batch as pb

    p = params or SceneParams()
    validate_params(p)
    x = _check_number(x, "x")
    y = _check_number(y, "y")
    force = _check_number(force, "force")
    angle_deg = _check_number(angle_deg, "angle_deg")
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
    bodies = []
    index: dict[Any, int] = {}
    for i in range(p.n_particles):
        body = pymunk.Body()
        body.position = (float(start[i, 0]), float(start[i, 1]))
        body.velocity = (float(v0[0]), float(v0[1]))
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


def simulate(force: float, angle_deg: float, x: float, y: float, steps: int = 600, *,
             params: SceneParams | None = None, include_initial: bool = False,
             return_energy: bool = False,
             **kwargs: Any) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Particle centres ``(steps, n_particles, 2)`` (float64, world units) of one trajectory.

    ``force``: impulse magnitude per particle; ``angle_deg``: its direction (0 = +x, 90 = +y);
    ``(x, y)``: start centre of the ring. Row ``k`` is the state after ``k + 1`` steps of ``dt``
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
    import dataclasses
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


# --------------------------------------------------------------------------- CLI
def add_cli(sub: Any) -> None:
    p = sub.add_parser("sim", help="simulate the paper's soft-body scene (pymunk)")
    ssub = p.add_subparsers(dest="sim_command", metavar="SIM_COMMAND")
    ssub.required = True
    for name, helptext in (("show", "write a PNG of one trajectory"),
                           ("run", "write one trajectory to a .npy file")):
        q = ssub.add_parser(name, help=helptext)
        q.add_argument("--force", type=float, default=1.3, help="impulse per particle (1.3)")
        q.add_argument("--angle", type=float, default=225.0, help="impulse direction, degrees")
        q.add_argument("--x", type=float, default=30.0, help="start centre x (30)")
        q.add_argument("--y", type=float, default=35.0, help="start centre y (35)")
        q.add_argument("--steps", type=int, default=600, help="simulation steps (600)")
        q.add_argument("--frequency", type=float, default=1.0, help="spring frequency, Hz")
        q.add_argument("--damping-ratio", type=float, default=0.0)
        q.add_argument("--wall-restitution", type=float, default=0.0)
        q.add_argument("-o", "--output", required=True,
                       help=".png (show) or .npy (run) file to write")
        if name == "show":
            q.add_argument("--every", type=int, default=4,
                           help="draw every k-th row (4 = one model frame)")
            q.set_defaults(func=_cli_show)
        else:
            q.set_defaults(func=_cli_run)


def _cli_traj(args: Any, include_initial: bool = False) -> np.ndarray:
    return simulate(args.force, args.angle, args.x, args.y, args.steps,
                    include_initial=include_initial, frequency=args.frequency,
                    damping_ratio=args.damping_ratio, wall_restitution=args.wall_restitution)


def _cli_run(args: Any) -> int:
    traj = _cli_traj(args)
    np.save(args.output, traj)
    print(f"wrote {traj.shape} to {args.output}")
    return 0


def _cli_show(args: Any) -> int:
    if args.every < 1:
        raise ValueError(f"--every: must be >= 1, got {args.every}")
    traj = _cli_traj(args, include_initial=True)
    show(traj, args.output, every=args.every,
         title=f"F={args.force:g} angle={args.angle:g} start=({args.x:g}, {args.y:g})")
    print(f"wrote {args.output}")
    return 0


def show(traj: np.ndarray, path: str, *, every: int = 4, title: str = "",
         params: SceneParams | None = None) -> None:
    """Write a PNG of a ``(steps, N, 2)`` trajectory: every ``every``-th point set coloured by
    time, the start ring and the walls."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p = params or SceneParams()
    fig, ax = plt.subplots(figsize=(6, 6), dpi=100)
    rows = traj[::every]
    colors = plt.cm.viridis(np.linspace(0, 1, len(rows)))
    for r, c in zip(rows, colors):
        ax.scatter(r[:, 0], r[:, 1], s=3, color=c)
    ax.plot(*np.vstack([traj[0], traj[0][:1]]).T, "r-", lw=1, label="start")
    ax.plot(*np.vstack([traj[-1], traj[-1][:1]]).T, "k-", lw=1, label="end")
    lo, hi = p.free_lo, p.free_hi
    ax.plot([lo, hi, hi, lo, lo], [lo, lo, hi, hi, lo], "k-", lw=2)
    ax.set_xlim(0, p.box_size)
    ax.set_ylim(0, p.box_size)
    ax.set_aspect("equal")
    ax.legend(loc="upper right")
    ax.set_title(title or f"{len(traj)} rows, every {every}")
    fig.savefig(path)
    plt.close(fig)


__all__ = ["SceneParams", "Scene", "simulate", "build_scene", "ring_positions", "spring_pairs",
           "connected_matrix", "validate_params", "spring_energy_k", "show"]
