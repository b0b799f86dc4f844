"""The testing kit (:mod:`tpnet_ref.testing`) on 3-D windows: ``windows(dim=3)`` draws ``(N_t, 3)``
frames (and ``windows()`` still draws, example for example, the 2-D windows it always drew),
the properties hold for a 3-D network itself -- the readable reference, the NumPy engine with
the canonical sort off, the PyTorch model -- and the first-point mutant of ``segment_max`` fails
the permutation property in 3-D as it does in 2-D (tests/test_invariance.py).

The network is a random one of the quarter structure (tests/property_helpers.py) with 3
coordinates per point and 42 predicted points.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("hypothesis")

import tpnet_ref.engines.layers as L  # noqa: E402
from property_helpers import MS, QUARTER, Implementations  # noqa: E402
from tpnet_ref import testing  # noqa: E402
from tpnet_ref.model import init_random  # noqa: E402
from tpnet_ref.testing import TOLERANCE, PropertyFailure  # noqa: E402

pytestmark = pytest.mark.lane("3-D")   # in a second test process (tests/lane.py)

CONFIG3D = dataclasses.replace(QUARTER, dim=3, n_out=42)


@pytest.fixture(scope="module")
def impl():
    made = Implementations(CONFIG3D)
    yield made
    made.clear()


def _drawn(strategy, examples: int = 25) -> list:
    """The windows ``strategy`` draws in a derandomised run (the same run for the same draws)."""
    from hypothesis import HealthCheck, given, settings
    seen = []

    @settings(max_examples=examples, deadline=None, derandomize=True, database=None,
              suppress_health_check=list(HealthCheck))
    @given(strategy)
    def collect(w):
        seen.append(w)
    collect()
    return seen


def _windows_as_they_were(step=(0.0, 0.0)):
    """The 2-D strategy as it was before ``dim``: m=4, 1..64 points, the same draws in order."""
    from hypothesis import strategies as st

    @st.composite
    def window(draw):
        mm, r = draw(st.just(4)), draw(st.booleans())
        n0 = draw(st.integers(1, 64))
        sizes = [draw(st.integers(1, 64)) if r else n0 for _ in range(mm)]
        scale = draw(st.sampled_from(list(testing.SCALES)))
        c = draw(st.floats(-100.0, 100.0, allow_nan=False, allow_infinity=False))
        tied = draw(st.booleans())
        speed = draw(st.floats(*step)) if step[1] > 0 else 0.0
        rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
        angle = rng.uniform(0, 2 * np.pi)
        v = speed * np.array([np.cos(angle), np.sin(angle)])
        frames = [c + t * v + scale * rng.standard_normal((k, 2)) for t, k in enumerate(sizes)]
        if tied:
            f = frames[0]
            f[len(f) // 2:] = f[:len(f) - len(f) // 2]
            f[:, 0] = c + scale * np.round(np.clip((f[:, 0] - c) / scale, -1, 1))
        return frames
    return window()


# ------------------------------------------------------------------ the strategy
@pytest.mark.parametrize("step", [(0.0, 0.0), (0.5, 2.0)])
def test_2d_windows_are_drawn_as_before(step):
    """``dim`` left at 2 changes no draw: a seed that found a 2-D window finds it again."""
    def same(a, b):
        return len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))
    new = _drawn(testing.windows(step=step))
    old = _drawn(_windows_as_they_were(step))
    assert len(new) == len(old) > 5
    assert all(same(a, b) for a, b in zip(new, old))
    assert all(same(a, b) for a, b in zip(_drawn(testing.windows(dim=2, step=step)), new))


def test_3d_windows_have_three_coordinates_and_move_in_3d():
    ws = _drawn(testing.windows(m=[1, 4], n=(1, 9), dim=3, step=(1.0, 1.0), scales=(1e-3,)),
                examples=30)
    assert all(f.ndim == 2 and f.shape[1] == 3 and f.dtype == np.float64 for w in ws for f in w)
    moves = np.array([w[1].mean(axis=0) - w[0].mean(axis=0) for w in ws if len(w) > 1])
    assert len(moves) > 3
    np.testing.assert_allclose(np.linalg.norm(moves, axis=1), 1.0, atol=0.01)  # one unit a frame
    assert (np.abs(moves[:, 2]) > 1e-3).any()                                   # z moves too
    tied = _drawn(testing.windows(m=1, n=(4, 9), dim=3, ties=True, normalized=True), 10)
    for (f,) in tied:
        half = len(f) // 2
        assert np.array_equal(f[half:2 * half], f[:half])            # duplicate points
        assert len(np.unique(f[:, 0])) <= 3 and len(np.unique(f[:, 2])) > 1


@pytest.mark.parametrize("dim", [0, -1, 2.5, True, "3"])
def test_a_bad_dim_is_refused(dim):
    with pytest.raises(ValueError, match=r"windows: dim must be a whole number of coordinates"):
        testing.windows(dim=dim)


# ------------------------------------------------------------------ the network itself
def network(impl: Implementations, name: str, dtype: str):
    if name == "reference":
        return impl.reference(dtype)
    if name == "torch":
        pytest.importorskip("torch")
        return impl.torch(dtype)
    return impl.engine(name, dtype, sort=False)


def network_property(fn, dtype: str, examples: int = 20, seed: int | None = None) -> float:
    return testing.permutation_invariant(fn, testing.windows(m=MS, dim=3), tol=TOLERANCE[dtype],
                                         max_examples=examples, seed=seed)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("name", ["reference", "numpy", "torch"])
def test_3d_network_is_permutation_invariant_without_the_sort(impl, name, dtype):
    worst = network_property(network(impl, name, dtype), dtype)
    assert worst <= TOLERANCE[dtype]
    assert "coordinates in" in worst.report


def _starts(counts):
    counts = np.asarray(counts)
    return np.concatenate(([0], np.cumsum(counts)[:-1])).astype(np.intp)


#: hypothesis's seed for the shrinking test: about one random draw in 9 ends its shrinking at a
#: larger window of tiny coordinates whose change barely exceeds the tolerance
SHRINK_SEED = 1


def test_first_point_mutant_fails_the_permutation_property_in_3d(impl, monkeypatch):
    """The first point's row instead of the max (tests/test_invariance.py's mutant), on the
    NumPy engine with the sort off: a one-line permutation failure, shrunk to one frame of two
    3-D points, each listed with its three coordinates."""
    monkeypatch.setattr(L, "segment_max", lambda x, counts: x[_starts(counts)].copy())
    with pytest.raises(PropertyFailure) as exc:
        network_property(network(impl, "numpy", "float32"), "float32", examples=30,
                         seed=SHRINK_SEED)       # a fixed draw, as in tests/test_invariance.py
    report = str(exc.value)
    assert "\n" not in report
    assert report.startswith("permutation_invariant: numpy_engine_unsorted_float32 changed by ")
    assert "minimal window: m=1, N=(2,)" in report
    frames = report.split("frames: ")[1].split(", permutations")[0]
    assert frames.count("(") == 2 and frames.count(",") == 4, frames


def test_the_unmutated_3d_engine_passes_the_same_run(impl):
    assert network_property(network(impl, "numpy", "float32"), "float32", examples=30) \
        <= TOLERANCE["float32"]


# ------------------------------------------------------------------ the other checks
def test_non_vacuity_and_reference_agreement_on_3d_windows(impl):
    """Fixed draws, as tests/test_invariance.py's non-vacuity test (a fresh draw once found a
    window whose moved point left this random network's output unchanged)."""
    fn, tol = network(impl, "reference", "float64"), TOLERANCE["float64"]
    moving = testing.windows(m=[2, 4], step=(0.5, 2.0), dim=3)
    assert testing.frame_order_matters(fn, moving, tol=tol, max_examples=8, seed=0) > tol
    assert testing.one_point_matters(fn, testing.windows(m=MS, dim=3), tol=tol,
                                     max_examples=8, seed=0) > tol
    # agrees_with_reference draws windows of the model's dim when none are given
    model = init_random(CONFIG3D, seed=21)
    f32 = impl.reference("float32")
    got = testing.agrees_with_reference(f32, model, max_examples=8, seed=1)
    assert "m=4" in got.report and got < 1e-2


def test_one_point_matters_moves_a_point_of_a_3d_frame_that_sits_on_its_centroid():
    """A frame of one point: nothing points away from the centroid, so the point moves along
    the first axis, in 3-D as in 2-D."""
    def first_point(window):
        return np.stack([f[0] for f in window])
    got = testing.one_point_matters(first_point, testing.windows(m=1, n=1, dim=3),
                                    max_examples=5)
    assert got == pytest.approx(2.0)
