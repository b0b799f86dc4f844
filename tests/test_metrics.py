"""Tests of tpnet_ref.metrics against brute-force NumPy and scipy's cKDTree."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from tpnet_ref.metrics import chamfer_loss, position_error, shape_error
from tpnet_ref.checks import NonFiniteResultError

from metrics_helpers import (METHODS, VARIANTS, assert_gradient_is_central_difference,  # noqa: E402,F401
                             kd_error, ref_error, ref_sums)


def cdist_reading(P, Q, variant):
    """The three readings written out from scipy's full distance matrix (docs/spec.md §3)."""
    d = cdist(np.asarray(P, np.float64), np.asarray(Q, np.float64))   # Euclidean, (N, M)
    to_q, to_p = d.min(axis=1), d.min(axis=0)
    return {"released": to_q.sum() + to_p.sum(),
            "squared": (to_q ** 2).sum() + (to_p ** 2).sum(),
            "paper": ((to_q ** 2).sum() + (to_p ** 2).sum()) / len(P)}[variant]


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("n,m", [(30, 30), (30, 7), (4, 45), (1, 9)])
def test_each_reading_matches_scipy_cdist_brute_force(variant, n, m):
    """Each named reading equals its formula on scipy's distance matrix, for |P| != |Q| too,
    for the position error, the shape error (sets centred first) and a batch."""
    rng = np.random.default_rng(100 * n + m)
    P = rng.random((3, n, 2))
    Q = rng.normal(0.4, 0.3, (3, m, 2))
    got = position_error(P, Q, variant)
    want = [cdist_reading(P[b], Q[b], variant) for b in range(3)]
    np.testing.assert_allclose(got, want, rtol=1e-12)
    got_s = shape_error(P, Q, variant)
    want_s = [cdist_reading(P[b] - P[b].mean(0), Q[b] - Q[b].mean(0), variant) for b in range(3)]
    np.testing.assert_allclose(got_s, want_s, rtol=1e-12, atol=1e-15)


def test_readings_differ_as_specified():
    """Two points at distance 3 and 4 from a one-point set: released 3+4+(nearest back: 3),
    squared 9+16+9, paper (9+16+9)/2; the loss of "squared" equals that of "paper"."""
    P = np.array([[3.0, 0.0], [0.0, 4.0]])
    Q = np.array([[0.0, 0.0]])
    assert position_error(P, Q, "released") == pytest.approx(10.0)
    assert position_error(P, Q, "squared") == pytest.approx(34.0)
    assert position_error(P, Q, "paper") == pytest.approx(17.0)
    assert position_error(P, Q) == pytest.approx(17.0)                 # default: "paper"
    assert chamfer_loss(P, Q, "squared") == chamfer_loss(P, Q, "paper") == pytest.approx(34.0)


# ---------------------------------------------------------------- values


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("n,m", [(1, 1), (1, 7), (30, 30), (30, 17), (5, 200), (300, 450)])
def test_matches_bruteforce_and_kdtree(method, variant, n, m):
    rng = np.random.default_rng(n * 1000 + m)
    P = rng.random((n, 2))
    Q = rng.normal(0.5, 0.4, (m, 2))
    got = position_error(P, Q, variant, method=method)
    assert isinstance(got, float)
    assert got == pytest.approx(ref_error(P, Q, variant), rel=1e-12, abs=0)
    assert got == pytest.approx(kd_error(P, Q, variant), rel=1e-9)
    got_s = shape_error(P, Q, variant, method=method)
    assert got_s == pytest.approx(ref_error(P, Q, variant, centre=True), rel=1e-12, abs=1e-15)


@pytest.mark.parametrize("variant", VARIANTS)
def test_float32_is_computed_in_float64(variant):
    rng = np.random.default_rng(3)
    P = rng.random((40, 2)).astype(np.float32)
    Q = rng.random((25, 2)).astype(np.float32)
    got = position_error(P, Q, variant)
    assert got == position_error(P.astype(np.float64), Q.astype(np.float64), variant)
    assert got == pytest.approx(ref_error(P, Q, variant), rel=1e-12)
    # integers are accepted too
    assert position_error([[0, 0], [3, 4]], [[0, 0]], "released") == 5.0
    assert position_error([[0, 0], [3, 4]], [[0, 0]], "paper") == 12.5


def test_broadcasting_and_result_shapes():
    rng = np.random.default_rng(4)
    T, S, N, M = 5, 3, 12, 9
    P = rng.random((T, 1, N, 2))
    Q = rng.random((S, M, 2)).astype(np.float32)
    got = position_error(P, Q, "released")
    assert isinstance(got, np.ndarray) and got.shape == (T, S) and got.dtype == np.float64
    for t in range(T):
        for s in range(S):
            assert got[t, s] == pytest.approx(ref_error(P[t, 0], Q[s], "released"), rel=1e-12)
    # a rollout against one fixed set, and the reverse
    assert position_error(P[:, 0], Q[0]).shape == (T,)
    assert shape_error(Q[0], P[:, 0], "released").shape == (T,)
    # a batch of zero pairs
    assert position_error(np.zeros((0, N, 2)), Q[0]).shape == (0,)
    # the batched grid kernel (medium sets, several pairs) agrees with brute force
    A = rng.random((8, 800, 2))  # enough work for the parallel kernel
    B = rng.random((8, 500, 2)) * 3
    for v in VARIANTS:
        np.testing.assert_allclose(position_error(A, B, v, method="grid"),
                                   position_error(A, B, v, method="brute"), rtol=1e-13)


def test_paper_divides_by_first_argument():
    P = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    Q = np.array([[0.0, 1.0]])
    # P->Q: 1 + 2 + 5 + 10 = 18; Q->P: 1; divided by |P| = 4
    assert position_error(P, Q, "paper") == pytest.approx(19 / 4)
    assert position_error(Q, P, "paper") == pytest.approx(19 / 1)
    assert chamfer_loss(P, Q, "paper") == pytest.approx(19.0)


# ------------------------------------------------------------- large sets


def _large_cases(rng, n):
    u = rng.random((n, 2))
    blobs = np.concatenate([rng.normal(c, 0.01, (n // 4, 2)) for c in (0, 1, 5, 50)])
    line = np.stack([rng.random(n) * 10, np.full(n, 0.5)], axis=1)
    diag = np.repeat(rng.random((n, 1)), 2, axis=1)
    dup = np.repeat(rng.random((n // 100, 2)), 100, axis=0)
    return {
        "uniform": (u, rng.random((n + 1234, 2))),
        "clustered": (blobs, rng.random((n, 2)) * 50),
        "line_vs_plane": (line, u),
        "diagonal_vs_line": (diag, line),
        "duplicates": (dup, u[: n // 2]),
        "extents_1e-4_vs_1e4": (u * 1e-4, u * 1e4),
        "far_apart": (u + 1e5, u),
        "single_point": (u[:1], u),
    }


@pytest.mark.parametrize("case", ["uniform", "clustered", "line_vs_plane", "diagonal_vs_line",
                                  "duplicates", "extents_1e-4_vs_1e4", "far_apart",
                                  "single_point"])
def test_large_sets_match_kdtree(case):
    rng = np.random.default_rng(7)
    P, Q = _large_cases(rng, 20_000)[case]
    dp = cKDTree(Q).query(P)[0]
    dq = cKDTree(P).query(Q)[0]
    released = dp.sum() + dq.sum()
    paper = ((dp ** 2).sum() + (dq ** 2).sum()) / len(P)
    for method in ("auto", "grid"):
        assert position_error(P, Q, "released", method=method) == pytest.approx(released, rel=1e-10)
        assert position_error(P, Q, "paper", method=method) == pytest.approx(paper, rel=1e-9)


# ------------------------------------------------------------------ loss


def test_loss_values_and_reductions():
    rng = np.random.default_rng(5)
    P = rng.random((6, 30, 2))
    Q = rng.random((6, 20, 2))
    per = chamfer_loss(P, Q, "paper", reduction="none")
    assert per.shape == (6,)
    np.testing.assert_allclose(per, 30 * position_error(P, Q, "paper"), rtol=1e-13)
    np.testing.assert_allclose(chamfer_loss(P, Q, "released", reduction="none"),
                               position_error(P, Q, "released"), rtol=1e-13)
    assert chamfer_loss(P, Q, "paper") == pytest.approx(per.mean(), rel=1e-13)
    assert chamfer_loss(P, Q, "paper", reduction="sum") == pytest.approx(per.sum(), rel=1e-13)
    assert isinstance(chamfer_loss(P[0], Q[0], reduction="none"), float)


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("reduction,method", [("mean", "auto"), ("sum", "grid"),
                                              ("none", "kdtree")])
def test_loss_gradient_matches_finite_differences(variant, reduction, method):
    rng = np.random.default_rng(6)
    P = rng.random((3, 8, 2))
    Q = rng.random((5, 2))  # broadcast against the batch: its gradient sums over the pairs
    loss, gP, gQ = chamfer_loss(P, Q, variant, reduction=reduction, return_grad=True,
                                method=method)
    assert gP.shape == P.shape and gQ.shape == Q.shape
    assert_gradient_is_central_difference(gP, gQ, P, Q, variant, reduction)


@pytest.mark.parametrize("variant", VARIANTS)
def test_loss_gradient_batched_paths_agree(variant):
    """Parallel brute force with indices, parallel grid, and k-d tree give the same gradient."""
    rng = np.random.default_rng(8)
    P = rng.random((300, 30, 2))
    Q = rng.random((300, 31, 2))
    ref = chamfer_loss(P, Q, variant, return_grad=True, method="kdtree")
    for method in ("auto", "grid"):
        got = chamfer_loss(P, Q, variant, return_grad=True, method=method)
        assert got[0] == pytest.approx(ref[0], rel=1e-12)
        np.testing.assert_allclose(got[1], ref[1], rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(got[2], ref[2], rtol=1e-10, atol=1e-14)


def test_loss_gradient_dtype_follows_input():
    P = np.random.default_rng(0).random((10, 2)).astype(np.float32)
    _, gP, gQ = chamfer_loss(P, P[::-1] + 0.1, return_grad=True)
    assert gP.dtype == np.float32 and gQ.dtype == np.float32


# ------------------------------------------------------------ validation


@pytest.mark.parametrize("fn", [position_error, shape_error, chamfer_loss])
@pytest.mark.parametrize("bad,exc,msg", [
    (np.zeros((0, 2)), ValueError, "empty"),
    (np.zeros((3, 0, 2)), ValueError, "empty"),
    (np.array([[0.0, np.nan]]), ValueError, "NaN"),
    (np.array([[0.0, np.inf]]), ValueError, "NaN or infinite"),
    (np.zeros((4, 3)), ValueError, r"\(\.\.\., N, 2\)"),
    (np.zeros(4), ValueError, r"\(\.\.\., N, 2\)"),
    ("abc", TypeError, "numeric"),
    (np.array([[1 + 1j, 0]]), TypeError, "real numbers"),
    (np.ones((3, 2), bool), TypeError, "real numbers"),
    ([[1, 2], [3]], ValueError, "one array"),
])
def test_invalid_inputs_name_the_argument(fn, bad, exc, msg):
    good = np.zeros((3, 2))
    with pytest.raises(exc, match=f"^P: .*{msg}"):
        fn(bad, good)
    with pytest.raises(exc, match=f"^Q: .*{msg}"):
        fn(good, bad)


def test_invalid_options_and_shapes():
    P = np.zeros((4, 5, 2))
    with pytest.raises(ValueError, match="P and Q: leading dimensions"):
        position_error(P, np.zeros((3, 5, 2)))
    with pytest.raises(ValueError, match="variant"):
        position_error(P, P, "euclidean")
    with pytest.raises(ValueError, match="method"):
        shape_error(P, P, method="octree")
    with pytest.raises(ValueError, match="reduction"):
        chamfer_loss(P, P, reduction="max")
    with pytest.raises(TypeError, match="return_grad"):
        chamfer_loss(P, P, return_grad="yes")


def test_overflow_is_an_error_not_inf():
    P = np.array([[1e200, 0.0]])
    Q = np.array([[-1e200, 0.0]])
    with pytest.raises(NonFiniteResultError, match="position_error"):
        position_error(P, Q)
    assert position_error(P, P, "released") == 0.0


def test_import_does_not_load_numba():
    import os

    import tpnet_ref
    root = os.path.dirname(os.path.dirname(os.path.abspath(tpnet_ref.__file__)))
    env = dict(os.environ, PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", ""))
    code = ("import sys, tpnet_ref, tpnet_ref.metrics; "
            f"assert tpnet_ref.__file__.startswith({root!r}), tpnet_ref.__file__; "
            "assert 'numba' not in sys.modules, 'numba imported'; "
            "tpnet_ref.metrics.position_error([[0, 0]], [[1, 0]]); "
            "assert 'numba' in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True, env=env)


# ------------------------------------------------------------ properties

coords = st.floats(-100, 100, allow_nan=False, allow_infinity=False, width=64)
point_sets = st.integers(1, 40).flatmap(lambda n: hnp.arrays(np.float64, (n, 2), elements=coords))
# few distinct values: many duplicates and collinear points
grid_sets = st.integers(1, 40).flatmap(
    lambda n: hnp.arrays(np.float64, (n, 2), elements=st.integers(-3, 3).map(float)))
any_sets = st.one_of(point_sets, grid_sets)
FAST = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FAST
@given(any_sets, any_sets, st.sampled_from(VARIANTS), st.randoms(use_true_random=False))
def test_property_permutation_invariant(P, Q, variant, rnd):
    pp = np.array(rnd.sample(range(len(P)), len(P)))
    qq = np.array(rnd.sample(range(len(Q)), len(Q)))
    a = position_error(P, Q, variant)
    assert position_error(P[pp], Q[qq], variant) == pytest.approx(a, rel=1e-12, abs=0)
    assert shape_error(P[pp], Q[qq], variant) == pytest.approx(
        shape_error(P, Q, variant), rel=1e-9, abs=1e-9)


@FAST
@given(any_sets, st.sampled_from(VARIANTS))
def test_property_zero_for_equal_sets(P, variant):
    assert position_error(P, P, variant) == 0.0
    assert shape_error(P, P.copy(), variant) == 0.0
    assert chamfer_loss(P, P, variant) == 0.0


@FAST
@given(any_sets, any_sets, st.sampled_from(VARIANTS),
       hnp.arrays(np.float64, 2, elements=coords), hnp.arrays(np.float64, 2, elements=coords))
def test_property_shape_error_translation_invariant(P, Q, variant, s, t):
    a = shape_error(P, Q, variant)
    b = shape_error(P + s, Q + t, variant)
    assert b == pytest.approx(a, rel=1e-6, abs=1e-9)


@FAST
@given(any_sets, any_sets)
def test_property_released_symmetric(P, Q):
    assert position_error(P, Q, "released") == pytest.approx(
        position_error(Q, P, "released"), rel=1e-12, abs=0)
    assert shape_error(P, Q, "released") == pytest.approx(
        shape_error(Q, P, "released"), rel=1e-12, abs=0)


@FAST
@given(any_sets, any_sets, st.sampled_from(VARIANTS))
def test_property_grid_equals_bruteforce(P, Q, variant):
    """The grid search is exact: the same value as brute force on arbitrary small sets."""
    assert position_error(P, Q, variant, method="grid") == pytest.approx(
        position_error(P, Q, variant, method="brute"), rel=1e-13, abs=0)
