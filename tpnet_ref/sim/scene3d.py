"""The 3-D scene (docs/spec.md §8): a soft ball thrown in a closed 45 x 45 x 45 box, in MuJoCo.

``simulate3d(force, azimuth_deg, elevation_deg, x, y, z)`` returns the ``(steps, 42, 3)``
particle centres in world units, row ``k`` the state after ``k + 1`` recorded steps of
``dt = 1/45`` s (the 2-D :func:`~tpnet_ref.sim.scene.simulate`'s convention; model frame ``j`` is
row ``4 j``).

The ball: ``N = 10 * 4**s + 2`` particles (``s = 1``: 42) on a sphere of radius 2, the vertices of
an icosphere (an icosahedron with a vertex at the top, ``s`` times subdivided, projected on the
sphere); one spring between every pair whose angle at the centre is at most 144 degrees (780
springs for N = 42), rest length = start distance, stiffness ``mu (2 pi f)^2`` with the pair's
reduced mass ``mu = m/2`` (the 2-D scene's rule), zero damping.

In MuJoCo every particle is a body with three slide joints (x, y, z: a particle does not turn)
and a sphere geom of radius 0.15. The springs are the edges of a 1-D flex (``springs="flex"``,
the default) or, the same forces to the bit, spatial tendons (``springs="tendon"``, 20 % slower;
kept to check the flex against). The walls, floor and ceiling are six planes (half-spaces: no
particle tunnels through them at any speed). Contacts: particle-wall, and the pairs of particles
that share no spring (81 pairs for N = 42, as explicit contact pairs); spring-connected pairs do
not collide. Friction 1, and contacts critically damped (restitution 0), as hard as the substep
resolves (``solref = (2 h, 1)``, MuJoCo's safe minimum).

The engine steps ``substeps`` times per recorded step with semi-implicit Euler (symplectic for
the undamped springs: energy oscillates, it does not drift). :func:`substeps_for` picks the
count once per throw, from the scene: at least ``min_substeps`` (6, measured), and enough that
the stiffest spring mode turns at most ``max_spring_phase`` radians (0.5) and the fastest
possible particle travels at most ``max_travel`` (0.1) world units per substep; more than
``max_substeps`` is a one-line ``ValueError`` naming the case. MuJoCo's speculative contacts are
on as a guard against tunnelling between two particles.

mujoco (the ``sim3d`` extra) is imported on first use.
"""
from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..extras import require
from .params import check_fields, check_number, check_positive

#: the springs' implementations (the same forces): a 1-D flex's edges or spatial tendons
SPRING_KINDS = ("flex", "tendon")
#: coordinates must resolve a particle radius to this many parts (float64 resolution)
_RESOLUTION = 1000.0
#: the icosphere's angles at the centre that lie within this (degrees) of the spring angle count
#: as equal to it: an icosphere has pairs at exactly 144 degrees, computed to within 1e-13
ANGLE_TOLERANCE_DEG = 1e-6


@dataclass(frozen=True)
class SceneParams3D:
    """Every parameter of the 3-D scene; defaults in docs/spec.md §8.

    Lengths in world units, times in seconds, angles in degrees.
    """

    subdivisions: int = 1                # icosphere: N = 10 * 4**s + 2 particles (42)
    ball_radius: float = 2.0
    particle_radius: float = 0.15
    particle_mass: float = math.pi * 0.15 ** 2   # the 2-D particle's: a force gives the same speed
    gravity: tuple[float, float, float] = (0.0, 0.0, -0.5)
    frequency: float = 1.0               # spring frequency, Hz (pair's reduced mass)
    damping_ratio: float = 0.0
    spring_angle_deg: float = 144.0      # springs join pairs at most this far apart on the sphere
    friction: float = 1.0                # particle-wall and particle-particle
    contact_dampratio: float = 1.0       # 1: critically damped contacts, restitution 0
    particle_contacts: bool = True       # pairs without a spring collide
    dt: float = 1.0 / 45.0               # one recorded step
    box_size: float = 45.0               # free area [t, size - t]^3
    wall_thickness: float = 1.0
    walls: bool = True
    min_substeps: int = 6
    max_spring_phase: float = 0.5        # radians the stiffest spring mode turns per substep
    max_travel: float = 0.1              # world units the fastest particle moves per substep
    max_substeps: int = 2000
    speculative: bool = True             # MuJoCo's speculative contacts
    springs: str = "flex"                # see SPRING_KINDS

    @property
    def n_particles(self) -> int:
        return 10 * 4 ** self.subdivisions + 2

    @property
    def free_lo(self) -> float:
        """Inner face of the left wall, the front wall and the floor."""
        return self.wall_thickness

    @property
    def free_hi(self) -> float:
        """Inner face of the right wall, the back wall and the ceiling."""
        return self.box_size - self.wall_thickness

    @property
    def stiffness(self) -> float:
        """Stiffness of one spring, ``mu (2 pi f)^2`` with the pair's reduced mass ``m/2``."""
        return 0.5 * self.particle_mass * (2.0 * math.pi * self.frequency) ** 2

    @property
    def damping(self) -> float:
        """Damping of one spring, ``2 zeta mu omega``."""
        return 2.0 * self.damping_ratio * 0.5 * self.particle_mass * 2.0 * math.pi * self.frequency


_INT_FIELDS = ("subdivisions", "min_substeps", "max_substeps")
_BOOL_FIELDS = ("particle_contacts", "walls", "speculative")
_POS_FIELDS = ("ball_radius", "particle_radius", "particle_mass", "frequency", "dt", "box_size",
               "wall_thickness", "max_spring_phase", "max_travel")


def validate_params3d(p: SceneParams3D) -> None:
    """Raise ``ValueError``/``TypeError`` naming the first parameter the scene cannot handle."""
    if not isinstance(p, SceneParams3D):
        raise TypeError(f"params: expected a SceneParams3D, got {type(p).__name__}")
    check_fields(p, _INT_FIELDS, _BOOL_FIELDS)
    if not isinstance(p.springs, str) or p.springs not in SPRING_KINDS:
        raise ValueError(f"springs: must be one of {', '.join(SPRING_KINDS)}, got {p.springs!r}")
    if not 0 <= p.subdivisions <= 3:
        raise ValueError(f"subdivisions: must be in 0..3 (12 to 642 particles), got "
                         f"{p.subdivisions}")
    if not 1 <= p.min_substeps <= p.max_substeps:
        raise ValueError(f"min_substeps: must be in 1..max_substeps ({p.max_substeps}), got "
                         f"{p.min_substeps}")
    if p.max_substeps > 1_000_000:
        raise ValueError(f"max_substeps: must be <= 1000000, got {p.max_substeps}")
    check_positive(p, _POS_FIELDS)
    if not 1e-12 <= p.particle_mass <= 1e12:
        raise ValueError(f"particle_mass: must be within 1e-12..1e12, got {p.particle_mass:g}")
    if not 0 <= check_number(p.damping_ratio, "damping_ratio") <= 1:
        raise ValueError(f"damping_ratio: must be in [0, 1], got {p.damping_ratio}")
    if check_number(p.friction, "friction") < 0:
        raise ValueError(f"friction: must be >= 0, got {p.friction}")
    if not 0 < check_number(p.contact_dampratio, "contact_dampratio") <= 10:
        raise ValueError(f"contact_dampratio: must be in (0, 10], got {p.contact_dampratio}")
    if not 0 < check_number(p.spring_angle_deg, "spring_angle_deg") <= 180:
        raise ValueError(f"spring_angle_deg: must be in (0, 180], got {p.spring_angle_deg}")
    g = p.gravity
    if not isinstance(g, (tuple, list, np.ndarray)) or len(g) != 3:
        raise ValueError(f"gravity: expected a triple (gx, gy, gz), got {g!r}")
    for k, gi in enumerate(g):
        if abs(check_number(gi, f"gravity[{k}]")) * p.dt ** 2 > 1e6:
            raise ValueError(f"gravity[{k}]: {gi} moves a particle more than 1e6 per step")
    if p.walls and p.box_size <= 2 * p.wall_thickness + 2 * (p.ball_radius + p.particle_radius):
        raise ValueError(f"box_size: {p.box_size} leaves no room for the ball "
                         f"(wall_thickness {p.wall_thickness}, ball_radius {p.ball_radius})")
    # neighbouring particles must not overlap at rest
    gap = p.ball_radius * _min_chord(p.subdivisions)
    if gap <= 2 * p.particle_radius:
        raise ValueError(f"particle_radius: {p.particle_radius} makes neighbouring particles "
                         f"overlap on a ball of radius {p.ball_radius} with {p.n_particles} "
                         "particles")
    if len(spring_pairs3d(p)) == 0:
        raise ValueError(f"spring_angle_deg: {p.spring_angle_deg} joins no pair of particles "
                         f"(the nearest neighbours are {_min_angle(p.subdivisions):.4g} deg "
                         "apart)")


# --------------------------------------------------------------------------- geometry
@functools.lru_cache(maxsize=8)
def _icosphere(subdivisions: int) -> np.ndarray:
    # the icosahedron with a vertex at the top: top, upper ring, lower ring, bottom
    zr = 1.0 / math.sqrt(5.0)
    rr = 2.0 / math.sqrt(5.0)
    verts = [(0.0, 0.0, 1.0)]
    verts += [(rr * math.cos(2 * math.pi * k / 5), rr * math.sin(2 * math.pi * k / 5), zr)
              for k in range(5)]
    verts += [(rr * math.cos(math.pi * (2 * k + 1) / 5), rr * math.sin(math.pi * (2 * k + 1) / 5),
               -zr) for k in range(5)]
    verts.append((0.0, 0.0, -1.0))
    v = np.asarray(verts, dtype=float)
    faces = _faces(v)
    for _ in range(subdivisions):
        v, faces = _subdivide(v, faces)
    return v


def _faces(v: np.ndarray) -> list[tuple[int, int, int]]:
    """The 20 faces of the icosahedron ``v``: the triples of mutual nearest neighbours."""
    d = np.linalg.norm(v[:, None] - v[None], axis=2)
    edge = d[d > 1e-9].min()
    near = np.abs(d - edge) < 1e-9
    n = len(v)
    return [(i, j, k) for i in range(n) for j in range(i + 1, n) for k in range(j + 1, n)
            if near[i, j] and near[j, k] and near[i, k]]


def _subdivide(v: np.ndarray, faces: list) -> tuple[np.ndarray, list]:
    """Each triangle into four; the new vertices (edge midpoints projected on the sphere) are
    appended in the order of their edges ``(i, j)``, ``i < j``, sorted."""
    edges = sorted({(min(a, b), max(a, b)) for f in faces for a, b in ((f[0], f[1]), (f[1], f[2]),
                                                                       (f[0], f[2]))})
    index = {e: len(v) + k for k, e in enumerate(edges)}
    mid = np.asarray([v[i] + v[j] for i, j in edges])
    mid /= np.linalg.norm(mid, axis=1)[:, None]
    out = []
    for a, b, c in faces:
        ab, bc, ac = (index[(min(a, b), max(a, b))], index[(min(b, c), max(b, c))],
                      index[(min(a, c), max(a, c))])
        out += [(a, ab, ac), (b, bc, ab), (c, ac, bc), (ab, bc, ac)]
    return np.vstack([v, mid]), out


def unit_ball(subdivisions: int = 1) -> np.ndarray:
    """``(N, 3)`` unit vectors of the icosphere: particle 0 at the top (+z), then the upper and
    lower rings of the icosahedron, particle 11 at the bottom, then each subdivision's edge
    midpoints (a copy)."""
    return _icosphere(int(subdivisions)).copy()


def ball_positions(x: float, y: float, z: float, params: SceneParams3D | None = None) -> np.ndarray:
    """``(N, 3)`` start positions: the icosphere of radius ``ball_radius`` around ``(x, y, z)``."""
    p = params or SceneParams3D()
    return np.asarray([x, y, z], dtype=float) + p.ball_radius * _icosphere(p.subdivisions)


def _angles(subdivisions: int) -> np.ndarray:
    u = _icosphere(subdivisions)
    return np.degrees(np.arccos(np.clip(u @ u.T, -1.0, 1.0)))


def _min_angle(subdivisions: int) -> float:
    a = _angles(subdivisions)
    return float(a[~np.eye(len(a), dtype=bool)].min())


def _min_chord(subdivisions: int) -> float:
    return 2.0 * math.sin(math.radians(_min_angle(subdivisions)) / 2.0)


def connected_matrix3d(params: SceneParams3D | None = None) -> np.ndarray:
    """``(N, N)`` bool: True where two particles share a spring (their angle at the centre is at
    most ``spring_angle_deg``, to within :data:`ANGLE_TOLERANCE_DEG`); they do not collide."""
    p = params or SceneParams3D()
    a = _angles(p.subdivisions)
    c = a <= p.spring_angle_deg + ANGLE_TOLERANCE_DEG
    np.fill_diagonal(c, False)
    return c


def spring_pairs3d(params: SceneParams3D | None = None) -> np.ndarray:
    """``(S, 2)`` index pairs ``(i, j)``, ``i < j``, in lexicographic order, of the springs
    (780 for the default ball)."""
    return np.argwhere(np.triu(connected_matrix3d(params))).astype(np.int64)


def contact_pairs3d(params: SceneParams3D | None = None) -> np.ndarray:
    """``(C, 2)`` index pairs ``(i, j)``, ``i < j``, of the particles that share no spring and
    so collide (81 for the default ball: each particle and the few nearest its antipode)."""
    p = params or SceneParams3D()
    c = connected_matrix3d(p)
    return np.argwhere(np.triu(~c, 1)).astype(np.int64)


@functools.lru_cache(maxsize=32)
def _unit_omega_max(subdivisions: int, spring_angle_deg: float) -> float:
    """sqrt of the largest eigenvalue of the ball's spring stiffness matrix with k = 1 and unit
    masses (the stiffest mode's angular frequency for k / m = 1)."""
    u = _icosphere(subdivisions)
    n = len(u)
    K = np.zeros((3 * n, 3 * n))
    p = SceneParams3D(subdivisions=subdivisions, spring_angle_deg=spring_angle_deg)
    for i, j in spring_pairs3d(p):
        d = u[j] - u[i]
        B = np.outer(d, d) / float(d @ d)
        K[3 * i:3 * i + 3, 3 * i:3 * i + 3] += B
        K[3 * j:3 * j + 3, 3 * j:3 * j + 3] += B
        K[3 * i:3 * i + 3, 3 * j:3 * j + 3] -= B
        K[3 * j:3 * j + 3, 3 * i:3 * i + 3] -= B
    return math.sqrt(max(float(np.linalg.eigvalsh(K).max()), 0.0))


def omega_max(params: SceneParams3D | None = None) -> float:
    """Angular frequency (rad/s) of the ball's stiffest spring mode: 26.3 for the default ball
    (4.19 Hz: 37 springs per particle stiffen the 1 Hz pair frequency), proportional to
    ``frequency``."""
    p = params or SceneParams3D()
    return _unit_omega_max(p.subdivisions, float(p.spring_angle_deg)) * math.sqrt(
        p.stiffness / p.particle_mass)


def substeps_for(force: float, params: SceneParams3D | None = None) -> int:
    """Engine substeps per recorded step for a throw of ``force`` (validated parameters):
    ``max(min_substeps, ceil(omega_max dt / max_spring_phase), ceil(v dt / max_travel))`` with
    ``v = sqrt(v0^2 + 2 |g| span)``, the start speed ``v0 = force / m`` raised by a fall across
    the box. The default scene gives 6 for every force up to 1.6, 51 at force 16. A count above
    ``max_substeps`` is a one-line ``ValueError`` naming the parameter that asks for it."""
    p = params or SceneParams3D()
    force = check_number(force, "force")
    spring = math.ceil(omega_max(p) * (1.0 + p.damping_ratio) * p.dt / p.max_spring_phase)
    g = math.sqrt(sum(float(gi) ** 2 for gi in p.gravity))
    span = math.sqrt(3.0) * ((p.free_hi - p.free_lo) if p.walls else p.box_size)
    v = math.sqrt((force / p.particle_mass) ** 2 + 2.0 * g * span)
    travel = math.ceil(v * p.dt / p.max_travel)
    n = max(p.min_substeps, spring, travel)
    if n > p.max_substeps:
        what = ("frequency", f"{p.frequency:g} Hz springs need") if spring >= travel else (
            "force", f"a throw of force {force:g} ({v:.4g} units/s) needs")
        raise ValueError(f"{what[0]}: {what[1]} {n} substeps per step of {p.dt:.4g} s, more "
                         f"than max_substeps = {p.max_substeps}; beyond what the scene resolves")
    return int(n)


def impulse_velocity(force: float, azimuth_deg: float, elevation_deg: float,
                     params: SceneParams3D | None = None) -> np.ndarray:
    """``(3,)`` start velocity of every particle: the impulse ``force (cos e cos a, cos e sin a,
    sin e)`` over the particle mass (azimuth ``a`` from +x towards +y, elevation ``e`` from the
    horizontal towards +z)."""
    p = params or SceneParams3D()
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    return force / p.particle_mass * np.array([math.cos(e) * math.cos(a),
                                               math.cos(e) * math.sin(a), math.sin(e)])


def check_throw(force: Any, azimuth_deg: Any, elevation_deg: Any, x: Any, y: Any, z: Any,
                params: SceneParams3D) -> tuple[float, ...]:
    """The six throw parameters as floats, or a one-line ``ValueError``/``TypeError`` naming
    the first the scene cannot take: finite numbers, ``force >= 0``, elevation in [-90, 90], the
    whole ball inside the box (the centre in [3.15, 41.85] on every axis by default)."""
    p = params
    force = check_number(force, "force")
    azimuth_deg = check_number(azimuth_deg, "azimuth_deg")
    elevation_deg = check_number(elevation_deg, "elevation_deg")
    x, y, z = (check_number(v, n) for v, n in ((x, "x"), (y, "y"), (z, "z")))
    if force < 0:
        raise ValueError(f"force: must be >= 0 (azimuth and elevation give the direction), "
                         f"got {force}")
    if not -90 <= elevation_deg <= 90:
        raise ValueError(f"elevation_deg: must be in [-90, 90], got {elevation_deg}")
    if force / p.particle_mass * p.dt > 1e6:
        raise ValueError(f"force: {force:g} moves a particle more than 1e6 per step; beyond "
                         "what the scene resolves")
    extent = max(abs(x), abs(y), abs(z), p.box_size if p.walls else 0.0) + p.ball_radius
    if extent * np.finfo(float).eps * _RESOLUTION > p.particle_radius:
        raise ValueError(f"x, y, z: coordinates up to {extent:g} cannot resolve particles of "
                         f"radius {p.particle_radius:g} in float64")
    if p.walls:
        reach = p.ball_radius + p.particle_radius
        lo, hi = p.free_lo + reach, p.free_hi - reach
        for name, v in (("x", x), ("y", y), ("z", z)):
            if not lo <= v <= hi:
                raise ValueError(f"{name}: start centre {v} puts the ball outside the box; must "
                                 f"be in [{lo:g}, {hi:g}]")
    return force, azimuth_deg, elevation_deg, x, y, z


# --------------------------------------------------------------------------- the model
def _f(v: float) -> str:
    return repr(float(v))


def model_xml(start: np.ndarray, substeps: int, params: SceneParams3D) -> str:
    """The MJCF of the scene with the ball's particles at ``start`` ``(N, 3)``."""
    p = params
    h = p.dt / substeps
    tc = 2.0 * h          # the hardest contact the substep resolves (MuJoCo's refsafe minimum)
    mu = p.friction
    grav = " ".join(_f(g) for g in p.gravity)
    out = [f'<mujoco model="tpnet-ball"><option timestep="{_f(h)}" gravity="{grav}" '
           'integrator="Euler" cone="elliptic">'
           f'<flag speculative="{"enable" if p.speculative else "disable"}"/></option>',
           f'<default><geom condim="3" friction="{_f(mu)} 0 0" '
           f'solref="{_f(tc)} {_f(p.contact_dampratio)}"/></default><worldbody>']
    if p.walls:
        lo, hi = p.free_lo, p.free_hi
        for k, axis in enumerate("xyz"):
            for side, at, sign in (("lo", lo, 1), ("hi", hi, -1)):
                pos = [0.0, 0.0, 0.0]
                pos[k] = at
                normal = [0, 0, 0]
                normal[k] = sign
                out.append(f'<geom name="wall_{axis}{side}" type="plane" size="0 0 1" '
                           f'pos="{" ".join(_f(c) for c in pos)}" '
                           f'zaxis="{" ".join(str(c) for c in normal)}" '
                           'contype="1" conaffinity="2"/>')
    site = p.springs == "tendon"
    for i, q in enumerate(start):
        out.append(f'<body name="p{i}" pos="{_f(q[0])} {_f(q[1])} {_f(q[2])}">'
                   '<joint type="slide" axis="1 0 0"/><joint type="slide" axis="0 1 0"/>'
                   '<joint type="slide" axis="0 0 1"/>'
                   f'<geom name="g{i}" type="sphere" size="{_f(p.particle_radius)}" '
                   f'mass="{_f(p.particle_mass)}" contype="2" conaffinity="1"/>'
                   + (f'<site name="s{i}"/>' if site else "") + '</body>')
    out.append('</worldbody>')
    pairs = spring_pairs3d(p)
    k, c = _f(p.stiffness), _f(p.damping)
    if p.springs == "flex":
        bodies = " ".join(f"p{i}" for i in range(len(start)))
        elements = " ".join(f"{i} {j}" for i, j in pairs)
        out.append(f'<deformable><flex name="springs" dim="1" body="{bodies}" '
                   f'element="{elements}"><edge stiffness="{k}" damping="{c}"/>'
                   '<contact contype="0" conaffinity="0" selfcollide="none"/></flex></deformable>')
    else:
        rest = np.linalg.norm(start[pairs[:, 1]] - start[pairs[:, 0]], axis=1)
        out.append('<tendon>')
        out += [f'<spatial stiffness="{k}" damping="{c}" springlength="{_f(r)}">'
                f'<site site="s{i}"/><site site="s{j}"/></spatial>'
                for (i, j), r in zip(pairs, rest)]
        out.append('</tendon>')
    if p.particle_contacts:
        cp = contact_pairs3d(p)
        if len(cp):
            out.append('<contact>')
            out += [f'<pair geom1="g{i}" geom2="g{j}" condim="3" '
                    f'friction="{_f(mu)} {_f(mu)} 0 0 0" '
                    f'solref="{_f(tc)} {_f(p.contact_dampratio)}"/>' for i, j in cp]
            out.append('</contact>')
    out.append('</mujoco>')
    return "".join(out)


def _mujoco() -> Any:
    return require("mujoco", "sim3d")


@contextlib.contextmanager
def _engine_log_off(mj: Any) -> Iterator[None]:
    """MuJoCo's default log handler neither prints nor writes its file (restored after)."""
    cfg = mj.MjLogConfig.get()
    keep = (cfg.logto_console, cfg.logto_file)
    cfg.logto_console = cfg.logto_file = False
    cfg.set()
    try:
        yield
    finally:
        cfg.logto_console, cfg.logto_file = keep
        cfg.set()


@dataclass
class Scene3D:
    """A built scene: the MuJoCo model and data, the start positions and the substep count."""

    params: SceneParams3D
    model: Any
    data: Any
    start: np.ndarray            # (N, 3) particle centres at t = 0 (the bodies' frames)
    pairs: np.ndarray            # (S, 2) spring index pairs
    rest: np.ndarray             # (S,) rest lengths
    substeps: int
    rows: int = 0                # recorded steps taken

    @property
    def n(self) -> int:
        return len(self.start)

    def positions(self) -> np.ndarray:
        """``(N, 3)`` particle centres now (a new array)."""
        return self.start + self.data.qpos.reshape(-1, 3)

    def velocities(self) -> np.ndarray:
        """``(N, 3)`` particle velocities now (a copy)."""
        return self.data.qvel.reshape(-1, 3).copy()

    def energy(self) -> float:
        """Mechanical energy now: kinetic, gravitational and the springs' potential energy."""
        p = self.params
        x = self.positions()
        v = self.data.qvel
        g = np.asarray(p.gravity, dtype=float)
        d = x[self.pairs[:, 1]] - x[self.pairs[:, 0]]
        stretch = np.sqrt((d ** 2).sum(1)) - self.rest
        return (0.5 * p.particle_mass * float(v @ v) - p.particle_mass * float((x @ g).sum())
                + 0.5 * p.stiffness * float(stretch @ stretch))

    def step(self) -> None:
        """Advance one recorded step (``substeps`` engine steps); a ``FloatingPointError`` (one
        line) when the engine reports an unstable acceleration (it would reset the state). The
        engine's own log (console and ``MUJOCO_LOG.TXT`` in the working directory) is off
        meanwhile: the error says it."""
        mj = _mujoco()
        with _engine_log_off(mj):
            mj.mj_step(self.model, self.data, nstep=self.substeps)
        self.rows += 1
        if self.data.warning[mj.mjtWarning.mjWARN_BADQACC].number:
            p = self.params
            raise FloatingPointError(
                f"simulate3d: the engine became unstable at row {self.rows - 1} (frequency "
                f"{p.frequency:g} Hz, {self.substeps} substeps); raise min_substeps or lower "
                "max_spring_phase / max_travel")


def build_scene3d(force: float, azimuth_deg: float, elevation_deg: float, x: float, y: float,
                  z: float, params: SceneParams3D | None = None) -> Scene3D:
    """The MuJoCo model of a ball centred at ``(x, y, z)`` that has received the impulse
    ``force`` per particle towards ``(azimuth_deg, elevation_deg)`` (validated)."""
    p = SceneParams3D() if params is None else params
    validate_params3d(p)
    force, azimuth_deg, elevation_deg, x, y, z = check_throw(force, azimuth_deg, elevation_deg,
                                                             x, y, z, p)
    substeps = substeps_for(force, p)
    mj = _mujoco()
    start = ball_positions(x, y, z, p)
    model = mj.MjModel.from_xml_string(model_xml(start, substeps, p))
    data = mj.MjData(model)
    data.qvel[:] = np.tile(impulse_velocity(force, azimuth_deg, elevation_deg, p), len(start))
    pairs = spring_pairs3d(p)
    rest = np.linalg.norm(start[pairs[:, 1]] - start[pairs[:, 0]], axis=1)
    return Scene3D(params=p, model=model, data=data, start=start, pairs=pairs, rest=rest,
                   substeps=substeps)


def simulate3d(force: float, azimuth_deg: float, elevation_deg: float, x: float, y: float,
               z: float, steps: int = 600, *, params: SceneParams3D | None = None,
               include_initial: bool = False, return_energy: bool = False,
               **kwargs: Any) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Particle centres ``(steps, N, 3)`` (float64, world units) of one throw of the ball.

    ``force``: impulse magnitude per particle (at its centre); ``azimuth_deg``: its direction in
    the horizontal plane (0 = +x, 90 = +y); ``elevation_deg``: above the horizontal (-90 =
    straight down); ``(x, y, z)``: the ball's start centre. Row ``k`` is the state after
    ``k + 1`` steps of ``dt`` (as :func:`~tpnet_ref.sim.scene.simulate`); with
    ``include_initial`` row 0 is the start. Any ``SceneParams3D`` field can be given as a
    keyword (e.g. ``frequency=8``, ``walls=False``); unknown keywords raise ``TypeError``. With
    ``return_energy`` also the ``(steps,)`` mechanical energy per row (:meth:`Scene3D.energy`).
    Deterministic: the same call gives the same bits.
    """
    if isinstance(steps, (bool, np.bool_)) or not isinstance(steps, (int, np.integer)):
        raise TypeError(f"steps: expected an integer, got {type(steps).__name__}")
    if steps < 1:
        raise ValueError(f"steps: must be >= 1, got {steps}")
    for name, v in (("include_initial", include_initial), ("return_energy", return_energy)):
        if not isinstance(v, (bool, np.bool_)):
            raise TypeError(f"{name}: expected a bool, got {type(v).__name__}")
    p = SceneParams3D() if params is None else params
    if not isinstance(p, SceneParams3D):
        raise TypeError(f"params: expected a SceneParams3D, got {type(p).__name__}")
    if kwargs:
        p = _replace(p, kwargs)
    scene = build_scene3d(force, azimuth_deg, elevation_deg, x, y, z, p)
    try:
        out = np.empty((steps, scene.n, 3))
        en = np.empty(steps) if return_energy else None
    except MemoryError:
        raise ValueError(f"steps: {steps} rows of {scene.n} particles do not fit in memory") \
            from None
    for k in range(steps):
        if k or not include_initial:
            scene.step()
        out[k] = scene.positions()
        if en is not None:
            en[k] = scene.energy()
    if not np.isfinite(out).all():  # pragma: no cover - guarded by the substeps and the check
        raise FloatingPointError("simulate3d: non-finite positions; parameters beyond the engine")
    return (out, en) if en is not None else out


def _replace(p: SceneParams3D, kwargs: dict[str, Any]) -> SceneParams3D:
    names = {f.name for f in dataclasses.fields(SceneParams3D)}
    bad = sorted(set(kwargs) - names)
    if bad:
        raise TypeError(f"simulate3d: unknown parameter(s) {', '.join(bad)}")
    if "gravity" in kwargs:
        g = kwargs["gravity"]
        if not isinstance(g, (tuple, list, np.ndarray)):
            raise TypeError(f"gravity: expected a triple (gx, gy, gz), got {type(g).__name__}")
        kwargs = dict(kwargs, gravity=tuple(g))
    return dataclasses.replace(p, **kwargs)


__all__ = ["SceneParams3D", "Scene3D", "simulate3d", "build_scene3d", "validate_params3d",
           "check_throw", "unit_ball", "ball_positions", "spring_pairs3d", "contact_pairs3d",
           "connected_matrix3d", "omega_max", "substeps_for", "impulse_velocity", "model_xml",
           "SPRING_KINDS", "ANGLE_TOLERANCE_DEG"]
