"""Property: TP-Net itself is invariant to the (N!)^m per-frame permutations -- without the sort.

tests/test_permutation.py checks the pipeline, which sorts each frame into a canonical order
first; that holds for any network, symmetric or not. Here the sort is off
(:meth:`tpnet_ref.model.TPNet.with_point_sort`, the ``sort_points`` flag) and the properties of
:mod:`tpnet_ref.testing` run on the network itself -- ``reference.forward``, the NumPy and the
Numba engine, the PyTorch model -- over ragged windows, spreads 1e-3..1e3, ties and duplicate
points: a per-frame permutation changes the output by at most ``testing.TOLERANCE[dtype]``
(world units; ``bench/probes/permutation_rounding.py`` measures what a permutation changes).

Teeth: the same properties run on deliberately broken networks (:data:`MUTANTS`) and each one
is caught; with the sort on, the network mutants pass the bit-exact pipeline check, which is why
the check without the sort exists. Non-vacuity: reversing or rotating the frames in time, and
moving one point, change the output by more than the tolerance.
"""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("numba")
pytest.importorskip("torch")

import tpnet_ref.engines.layers as L  # noqa: E402
import tpnet_ref.model as M  # noqa: E402
from property_helpers import MS, Implementations  # noqa: E402
from tpnet_ref import testing  # noqa: E402
from tpnet_ref.testing import TOLERANCE, PropertyFailure  # noqa: E402

NETWORKS = ["reference", "numpy", "numba", "torch"]
DTYPES = ["float32", "float64"]


@pytest.fixture(scope="module")
def impl():
    made = Implementations()
    yield made
    made.clear()


def network(impl: Implementations, name: str, dtype: str):
    """The network alone (no canonical sort) as window -> next point set, world units."""
    if name == "reference":
        return impl.reference(dtype)
    if name == "torch":
        return impl.torch(dtype)
    return impl.engine(name, dtype, sort=False)


def network_property(fn, dtype: str, examples: int = 30, seed: int | None = None) -> float:
    """The network's own invariance: per-frame permutations within the rounding bound
    (``seed``: hypothesis's, for a test that pins where the shrinking ends)."""
    return testing.permutation_invariant(fn, testing.windows(m=MS), tol=TOLERANCE[dtype],
                                         max_examples=examples, seed=seed)


def pipeline(impl: Implementations, dtype: str):
    """The sorted pipeline as one function: ``predict``'s output and the canonical points the
    network sees, both of which must not change by a bit."""
    predict = impl.engine("numpy", dtype, sort=True)

    def sorted_pipeline(window):
        model = impl.model(len(window), dtype)
        points, _ = model.canonical_points([np.asarray(f, dtype=dtype) for f in window])
        return np.concatenate([predict(window).ravel(), points.ravel()])
    return sorted_pipeline


def pipeline_property(impl: Implementations, dtype: str, examples: int = 30) -> float:
    return testing.permutation_invariant(pipeline(impl, dtype), testing.windows(m=MS), tol=0.0,
                                         max_examples=examples)


# ------------------------------------------------------------------ the broken variants
def _starts(counts):
    counts = np.asarray(counts)
    return np.concatenate(([0], np.cumsum(counts)[:-1])).astype(np.intp)


def first_point(segment_max):
    """The first point's row instead of the max (not symmetric)."""
    return lambda x, counts: x[_starts(counts)].copy()


def position_weighted_sum(segment_max):
    """A sum weighted by each point's position in its frame (not symmetric)."""
    def pool(x, counts):
        counts = np.asarray(counts)
        pos = np.arange(len(x)) - np.repeat(_starts(counts), counts)
        w = ((pos + 1) / np.repeat(counts, counts)).astype(x.dtype)
        return np.add.reduceat(x * w[:, None], _starts(counts), axis=0)
    return pool


def mixed_across_frames(segment_max):
    """The max over a window shifted by one point: each frame's pool takes the previous
    frame's last point instead of its own last one."""
    return lambda x, counts: segment_max(np.roll(x, 1, axis=0), counts)


def sort_ignoring_ties(sorted_points):
    """The canonical order by x alone, on every path (the compiled sort of equal frames and
    :func:`~tpnet_ref.point_order.canonical_order` of ragged ones): points that tie in x keep
    their input order."""
    def broken(self, points, counts):
        if not self.sort_points:
            return points
        frame_id = np.repeat(np.arange(len(counts)), counts)
        return points[np.lexsort([points[:, 0], frame_id])]
    return broken


#: name -> (module, attribute, broken replacement, property that must catch it)
MUTANTS = {
    "first point instead of max": (L, "segment_max", first_point, "network"),
    "position-weighted sum": (L, "segment_max", position_weighted_sum, "network"),
    "points mixed across frames": (L, "segment_max", mixed_across_frames, "network"),
    "a sort that ignores ties": (M.TPNet, "sorted_points", sort_ignoring_ties, "pipeline"),
}


def _run_property(impl, kind, dtype="float64", examples=30):
    if kind == "network":
        return network_property(network(impl, "numpy", dtype), dtype, examples)
    return pipeline_property(impl, dtype, examples)


# ------------------------------------------------------------------ the network itself
@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("name", NETWORKS)
def test_network_is_permutation_invariant_without_the_sort(impl, name, dtype):
    worst = network_property(network(impl, name, dtype), dtype)
    assert worst <= TOLERANCE[dtype]


@pytest.mark.parametrize("dtype", DTYPES)
def test_sorted_pipeline_is_bit_exact(impl, dtype):
    assert pipeline_property(impl, dtype) == 0.0


def test_every_mutant_is_caught(impl, monkeypatch):
    caught = {}
    for name, (module, attr, broken, kind) in MUTANTS.items():
        with monkeypatch.context() as mp:
            mp.setattr(module, attr, broken(getattr(module, attr)))
            try:
                _run_property(impl, kind)
            except PropertyFailure as exc:
                caught[name] = str(exc)
    assert sorted(caught) == sorted(MUTANTS), f"not caught: {set(MUTANTS) - set(caught)}"
    assert all("\n" not in report for report in caught.values())


#: hypothesis's seed for the shrinking tests: about one random draw in 25 ends its shrinking at a
#: larger window of tiny coordinates whose change barely exceeds the tolerance
SHRINK_SEED = 1


def test_first_point_mutant_fails_the_permutation_property(impl, monkeypatch):
    """The issue's mutant, with the sort off: a permutation failure (not only a disagreement
    with the reference), shrunk to one frame of two points and reported in one line."""
    monkeypatch.setattr(L, "segment_max", first_point(L.segment_max))
    with pytest.raises(PropertyFailure) as exc:      # a fixed draw (SHRINK_SEED)
        network_property(network(impl, "numpy", "float32"), "float32", seed=SHRINK_SEED)
    report = str(exc.value)
    assert "\n" not in report
    assert report.startswith("permutation_invariant: numpy_engine_unsorted_float32 changed by ")
    assert "minimal window: m=1, N=(2,)" in report


@pytest.mark.parametrize("mutant", [k for k, v in MUTANTS.items() if v[3] == "network"])
def test_the_sort_hides_network_mutants(impl, monkeypatch, mutant):
    """Why the checks above run without the sort: with it on, every broken network passes the
    bit-exact pipeline property (it sees one canonical matrix whatever the input order)."""
    module, attr, broken, _ = MUTANTS[mutant]
    monkeypatch.setattr(module, attr, broken(getattr(module, attr)))
    assert pipeline_property(impl, "float64", examples=15) == 0.0


# ------------------------------------------------------------------ non-vacuity
@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("name", NETWORKS)
def test_frame_order_and_one_point_change_the_output(impl, name, dtype):
    """Fixed draws (``seed``): these check the checks on a random network, which may well ignore
    one moved point of some window (a fresh draw in CI once found such a window for the 3-D
    network of tests/test_testing3d.py, its output unchanged to the bit)."""
    fn, tol = network(impl, name, dtype), TOLERANCE[dtype]
    moving = testing.windows(m=[2, 4], step=(0.5, 2.0))
    assert testing.frame_order_matters(fn, moving, tol=tol, max_examples=10, seed=0) > tol
    assert testing.one_point_matters(fn, testing.windows(m=MS), tol=tol, max_examples=10,
                                     seed=0) > tol


def test_non_vacuity_checks_catch_functions_that_ignore_time_or_points():
    def constant(window):
        return np.zeros((30, 2))

    def pooled_over_time(window):           # symmetric in the frames' order
        return np.repeat(np.concatenate(window).max(axis=0, keepdims=True), 30, axis=0)

    windows = testing.windows(m=[2, 3], n=(1, 8))
    for fn in (constant, pooled_over_time):
        with pytest.raises(PropertyFailure, match="^frame_order_matters: .* on reversing"):
            testing.frame_order_matters(fn, windows, max_examples=20)
    with pytest.raises(PropertyFailure, match="^one_point_matters: constant changed by only 0"):
        testing.one_point_matters(constant, windows, max_examples=20)
    # and a function that does depend on both passes them
    assert testing.frame_order_matters(lambda w: np.stack([f.mean(0) for f in w]), windows) > 0


def test_the_sort_switch(impl):
    """``with_point_sort(False)`` is the same network on the same parameters: on frames already
    in canonical order it gives the same bits as with the sort, ``predict`` and ``rollout``."""
    model = impl.model(2, "float64")
    off = model.with_point_sort(False)
    assert off.sort_points is False and model.sort_points is True
    assert off.params["global.w"] is model.params["global.w"] and "unsorted points" in repr(off)
    rng = np.random.default_rng(0)
    window = [f[np.lexsort((f[:, 1], f[:, 0]))] for f in rng.uniform(0, 44, (2, 30, 2))]
    assert np.array_equal(off.predict(window), model.predict(window))
    roll_on, roll_off = model.rollout(window, 3), off.rollout(window, 3)
    assert np.abs(roll_on - roll_off).max() <= TOLERANCE["float64"]
    with pytest.raises(TypeError, match="sort_points must be True or False"):
        model.with_point_sort("no")
