"""Tests of tpnet_ref.metrics on 3-D point sets, against brute-force NumPy and scipy's cKDTree
(the 3-D twins of tests/test_metrics.py), and of the dim checks shared by 2-D and 3-D."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tpnet_ref.checks import NonFiniteResultError
from tpnet_ref.metrics import DIMS, chamfer_loss, position_error, shape_error

spatial = pytest.importorskip("scipy.spatial")
cKDTree = spatial.cKDTree
pytestmark = pytest.mark.lane("3-D")   # in a second test process (tests/lane.py)

from metrics_helpers import (METHODS, VARIANTS, assert_gradient_is_central_difference,  # noqa: E402,F401
                             kd_error, ref_error, ref_sums)


def test_dims_are_two_and_three():
    assert DIMS == (2, 3)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("n,m", [(1, 1), (1, 7), (30, 30), (42, 17), (5, 200), (300, 450),
                                 (700, 900)])
def test_matches_bruteforce_and_kdtree(method, variant, n, m):
    rng = np.random.default_rng(n * 1000 + m)
    P = rng.random((n, 3))
    Q = rng.normal(0.5, 0.4, (m, 3))
    got = position_error(P, Q, variant, method=method)
    assert isinstance(got, float)
    assert got == pytest.approx(ref_error(P, Q, variant), rel=1e-12, abs=0)
    assert got == pytest.approx(kd_error(P, Q, variant), rel=1e-9)
    got_s = shape_error(P, Q, variant, method=method)
    assert got_s == pytest.approx(ref_error(P, Q, variant, centre=True), rel=1e-12, abs=1e-15)


def test_readings_on_a_known_3d_pair():
    """Two points at distance 3 and 4 (along y and z) from a one-point set."""
    P = np.array([[0.0, 3.0, 0.0], [0.0, 0.0, 4.0]])
    Q = np.array([[0.0, 0.0, 0.0]])
    assert position_error(P, Q, "released") == pytest.approx(10.0)
    assert position_error(P, Q, "squared") == pytest.approx(34.0)
    assert position_error(P, Q, "paper") == pytest.approx(17.0)
    assert chamfer_loss(P, Q, "squared") == chamfer_loss(P, Q, "paper") == pytest.approx(34.0)


def test_a_third_coordinate_of_zero_gives_the_2d_value():
    """Points in the plane z = 0 give exactly the 2-D values (distances gain + 0.0)."""
    rng = np.random.default_rng(11)
    for n, m in ((30, 30), (400, 500), (3000, 2000)):
        P2 = rng.random((n, 2))
        Q2 = rng.random((m, 2))
        P3 = np.concatenate([P2, np.zeros((n, 1))], axis=1)
        Q3 = np.concatenate([Q2, np.zeros((m, 1))], axis=1)
        for v in VARIANTS:
            assert position_error(P3, Q3, v) == position_error(P2, Q2, v)
            assert position_error(P3, Q3, v, method="grid") == position_error(P2, Q2, v)


@pytest.mark.parametrize("variant", VARIANTS)
def test_float32_and_integers_are_computed_in_float64(variant):
    rng = np.random.default_rng(3)
    P = rng.random((40, 3)).astype(np.float32)
    Q = rng.random((25, 3)).astype(np.float32)
    got = position_error(P, Q, variant)
    assert got == position_error(P.astype(np.float64), Q.astype(np.float64), variant)
    assert got == pytest.approx(ref_error(P, Q, variant), rel=1e-12)
    assert position_error([[0, 0, 0], [2, 3, 6]], [[0, 0, 0]], "released") == 7.0
    assert position_error([[0, 0, 0], [2, 3, 6]], [[0, 0, 0]], "paper") == 24.5


def test_broadcasting_ragged_sizes_and_result_shapes():
    rng = np.random.default_rng(4)
    T, S, N, M = 5, 3, 12, 9
    P = rng.random((T, 1, N, 3))
    Q = rng.random((S, M, 3)).astype(np.float32)
    got = position_error(P, Q, "released")
    assert isinstance(got, np.ndarray) and got.shape == (T, S) and got.dtype == np.float64
    for t in range(T):
        for s in range(S):
            assert got[t, s] == pytest.approx(ref_error(P[t, 0], Q[s], "released"), rel=1e-12)
    assert position_error(P[:, 0], Q[0]).shape == (T,)
    assert shape_error(Q[0], P[:, 0], "released").shape == (T,)
    assert position_error(np.zeros((0, N, 3)), Q[0]).shape == (0,)
    # the batched kernels (serial and parallel, brute force and grid) agree with each other
    for A, B in ((rng.random((8, 800, 3)), rng.random((8, 500, 3)) * 3),
                 (rng.random((400, 30, 3)), rng.random((400, 42, 3)))):
        for v in VARIANTS:
            want = [ref_error(A[b], B[b], v) for b in range(len(A))]
            for method in ("auto", "brute", "grid"):
                np.testing.assert_allclose(position_error(A, B, v, method=method), want,
                                           rtol=1e-12)


def _large_cases(rng, n):
    u = rng.random((n, 3))
    blobs = np.concatenate([rng.normal(c, 0.01, (n // 4, 3)) for c in (0, 1, 5, 50)])
    line = np.stack([rng.random(n) * 10, np.full(n, 0.5), np.full(n, -0.5)], axis=1)
    plane = np.stack([rng.random(n) * 10, rng.random(n), np.full(n, 0.25)], axis=1)
    diag = np.repeat(rng.random((n, 1)), 3, axis=1)
    dup = np.repeat(rng.random((n // 100, 3)), 100, axis=0)
    return {
        "uniform": (u, rng.random((n + 1234, 3))),
        "clustered": (blobs, rng.random((n, 3)) * 50),
        "line_vs_volume": (line, u),
        "plane_vs_line": (plane, line),
        "diagonal_vs_plane": (diag, plane),
        "duplicates": (dup, u[: n // 2]),
        "extents_1e-4_vs_1e4": (u * 1e-4, u * 1e4),
        "far_apart": (u + 1e5, u),
        "single_point": (u[:1], u),
    }


@pytest.mark.parametrize("case", ["uniform", "clustered", "line_vs_volume", "plane_vs_line",
                                  "diagonal_vs_plane", "duplicates", "extents_1e-4_vs_1e4",
                                  "far_apart", "single_point"])
def test_large_sets_match_kdtree(case):
    rng = np.random.default_rng(7)
    P, Q = _large_cases(rng, 10_000)[case]   # N + M >= 20,000: the parallel path
    dp = cKDTree(Q).query(P)[0]
    dq = cKDTree(P).query(Q)[0]
    released = dp.sum() + dq.sum()
    paper = ((dp ** 2).sum() + (dq ** 2).sum()) / len(P)
    for method in ("auto", "grid"):
        assert position_error(P, Q, "released", method=method) == pytest.approx(released, rel=1e-10)
        assert position_error(P, Q, "paper", method=method) == pytest.approx(paper, rel=1e-9)


@pytest.mark.parametrize("kind", ["volume", "plane", "line", "thin slab", "one point"])
def test_grid_cells_fit_flat_and_straight_sets(kind):
    """The grid has about M / 4 cells whatever the set's shape (a plane is not one cell, a line
    not a cube of empty cells), and no cell holds many points of uniform data."""
    kernels = pytest.importorskip("tpnet_ref.metrics.chamfer_kernels3d")
    rng = np.random.default_rng(12)
    m = 9000
    X = rng.random((m, 3)) * [1e3, 2.0, 0.5]
    if kind == "plane":
        X[:, 1] = 0.7
    elif kind == "line":
        X[:, 1:] = [0.7, -3.0]
    elif kind == "thin slab":
        X[:, 2] *= 1e-9
    elif kind == "one point":
        X[:] = X[0]
    g = kernels.grid_build(X)
    pts, idx, start, nx, ny, nz = g[:6]
    cells = nx * ny * nz
    counts = np.diff(start)
    assert counts.sum() == m and sorted(idx) == list(range(m))
    np.testing.assert_array_equal(pts, X[idx])
    if kind == "one point":
        assert cells == 1
    else:
        assert m / 4 / 8 <= cells <= 8 * m / 4, (nx, ny, nz)
        assert counts.max() <= 40, counts.max()


@pytest.mark.parametrize("spread", [1e-120, 1e-9, 1.0, 1e9, 1e120])
def test_small_and_huge_spreads(spread):
    """Grid and brute force agree exactly at any scale; the k-d tree to rounding."""
    rng = np.random.default_rng(9)
    P = rng.normal(0, spread, (600, 3))
    Q = rng.normal(0, spread, (700, 3)) + spread
    want = ref_error(P, Q, "released")
    assert position_error(P, Q, "released", method="grid") == \
        position_error(P, Q, "released", method="brute")
    assert position_error(P, Q, "released") == pytest.approx(want, rel=1e-12)
    assert position_error(P, Q, "released", method="kdtree") == pytest.approx(want, rel=1e-9)


def test_degenerate_sets():
    """Duplicates, one point, and all points coinciding, in every method."""
    rng = np.random.default_rng(10)
    one = rng.random((1, 3))
    dup = np.repeat(rng.random((3, 3)), 200, axis=0)
    same = np.repeat(one, 500, axis=0)
    for P, Q in ((one, dup), (dup, one), (dup, dup[::-1]), (same, one), (same, dup),
                 (dup, rng.random((700, 3)))):
        for method in METHODS:
            for v in VARIANTS:
                assert position_error(P, Q, v, method=method) == pytest.approx(
                    ref_error(P, Q, v), rel=1e-12, abs=1e-300)
    assert position_error(dup, dup[::-1], "released", method="grid") == 0.0


def test_overflow_is_an_error_not_inf():
    P = np.array([[1e200, 0.0, 0.0]])
    Q = np.array([[-1e200, 0.0, 0.0]])
    with pytest.raises(NonFiniteResultError, match="position_error"):
        position_error(P, Q)
    assert position_error(P, P, "released") == 0.0


# ------------------------------------------------------------------ loss


def test_loss_values_and_reductions():
    rng = np.random.default_rng(5)
    P = rng.random((6, 42, 3))
    Q = rng.random((6, 20, 3))
    per = chamfer_loss(P, Q, "paper", reduction="none")
    assert per.shape == (6,)
    np.testing.assert_allclose(per, 42 * position_error(P, Q, "paper"), rtol=1e-13)
    np.testing.assert_allclose(chamfer_loss(P, Q, "released", reduction="none"),
                               position_error(P, Q, "released"), rtol=1e-13)
    assert chamfer_loss(P, Q, "paper") == pytest.approx(per.mean(), rel=1e-13)
    assert chamfer_loss(P, Q, "paper", reduction="sum") == pytest.approx(per.sum(), rel=1e-13)
    assert isinstance(chamfer_loss(P[0], Q[0], reduction="none"), float)


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("reduction,method", [("mean", "auto"), ("sum", "grid"),
                                              ("none", "kdtree"), ("mean", "brute")])
def test_loss_gradient_matches_finite_differences(variant, reduction, method):
    rng = np.random.default_rng(6)
    P = rng.random((3, 8, 3))
    Q = rng.random((5, 3))
    loss, gP, gQ = chamfer_loss(P, Q, variant, reduction=reduction, return_grad=True,
                                method=method)
    assert gP.shape == P.shape and gQ.shape == Q.shape
    assert_gradient_is_central_difference(gP, gQ, P, Q, variant, reduction)


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("n", [42, 800])
def test_loss_gradient_batched_paths_agree(variant, n):
    """Brute force with indices, the grid, and the k-d tree give the same gradient."""
    rng = np.random.default_rng(8)
    B = 12000 // n
    P = rng.random((B, n, 3))
    Q = rng.random((B, n + 1, 3))
    ref = chamfer_loss(P, Q, variant, return_grad=True, method="kdtree")
    for method in ("auto", "brute", "grid"):
        got = chamfer_loss(P, Q, variant, return_grad=True, method=method)
        assert got[0] == pytest.approx(ref[0], rel=1e-12)
        np.testing.assert_allclose(got[1], ref[1], rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(got[2], ref[2], rtol=1e-10, atol=1e-14)


def test_loss_gradient_dtype_follows_input():
    P = np.random.default_rng(0).random((10, 3)).astype(np.float32)
    _, gP, gQ = chamfer_loss(P, P[::-1] + 0.1, return_grad=True)
    assert gP.dtype == np.float32 and gQ.dtype == np.float32 and gP.shape == (10, 3)


# ------------------------------------------------------------ validation


@pytest.mark.parametrize("fn", [position_error, shape_error, chamfer_loss])
@pytest.mark.parametrize("bad,msg", [
    (np.zeros((4, 4)), r"^{0}: expected shape \(\.\.\., N, 2\) or \(\.\.\., N, 3\), got \(4, 4\)$"),
    (np.zeros((4, 1)), r"^{0}: expected shape \(\.\.\., N, 2\) or \(\.\.\., N, 3\), got \(4, 1\)$"),
    (np.zeros(3), r"^{0}: expected shape \(\.\.\., N, 2\) or \(\.\.\., N, 3\), got \(3,\)$"),
    (np.zeros((0, 3)), r"^{0}: is empty"),
    (np.array([[0.0, 1.0, np.nan]]), r"^{0}: contains 1 NaN or infinite"),
])
def test_invalid_3d_inputs_name_the_argument(fn, bad, msg):
    good = np.zeros((3, 3))
    with pytest.raises(ValueError, match=msg.format("P")):
        fn(bad, good)
    with pytest.raises(ValueError, match=msg.format("Q")):
        fn(good, bad)


@pytest.mark.parametrize("fn", [position_error, shape_error, chamfer_loss])
def test_mixed_dims_are_one_line_errors(fn):
    """A 2-D set beside a 3-D one: the 3-D argument is named, with both shapes."""
    P2, P3 = np.zeros((5, 2)), np.zeros((4, 6, 3))
    msg = ("must hold points of the same dim (2 or 3)")
    with pytest.raises(ValueError, match=r"^P: expected shape \(\.\.\., N, 2\) like Q \(5, 2\), "
                       r"got \(4, 6, 3\)") as e:
        fn(P3, P2)
    assert msg in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(ValueError, match=r"^Q: expected shape \(\.\.\., N, 2\) like P \(5, 2\), "
                       r"got \(4, 6, 3\)") as e:
        fn(P2, P3)
    assert msg in str(e.value) and "\n" not in str(e.value)


def test_invalid_options_and_leading_shapes():
    P = np.zeros((4, 5, 3))
    with pytest.raises(ValueError, match="P and Q: leading dimensions"):
        position_error(P, np.zeros((3, 5, 3)))
    with pytest.raises(ValueError, match="variant"):
        position_error(P, P, "euclidean")
    with pytest.raises(ValueError, match="method"):
        shape_error(P, P, method="octree")
    with pytest.raises(ValueError, match="reduction"):
        chamfer_loss(P, P, reduction="max")


# ------------------------------------------------------------ properties

coords = st.floats(-100, 100, allow_nan=False, allow_infinity=False, width=64)
point_sets = st.integers(1, 40).flatmap(lambda n: hnp.arrays(np.float64, (n, 3), elements=coords))
# few distinct values: many duplicates, collinear and coplanar points
grid_sets = st.integers(1, 40).flatmap(
    lambda n: hnp.arrays(np.float64, (n, 3), elements=st.integers(-3, 3).map(float)))
any_sets = st.one_of(point_sets, grid_sets)
FAST = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FAST
@given(any_sets, any_sets, st.sampled_from(VARIANTS))
def test_property_grid_equals_bruteforce_and_numpy(P, Q, variant):
    """The grid search is exact: the same value as brute force on arbitrary small sets."""
    brute = position_error(P, Q, variant, method="brute")
    assert position_error(P, Q, variant, method="grid") == brute
    assert brute == pytest.approx(ref_error(P, Q, variant), rel=1e-12, abs=0)


@FAST
@given(any_sets, any_sets, st.sampled_from(VARIANTS), st.randoms(use_true_random=False))
def test_property_permutation_invariant(P, Q, variant, rnd):
    pp = np.array(rnd.sample(range(len(P)), len(P)))
    qq = np.array(rnd.sample(range(len(Q)), len(Q)))
    a = position_error(P, Q, variant)
    assert position_error(P[pp], Q[qq], variant) == pytest.approx(a, rel=1e-12, abs=0)


@FAST
@given(any_sets, st.sampled_from(VARIANTS))
def test_property_zero_for_equal_sets(P, variant):
    assert position_error(P, P, variant) == 0.0
    assert shape_error(P, P.copy(), variant) == 0.0
    assert chamfer_loss(P, P, variant) == 0.0


@FAST
@given(any_sets, any_sets, st.sampled_from(VARIANTS),
       hnp.arrays(np.float64, 3, elements=coords), hnp.arrays(np.float64, 3, elements=coords))
def test_property_shape_error_translation_invariant(P, Q, variant, s, t):
    a = shape_error(P, Q, variant)
    b = shape_error(P + s, Q + t, variant)
    assert b == pytest.approx(a, rel=1e-6, abs=1e-9)


# a cloud of 300-1500 points: the grid path (not brute force) under "auto"
clouds = st.tuples(st.integers(300, 1500), st.integers(0, 2 ** 32 - 1),
                   st.sampled_from([1e-3, 1.0, 1e3]), st.sampled_from([0, 1, 2, 3]))


def _cloud(n, seed, scale, kind):
    rng = np.random.default_rng(seed)
    X = rng.random((n, 3)) * scale
    if kind == 1:
        X[:, 2] = X[0, 2]                         # a plane
    elif kind == 2:
        X = rng.normal(0, scale * 1e-3, (n, 3)) + rng.integers(0, 3, (n, 1)) * scale  # blobs
    elif kind == 3:
        X = np.round(X / scale * 4) * scale / 4   # lattice: many exact ties
    return X


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(clouds, clouds)
def test_property_grid_on_clouds_equals_bruteforce(a, b):
    P, Q = _cloud(*a), _cloud(*b)
    for v in ("released", "paper"):
        assert position_error(P, Q, v, method="grid") == position_error(P, Q, v, method="brute")
