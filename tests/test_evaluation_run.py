"""tpnet_ref.evaluation.run: simulated frames, what each model is fed and scored against, batched
rollouts, ordering invariance, the generalisation scenes.

Everything runs on small random networks, a few cases and short rollouts.
"""
from __future__ import annotations


import numpy as np
import pytest

pytest.importorskip("h5py")

from tpnet_ref import evaluation as E  # noqa: E402
from tpnet_ref.metrics import position_error  # noqa: E402
from evaluation_helpers import frames3, small_model  # noqa: E402,F401


def test_simulated_frames_are_every_fourth_row(frames3):
    from tpnet_ref.sim import simulate
    rows = simulate(*E.TEST_CASES[1], 41)
    assert frames3.shape == (3, 11, 30, 2)
    np.testing.assert_array_equal(frames3[1], rows[::4])
    np.testing.assert_array_equal(frames3[1, 0], rows[0])                  # frame 0 = initial ring


def test_evaluate_feeds_frames_0_to_m_minus_1(frames3):
    model = small_model(4)
    curves = E.evaluate(frames3, [E.ModelSpec("net", model)], ms=[4], horizon=5,
                        orderings=("given",))
    net = [c for c in curves if c.name == "net"][0]
    n = E.normalize(frames3)
    for c in range(3):
        pred = model.rollout(n[c, :4], 5, normalized=True)
        want = position_error(n[c, 4:9], pred, variant="released")
        np.testing.assert_allclose(net.err["Ep_released"][c], want, rtol=1e-9, atol=1e-12)
    copy = [c for c in curves if c.name == "copy last"][0]
    np.testing.assert_allclose(copy.err["Ep_released"][:, 0],
                               position_error(n[:, 4], n[:, 3], variant="released"))


def test_batched_rollout_matches_model_rollout():
    model = small_model(3, seed=1)
    w = np.random.default_rng(0).uniform(0.2, 0.8, (5, 3, 30, 2))
    got = E.batched_rollout(model, w, 4, batch=2)
    for b in range(5):
        np.testing.assert_allclose(got[b], model.rollout(w[b], 4, normalized=True),
                                   rtol=1e-10, atol=1e-12)
    world = E.batched_rollout(model, E.denormalize(w), 2, normalized=False)
    np.testing.assert_allclose(E.normalize(world), got[:, :2], atol=1e-9)
    with pytest.raises(ValueError, match="m=3"):
        E.batched_rollout(model, w[:, :2], 1)


def test_tpnet_invariant_and_constant_velocity_not(frames3):
    curves = E.evaluate(frames3, [E.ModelSpec("net", small_model(4))], ms=[4], horizon=3)
    by = {(c.name, c.ordering): c for c in curves}
    for o in E.ORDERINGS:
        np.testing.assert_array_equal(by[("net", o)].err["Ep_released"],
                                      by[("net", "given")].err["Ep_released"])
        np.testing.assert_allclose(by[("copy last", o)].err["Ep_released"],
                                   by[("copy last", "given")].err["Ep_released"], rtol=1e-12)
    assert (by[("constant velocity", "shuffle")].at(3)
            > 2 * by[("constant velocity", "given")].at(3))


def test_generalisation_cases_outside_training_ranges():
    g = E.generalisation_cases(10, seed=0)
    assert set(g) == {"force > 1.6", "angle outside 180-270", "start near other walls"}
    assert (g["force > 1.6"][:, 0] > 1.6).all()
    a = g["angle outside 180-270"][:, 1]
    assert ((a < 180) | (a > 270)).all()
    xy = g["start near other walls"][:, 2:]
    assert (xy.min(axis=1) <= 8.0).all() and (xy >= 2.85).all()
    for cases in g.values():
        assert cases.shape == (10, 4)
    np.testing.assert_array_equal(g["force > 1.6"], E.generalisation_cases(10, 0)["force > 1.6"])
