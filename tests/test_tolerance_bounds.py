"""The checker every tolerance test relies on (tests/tolerance_bounds.py) fails where it must:
NaN or inf on either side, a gap at any rollout step (not only the stated 10, 40 and 80), a
gap in a single point, a shape mismatch; and passes two ways within the bounds."""
from __future__ import annotations

import numpy as np
import pytest

from tolerance_bounds import BOUNDS, assert_within, gaps, step_bound


def _pair(dtype="float32", steps=80, k=2):
    rng = np.random.default_rng(0)
    pred = rng.uniform(5, 40, (k, 30, 2))
    roll = rng.uniform(5, 40, (k, steps, 30, 2))
    return pred, pred.copy(), roll, roll.copy()


@pytest.mark.parametrize("dtype", list(BOUNDS))
def test_equal_and_within_the_bounds_pass(dtype):
    a, b, ra, rb = _pair(dtype)
    assert assert_within(a, b, ra, rb, dtype, "same")["predict"] == 0.0
    half = {s: 0.5 * step_bound(BOUNDS[dtype], s) for s in range(1, 81)}
    rb = rb + np.array([half[s] for s in range(1, 81)])[None, :, None, None]
    g = assert_within(a + 0.5 * BOUNDS[dtype]["predict"], b, ra, rb, dtype, "within")
    assert set(g) == {"predict", *range(1, 81)}


@pytest.mark.parametrize("where", ["a_pred", "b_pred", "a_roll", "b_roll"])
@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_a_value_that_is_not_finite_fails(where, value):
    arrays = dict(zip(["a_pred", "b_pred", "a_roll", "b_roll"], _pair()))
    arrays[where][(1, 7) if "pred" in where else (1, 33, 7)] = value
    with pytest.raises(AssertionError, match="exceed the stated bounds"):
        assert_within(*arrays.values(), "float32", "non-finite")


def test_all_nan_fails():
    a, b, ra, rb = _pair()
    with pytest.raises(AssertionError):
        assert_within(np.full_like(a, np.nan), b, np.full_like(ra, np.nan), rb, "float32", "nan")


@pytest.mark.parametrize("step", [1, 2, 9, 11, 37, 41, 79])
@pytest.mark.parametrize("dtype", list(BOUNDS))
def test_a_gap_at_any_rollout_step_fails(step, dtype):
    a, b, ra, rb = _pair(dtype)
    rb[0, step - 1, 12, 1] += 3 * step_bound(BOUNDS[dtype], step)    # one point, one step
    with pytest.raises(AssertionError, match=rf"\b{step}: "):
        assert_within(a, b, ra, rb, dtype, f"step {step}")


def test_a_gap_in_one_predicted_point_fails():
    a, b, ra, rb = _pair()
    b[1, 29, 0] += 1e-3
    with pytest.raises(AssertionError, match="'predict'"):
        assert_within(a, b, ra, rb, "float32", "one point")


def test_shapes_must_match():
    a, b, ra, rb = _pair()
    with pytest.raises(AssertionError, match="shapes differ"):
        assert_within(a, b[:, :1], ra, rb, "float32", "broadcast")
    with pytest.raises(AssertionError, match="shapes differ"):
        assert_within(a, b, ra, rb[:, :1], "float32", "broadcast")


def test_the_step_bounds():
    f32 = BOUNDS["float32"]
    assert step_bound(f32, 1) == f32["predict"]
    assert [step_bound(f32, s) for s in (2, 10, 11, 40, 41, 80)] == [
        f32[10], f32[10], f32[40], f32[40], f32[80], f32[80]]
    with pytest.raises(ValueError, match="no stated bound for rollout step 81"):
        step_bound(f32, 81)
    assert list(gaps(np.zeros((1, 3, 2, 2)), np.ones((1, 3, 2, 2)))) == [1, 2, 3]
