"""tpnet_ref.checks: one-line errors naming the argument, and the training-range warning that
leaves the result unchanged."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import tpnet_ref
from tpnet_ref.checks import (OutsideTrainingRangeWarning, as_point_set, as_real_array,
                              training_range_problem)
from tpnet_ref.config import NORM_HI, NORM_LO, normalize


def _ring(cx=20.0, cy=20.0, r=2.0, n=30):
    a = np.arange(n) * 2 * np.pi / n
    return np.stack([cx + r * np.sin(a), cy + r * np.cos(a)], axis=1)


def _window(**kw):
    return np.stack([_ring(**kw) + [0.3 * i, -0.1 * i] for i in range(4)])


@pytest.fixture(scope="module")
def net(released_random64):
    return released_random64


@pytest.mark.parametrize("x, exc, msg", [
    ("abc", TypeError, "pts: expected a numeric array"),
    ([[1, 2], [3]], ValueError, "pts: cannot be read as one array"),
    (np.zeros((3, 2), dtype=complex), TypeError, "pts: expected real numbers"),
    (np.zeros((3, 3)), ValueError, r"pts: expected shape \(N, 2\)"),
    (np.zeros((0, 2)), ValueError, "pts: is empty"),
    (np.array([[0.0, np.nan]]), ValueError, "pts: contains 1 NaN"),
])
def test_point_set_errors_name_the_argument(x, exc, msg):
    with pytest.raises(exc, match=msg):
        as_point_set(x, "pts")


def test_integers_are_accepted_and_converted():
    assert as_real_array([1, 2], "x", np.float32).dtype == np.float32


def _problem(window, normalized=False):
    frames = [np.asarray(f, float) if normalized else normalize(np.asarray(f, float))
              for f in window]
    return training_range_problem(frames, NORM_LO, NORM_HI, normalized)


def test_a_ring_in_the_box_is_in_range():
    assert _problem(_window()) is None


@pytest.mark.parametrize("window, normalized, msg", [
    (_window(cx=120.0), False, "outside the training box"),
    (_window(), True, "world units passed as normalized=True"),
    ((_window() - NORM_LO) / (NORM_HI - NORM_LO), False, "model coordinates given as world units"),
    (_window(r=0.3), False, "mean radius is 0.3"),
    (_window(r=8.0), False, "mean radius is 8"),
])
def test_out_of_range_inputs_are_named(window, normalized, msg):
    assert msg in _problem(window, normalized)


def test_public_predict_warns_once_in_one_line_and_keeps_the_result(net):
    w = _window(cx=120.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = tpnet_ref.predict(w, model=net)
    hits = [c for c in caught if issubclass(c.category, OutsideTrainingRangeWarning)]
    assert len(hits) == 1 and "\n" not in str(hits[0].message)
    assert hits[0].filename == __file__                      # points at the caller's line
    np.testing.assert_array_equal(got, net.predict(w))       # the result is not changed


def test_in_range_input_does_not_warn(net):
    with warnings.catch_warnings():
        warnings.simplefilter("error", OutsideTrainingRangeWarning)
        tpnet_ref.predict(_window(), model=net)
        tpnet_ref.predict_batch(np.stack([_window(), _window(cx=30.0)]), model=net)
        tpnet_ref.rollout(_window(), 2, model=net)


def test_the_one_body_test_is_bounded_in_memory():
    """Regression: a 10,000-point frame made the warning build 10,000 x 10,000 x 2 differences
    (2.4 GB, the suite's memory guard tripped). Frames above BODY_MAX_POINTS are not judged;
    body_outliers refuses them in one line."""
    import tracemalloc

    from tpnet_ref.checks import BODY_MAX_POINTS, body_outliers, window_body_problem
    rng = np.random.default_rng(0)
    big = rng.uniform(-1e6, 1e6, (4, 10_000, 2))
    tracemalloc.start()
    try:
        assert window_body_problem(big) is None
        assert window_body_problem(list(big)) is None
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 50 * 2**20, peak
    with pytest.raises(ValueError, match=f"^points: 10000 points, .*at most {BODY_MAX_POINTS}"):
        body_outliers(big[0])
    # at the limit the test still runs (and finds the scattered points are no body)
    assert body_outliers(big[0, :BODY_MAX_POINTS]).shape == (BODY_MAX_POINTS,)


# ------------------------------------------------------------------ pinned by mutation testing
# (tools/mutation.py: each of these was a surviving mutant of checks.py)
def test_an_empty_batch_of_point_sets_is_named():
    from tpnet_ref.checks import as_point_sets
    with pytest.raises(ValueError, match=r"^P: is empty \(0 points per set, shape \(3, 0, 2\)\)$"):
        as_point_sets(np.zeros((3, 0, 2)), "P")
    assert as_point_sets(np.zeros((3, 1, 2)), "P").shape == (3, 1, 2)


def test_a_sparse_ring_is_one_body_by_its_pairwise_links():
    """8 points on a ring of radius 2: the path around the centre has steps of 1.53 (more than
    BODY_LINK_MIN), so the pairwise test decides -- one body, no warning."""
    from tpnet_ref.checks import _all_one_body, body_outliers, window_body_problem
    w = np.stack([_ring(n=8) + [0.3 * i, 0.0] for i in range(4)])
    assert _all_one_body(w)
    assert window_body_problem(w) is None and window_body_problem(list(w)) is None
    assert not body_outliers(w[0]).any()


def test_two_arcs_of_a_broken_outline_are_one_body_and_a_far_blob_is_not():
    from tpnet_ref.checks import body_outliers
    ring = _ring(n=30)
    arcs = np.concatenate([ring[1:12], ring[16:27]])        # two gaps of 5 points
    assert not body_outliers(arcs, link=1.0).any()             # two groups, one body
    # a piece of only 3 points still counts (the smallest piece that does), after the body
    assert not body_outliers(np.concatenate([ring[2:25], ring[27:30]]), link=1.0).any()
    # a tail linked to the body but reaching past max_radius: its far end is apart
    tail = np.repeat(np.linspace(21.7, 25.0, 10)[:, None], 2, axis=1)     # along the diagonal
    out = body_outliers(np.concatenate([ring, tail]))
    assert out[-1] and not body_outliers(np.concatenate([ring, tail[:3]])).any()
    blob = np.array([[30.0, 20.0], [30.3, 20.0], [30.0, 20.3]])   # 3 points, 10 away
    out = body_outliers(np.concatenate([arcs, blob]), link=1.0)
    assert out[-3:].all() and not out[:-3].any()


def test_spurs_are_points_off_the_outline_with_both_neighbours_on_one_side():
    from tpnet_ref.checks import body_outliers
    ring = _ring(n=30)
    spur = 20.0 + 3.0 * np.array([np.sin(0.1), np.cos(0.1)])   # 1 world unit outside
    out = body_outliers(np.concatenate([ring, [spur]]), spur_factor=2.0)
    assert out[-1] and not out[:-1].any()
    # a point far from both neighbours but between them (a thinly sampled stretch of the
    # outline) is no spur
    thin = np.delete(ring, [13, 14, 16, 17], axis=0)
    assert not body_outliers(thin, spur_factor=2.0).any()


def test_a_spur_is_further_than_spur_factor_median_spacings_not_at_it():
    """A point whose nearest neighbour is exactly spur_factor x the median nearest-neighbour
    distance away is kept; a hair further, it is a spur (drop_outliers' words: "further than")."""
    from tpnet_ref.checks import body_outliers
    from tpnet_ref.observe import drop_outliers
    line = np.stack([0.25 * np.arange(5), np.zeros(5)], axis=1) + 20.0   # spacing 0.25
    at = np.concatenate([[[19.5, 20.0]], line])         # 0.5 = 2 x 0.25 before the first point
    assert not body_outliers(at, spur_factor=2.0).any()
    np.testing.assert_array_equal(drop_outliers(at), at)
    beyond = np.concatenate([[[19.5 - 1e-9, 20.0]], line])
    np.testing.assert_array_equal(body_outliers(beyond, spur_factor=2.0), [True] + [False] * 5)
    np.testing.assert_array_equal(drop_outliers(beyond), line)


def test_a_frame_of_mostly_scattered_points_is_left_to_the_range_check():
    """More points apart from the body than in it: not judged as "not one body" (no body of
    the scene's size; training_range_problem says what is wrong)."""
    from tpnet_ref.checks import body_outliers, window_body_problem
    body = _ring(r=1.0, n=6)
    apart = [[60.0, 60.0], [60.3, 60.0], [-40.0, 60.0], [-40.3, 60.0], [60.0, -40.0],
             [60.3, -40.0], [-40.0, -40.0]]
    frame = np.concatenate([body, apart])
    assert body_outliers(frame).sum() == 7
    assert window_body_problem([frame] * 4) is None


def test_a_ragged_window_moving_steadily_is_one_body():
    """Frames of different sizes are judged one by one; the steps between neighbouring frames
    (3 world units each), not between the first and the last (9), are what is judged."""
    from tpnet_ref.checks import window_body_problem
    frames = [_ring(cx=20.0 + 3.0 * i, n=30 - i) for i in range(4)]
    assert window_body_problem(frames) is None
    far = frames[:3] + [_ring(cx=35.0, n=27)]
    assert window_body_problem(far).startswith("frame 3's body is 9 world units from frame 2's")


def test_the_out_of_range_message_gives_the_span():
    w = _window(cx=120.0)
    lo, hi = w.min(), w.max()
    assert _problem(w, False).startswith(f"coordinates span [{lo:.3g}, {hi:.3g}] world units, "
                                         f"outside the training box [{NORM_LO:g}, {NORM_HI:g}]")
    model = np.full((4, 30, 2), 0.5)
    model[0, 0, 0] = 2.0                                  # model units: the hint starts above 2
    assert _problem(model, True) == ("coordinates span [0.5, 2] in model units, outside the "
                                     "training box [0, 1]")
    model[0, 0, 0] = 2.5
    assert _problem(model, True).endswith("(world units passed as normalized=True / --normalized?)")



def test_point_sets_check_their_last_axis():
    from tpnet_ref.checks import as_point_sets
    with pytest.raises(ValueError, match=r"^Q: expected shape \(\.\.\., N, 2\), got \(3, 2, 5\)$"):
        as_point_sets(np.zeros((3, 2, 5)), "Q")
    with pytest.raises(ValueError, match=r"^Q: expected shape"):
        as_point_sets(np.zeros(4), "Q")


def test_the_radius_is_judged_from_20_points_on():
    from tpnet_ref.checks import RADIUS_MIN_POINTS
    assert RADIUS_MIN_POINTS == 20
    assert "mean radius is 0.3" in _problem(_window(r=0.3, n=20))
    assert _problem(_window(r=0.3, n=19)) is None                # too few points to judge


@pytest.mark.parametrize("step, warns", [(3.0, False), (5.0, True)])
def test_model_coordinates_are_judged_in_world_units(step, warns):
    """warn_about_input with normalized=True maps the frames back to world units before the
    one-body test: a ring moving 3 world units a frame is one body, 5 is not."""
    from tpnet_ref.checks import NotOneBodyWarning, warn_about_input
    w = np.stack([_ring() + [step * i, 0.0] for i in range(4)])
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        warn_about_input(list(normalize(w)), NORM_LO, NORM_HI, True, "window", True)
    body = [str(x.message) for x in got if issubclass(x.category, NotOneBodyWarning)]
    assert bool(body) == warns, body
    if warns:
        assert f"frame 1's body is {step:.3g} world units from frame 0's" in body[0]


# --------------------------------------------------------------------------- sparse frames, motion
def _caught(call):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = call()
    return out, [c for c in caught if issubclass(c.category, OutsideTrainingRangeWarning)]


def _quiet(call):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutsideTrainingRangeWarning)
        return call()


@pytest.mark.parametrize("n", [1, 2])
def test_frames_of_too_few_points_warn_in_one_line_and_keep_the_result(net, n):
    from tpnet_ref.checks import TooFewPointsWarning
    w = _window()[:, :n]
    got, caught = _caught(lambda: tpnet_ref.predict(w, model=net))
    assert [c.category for c in caught] == [TooFewPointsWarning]
    msg = str(caught[0].message)
    assert "\n" not in msg and f"frame 0 has {n} point(s)" in msg and "at least 3" in msg
    assert caught[0].filename == __file__
    np.testing.assert_array_equal(got, _quiet(lambda: net.predict(w)))
    ragged = [f for f in _window()]
    ragged[2] = ragged[2][:1]                                   # one sparse frame of four
    _, caught = _caught(lambda: tpnet_ref.predict(ragged, model=net))
    assert [c.category for c in caught] == [TooFewPointsWarning]
    assert "frame 2 has 1 point(s); " in str(caught[0].message)


def test_three_points_a_frame_are_enough(net):
    _, caught = _caught(lambda: tpnet_ref.predict(_window()[:, ::10], model=net))
    assert caught == []


@pytest.mark.parametrize("step, why", [(0.02, "closer in time"), (3.0, "further apart in time")])
def test_motion_outside_the_training_windows_warns_and_keeps_the_result(net, step, why):
    from tpnet_ref.checks import MOTION_RANGE, FrameSpacingWarning
    w = np.stack([_ring() + [step * i, 0.0] for i in range(4)])
    for call in (lambda: tpnet_ref.predict(w, model=net),
                 lambda: tpnet_ref.predict(net.normalize(w), model=net, normalized=True),
                 lambda: net.rollout(w, 2)):
        got, caught = _caught(call)
        assert [c.category for c in caught] == [FrameSpacingWarning]
        msg = str(caught[0].message)
        assert "\n" not in msg and why in msg and caught[0].filename == __file__
        assert f"moves {step:.3g} world units per frame" in msg
        assert f"{MOTION_RANGE[0]:g}..{MOTION_RANGE[1]:g}" in msg
        np.testing.assert_array_equal(got, _quiet(call))


def test_motion_at_the_edges_of_the_range_does_not_warn(net):
    from tpnet_ref.checks import MOTION_RANGE, motion_problem
    lo, hi = MOTION_RANGE
    for step in (lo * 1.001, hi * 0.999):                      # just inside (rounding aside)
        w = np.stack([_ring() + [step * i, 0.0] for i in range(4)])
        assert motion_problem(w) is None
        assert motion_problem(list(w)) is None
    assert motion_problem(np.stack([_ring() + [0.099 * i, 0.0] for i in range(4)]))
    assert motion_problem(np.stack([_ring() + [2.51 * i, 0.0] for i in range(4)]))


def test_consecutive_simulator_rows_warn_and_every_fourth_row_does_not(net):
    pytest.importorskip("pymunk")
    from tpnet_ref.checks import FrameSpacingWarning
    from tpnet_ref.sim import simulate
    rows = simulate(1.3, 220.0, 35.0, 33.0, steps=520)   # inside the training grid
    w = rows[500:504]                  # consecutive rows, where the ring rolls 0.29 a model frame
    got, caught = _caught(lambda: tpnet_ref.predict(w, model=net))
    assert [c.category for c in caught] == [FrameSpacingWarning]
    assert "consecutive simulator rows" in str(caught[0].message)
    np.testing.assert_array_equal(got, _quiet(lambda: net.predict(w)))
    _, caught = _caught(lambda: tpnet_ref.predict(rows[500:516:4], model=net))
    assert caught == []


def _falling(rows_apart: float, v=(0.3, 0.1), ax: float = 0.0) -> np.ndarray:
    """A ring whose centroid falls freely (the scene's gravity) with frames ``rows_apart``
    simulator rows apart, moving ``v`` world units a frame; ``ax`` an extra x acceleration."""
    from tpnet_ref.checks import GRAVITY, SIM_DT
    a = np.array([ax, -GRAVITY * (rows_apart * SIM_DT) ** 2])
    return np.stack([_ring() + np.array(v) * i + 0.5 * a * i * i for i in range(4)])


@pytest.mark.parametrize("rows_apart, flagged", [(1, True), (2, True), (2.9, True), (3.1, False),
                                                 (4, False), (4.9, False), (5.1, True), (8, True)])
def test_a_body_in_free_fall_shows_its_frame_spacing(rows_apart, flagged):
    from tpnet_ref.checks import free_fall_rows, motion_problem
    w = _falling(rows_apart)
    assert free_fall_rows(w.mean(axis=1)) == pytest.approx(rows_apart, rel=1e-6)
    why = motion_problem(w)                   # 0.32 a frame: inside MOTION_RANGE either way
    assert (why is not None) == flagged
    if flagged:
        assert f"as if the frames were {rows_apart:.2g}/45 s apart, not 4/45 s" in why
        assert ("consecutive simulator rows" in why) == (rows_apart < 1.5)
    assert motion_problem(list(w)) == why


def test_the_free_fall_constants_are_the_scenes_and_the_protocols():
    from tpnet_ref.sim import protocol
    from tpnet_ref.checks import FRAME_ROWS, GRAVITY, SIM_DT
    from tpnet_ref.sim.scene import SceneParams
    assert (FRAME_ROWS, SIM_DT) == (protocol.FRAME_EVERY, protocol.REFERENCE_DT)
    assert SceneParams().gravity == (0.0, -GRAVITY) and SceneParams().dt == SIM_DT


def test_a_window_not_in_free_fall_is_judged_by_its_speed_alone():
    from tpnet_ref.checks import FREE_FALL_TOL, free_fall_rows, motion_problem
    assert free_fall_rows(_falling(1, ax=1.5 * FREE_FALL_TOL).mean(axis=1)) is None   # a push
    assert motion_problem(_falling(1, ax=1.5 * FREE_FALL_TOL)) is None
    assert free_fall_rows(_falling(1, ax=0.5 * FREE_FALL_TOL).mean(axis=1)) is not None
    uneven = _falling(1)
    uneven[3] += [0.0, -2 * FREE_FALL_TOL]         # its two falls differ: a contact, not free fall
    assert free_fall_rows(uneven.mean(axis=1)) is None
    assert free_fall_rows(_falling(1, v=(0.0, 0.0))[:3].mean(axis=1)) is None   # m = 3: one fall
    rest = np.stack([_ring()] * 4)                 # no fall at all: a body at rest
    assert free_fall_rows(rest.mean(axis=1)) is None and "closer in time" in motion_problem(rest)


def test_free_fall_is_read_to_within_1_2e_5_world_units():
    """The second differences must match free fall to within 5 % of one simulator row's fall
    (0.05 g dt^2 = 1.23e-5 world units): a sideways push of 1e-5 a frame is still free fall, one
    of 2e-5 is not, whatever the spacing."""
    from tpnet_ref.checks import free_fall_rows, motion_problem
    for rows in (1, 4, 8):
        assert free_fall_rows(_falling(rows, ax=1e-5).mean(axis=1)) == pytest.approx(rows, rel=1e-3)
        assert free_fall_rows(_falling(rows, ax=2e-5).mean(axis=1)) is None
    assert motion_problem(_falling(1, ax=2e-5)) is None          # judged by its speed: inside
    assert "consecutive simulator rows" in motion_problem(_falling(1, ax=1e-5))


def test_the_least_fall_read_as_free_fall_is_half_a_rows_fall():
    """A centroid falling g dt² / 2 a frame (frames 1/sqrt(2) simulator rows apart) is the least
    fall read as free fall: exactly that is read, and named by motion_problem as a fall; a hair
    less is not, and the window is judged by its speed (here: at rest)."""
    from tpnet_ref.checks import GRAVITY, SIM_DT, free_fall_rows, motion_problem
    a = 0.5 * GRAVITY * SIM_DT ** 2
    # thrown upwards: its second differences are exactly (0, -a) (no rounding in these sums)
    c = np.array([[0.0, -a], [0.0, 0.0], [0.0, 0.0], [0.0, -a]])
    assert free_fall_rows(c) == pytest.approx(np.sqrt(0.5), rel=1e-12)
    assert "as if the frames were 0.71/45 s apart" in motion_problem(c[:, None, :])
    less = c * (1 - 1e-12)
    assert free_fall_rows(less) is None
    assert "a body at rest" in motion_problem(less[:, None, :])


def test_the_thrown_ring_of_the_demo_warns_on_consecutive_rows(net):
    pytest.importorskip("pymunk")
    from tpnet_ref.checks import FrameSpacingWarning
    from tpnet_ref.sim import simulate
    rows = simulate(1.3, 195, 39.5, 29.5)        # held-out test case 1, the demo's scene
    for w, says in ((rows[0:4], "consecutive simulator rows"), (rows[40:48:2], "2/45 s apart"),
                    (rows[40:72:8], "8/45 s apart")):
        got, caught = _caught(lambda: tpnet_ref.predict(w, model=net))
        assert [c.category for c in caught] == [FrameSpacingWarning]
        assert says in str(caught[0].message)
        np.testing.assert_array_equal(got, _quiet(lambda: net.predict(w)))
    for start in (0, 40, 300):
        assert _caught(lambda: tpnet_ref.predict(rows[start:start + 16:4], model=net))[1] == []


def test_a_batch_is_not_judged_by_its_motion(net):
    w = np.stack([_ring() + [0.02 * i, 0.0] for i in range(4)])
    _, caught = _caught(lambda: tpnet_ref.predict_batch(np.stack([w, w]), model=net))
    assert caught == []


@pytest.mark.parametrize("window, says", [
    (_window()[:, :1], "too few points: frame 0 has 1 point(s)"),
    (np.stack([_ring() + [0.02 * i, 0.0] for i in range(4)]), "unusual motion: the body's centroid"),
])
def test_tpnet_predict_prints_the_new_warnings_in_one_line(tmp_path, capsys, window, says):
    from tpnet_ref.cli import main
    p = tmp_path / "w.npy"
    np.save(p, window)
    assert main(["predict", str(p), "--steps", "1"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tpnet predict: warning: window: " + says), err


def test_the_dtype_rule_of_predict_docs_api():
    """docs/api.md, predict's docstring: the output has the model's dtype, whatever the input's;
    a float64 window on the float32 model is the float32-rounded window's prediction."""
    w = tpnet_ref.example_window().astype(np.float64) + 1e-9       # not a float32 value
    got = tpnet_ref.predict(w)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, tpnet_ref.predict(w.astype(np.float32)))
    assert tpnet_ref.predict(w, dtype="float64").dtype == np.float64


# ------------------------------------------------------------------ every behaviour, both sides
# (what a user sees of each rule, at and around its threshold; written from the rules, not
# from a mutation sample)
from hypothesis import given  # noqa: E402
from hypothesis import settings as hsettings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from tpnet_ref import checks as C  # noqa: E402


@pytest.mark.parametrize("x, exc, msg", [
    (b"12", TypeError, r"^a: expected a numeric array, got bytes$"),
    ("12", TypeError, r"^a: expected a numeric array, got str$"),
    (np.array([1, "x"], dtype=object), TypeError, r"^a: expected a numeric array, got an object"),
    (np.array([True, False]), TypeError, r"^a: expected real numbers, got dtype bool$"),
    (np.zeros(2, dtype=np.complex64), TypeError, r"^a: expected real numbers, got dtype complex64$"),
])
def test_real_arrays_refuse_what_is_not_a_real_number(x, exc, msg):
    with pytest.raises(exc, match=msg):
        as_real_array(x, "a")


@pytest.mark.parametrize("x", [np.arange(3, dtype=np.int8), np.arange(3, dtype=np.uint16),
                               np.arange(3.0, dtype=np.float32), [1.5, 2.0]])
def test_real_arrays_keep_their_dtype_unless_one_is_asked(x):
    arr = as_real_array(x, "a")
    assert arr.dtype == np.asarray(x).dtype
    np.testing.assert_array_equal(as_real_array(x, "a", np.float64), np.asarray(x, np.float64))
    assert as_real_array(x, "a", np.float64).dtype == np.float64


def test_non_finite_values_are_counted_and_integers_pass():
    from tpnet_ref.checks import check_finite
    with pytest.raises(ValueError, match=r"^b: contains 3 NaN or infinite value\(s\)$"):
        check_finite(np.array([np.nan, 1.0, np.inf, -np.inf]), "b")
    ints = np.arange(4)
    assert check_finite(ints, "b") is ints
    fine = np.ones(3)
    assert check_finite(fine, "b") is fine


def test_point_sets_of_other_dimensions_and_empty_ones_when_allowed():
    assert as_point_set(np.zeros((4, 3)), "p", dim=3).shape == (4, 3)
    with pytest.raises(ValueError, match=r"^p: expected shape \(N, 3\), got \(4, 2\)$"):
        as_point_set(np.zeros((4, 2)), "p", dim=3)
    with pytest.raises(ValueError, match=r"^p: expected shape \(N, 2\), got \(1, 4, 2\)$"):
        as_point_set(np.zeros((1, 4, 2)), "p")
    assert as_point_set(np.zeros((0, 2)), "p", allow_empty=True).shape == (0, 2)
    assert as_point_set([[1, 2]], "p", dtype=np.float32).dtype == np.float32
    # one point without the set's axis, or a number, is not a set of points
    with pytest.raises(ValueError, match=r"^p: expected shape \(N, 2\), got \(2,\)$"):
        as_point_set(np.array([20.0, 21.0]), "p")
    with pytest.raises(ValueError, match=r"^p: expected shape \(N, 2\), got \(\)$"):
        as_point_set(20.0, "p")
    with pytest.raises(ValueError, match=r"^window\[0\]: expected shape \(N, 2\), got \(2,\)$"):
        C.check_window([np.array([20.0, 21.0])] * 4, 4, 2, np.dtype(np.float32))
    from tpnet_ref.checks import as_point_sets
    with pytest.raises(ValueError, match=r"^P: contains 1 NaN"):
        as_point_sets(np.array([[[0.0, 1.0]], [[np.inf, 0.0]]]), "P")
    assert as_point_sets(np.zeros((2, 3, 4, 2)), "P").shape == (2, 3, 4, 2)


def test_parameters_are_checked_by_name_shape_and_value_and_come_in_the_config_order():
    from tpnet_ref.checks import check_params
    shapes = {"w": (2, 3), "b": (3,)}
    p = {"b": [0, 1, 2], "w": np.ones((2, 3), dtype=np.float64)}
    out = check_params(p, shapes, np.dtype(np.float32))
    assert list(out) == ["w", "b"]
    assert all(v.dtype == np.float32 and v.flags.c_contiguous for v in out.values())
    np.testing.assert_array_equal(out["b"], [0, 1, 2])
    with pytest.raises(ValueError, match=r"^parameters do not fit the config: missing \['b'\], "
                                         r"unexpected \['c'\]$"):
        check_params({"w": p["w"], "c": 1}, shapes, np.dtype(np.float32))
    with pytest.raises(ValueError, match=r"^parameter 'b': expected shape \(3,\), got \(4,\)$"):
        check_params({**p, "b": np.zeros(4)}, shapes, np.dtype(np.float32))
    with pytest.raises(ValueError, match=r"^parameter 'w': contains NaN or infinite values$"):
        check_params({**p, "w": np.full((2, 3), np.nan)}, shapes, np.dtype(np.float32))
    with pytest.raises(TypeError, match=r"^parameter 'w': expected real numbers"):
        check_params({**p, "w": np.zeros((2, 3), dtype=bool)}, shapes, np.dtype(np.float32))
    fortran = np.asfortranarray(np.ones((2, 3)))
    assert check_params({**p, "w": fortran}, shapes, np.dtype(np.float64))["w"].flags.c_contiguous


F32, F64 = np.dtype(np.float32), np.dtype(np.float64)


def test_a_window_that_is_a_path_or_a_string_is_refused_in_one_line(tmp_path):
    from tpnet_ref.checks import check_window, check_windows
    for bad in ("w.npy", b"w.npy", tmp_path / "w.npy"):
        with pytest.raises(TypeError, match=r"^window: expected points, got the path or string .*"
                                            r"load the file first, e\.g\. np\.load\(path\)"):
            check_window(bad, 4, 2, F32)
        with pytest.raises(TypeError, match=r"^windows: expected points, got the path"):
            check_windows(bad, 4, 2, F32)


@pytest.mark.parametrize("window, msg", [
    (np.zeros((4, 30)), r"^window: expected shape \(m=4, N, 2\) or a sequence of m arrays "
                        r"\(N_i, 2\), got an array of shape \(4, 30\)$"),
    (np.zeros((4, 30, 3)), r"^window: expected shape \(m=4, N, 2\).*got an array of shape "
                           r"\(4, 30, 3\)$"),
    (np.zeros((3, 30, 2)), r"^window: the model takes m=4 frames, got 3$"),
    ([np.zeros((30, 2))] * 5, r"^window: the model takes m=4 frames, got 5$"),
    ([np.zeros((30, 2))] * 3 + [np.zeros((0, 2))], r"^window\[3\]: is empty \(0 points\)$"),
    ([np.zeros((30, 2)), np.full((30, 2), np.nan)] + [np.zeros((30, 2))] * 2,
     r"^window\[1\]: contains 60 NaN"),
    (5.0, r"^window: expected shape \(m=4, N, 2\).*got an array of shape \(\)$"),
])
def test_a_window_of_the_wrong_shape_is_refused_naming_the_frame(window, msg):
    from tpnet_ref.checks import check_window
    with pytest.raises(ValueError, match=msg):
        check_window(window, 4, 2, F32)


def test_a_ragged_window_is_its_frames():
    from tpnet_ref.checks import check_window
    frames = [np.zeros((30 - i, 2)) for i in range(4)]
    out = check_window(tuple(frames), 4, 2, F32)
    assert [f.shape for f in out] == [(30, 2), (29, 2), (28, 2), (27, 2)]
    assert [f.shape for f in check_window(np.zeros((4, 7, 2)), 4, 2, F32)] == [(7, 2)] * 4


def test_values_beyond_the_models_dtype_are_refused_and_those_at_its_edge_are_not():
    from tpnet_ref.checks import check_window, check_windows
    top = float(np.finfo(np.float32).max)
    w = np.zeros((4, 3, 2))
    w[2, 1, 0] = -top                                           # exactly at the edge: accepted
    assert len(check_window(w, 4, 2, F32)) == 4
    assert check_windows(w[None], 4, 2, F32)[1] == 1
    w[2, 1, 0] = -top * 1.0001
    with pytest.raises(ValueError, match=r"^window\[2\]: values beyond the float32 range "
                                         r"\(\|x\| > 3\.4e\+38\); predict in float64"):
        check_window(w, 4, 2, F32)
    with pytest.raises(ValueError, match=r"^windows\[1\]\[2\]: values beyond the float32 range"):
        check_windows(np.stack([np.zeros((4, 3, 2)), w]), 4, 2, F32)
    assert len(check_window(w, 4, 2, F64)) == 4                 # float64 model: fine
    assert check_windows(np.stack([w, w]), 4, 2, F64)[1] == 2
    # a float32 window always fits a float32 model
    assert len(check_window(np.full((4, 3, 2), top, np.float32), 4, 2, F32)) == 4


@pytest.mark.parametrize("windows, exc, msg", [
    (np.zeros((4, 30, 2)), ValueError, r"^windows: expected shape \(B, m, N, 2\) or a sequence "
                                       r"of windows, got an array of shape \(4, 30, 2\)$"),
    (np.zeros((0, 4, 30, 2)), ValueError, r"^windows: empty batch$"),
    ([], ValueError, r"^windows: empty batch$"),
    (7, TypeError, r"^windows: expected an array or a sequence of windows, got int$"),
    (np.zeros((2, 3, 30, 2)), ValueError, r"^windows\[0\]: the model takes m=4 frames, got 3$"),
    (np.zeros((2, 4, 0, 2)), ValueError, r"^windows\[0\]\[0\]: is empty \(0 points\)$"),
    (np.zeros((2, 4, 30, 3)), ValueError, r"^windows\[0\]: expected shape \(m=4, N, 2\)"),
    (np.zeros((2, 4, 30, 2), dtype=bool), TypeError, r"^windows: expected real numbers"),
])
def test_a_batch_is_refused_naming_the_window_and_frame(windows, exc, msg):
    from tpnet_ref.checks import check_windows
    with pytest.raises(exc, match=msg):
        check_windows(windows, 4, 2, F32)


def test_a_batch_names_its_first_bad_frame_and_a_good_one_is_its_frames_in_order():
    from tpnet_ref.checks import check_windows
    b = np.arange(3 * 4 * 5 * 2, dtype=np.float64).reshape(3, 4, 5, 2)
    frames, n = check_windows(b, 4, 2, F32)
    assert n == 3 and len(frames) == 12
    np.testing.assert_array_equal(frames[6], b[1, 2])
    frames, n = check_windows([b[0], list(b[1]), b[2]], 4, 2, F32)
    assert n == 3 and len(frames) == 12
    np.testing.assert_array_equal(frames[7], b[1, 3])
    b[2, 1, 3, 0] = np.nan
    with pytest.raises(ValueError, match=r"^windows\[2\]\[1\]: contains 1 NaN"):
        check_windows(b, 4, 2, F32)


def test_an_overflow_advises_float64_on_float32_and_rescaling_on_float64():
    from tpnet_ref.checks import FLOAT64_ADVICE, NonFiniteResultError, overflow_error
    e32 = overflow_error(F32, "step 3")
    assert isinstance(e32, NonFiniteResultError) and isinstance(e32, ArithmeticError)
    assert str(e32).startswith("the prediction network overflowed in float32 at step 3 ")
    assert str(e32).endswith(FLOAT64_ADVICE)
    e64 = str(overflow_error(F64, "the head"))
    assert "in float64 at the head" in e64 and e64.endswith("rescale the input towards the "
                                                            "training range")
    assert "\n" not in str(e32) + e64


# the training range: the box [-0.05, 1.05] in model units, radius 1..3 world units
@pytest.mark.parametrize("edge, inside", [(-0.05, True), (-0.0501, False), (1.05, True),
                                          (1.0501, False)])
def test_the_training_box_has_a_margin_of_5_percent_on_both_sides(edge, inside):
    model = np.full((4, 19, 2), 0.5)                            # (radius not judged: < 20)
    model[1, 3, 1] = edge
    got = training_range_problem(model, NORM_LO, NORM_HI, True)
    assert (got is None) == inside, got
    if not inside:
        assert got == (f"coordinates span [{min(edge, 0.5):.3g}, {max(edge, 0.5):.3g}] in model "
                       "units, outside the training box [0, 1]")


@pytest.mark.parametrize("r, inside", [(0.99, False), (1.01, True), (2.0, True), (2.99, True),
                                       (3.01, False)])
def test_the_bodys_mean_radius_is_accepted_from_1_to_3_world_units(r, inside):
    w = _window(r=r)
    for frames in (normalize(w), list(normalize(w))):
        got = training_range_problem(frames, NORM_LO, NORM_HI)
        assert (got is None) == inside, got
    if not inside:
        assert got == (f"a frame's mean radius is {r:.3g} world units; the trained body is a "
                       "ring of radius 2 (accepted 1..3)")


def test_a_tiny_radius_hints_at_model_coordinates_only_when_world_units_were_claimed():
    w = _window(r=0.05)
    assert _problem(w).endswith("(accepted 1..3) (model coordinates given as world units? pass "
                                "normalized=True)")
    assert _problem(normalize(w), normalized=True).endswith("(accepted 1..3)")
    assert _problem(_window(r=0.5)).endswith("(accepted 1..3)")          # small, not tiny


def test_ragged_frames_are_judged_one_by_one_by_range_and_radius():
    frames = [_ring(n=30 - i) for i in range(4)]
    assert _problem(frames) is None
    small = frames[:2] + [_ring(r=0.5, n=25), frames[3]]
    assert "mean radius is 0.5 world units" in _problem(small)
    assert _problem(frames[:2] + [_ring(r=0.5, n=19), frames[3]]) is None   # too few to judge
    far = frames[:3] + [_ring(cx=60.0, n=22)]
    assert _problem(far).startswith("coordinates span [")


def test_the_range_warning_is_one_line_at_the_callers_line_and_says_whether_it_warned():
    from tpnet_ref.checks import warn_outside_training_range
    model = normalize(_window(cx=120.0))
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        assert warn_outside_training_range(model, NORM_LO, NORM_HI, "win") is True
        assert warn_outside_training_range(normalize(_window()), NORM_LO, NORM_HI, "w") is False
    [w] = got
    assert w.category is OutsideTrainingRangeWarning and w.filename == __file__
    msg = str(w.message)
    assert msg.startswith("win: outside the training range: coordinates span [")
    assert msg.endswith("; the prediction is an extrapolation") and "\n" not in msg


def test_an_explicit_stacklevel_points_the_warning_that_many_frames_up():
    """stacklevel=k counts as warnings.warn's from the function called (1: its own line, 2: its
    caller ...); warn_range, the words' helper, counts from its caller."""
    import sys
    from tpnet_ref.checks import warn_not_one_body, warn_outside_training_range, warn_range
    far = normalize(_window(cx=120.0))

    def helper(fn, *args):               # one frame between the test and the function called
        fn(*args, stacklevel=3)

    def where(fn, *args):
        with warnings.catch_warnings(record=True) as got:
            warnings.simplefilter("always")
            line = sys._getframe().f_lineno + 1
            fn(*args)
        [w] = got
        return (w.filename, w.lineno) == (__file__, line)
    assert where(helper, warn_outside_training_range, far, NORM_LO, NORM_HI, "w")
    assert where(helper, warn_not_one_body, [_with_strays(3)] * 4, "w")
    assert where(warn_range, "w", "a problem", 1)


# one body: the outlier rule
def _line(n, spacing, y=0.0, x0=0.0):
    return np.stack([x0 + spacing * np.arange(n), np.full(n, y)], axis=1)


def test_fewer_than_5_points_have_no_outliers_and_5_do():
    from tpnet_ref.checks import body_outliers
    four = np.array([[0.0, 0.0], [0.1, 0.0], [0.0, 0.1], [50.0, 50.0]])
    assert not body_outliers(four).any()
    five = np.concatenate([four[:3], [[0.1, 0.1]], [[50.0, 50.0]]])
    np.testing.assert_array_equal(body_outliers(five), [False] * 4 + [True])


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_link_and_max_radius_must_be_finite_distances_above_0(bad):
    from tpnet_ref.checks import body_outliers
    ring = _ring()
    with pytest.raises(ValueError, match=r"^link: must be a finite distance > 0, got "):
        body_outliers(ring, link=bad)
    with pytest.raises(ValueError, match=r"^max_radius: must be a finite distance > 0, got "):
        body_outliers(ring, max_radius=bad)


@pytest.mark.parametrize("max_radius, flagged", [(0.5, []), (0.33, []), (0.3, [2, 5])])
def test_a_max_radius_below_1_is_valid_and_used(max_radius, flagged):
    """A small body: its bounding box's centre is (0, 0.125), its points lie 0.075 to 0.325 from
    it; a max_radius below 1 is a valid distance and decides which points are apart."""
    from tpnet_ref.checks import body_outliers
    pts = np.array([[-0.2, 0.0], [0.2, 0.0], [0.0, -0.2], [0.0, 0.2], [0.0, 0.3], [0.0, 0.45]])
    assert list(np.flatnonzero(body_outliers(pts, max_radius=max_radius))) == flagged


def test_points_exactly_max_radius_from_the_bodys_centre_are_kept():
    from tpnet_ref.checks import body_outliers
    pts = np.stack([np.linspace(-3.6, 3.6, 9), np.zeros(9)], axis=1)   # centre exactly 0
    assert not body_outliers(pts).any()                        # ends exactly 3.6 away: kept
    np.testing.assert_array_equal(np.flatnonzero(body_outliers(pts, max_radius=3.59)), [0, 8])
    small = pts * (0.7 / 3.6)                                  # ends exactly 0.7 away
    assert not body_outliers(small, max_radius=0.7).any()
    assert body_outliers(small, max_radius=0.69).sum() == 2


def test_points_exactly_link_apart_are_joined():
    from tpnet_ref.checks import body_outliers
    pts = np.concatenate([_line(6, 1.0), _line(3, 1.0, x0=7.0)])   # gap 2.0 between groups
    assert not body_outliers(pts, link=2.0, max_radius=100.0).any()   # 2.0 apart: one group
    out = body_outliers(pts, link=1.0, max_radius=100.0)       # two groups; the 3 join: reach
    assert not out.any()
    out = body_outliers(np.concatenate([_line(6, 1.0), _line(2, 1.0, x0=7.0)]), link=1.999,
                        max_radius=100.0)
    np.testing.assert_array_equal(np.flatnonzero(out), [6, 7])  # 2 points: no piece of a body
    out = body_outliers(np.concatenate([_line(6, 1.0), _line(2, 1.0, x0=7.0)]), link=2.0,
                        max_radius=100.0)
    assert not out.any()                                       # joined at exactly the link


@pytest.mark.parametrize("piece, joins", [(1, False), (2, False), (3, True), (4, True)])
def test_only_a_piece_of_3_or_more_points_joins_the_body_and_only_within_its_reach(piece, joins):
    """Far pieces (10 world units off, beyond any link) with a max_radius wide enough to hold both:
    a piece of 3 or more points is part of the body, fewer are apart."""
    from tpnet_ref.checks import body_outliers
    ring = _ring(n=30)
    blob = np.array([[31.0, 20.0], [31.3, 20.0], [31.0, 20.3], [31.3, 20.3]])[:piece]
    out = body_outliers(np.concatenate([ring, blob]), max_radius=100.0)
    assert not out[:30].any()
    assert out[30:].all() != joins and (out[30:].any() != joins)
    # the same piece that would not fit within max_radius (the default 3.6) stays apart
    out = body_outliers(np.concatenate([ring, blob]))
    assert out[30:].all() and not out[:30].any()


def test_the_largest_group_is_the_body():
    from tpnet_ref.checks import body_outliers
    small, big = _ring(n=8, r=1.0), _ring(cx=40.0, n=30)
    out = body_outliers(np.concatenate([small, big]))
    assert out[:8].all() and not out[8:].any()
    out = body_outliers(np.concatenate([big, small]))
    assert out[30:].all() and not out[:30].any()


def test_of_two_pieces_that_fit_with_the_body_one_at_a_time_the_larger_joins():
    """Pieces join the body largest first: of a piece of 5 and one of 3 points, each within the
    body's reach (3.6) with it alone but not both together, the 5 join and the 3 lie apart."""
    from tpnet_ref.checks import body_outliers, window_body_problem
    body = np.stack([20.0 + 0.3 * np.arange(8), np.full(8, 20.0)], axis=1)     # x 20 .. 22.1
    five = np.stack([24.0 + 0.3 * np.arange(5), np.full(5, 20.0)], axis=1)     # x 24 .. 25.2
    three = np.array([[16.0, 20.0], [16.3, 20.0], [16.6, 20.0]])
    for order in ((body, five, three), (three, body, five), (five, three, body)):
        frame = np.concatenate(order)
        out = body_outliers(frame)          # link 1.2: three groups; reach 2.6, 3.05, both 4.6
        np.testing.assert_array_equal(frame[out], three)
    frame = np.concatenate([body, five, three])
    why = window_body_problem([frame + [0.5 * t, 0.0] for t in range(4)])
    assert why.startswith("frame 0 does not look like one body: 3 of 16 points lie apart from "
                          "it (likely stray points")


@hsettings(max_examples=25)
@given(st.floats(0.6, 2.8), st.integers(12, 60), st.floats(3.0, 42.0), st.floats(3.0, 42.0),
       st.floats(0.0, 2 * np.pi), st.floats(10.0, 20.0))
def test_a_ring_has_no_outliers_and_a_far_stray_point_is_the_only_one(r, n, cx, cy, angle, off):
    from tpnet_ref.checks import body_outliers, window_body_problem
    ring = _ring(cx=cx, cy=cy, r=r, n=n)
    assert not body_outliers(ring).any()
    stray = [[cx + off * np.cos(angle), cy + off * np.sin(angle)]]
    out = body_outliers(np.concatenate([ring, stray]))
    assert out[-1] and not out[:-1].any()
    w = np.stack([ring + [0.5 * i, 0.0] for i in range(4)])
    assert window_body_problem(w) is None and window_body_problem(list(w)) is None
    moved = [np.add(stray, [0.5 * i, 0.0]) for i in range(4)]         # moving with the ring
    bad = [np.concatenate([f, moved[i]]) if i == 2 else f for i, f in enumerate(w)]
    for frames in (bad, [np.concatenate([f, moved[i]]) for i, f in enumerate(w)]):
        got = window_body_problem(frames)
        assert got.startswith(f"frame {0 if len(frames[0]) > n else 2} does not look like one "
                              f"body: 1 of {n + 1} points lie apart from it (likely stray points")


# one body: the window
def _with_strays(k, n=30):
    """A ring of n points and k stray points, 8 to 9 world units off, 1 apart."""
    ring = _ring(n=n)
    return np.concatenate([ring, [[28.0 + 0.2 * i, 20.0 + 0.2 * i] for i in range(k)]])


@pytest.mark.parametrize("k, what", [(1, "stray points"), (4, "stray points"),
                                     (5, "a second blob"), (12, "a second blob")])
def test_stray_points_and_a_second_blob_are_named_in_one_line(k, what):
    from tpnet_ref.checks import NotOneBodyWarning, warn_not_one_body, window_body_problem
    frames = [_ring(cx=20.0 + 0.5 * i) for i in range(4)]
    frames[1] = _with_strays(k)
    frames[1][:30] += [0.5, 0.0]
    expect = (f"frame 1 does not look like one body: {k} of {30 + k} points lie apart from it "
              f"(likely {what}: background specks, reflections, another object); max pooling "
              "takes them as part of the body, so clean each frame with "
              "tpnet_ref.observe.drop_outliers")
    assert window_body_problem(frames) == expect
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        assert warn_not_one_body(frames, "wdw") is True
        assert warn_not_one_body([_ring()] * 4, "wdw") is False
    [w] = got
    assert w.category is NotOneBodyWarning and issubclass(w.category, OutsideTrainingRangeWarning)
    assert str(w.message) == f"wdw: {expect}; the prediction is unreliable"
    assert w.filename == __file__


def test_a_body_must_outnumber_the_points_apart_from_it_and_have_5_points():
    from tpnet_ref.checks import window_body_problem
    body = _ring(r=0.5, n=5)
    stray = [[30.0, 20.0]]
    five = np.concatenate([body, stray])                       # 5 in the body, 1 apart
    assert window_body_problem([five] * 4).startswith("frame 0 does not look like one body: 1 of "
                                                      "6 points")
    four = np.concatenate([body[:4], stray])                   # 4 in the body: no body
    assert window_body_problem([four] * 4) is None
    # a body of 6 and, far from it, three pairs: as many apart as in the body -- named; one more
    # point apart and they outnumber it: no body of the scene's size, left to the range check
    pairs = [[20.0, 60.0], [20.3, 60.0], [60.0, 20.0], [60.0, 20.3], [-40.0, -40.0],
             [-40.3, -40.0]]
    even = np.concatenate([_ring(r=1.0, n=6), pairs])
    assert window_body_problem([even] * 4).startswith("frame 0 does not look like one body: 6 of "
                                                      "12 points lie apart from it (likely a "
                                                      "second blob")
    assert window_body_problem([np.concatenate([even, [[60.0, 60.0]]])] * 4) is None


def test_four_points_are_no_body_even_with_the_strays_beside_them():
    """A body of 4 points and 2 strays 5 world units off (all 6 within one strip of the body's
    size, so the scattered-points shortcut does not decide): no body of the scene's size, left
    to the range check; with a fifth point in the body the strays are named."""
    from tpnet_ref.checks import window_body_problem
    strays = [[25.0, 20.0], [25.3, 20.0]]
    four = np.concatenate([_ring(r=0.5, n=4), strays])
    assert window_body_problem([four] * 4) is None
    five = np.concatenate([_ring(r=0.5, n=5), strays])
    assert window_body_problem([five] * 4).startswith("frame 0 does not look like one body: 2 of "
                                                      "7 points lie apart from it")


@pytest.mark.parametrize("step, says", [(3.99, False), (4.01, True)])
def test_a_frame_more_than_4_world_units_from_the_previous_one_is_named(step, says):
    from tpnet_ref.checks import window_body_problem
    w = np.stack([_ring() + [0.5 * i, 0.0] for i in range(4)])
    w[3:] += [step - 0.5, 0.0]                                  # frame 2 -> 3: `step` apart
    ragged = [w[0], w[1][:29], w[2], w[3]]
    for frames in (w, list(w), ragged):
        got = window_body_problem(frames)
        assert (got is not None) == says, got
    if says:
        assert got.startswith(f"frame 3's body is {step:.3g} world units from frame 2's (the "
                              "scene's bodies move at most ~2.1 per frame): a frame from another "
                              "moment or object, or frames not 4/45 s apart?")


def test_a_scattered_frame_leaves_the_window_to_the_range_check_even_after_a_jump():
    """Frames 0 and 1 are a ring 6 world units apart, frame 2 is scattered points: the window is
    not judged as one body at all (no body in frame 2), whichever path judges it; with a ring
    in frame 2 the jump is named."""
    from tpnet_ref.checks import window_body_problem
    rng = np.random.default_rng(5)
    w = np.stack([_ring(cx=10.0), _ring(cx=16.0), rng.uniform(1, 44, (30, 2)), _ring(cx=16.5)])
    ragged = [w[0], w[1], w[2][:29], w[3]]
    for frames in (w, list(w), ragged):
        assert window_body_problem(frames) is None
    w[2] = _ring(cx=16.2)
    assert window_body_problem(w).startswith("frame 1's body is 6 world units from frame 0's")
    # a stray point before the scattered frame is still named
    w = np.stack([_with_strays(1)[1:], _ring(cx=20.5), rng.uniform(1, 44, (30, 2)),
                  _ring(cx=21.0)])
    assert window_body_problem(w).startswith("frame 0 does not look like one body: 1 of 30")


def test_frames_above_the_pairwise_limit_are_not_judged():
    from tpnet_ref.checks import BODY_MAX_POINTS, window_body_problem
    frames = [_with_strays(3)] * 4
    assert window_body_problem(frames) is not None
    big = np.concatenate([_ring(n=BODY_MAX_POINTS - 2), [[30.0, 20.0], [31.0, 30.0], [1, 1]]])
    assert window_body_problem([big, *frames[1:]]) is None


def test_the_pairwise_limit_is_2048_points():
    """A frame of 2,048 points is still judged (its strays named), one of 2,049 is not, and
    body_outliers says so in one line."""
    from tpnet_ref.checks import body_outliers, window_body_problem
    frames = [_with_strays(3)] * 4
    strays = [[30.0, 20.0], [31.0, 30.0], [1.0, 1.0]]
    at = np.concatenate([_ring(n=2045), strays])
    assert window_body_problem([at, *frames[1:]]).startswith(
        "frame 0 does not look like one body: 3 of 2048 points lie apart from it")
    over = np.concatenate([_ring(n=2046), strays])
    assert window_body_problem([over, *frames[1:]]) is None
    with pytest.raises(ValueError, match=r"^points: 2049 points, the one-body test takes at "
                                         r"most 2048 \(it compares every pair\)"):
        body_outliers(over)


# sparse frames and motion
@pytest.mark.parametrize("counts, says", [
    ([30, 30, 30, 30], None), ([3, 3, 3, 3], None),
    ([30, 2, 30, 30], "frame 1 has 2 point(s); a body's outline needs at least 3 (fewer cannot "
                      "span an area; the model was trained on 30 per frame)"),
    ([30, 2, 1, 0], "frame 1 has 2 point(s) (3 frames have too few); a body's outline needs at "
                    "least 3"),    ([30, 2, 30, 1], "frame 1 has 2 point(s) (2 frames have too few); a body's outline needs at "
                     "least 3"),
])
def test_sparse_frames_name_the_first_and_count_the_others(counts, says):
    from tpnet_ref.checks import sparse_frames_problem
    got = sparse_frames_problem(counts)
    assert (got is None) if says is None else got.startswith(says), got


def test_motion_is_the_mean_step_of_the_centroids_and_one_frame_has_none():
    from tpnet_ref.checks import motion_problem
    assert motion_problem(_window()[:1]) is None and motion_problem([_ring()]) is None
    # steps 0.05, 0.05, 0.35: mean 0.15, inside although two steps are below 0.1
    xs = [0.0, 0.05, 0.1, 0.45]
    w = np.stack([_ring() + [x, 0.0] for x in xs])
    assert motion_problem(w) is None
    ragged = [_ring(cx=20.0 + x, n=30 - i) for i, x in enumerate([0.0, 0.01, 0.02, 0.03])]
    got = motion_problem(ragged)
    assert got.startswith("the body's centroid moves 0.01 world units per frame on average; the "
                          "training windows move 0.1..2.5 (frames 4/45 s apart): frames closer "
                          "in time than 4/45 s, e.g. consecutive simulator rows instead of every "
                          "fourth, or a body at rest? (tpnet_ref.observe.frames_at_model_rate")
    fast = motion_problem(np.stack([_ring() + [0.0, 2.6 * i] for i in range(4)]))
    assert "moves 2.6 world units" in fast and "further apart in time than 4/45 s, e.g. every " \
                                               "8th simulator row?" in fast


def _warned(frames, normalized=False, one_window=True):
    from tpnet_ref.checks import warn_about_input
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        warn_about_input(frames, NORM_LO, NORM_HI, normalized, "w", one_window)
    return [(g.category.__name__, str(g.message)) for g in got]


def test_the_input_warnings_come_one_cause_at_a_time_in_order():
    slow = [_ring() + [0.02 * i, 0.0] for i in range(4)]
    assert [c for c, _ in _warned(slow)] == ["FrameSpacingWarning"]
    assert _warned(slow, one_window=False) == []               # a batch: no motion judged
    stray = [np.concatenate([f, [[29.0, 20.0]]]) for f in slow]
    assert [c for c, _ in _warned(stray)] == ["NotOneBodyWarning"]     # not also the motion
    assert _warned(stray, one_window=False) == []
    far = [f + [100.0, 0.0] for f in slow]
    assert [c for c, _ in _warned(far)] == ["OutsideTrainingRangeWarning"]
    few = [f[:2] for f in slow]
    got = _warned(few)
    assert [c for c, _ in got] == ["TooFewPointsWarning", "FrameSpacingWarning"]
    assert got[0][1].startswith("w: too few points: frame 0 has 2 point(s) (4 frames have too "
                                "few); ") and got[0][1].endswith("; the prediction is an "
                                                                 "extrapolation")
    assert got[1][1].startswith("w: unusual motion: the body's centroid moves 0.02 world units")
    assert [c for c, _ in _warned(few, one_window=False)] == ["TooFewPointsWarning"]
    assert _warned([_ring() + [0.5 * i, 0.0] for i in range(4)]) == []


def test_the_input_warnings_of_ragged_and_normalized_frames():
    ragged = [_ring(cx=20.0 + 0.02 * i, n=30 - i) for i in range(4)]
    assert [c for c, _ in _warned(ragged)] == ["FrameSpacingWarning"]
    assert [c for c, _ in _warned([normalize(f) for f in ragged], True)] == ["FrameSpacingWarning"]
    steady = [_ring(cx=20.0 + 0.5 * i, n=30 - i) for i in range(4)]
    assert _warned(steady) == [] and _warned([normalize(f) for f in steady], True) == []
    stray = steady[:2] + [np.concatenate([steady[2], [[29.0, 20.0]]]), steady[3]]
    assert [c for c, _ in _warned(stray)] == ["NotOneBodyWarning"]
    assert [c for c, _ in _warned([normalize(f) for f in stray], True)] == ["NotOneBodyWarning"]
    small = [normalize(_ring(r=0.5, n=25 + i)) for i in range(4)]
    got = _warned(small, True)
    assert [c for c, _ in got] == ["OutsideTrainingRangeWarning"] and "radius is 0.5" in got[0][1]


def test_stray_points_just_outside_the_outline_within_the_bodys_reach_are_named():
    """Two points 1.5 world units outside a ring of radius 2 (beyond the link, within 3.6 of the
    body's centre): apart from the body, named -- whichever path judges the window (found by a
    fresh mutation sample, seed 478775425: the outline and pairwise shortcuts that call any
    frame within the body's reach one body)."""
    from tpnet_ref.checks import body_outliers, window_body_problem
    strays = [[20.0, 23.5], [20.3, 23.5]]
    frame = np.concatenate([_ring(), strays])
    assert list(np.flatnonzero(body_outliers(frame))) == [30, 31]
    w = np.stack([frame + [0.5 * i, 0.0] for i in range(4)])
    for frames in (w, list(w), [w[0], w[1], w[2][1:], w[3]]):
        got = window_body_problem(frames)
        assert got is not None and "2 of " in got and "(likely stray points" in got, got
    assert window_body_problem(w[:, :30]) is None               # the ring alone: one body


def test_two_frames_are_enough_to_judge_the_motion():
    """A model of m = 2 frames (TPNetConfig takes any m >= 1): its window's motion is judged
    (found by a fresh mutation sample, seed 670151351)."""
    from tpnet_ref.checks import motion_problem
    slow = np.stack([_ring() + [0.02 * i, 0.0] for i in range(2)])
    assert "moves 0.02 world units per frame" in motion_problem(slow)
    assert "moves 0.02 world units per frame" in motion_problem(list(slow))
    assert motion_problem(np.stack([_ring() + [0.5 * i, 0.0] for i in range(2)])) is None
    assert [c for c, _ in _warned(list(slow))] == ["FrameSpacingWarning"]


# ------------------------------------------------------------------ scattered points
# The one-body test's shortcut: ``checks._cannot_hold_a_body`` decides in a few NumPy calls that a
# frame holds no body of the scene's size, and ``window_body_problem`` says exactly what it says
# without it, on rings, rings with strays, two blobs, arcs and scattered points.
def _random_ring(rng, n=30, r=2.0, centre=(20.0, 20.0)):
    a = np.sort(rng.uniform(0, 2 * np.pi, n))
    return np.stack([centre[0] + r * np.cos(a), centre[1] + r * np.sin(a)], axis=1)


def _windows(seed: int):
    rng = np.random.default_rng(seed)
    c = rng.uniform(5, 40, 2)
    ring = np.stack([_random_ring(rng, centre=c + [0.5 * t, 0]) for t in range(4)])
    yield "ring", ring
    stray = ring.copy()
    stray[2, 5] += rng.uniform(3, 9, 2)
    yield "ring with a stray point", stray
    blob = ring.copy()
    blob[1, :12] = c + rng.uniform(6, 12, 2) + rng.normal(0, 0.4, (12, 2))
    yield "a second blob", blob
    yield "random points", rng.uniform(1, 44, (4, 30, 2))
    yield "random points, small box", rng.uniform(10, 10 + rng.uniform(5, 15), (4, 30, 2))
    half = ring.copy()
    half[:, 15:] = rng.uniform(1, 44, (4, 15, 2))
    yield "half ring, half scattered", half
    first_ok = rng.uniform(1, 44, (4, 30, 2))
    first_ok[0] = stray[2]
    yield "a stray frame, then scattered ones", first_ok
    yield "a tiny ring", ring * 0.01 + 20
    yield "few points", ring[:, :6]
    yield "ragged", [ring[0], ring[1][:20], rng.uniform(1, 44, (25, 2)), ring[3]]


@pytest.mark.parametrize("seed", range(12))
def test_the_shortcut_changes_no_answer(seed, monkeypatch):
    cases = list(_windows(seed))
    fast = [C.window_body_problem(w if isinstance(w, np.ndarray) else list(w)) for _, w in cases]
    monkeypatch.setattr(C, "_cannot_hold_a_body", lambda f: np.zeros(len(f), dtype=bool))
    slow = [C.window_body_problem(w if isinstance(w, np.ndarray) else list(w)) for _, w in cases]
    assert fast == slow, [name for (name, _), a, b in zip(cases, fast, slow) if a != b]


def test_scattered_frames_are_decided_without_the_pairwise_test(monkeypatch):
    rng = np.random.default_rng(0)
    window = rng.uniform(1, 44, (4, 30, 2))
    assert C._cannot_hold_a_body(window).all()
    assert not C._cannot_hold_a_body(np.stack([_random_ring(rng) for _ in range(4)])).any()

    def pairwise(*a, **k):
        raise AssertionError("body_outliers ran on a scattered window")

    monkeypatch.setattr(C, "body_outliers", pairwise)
    assert C.window_body_problem(window) is None


@pytest.mark.parametrize("ndim", [3, 5, 6])
def test_a_batch_array_of_another_rank_is_named_in_one_line(ndim):
    """``predict_batch`` takes ``(B, m, N, dim)``: an array of rank 3, 5 or 6 is refused with the
    shape it expects and the one it got (not a failure to unpack the shape)."""
    shape = {3: (4, 30, 2), 5: (1, 1, 4, 30, 2), 6: (1, 1, 1, 4, 30, 2)}[ndim]
    with pytest.raises(ValueError, match=r"windows: expected shape \(B, m, N, 2\)") as err:
        tpnet_ref.predict_batch(np.full(shape, 20.0))
    assert str(shape) in str(err.value) and "\n" not in str(err.value)
