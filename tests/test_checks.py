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
