"""The 3-D scene (tpnet_ref.sim.scene3d): the ball's geometry and springs, free flight, rest,
collisions, stiff and extreme throws, determinism, validation. The engine's tests need mujoco
(the ``sim3d`` extra) and are skipped without it; the geometry's do not."""
from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tpnet_ref.extras import MissingExtraError
from tpnet_ref.sim import scene3d as S
from tpnet_ref.sim.scene3d import SceneParams3D, simulate3d

pytestmark = pytest.mark.lane("3-D")   # in a second test process (tests/lane.py)

needs_mujoco = pytest.mark.skipif(importlib.util.find_spec("mujoco") is None,
                                  reason="the 3-D scene needs mujoco: pip install "
                                         "'tpnet-ref[sim3d]'")
P = SceneParams3D()
DT = 1.0 / 45.0


def inside_box(traj: np.ndarray, p: SceneParams3D = P) -> bool:
    """Every particle centre finite and inside the free area (no centre beyond a wall's face)."""
    return bool(np.isfinite(traj).all() and traj.min() >= p.free_lo and traj.max() <= p.free_hi)


# ----------------------------------------------------------------- geometry (no engine)
def test_the_ball_is_an_icosphere_spread_evenly():
    u = S.unit_ball()
    assert u.shape == (42, 3) and P.n_particles == 42
    np.testing.assert_allclose(np.linalg.norm(u, axis=1), 1.0, atol=1e-15)
    np.testing.assert_array_equal(u[0], [0, 0, 1])
    np.testing.assert_array_equal(u[11], [0, 0, -1])
    ang = np.degrees(np.arccos(np.clip(u @ u.T, -1, 1)))
    np.fill_diagonal(ang, 360)
    nearest = ang.min(axis=1)
    # every particle's nearest neighbours lie 31.7 to 36 degrees away: 12 with five, 30 with six
    assert 31.7 < nearest.min() and nearest.max() < 36.01
    counts = (ang < 37).sum(axis=1)
    assert sorted(counts.tolist()) == [5] * 12 + [6] * 30
    assert [S.SceneParams3D(subdivisions=s).n_particles for s in range(4)] == [12, 42, 162, 642]
    assert len(S.unit_ball(2)) == 162
    x = S.ball_positions(30.0, 31.0, 32.0)
    np.testing.assert_allclose(np.linalg.norm(x - [30, 31, 32], axis=1), 2.0, atol=1e-13)


def test_the_spring_set_is_exactly_the_144_degree_rule():
    x = S.ball_positions(22.0, 22.0, 22.0)
    d = x - x.mean(axis=0)
    cosang = (d @ d.T) / np.outer(np.linalg.norm(d, axis=1), np.linalg.norm(d, axis=1))
    ang = np.degrees(np.arccos(np.clip(cosang, -1, 1)))
    i, j = np.triu_indices(42, 1)
    want = {(a, b) for a, b in zip(i, j) if ang[a, b] <= 144.0 + 1e-6}
    pairs = S.spring_pairs3d()
    assert {tuple(q) for q in pairs.tolist()} == want and len(pairs) == 780
    assert (pairs[:, 0] < pairs[:, 1]).all() and len({tuple(q) for q in pairs.tolist()}) == 780
    # the rule's edge: pairs at exactly 144 degrees are in, the next angle (148.28) is out
    assert ang[pairs[:, 0], pairs[:, 1]].max() == pytest.approx(144.0, abs=1e-9)
    contact = S.contact_pairs3d()
    assert len(contact) == 81 and len(pairs) + len(contact) == 42 * 41 // 2
    assert ang[contact[:, 0], contact[:, 1]].min() == pytest.approx(148.2825, abs=1e-4)
    per = np.bincount(pairs.ravel(), minlength=42)
    assert per.min() == 35 and per.max() == 38
    c = S.connected_matrix3d()
    assert (c == c.T).all() and not c.diagonal().any() and c.sum() == 2 * 780
    # a narrower rule keeps fewer pairs: at 40 degrees the icosphere's 120 edges; below the
    # nearest neighbours none (refused)
    assert len(S.spring_pairs3d(SceneParams3D(spring_angle_deg=40.0))) == 120
    with pytest.raises(ValueError, match="spring_angle_deg"):
        S.validate_params3d(SceneParams3D(spring_angle_deg=30.0))


def test_stiffest_mode_and_substeps():
    # 37 springs per particle: the stiffest mode of the 1 Hz ball turns at 26.3 rad/s (4.19 Hz)
    assert S.omega_max() == pytest.approx(26.3133, abs=1e-4)
    assert S.omega_max(SceneParams3D(frequency=8.0)) == pytest.approx(8 * S.omega_max())
    assert P.stiffness == pytest.approx(0.5 * math.pi * 0.15 ** 2 * (2 * math.pi) ** 2)
    # every force of the grid runs at 6 substeps; a throw 10x the grid's or stiff springs at more
    assert [S.substeps_for(f) for f in (0.0, 1.0, 1.6)] == [6, 6, 6]
    assert S.substeps_for(16.0) == 51
    assert S.substeps_for(1.6, SceneParams3D(frequency=8.0)) == 10
    with pytest.raises(ValueError, match=r"^frequency: 10000 Hz springs need \d+ substeps"):
        S.substeps_for(1.0, SceneParams3D(frequency=1e4))
    with pytest.raises(ValueError, match=r"^force: a throw of force 100000 "):
        S.substeps_for(1e5)


def test_impulse_direction():
    m = P.particle_mass
    np.testing.assert_allclose(S.impulse_velocity(1.0, 0, 0), [1 / m, 0, 0], atol=1e-12)
    np.testing.assert_allclose(S.impulse_velocity(1.0, 90, 0), [0, 1 / m, 0], atol=1e-12)
    np.testing.assert_allclose(S.impulse_velocity(2.0, 123, -90), [0, 0, -2 / m], atol=1e-12)
    v = S.impulse_velocity(1.6, 225, -35)
    assert np.linalg.norm(v) == pytest.approx(1.6 / m)


@pytest.mark.parametrize("call, says", [
    (lambda: simulate3d(float("nan"), 0, 0, 22, 22, 22), "force: must be finite"),
    (lambda: simulate3d(-1.0, 0, 0, 22, 22, 22), "force: must be >= 0"),
    (lambda: simulate3d(1.0, float("inf"), 0, 22, 22, 22), "azimuth_deg: must be finite"),
    (lambda: simulate3d(1.0, 0, 91, 22, 22, 22), "elevation_deg: must be in [-90, 90]"),
    (lambda: simulate3d(1.0, 0, 0, 22, 22, 41.9), "z: start centre 41.9"),
    (lambda: simulate3d(1.0, 0, 0, 3.1, 22, 22),
     "x: start centre 3.1 puts the ball outside the box; must be in [3.15, 41.85]"),
    (lambda: simulate3d(1.0, 0, 0, 22, float("nan"), 22), "y: must be finite"),
    (lambda: simulate3d(1.0, 0, 0, 22, 22, 22, steps=0), "steps: must be >= 1"),
    (lambda: simulate3d(1.0, 0, 0, 22, 22, 22, frequency=-1.0), "frequency: must be > 0"),
    (lambda: simulate3d(1.0, 0, 0, 22, 22, 22, frequency=float("nan")), "frequency: must be finite"),
    (lambda: simulate3d(1.0, 0, 0, 22, 22, 22, damping_ratio=2.0), "damping_ratio"),
    (lambda: simulate3d(1.0, 0, 0, 22, 22, 22, subdivisions=5), "subdivisions"),
    (lambda: simulate3d(1.0, 0, 0, 22, 22, 22, springs="rods"), "springs"),
    (lambda: simulate3d(1.0, 0, 0, 22, 22, 22, gravity=(0, -0.5)), "gravity"),
    (lambda: simulate3d(1.0, 0, 0, 22, 22, 22, particle_radius=0.7), "particle_radius"),
    (lambda: simulate3d(1.0, 0, 0, 22, 22, 22, box_size=6.0), "box_size"),
    (lambda: simulate3d(1.0, 0, 0, 22, 22, 22, friction=-1.0), "friction"),
    (lambda: simulate3d(1.0, 0, 0, 22, 22, 22, min_substeps=0), "min_substeps"),
    (lambda: simulate3d(1e4, 0, 0, 22, 22, 22), "force: a throw of force 10000"),
    (lambda: simulate3d(1.0, 0, 0, 22, 22, 22, frequency=5000.0), "frequency: 5000 Hz"),
])
def test_value_errors_name_the_parameter(call, says):
    with pytest.raises(ValueError) as info:
        call()
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(says.split(":")[0]) and says in msg


def test_type_errors():
    with pytest.raises(TypeError, match="unknown parameter"):
        simulate3d(1.0, 0, 0, 22, 22, 22, colour="red")
    with pytest.raises(TypeError, match="steps"):
        simulate3d(1.0, 0, 0, 22, 22, 22, steps=2.0)
    with pytest.raises(TypeError, match="params"):
        simulate3d(1.0, 0, 0, 22, 22, 22, params=object())
    with pytest.raises(TypeError, match="force"):
        simulate3d("1", 0, 0, 22, 22, 22)


def test_missing_mujoco_names_the_extra(monkeypatch):
    import sys
    monkeypatch.setitem(sys.modules, "mujoco", None)
    with pytest.raises(MissingExtraError) as info:
        simulate3d(1.0, 0, 0, 22, 22, 22, steps=1)
    msg = str(info.value)
    assert "pip install 'tpnet-ref[sim3d]'" in msg and "mujoco" in msg and "\n" not in msg


# ----------------------------------------------------------------- the engine
@needs_mujoco
def test_model_holds_the_scene():
    sc = S.build_scene3d(1.3, 225.0, -30.0, 30.0, 31.0, 32.0)
    m = sc.model
    assert (m.nbody, m.njnt, m.nv) == (43, 126, 126) and sc.substeps == 6
    assert m.opt.timestep == pytest.approx(DT / 6)
    np.testing.assert_array_equal(m.opt.gravity, [0, 0, -0.5])
    assert m.nflexedge == 780 and m.npair == 81
    np.testing.assert_allclose(m.body_mass[1:], math.pi * 0.15 ** 2)
    np.testing.assert_allclose(m.flexedge_length0, sc.rest, atol=1e-12)
    np.testing.assert_allclose(sc.rest, np.linalg.norm(
        sc.start[sc.pairs[:, 1]] - sc.start[sc.pairs[:, 0]], axis=1))
    planes = [i for i in range(m.ngeom) if m.geom_type[i] == 0]
    assert len(planes) == 6
    np.testing.assert_allclose(m.geom_friction[:, 0], 1.0)
    np.testing.assert_allclose(sc.velocities(), np.tile(S.impulse_velocity(1.3, 225, -30), (42, 1)))
    np.testing.assert_array_equal(sc.positions(), sc.start)


@needs_mujoco
def test_rows_follow_the_2d_convention():
    a = simulate3d(1.3, 200.0, -20.0, 35.0, 36.0, 37.0, steps=5)
    b = simulate3d(1.3, 200.0, -20.0, 35.0, 36.0, 37.0, steps=6, include_initial=True)
    np.testing.assert_array_equal(b[0], S.ball_positions(35.0, 36.0, 37.0))
    np.testing.assert_array_equal(a, b[1:])


@needs_mujoco
@settings(max_examples=6, deadline=None)
@given(force=st.floats(0.0, 3.0), az=st.floats(0.0, 360.0), el=st.floats(-90.0, 90.0),
       start=st.tuples(*[st.floats(10.0, 35.0)] * 3))
def test_free_flight_centroid_falls_with_gravity(force, az, el, start):
    """No walls: the springs' forces cancel in pairs, so the centroid's second difference over
    recorded rows is exactly g dt^2 (semi-implicit Euler integrates a constant force exactly)."""
    traj = simulate3d(force, az, el, *start, steps=40, walls=False)
    d2 = np.diff(traj.mean(axis=1), 2, axis=0)
    np.testing.assert_allclose(d2[:, 2], -0.5 * DT ** 2, rtol=0, atol=1e-9)
    np.testing.assert_allclose(d2[:, :2], 0.0, rtol=0, atol=1e-9)


@needs_mujoco
def test_free_vibration_keeps_momentum_and_energy():
    """No gravity, no walls, random velocities of zero sum: the centroid stays put to rounding and
    the energy (kinetic + springs) oscillates within a few percent without drifting."""
    p = SceneParams3D(walls=False, gravity=(0.0, 0.0, 0.0))
    sc = S.build_scene3d(0.0, 0.0, 0.0, 22.0, 22.0, 22.0, p)
    v = np.random.default_rng(0).normal(0.0, 3.0, (42, 3))
    v -= v.mean(axis=0)
    sc.data.qvel[:] = v.ravel()
    e0 = sc.energy()
    energy, centre = [], []
    for _ in range(600):
        sc.step()
        energy.append(sc.energy())
        centre.append(sc.positions().mean(axis=0))
    e = np.asarray(energy) / e0
    np.testing.assert_allclose(np.asarray(centre), 22.0, rtol=0, atol=1e-11)
    assert 0.95 < e.min() and e.max() < 1.05
    assert abs(e[-100:].mean() - e[:100].mean()) < 0.01


@needs_mujoco
def test_ball_keeps_its_shape_at_rest():
    """Set down on the floor (its bottom particle touching it), the ball sags under gravity
    and keeps every spring within 5 % of its rest length; it neither rolls nor drifts."""
    z0 = P.free_lo + P.particle_radius + P.ball_radius
    traj = simulate3d(0.0, 0.0, 0.0, 22.5, 22.5, z0, steps=600)
    sc = S.build_scene3d(0.0, 0.0, 0.0, 22.5, 22.5, z0)
    length = np.linalg.norm(traj[:, sc.pairs[:, 1]] - traj[:, sc.pairs[:, 0]], axis=2)
    assert (np.abs(length - sc.rest) / sc.rest).max() < 0.05
    c = traj.mean(axis=1)
    np.testing.assert_allclose(c[:, :2], 22.5, rtol=0, atol=1e-9)
    assert z0 - 0.2 < c[:, 2].min() and c[:, 2].max() <= z0 + 1e-9
    assert inside_box(traj) and traj[:, :, 2].min() > P.free_lo + P.particle_radius - 0.01


@needs_mujoco
@settings(max_examples=6, deadline=None)
@given(force=st.floats(1.0, 1.6), az=st.floats(0.0, 360.0), el=st.floats(-90.0, 90.0),
       start=st.tuples(*[st.floats(3.15, 41.85)] * 3))
def test_collisions_keep_points_in_the_box(force, az, el, start):
    traj = simulate3d(force, az, el, *start, steps=150)
    assert inside_box(traj)


@needs_mujoco
@pytest.mark.parametrize("frequency, force, substeps", [(8.0, 1.6, 10), (16.0, 1.6, 19),
                                                        (1.0, 16.0, 51), (8.0, 16.0, 51)])
def test_stiff_and_extreme_throws_stay_finite_and_inside(frequency, force, substeps):
    """Springs 8 and 16 times the scene's, throws 10 times the grid's largest force, both:
    from a corner into it and from the middle, every centre finite and inside the box."""
    p = SceneParams3D(frequency=frequency)
    assert S.substeps_for(force, p) == substeps
    for case in ((force, 45.0, 35.0, 41.0, 41.0, 41.0), (force, 225.0, -35.0, 4.0, 4.0, 4.0),
                 (force, 200.0, -60.0, 22.5, 22.5, 22.5)):
        traj = simulate3d(*case, steps=120, params=p)
        assert inside_box(traj, p), case
    # the stiff ball deforms less than the scene's at the same throw
    if frequency > 1:
        sc = S.build_scene3d(*case, params=p)

        def stretch(t):
            length = np.linalg.norm(t[:, sc.pairs[:, 1]] - t[:, sc.pairs[:, 0]], axis=2)
            return (np.abs(length - sc.rest) / sc.rest).max()
        assert stretch(traj) < 0.5 * stretch(simulate3d(*case, steps=120))


@needs_mujoco
def test_extreme_throw_does_not_turn_the_ball_inside_out():
    """At 10x the grid's force the ball is crushed against a wall; the particle pairs without a
    spring collide, so opposite particles do not pass through each other."""
    case = (16.0, 0.0, -90.0, 41.0, 41.0, 41.0)      # straight down onto the floor
    cp = S.contact_pairs3d()

    def gap(t):
        return np.linalg.norm(t[:, cp[:, 0]] - t[:, cp[:, 1]], axis=2).min()
    # two particle radii are 0.3: the pairs touch and hold (0.302 measured)
    assert gap(simulate3d(*case, steps=60)) > 0.25
    # without their contacts they nearly pass through each other (0.021 measured)
    assert gap(simulate3d(*case, steps=60, particle_contacts=False)) < 0.1


@needs_mujoco
def test_an_unstable_engine_is_one_line_not_nan(tmp_path, monkeypatch, capfd):
    """One substep per step at 8 Hz (the stiffest mode turns 4.7 rad a step, beyond the
    integrator's limit of 2): the engine's instability is reported, never returned; the engine
    neither prints nor leaves a MUJOCO_LOG.TXT in the working directory."""
    import mujoco
    monkeypatch.chdir(tmp_path)
    with pytest.raises(FloatingPointError) as info:
        simulate3d(1.6, 225.0, -35.0, 30.0, 30.0, 30.0, steps=100, frequency=8.0,
                   min_substeps=1, max_spring_phase=100.0, max_travel=100.0)
    assert "\n" not in str(info.value) and "unstable" in str(info.value)
    assert not list(tmp_path.iterdir())
    assert "WARNING" not in capfd.readouterr().out
    cfg = mujoco.MjLogConfig.get()            # the engine's log settings are restored
    assert cfg.logto_file and cfg.logto_console


@needs_mujoco
def test_same_call_same_bits_and_flex_equals_tendons():
    case = (1.6, 250.0, -40.0, 33.0, 35.0, 36.0)
    a = simulate3d(*case, steps=120)
    assert np.array_equal(a, simulate3d(*case, steps=120))
    # the springs as spatial tendons: the same forces, the same bits
    assert np.array_equal(a, simulate3d(*case, steps=120, springs="tendon"))


@needs_mujoco
def test_energy_is_returned_per_row_and_falls_at_the_walls():
    traj, e = simulate3d(1.6, 225.0, -35.0, 35.0, 35.0, 35.0, steps=300, return_energy=True)
    assert e.shape == (300,) and np.isfinite(e).all()
    # contacts only take energy (friction, inelastic particle contacts); the springs' share
    # swings a few percent with the symplectic integrator
    assert e.max() < 1.05 * e[0] and e[-1] < e[0]
