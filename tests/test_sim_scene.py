"""The soft-body scene (tpnet_ref.sim.scene): construction, rows, determinism, stability, validation,
agreement with Box2D."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tpnet_ref import sim
from tpnet_ref.sim.scene import SceneParams, build_scene, simulate, spring_pairs

P = SceneParams()


def inside_box(traj: np.ndarray, p: SceneParams = P) -> bool:
    """Every particle centre (after row 0) in the free area and not deeper than one radius."""
    t = traj[1:]
    return bool(np.isfinite(t).all() and t.min() >= p.free_lo and t.max() <= p.free_hi)


# ----------------------------------------------------------------- construction
def test_scene_construction():
    sc = build_scene(30.0, 35.0, 1.3, 225.0)
    assert len(sc.bodies) == 30
    assert sc.pairs.shape == (360, 2)
    assert len({tuple(sorted(q)) for q in sc.pairs.tolist()}) == 360
    d = (sc.pairs[:, 1] - sc.pairs[:, 0]) % 30
    d = np.minimum(d, 30 - d)
    assert d.min() == 1 and d.max() == 12 and np.bincount(d)[1:].tolist() == [30] * 12
    mass = math.pi * 0.15 ** 2
    assert all(b.mass == pytest.approx(mass) for b in sc.bodies)
    assert all(b.moment == pytest.approx(0.5 * mass * 0.15 ** 2) for b in sc.bodies)
    pos = sc.positions()
    a = np.arange(30) * 2 * np.pi / 30
    np.testing.assert_allclose(pos, np.stack([30 + 2 * np.sin(a), 35 + 2 * np.cos(a)], 1),
                               atol=1e-12)
    np.testing.assert_allclose(sc.rest, 4 * np.sin(np.pi * d / 30), atol=1e-12)
    # the walls are half-planes in the step kernel, not pymunk shapes
    assert len(sc.space.shapes) == 30
    assert sc.params.free_lo == 1.0 and sc.params.free_hi == 44.0
    assert sc.wall_ln.shape == (30, 4)
    assert sc.space.collision_slop == pytest.approx(0.005)
    assert sc.space.iterations == 10


def test_no_walls_builds_none():
    sc = build_scene(30.0, 35.0, params=SceneParams(walls=False))
    assert all(s.body.body_type == s.body.DYNAMIC for s in sc.space.shapes)
    assert len(sc.space.shapes) == 30
    traj = simulate(1.6, 270.0, 22.0, 4.0, steps=100, walls=False)
    assert traj[-1, :, 1].max() < 0.0        # falls through where the floor would be


def test_spring_pairs_small_ring():
    assert spring_pairs(6, 3).shape == (15, 2)  # every pair once when reach = n/2


# ----------------------------------------------------------------- rows and determinism
def test_rows_are_states_after_each_step():
    traj = simulate(1.3, 225.0, 22.0, 22.0, steps=3)
    assert traj.shape == (3, 30, 2)
    ring = sim.ring_positions(22.0, 22.0)
    v0 = 1.3 / P.mass * np.array([math.cos(math.radians(225)), math.sin(math.radians(225))])
    v1 = v0 + P.dt * np.array(P.gravity)      # springs at rest: no force on the first step
    np.testing.assert_allclose(traj[0], ring + P.dt * v1, atol=1e-9)
    full = simulate(1.3, 225.0, 22.0, 22.0, steps=4, include_initial=True)
    np.testing.assert_allclose(full[0], ring, atol=1e-12)
    np.testing.assert_array_equal(full[1:], traj)


def test_deterministic():
    a = simulate(1.45, 200.0, 35.0, 30.0, steps=200)
    b = simulate(1.45, 200.0, 35.0, 30.0, steps=200)
    assert np.array_equal(a, b)


def test_keyword_params_and_params_object_agree():
    a = simulate(1.0, 250.0, 30.0, 30.0, steps=50, frequency=2.0)
    b = simulate(1.0, 250.0, 30.0, 30.0, steps=50, params=SceneParams(frequency=2.0))
    assert np.array_equal(a, b)


def test_default_trajectory_stays_in_box_and_touches_walls():
    traj = simulate(1.6, 200.0, 30.0, 30.0)
    assert inside_box(traj)
    # Box2D's continuous collision stops centres at 0.145 from the wall (docs/spec.md §5: 1.1438)
    assert traj.min() == pytest.approx(1.145, abs=0.01)


# ----------------------------------------------------------------- stability
def _motion_energy(start, p):
    """(600,) kinetic + gravitational energy per row (springs left out: for stiff springs the
    ideal-spring energy of a constraint's residual is not energy of the motion)."""
    sc = build_scene(*start, params=p)
    e = []
    for _ in range(600):
        sc.read()
        e.append(sc.energy(springs=False))
        sc.step()
    return np.array(e)


@pytest.mark.parametrize("frequency", [5.0, 20.0, 100.0, 1000.0])
def test_stiff_springs_stay_finite_in_box_and_do_not_gain_energy(frequency):
    p = SceneParams(frequency=frequency, sleep=False)
    traj = simulate(1.6, 225.0, 30.0, 30.0, params=p)
    assert inside_box(traj)
    e = _motion_energy((30.0, 30.0, 1.6, 225.0), p)
    assert np.isfinite(e).all() and e.max() <= e[0] * (1 + 1e-9)


@pytest.mark.parametrize("angle", [0.0, 45.0, 100.0, 180.0, 225.0, 270.0, 315.0])
@pytest.mark.parametrize("clamp", [True, False])
@pytest.mark.parametrize("impulse_point", ["ring_centre", "particle_centre"])
def test_extreme_impulse_never_leaves_box(angle, clamp, impulse_point):
    traj = simulate(16.0, angle, 41.0, 41.0, steps=300,
                    max_translation=2.0 if clamp else None, impulse_point=impulse_point)
    assert inside_box(traj)


@pytest.mark.parametrize("case", [(1.6, 200.0, 41.9, 41.2), (1.6, 270.0, 41.9, 31.7),
                                  (16.0, 225.0, 30.0, 30.0)])
def test_particles_spinning_at_the_clamp_stay_finite_inside_and_lose_energy(case):
    # every particle spins at Box2D's limit (pi/2 per step) against walls with friction 1
    traj, e = simulate(*case, steps=3000, return_energy=True)
    assert inside_box(traj)
    assert traj[1:].min() >= P.free_lo + P.toi_distance - 1e-9
    assert traj[1:].max() <= P.free_hi - P.toi_distance + 1e-9
    assert np.isfinite(e).all() and e.max() <= e[0] * (1 + 1e-9)
    assert e[-1] < 0.5 * e[0]                     # wall friction takes the spin's energy
    unclamped = simulate(*case[:4], steps=300, max_rotation=None)
    assert inside_box(unclamped)


def test_very_extreme_impulse_without_clamp():
    traj = simulate(160.0, 200.0, 40.0, 40.0, steps=200, max_translation=None)
    assert inside_box(traj)


def test_long_run_energy_never_grows():
    traj, e = simulate(1.6, 225.0, 30.0, 30.0, steps=10_000, sleep=False, return_energy=True)
    assert inside_box(traj)
    assert e.max() <= e[0] * (1 + 1e-9)
    assert e[5000:].max() < 0.1 * e[0]          # soft joints lose energy, as in Box2D


def test_free_flight_conserves_energy_and_shape():
    traj, e = simulate(1.6, 45.0, 22.0, 22.0, steps=2000, walls=False, gravity=(0.0, 0.0),
                       return_energy=True)
    np.testing.assert_allclose(e, e[0], rtol=1e-9)
    np.testing.assert_allclose(traj[-1] - traj[-1].mean(0), traj[0] - traj[0].mean(0),
                               atol=1e-9)


def test_sleeping_freezes_the_body():
    # dropped from rest onto the floor: Box2D's island falls asleep at row 928
    traj = simulate(0.0, 270.0, 22.0, 3.3, steps=1200, sleep=True)
    assert np.array_equal(traj[-1], traj[-2])
    moving = np.nonzero(np.abs(np.diff(traj, axis=0)).max(axis=(1, 2)) > 0)[0]
    assert 800 < moving.max() < 1100


@settings(max_examples=8, deadline=None)
@given(force=st.floats(0.0, 16.0), angle=st.floats(-360.0, 720.0),
       x=st.floats(2.85, 42.15), y=st.floats(2.85, 42.15),
       freq=st.sampled_from([0.5, 1.0, 3.0, 30.0]))
def test_random_valid_inputs_stay_finite_and_in_box(force, angle, x, y, freq):
    traj = simulate(force, angle, x, y, steps=120, frequency=freq)
    assert inside_box(traj)


# ----------------------------------------------------------------- validation
@pytest.mark.parametrize("kwargs, match", [
    (dict(force=float("nan")), "force"),
    (dict(force=-1.0), "force"),
    (dict(force=1e300), "force"),
    (dict(angle_deg=float("inf")), "angle_deg"),
    (dict(x=float("nan")), "x"),
    (dict(x=2.0), "x"),
    (dict(y=43.0), "y"),
    (dict(steps=0), "steps"),
    (dict(dt=0.0), "dt"),
    (dict(dt=-1 / 45), "dt"),
    (dict(dt=float("nan")), "dt"),
    (dict(frequency=0.0), "frequency"),
    (dict(frequency=1e9), "frequency"),
    (dict(damping_ratio=-0.1), "damping_ratio"),
    (dict(n_particles=2), "n_particles"),
    (dict(spring_reach=16), "spring_reach"),
    (dict(spring_reach=0), "spring_reach"),
    (dict(particle_radius=0.5), "particle_radius"),
    (dict(wall_restitution=1.5), "wall_restitution"),
    (dict(particle_friction=-1.0), "particle_friction"),
    (dict(box_size=6.0), "box_size"),
    (dict(gravity=(0.0, float("nan"))), "gravity"),
    (dict(gravity=(0.0, -1e300)), "gravity"),
    (dict(density=1e-300), "density"),
    (dict(iterations=0), "iterations"),
    (dict(max_translation=-1.0), "max_translation"),
])
def test_value_errors_name_the_parameter(kwargs, match):
    args = dict(force=1.0, angle_deg=200.0, x=30.0, y=30.0, steps=10)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        simulate(args.pop("force"), args.pop("angle_deg"), args.pop("x"), args.pop("y"),
                 args.pop("steps"), **args)


@pytest.mark.parametrize("kwargs", [dict(steps=1.5), dict(n_particles=30.0), dict(bogus=1),
                                    dict(steps=True)])
def test_type_errors(kwargs):
    args = dict(steps=10)
    args.update(kwargs)
    with pytest.raises(TypeError):
        simulate(1.0, 200.0, 30.0, 30.0, args.pop("steps"), **args)


def test_string_force_is_type_error():
    with pytest.raises(TypeError, match="force"):
        simulate("1.0", 200.0, 30.0, 30.0, 10)  # type: ignore[arg-type]


def test_no_walls_allows_any_start():
    traj = simulate(1.0, 200.0, -100.0, 500.0, steps=5, walls=False)
    assert np.isfinite(traj).all()


# ----------------------------------------------------------------- against Box2D
@pytest.mark.parametrize("impulse_point", ["ring_centre", "particle_centre"])
def test_matches_box2d_on_test_cases(impulse_point):
    pytest.importorskip("Box2D")
    from tpnet_ref.sim.box2d import simulate_box2d
    cases = [(1.3, 195, 39.5, 29.5), (1.0, 205, 34.6, 42.0), (1.6, 270, 41.9, 31.7),
             (1.3, 225.0, 39.5, 29.5)]
    for f, a, x, y in cases:
        b = simulate_box2d(f, a, x, y, 161, impulse_point=impulse_point)
        p = simulate(f, a, x, y, 161, impulse_point=impulse_point)
        assert np.linalg.norm(b[160].mean(0) - p[160].mean(0)) < 0.05


def test_released_and_centre_of_mass_conventions_differ_after_the_first_bounce():
    a = simulate(1.3, 225.0, 39.5, 29.5, 300)
    b = simulate(1.3, 225.0, 39.5, 29.5, 300, impulse_point="particle_centre")
    np.testing.assert_allclose(a[:5], b[:5], atol=1e-9)      # free flight: spin moves nothing
    assert np.linalg.norm(a[-1].mean(0) - b[-1].mean(0)) > 0.05


# ----------------------------------------------------------------- the released start impulse
def test_defaults_are_the_released_scene():
    assert P.impulse_point == "ring_centre" and P.sleep is False


def test_ring_centre_impulse_spins_each_particle_by_its_lever_arm():
    f, a, x, y = 1.3, 225.0, 22.0, 22.0
    sc = build_scene(x, y, f, a)
    w0 = sc.read()[:30, 4]
    ring = sim.ring_positions(x, y)
    j = f * np.array([math.cos(math.radians(a)), math.sin(math.radians(a))])
    lever = np.array([x, y]) - ring
    np.testing.assert_allclose(w0 * P.inertia, lever[:, 0] * j[1] - lever[:, 1] * j[0],
                               rtol=1e-12, atol=1e-15)
    assert np.abs(w0).max() > 3000.0                    # thousands of rad/s before the clamp
    sc.step()
    w1 = sc.read()[:30, 4]
    limit = P.max_rotation / P.dt                       # pi/2 per step: 70.7 rad/s
    np.testing.assert_allclose(np.abs(w1), np.minimum(np.abs(w0), limit), rtol=1e-12)
    assert np.array_equal(np.sign(w1), np.sign(w0))
    still = build_scene(x, y, f, a, SceneParams(impulse_point="particle_centre"))
    assert not still.read()[:30, 4].any()


def test_unknown_impulse_point_is_a_one_line_error():
    with pytest.raises(ValueError, match="impulse_point"):
        simulate(1.0, 200.0, 30.0, 30.0, 5, impulse_point="centre")


def test_restitution_settings_stay_sane():
    # the paper's stated wall restitution 1 and bouncy particles: finite, inside, no energy gain
    traj, e = simulate(1.6, 250.0, 30.0, 30.0, steps=600, wall_restitution=1.0,
                       particle_restitution=0.5, return_energy=True)
    assert inside_box(traj)
    # an elastic impact of a spring body can lift the energy by a fraction of a percent for a
    # step (the time-of-impact position solve moves the particle without work); never more
    assert e.max() <= e[0] * 1.01
    assert e[-1] < 0.5 * e[0]
    plain = simulate(1.6, 250.0, 30.0, 30.0, steps=600)
    assert np.abs(plain - traj).max() > 0.1


def test_start_against_the_wall_row0_untouched():
    # the test set has a start at y = 42.0: the top particle starts at 44.0, on the wall face
    traj = simulate(1.0, 205.0, 34.6, 42.0, steps=5, include_initial=True)
    np.testing.assert_allclose(traj[0], sim.ring_positions(34.6, 42.0), atol=1e-12)
    assert inside_box(traj)
    assert traj[1:, :, 1].max() <= 44.0 - 0.145
