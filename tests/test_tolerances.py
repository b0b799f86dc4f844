"""Every stated tolerance is a test (docs/tolerances.md): the ways of computing the same
prediction that are not bit-identical stay within the bounds the docs state, per prediction
and over an 80-step rollout, in float32 and float64, on the shipped model and windows of a
simulated training-grid trajectory. (Another BLAS kernel: tests/test_determinism.py.)"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import tpnet_ref
from tolerance_bounds import BOUNDS, assert_within

pytest.importorskip("pymunk")
numba = pytest.importorskip("numba")

STEPS = 80


@pytest.fixture(scope="module")
def windows():
    from tpnet_ref.sim import simulate
    from tpnet_ref.sim.cases import TRAIN_POSITIONS
    traj = simulate(1.3, 195.0, *TRAIN_POSITIONS[7])          # a training-grid trajectory
    return np.stack([traj[s:s + 16:4] for s in (0, 60)])


@pytest.fixture(scope="module")
def shipped():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return tpnet_ref.load()


def _single(model, w):
    return (np.stack([model.predict(x) for x in w]),
            np.stack([model.rollout(x, STEPS) for x in w]))


def _batch(model, w):
    return model.predict_batch(w), model.rollout_batch(w, STEPS)


@pytest.fixture(scope="module")
def plain(shipped, windows):
    """Each window alone through the NumPy engine, float32 and float64."""
    return {dt: _single(shipped.astype(dt), windows) for dt in BOUNDS}


@pytest.mark.parametrize("dtype", list(BOUNDS))
@pytest.mark.parametrize("engine", ["numpy", "numba"])
def test_a_window_in_a_batch_against_it_alone(shipped, windows, plain, dtype, engine):
    model = shipped.astype(dtype).with_engine(engine)
    alone = plain[dtype] if engine == "numpy" else _single(model, windows)
    b = _batch(model, windows)
    assert_within(b[0], alone[0], b[1], alone[1], dtype, f"batch vs single, {engine}")
    assert np.array_equal(alone[1][:, 0], alone[0])        # a rollout starts with predict: bits


@pytest.mark.parametrize("dtype", list(BOUNDS))
def test_the_two_engines(shipped, windows, plain, dtype):
    nb = _single(shipped.astype(dtype).with_engine("numba"), windows)
    assert_within(nb[0], plain[dtype][0], nb[1], plain[dtype][1], dtype, "numba vs numpy")


@pytest.mark.parametrize("dtype", list(BOUNDS))
def test_a_specialised_model_against_the_plain_one(shipped, windows, plain, dtype):
    from tpnet_ref.sim import simulate
    from tpnet_ref.sim.cases import TRAIN_POSITIONS
    traj = simulate(1.15, 230.0, *TRAIN_POSITIONS[40])       # calibrated on another trajectory
    scene = shipped.astype(dtype).specialize(np.stack([traj[i:i + 16:4] for i in range(0, 400, 8)]))
    sp = _single(scene, windows)
    assert_within(sp[0], plain[dtype][0], sp[1], plain[dtype][1], dtype, "specialised vs plain")


@pytest.mark.parametrize("dtype", list(BOUNDS))
def test_unit_sorted_against_the_file_order(shipped, windows, plain, dtype):
    assert shipped.unit_order is not None                  # the shipped file carries an order
    fo = _single(shipped.astype(dtype).with_unit_order(None), windows)
    assert_within(fo[0], plain[dtype][0], fo[1], plain[dtype][1], dtype,
                  "file order vs unit-sorted")


def test_float32_against_float64(windows, plain):
    f32, f64 = plain["float32"], plain["float64"]
    assert_within(f32[0], f64[0], f32[1], f64[1], "float32", "float32 vs float64")
