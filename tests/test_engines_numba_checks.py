"""tpnet_ref.engines.numba_checks: the Numba engine's compiled first pass says what the checks say, or
leaves the window to them; its points are canonical_points' bits, and a prediction through it
is the prediction through the checks."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pytest.importorskip("numba")

from tpnet_ref import checks as C  # noqa: E402
from tpnet_ref.engines import numba_checks as EC  # noqa: E402
from tpnet_ref.config import TPNetConfig  # noqa: E402
from tpnet_ref.model import init_random  # noqa: E402
from ring_helpers import thrown_ball  # noqa: E402

SMALL = TPNetConfig(mlp1=(8, 8), mlp2=(8, 8, 16), global_features=8, lstm_units=(8, 8, 8))


@pytest.fixture(scope="module", params=["float32", "float64"])
def net(request):
    """A small random network on the Numba engine: the first pass does not depend on the weights."""
    return init_random(SMALL, seed=1, dtype=request.param).with_engine("numba")


def _ring(cx=20.0, cy=20.0, r=2.0, n=30, phase=0.0):
    a = phase + np.arange(n) * 2 * np.pi / n
    return np.stack([cx + r * np.sin(a), cy + r * np.cos(a)], axis=1)


def _window(step=(0.5, -0.2), **kw):
    return np.stack([_ring(**kw) + np.multiply(step, i) for i in range(4)])


def _falling(rows_apart, v=(0.3, 0.1)):
    a = np.array([0.0, -C.GRAVITY * (rows_apart * C.SIM_DT) ** 2])
    return np.stack([_ring() + np.array(v) * i + 0.5 * a * i * i for i in range(4)])


#: the warnings of each decided verdict
_WARNINGS = {EC.VERDICT_CLEAR: [], EC.VERDICT_SPAN: [C.OutsideTrainingRangeWarning],
             EC.VERDICT_RADIUS: [C.OutsideTrainingRangeWarning],
             EC.VERDICT_FALL: [C.FrameSpacingWarning], EC.VERDICT_STEP: [C.FrameSpacingWarning]}


def _first_pass(net, x, one, normalized):
    """The model's compiled first pass on ``x`` (None: not decided, or no first pass)."""
    return None if net.screen is None else net.screen(net, x, one, normalized)


def _record(fn):
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        out = fn()
    return out, [(w.category, str(w.message)) for w in rec]


def _by_checks(net, x, one, normalized):
    """What the checks say of ``x`` and canonical_points' points (None: an error)."""
    c = net.config

    def run():
        if one:
            frames = C.check_window(x, c.m, c.dim, net.dtype)
        else:
            frames = C.check_windows(x, c.m, c.dim, net.dtype)[0]
        C.warn_about_input(frames, c.norm_lo, c.norm_hi, normalized,
                           "window" if one else "windows", one)
        return net.canonical_points(frames, normalized)[0]
    try:
        return _record(run)
    except (ValueError, TypeError):
        return None


def _decided(net, x, one=True, normalized=False):
    """Whether the first pass decides ``x``; where it does, its warnings and points are the
    checks' (the points bit for bit)."""
    got, said = _record(lambda: _first_pass(net, x, one, normalized))
    if got is None:
        return False
    pts, counts, batch = got
    ref = _by_checks(net, x, one, normalized)
    assert ref is not None, "the first pass passed a window the checks refuse"
    ref_pts, ref_said = ref
    assert said == ref_said
    assert pts.dtype == ref_pts.dtype == net.dtype
    assert pts.tobytes() == ref_pts.tobytes()           # bits, signed zeros included
    assert batch == (1 if one else len(x)) and counts.tolist() == [x.shape[-2]] * (batch * 4)
    return True


def _scene_windows():
    from tpnet_ref.sim.cases import TEST_CASES
    from tpnet_ref.sim.scene import simulate
    out = []
    for case in TEST_CASES[5:8]:
        frames = simulate(*case)[::4]
        out += [frames[s:s + 4] for s in range(0, len(frames) - 4, 9)]
    return out


def test_scene_windows_are_decided_and_say_what_the_checks_say(net):
    wins = _scene_windows()
    decided = [_decided(net, w.astype(dt), normalized=False) for w in wins
               for dt in (np.float32, np.float64)]
    assert sum(decided) >= 0.95 * len(decided)          # the common case takes the first pass


@pytest.mark.parametrize("name, make, normalized, verdict", [
    ("ring in the box", lambda: _window(), False, EC.VERDICT_CLEAR),
    ("random points", lambda: np.random.default_rng(0).uniform(5.4, 39.6, (4, 30, 2)), False,
     EC.VERDICT_RADIUS),
    ("out of the box", lambda: _window(cx=60.0), False, EC.VERDICT_SPAN),
    ("out of the box, below", lambda: _window(cx=-20.0), False, EC.VERDICT_SPAN),
    ("model units", lambda: (_window() - 1.1438) / 42.7124, True, EC.VERDICT_CLEAR),
    ("world units as normalized", lambda: _window(), True, EC.VERDICT_SPAN),
    ("model units as world", lambda: (_window() - 1.1438) / 42.7124, False, EC.VERDICT_RADIUS),
    ("a small ring", lambda: _window(r=0.7), False, EC.VERDICT_RADIUS),
    ("a large ring", lambda: _window(r=3.3, n=60), False, None),       # links > 1.2: undecided
    ("a ring of 12 points", lambda: _window(n=12), False, None),     # no radius test, links 1.05
    ("falling, consecutive rows", lambda: _falling(1), False, EC.VERDICT_FALL),
    ("falling, every 8th row", lambda: _falling(8), False, EC.VERDICT_FALL),
    ("falling, every 4th row", lambda: _falling(4), False, EC.VERDICT_CLEAR),
    ("at rest", lambda: _window(step=(0.0, 0.0)), False, EC.VERDICT_STEP),
    ("fast", lambda: _window(step=(3.0, 0.0)), False, EC.VERDICT_STEP),
    ("a jump", lambda: _window(step=(5.0, 0.0)), False, EC.VERDICT_UNDECIDED),
    ("a stray point", lambda: np.concatenate([_window(), _window()[:, :1] + [9.0, 0.0]], axis=1),
     False, EC.VERDICT_UNDECIDED),
    ("a NaN", lambda: np.where(np.arange(240).reshape(4, 30, 2) == 7, np.nan, _window()), False,
     EC.VERDICT_UNDECIDED),
    ("an infinity", lambda: np.where(np.arange(240).reshape(4, 30, 2) == 7, np.inf, _window()),
     False, EC.VERDICT_UNDECIDED),
    ("4 points a frame", lambda: _window(n=4), False, EC.VERDICT_UNDECIDED),
])
def test_each_verdict_is_the_checks_warning_or_left_to_them(net, name, make, normalized, verdict):
    x = make()
    for dt in (np.float32, np.float64):
        w = x.astype(dt)
        decided = _decided(net, w, normalized=normalized)
        if verdict == EC.VERDICT_UNDECIDED:
            assert not decided, name
        elif verdict is not None:
            assert decided, name
            _, said = _record(lambda: _first_pass(net, w, True, normalized))
            assert [k for k, _ in said] == _WARNINGS[verdict], name


def test_values_beyond_the_models_dtype_are_left_to_the_checks_error():
    net = init_random(SMALL, seed=1, dtype="float32").with_engine("numba")
    w = _window()
    w[2, 3, 0] = 1e39
    assert _first_pass(net, w, True, False) is None
    with pytest.raises(ValueError, match=r"window\[2\]: values beyond the float32 range"):
        net.predict(w)


def test_a_batch_is_judged_by_range_alone_and_names_itself(net):
    slow = np.stack([_ring() + [0.02 * i, 0.0] for i in range(4)])      # a batch: no motion
    far = _window(cx=60.0)
    assert _decided(net, np.stack([slow, _window()]), one=False)
    got, said = _record(lambda: _first_pass(net, np.stack([_window(), far]), False, False))
    assert got is not None and [k for k, _ in said] == [C.OutsideTrainingRangeWarning]
    assert said[0][1].startswith("windows: outside the training range: coordinates span")
    assert _decided(net, np.stack([_window(), far, slow]), one=False)
    stray = np.concatenate([_window(), _window()[:, :1] + [9.0, 0.0]], axis=1)
    assert _decided(net, stray[None], one=False)          # no one-body test for batches
    assert _first_pass(net, np.zeros((0, 4, 30, 2)), False, False) is None
    assert _first_pass(net, np.zeros((64, 4, 30, 2)), False, False) is None   # split batches


def test_inputs_it_does_not_read_go_to_the_checks(net):
    w = _window()
    assert _first_pass(net, list(w), True, False) is None               # a list of frames
    assert _first_pass(net, w.astype(np.int64), True, False) is None      # integers
    assert _first_pass(net, w.astype(np.float16), True, False) is None
    assert _first_pass(net, w[:3], True, False) is None                   # m = 3 for a 4-frame model
    assert _first_pass(net, w[None], True, False) is None                 # a batch as one window
    assert _first_pass(net, w[:, :, :1], True, False) is None
    assert net.with_engine("numpy").screen is None                      # the NumPy engine: checks


def test_the_points_are_unsorted_when_the_model_runs_them_as_given(net):
    w = _window()[:, ::-1].copy()
    assert _decided(net.with_point_sort(False), w)
    pts = _first_pass(net.with_point_sort(False), w, True, False)[0]
    assert pts.tobytes() == net.with_point_sort(False).normalize(
        w.reshape(-1, 2).astype(net.dtype)).tobytes()


@pytest.mark.parametrize("r, inside", [(1.0, True), (3.0, True)])
def test_numbers_on_a_threshold_are_left_to_the_checks_or_agree(net, r, inside):
    # a radius exactly on the accepted range's edge, and a hair either side
    for rr in (np.nextafter(r, 0), r, np.nextafter(r, 9)):
        w = np.stack([_ring(r=rr, n=96) + [0.5 * i, 0.0] for i in range(4)])
        _decided(net, w)                       # asserts agreement whenever it decides


def test_the_warning_points_at_the_callers_line(net):
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        net.predict(_window(cx=60.0))
    assert [w.filename for w in rec] == [__file__]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cx=st.floats(-5, 50), cy=st.floats(-5, 50), r=st.floats(0.05, 5.0),
       n=st.integers(5, 70), vx=st.floats(-3, 3), vy=st.floats(-3, 3),
       fall=st.sampled_from([None, 0.5, 1.0, 2.0, 3.0, 3.9999, 4.0, 5.0, 8.0]),
       noise=st.sampled_from([0.0, 1e-3, 0.3]), seed=st.integers(0, 2 ** 16),
       normalized=st.booleans(), f32=st.booleans())
def test_whatever_it_decides_is_what_the_checks_say(net, cx, cy, r, n, vx, vy, fall, noise,
                                                     seed, normalized, f32):
    rng = np.random.default_rng(seed)
    t = np.arange(4)[:, None, None]
    acc = 0.0 if fall is None else -C.GRAVITY * (fall * C.SIM_DT) ** 2
    w = (_ring(cx, cy, r, n, phase=rng.uniform(0, 6.3))[None] + np.array([vx, vy]) * t
         + np.array([0.0, 0.5 * acc]) * t * t + noise * rng.standard_normal((4, n, 2)))
    w = w[:, rng.permutation(n)]
    if normalized:
        w = (w - 1.1438) / 42.7124
    _decided(net, w.astype(np.float32 if f32 else np.float64), normalized=normalized)


def _without_first_pass(net):
    import copy
    slow = copy.copy(net)
    slow.screen = None
    return slow


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_a_prediction_through_it_is_the_prediction_through_the_checks(released_random64, dtype):
    net = released_random64.astype(dtype).with_engine("numba")
    checked = _without_first_pass(net)
    rng = np.random.default_rng(5)
    for w in (_window(), rng.uniform(5.4, 39.6, (4, 30, 2)), _falling(1)):
        for x in (w, w.astype(np.float32)):
            assert _first_pass(net, x, True, False) is not None
            fast, said = _record(lambda: net.predict(x))
            slow, said_slow = _record(lambda: checked.predict(x))
            assert fast.tobytes() == slow.tobytes() and said == said_slow
    for b in (1, 3, 8, 9):
        x = np.stack([_window(cx=15 + i) for i in range(b)])
        fast = net.predict_batch(x)
        assert fast.tobytes() == checked.predict_batch(x).tobytes()
        if b <= 8:              # the engine's own feature extractor: batch == single
            assert fast[0].tobytes() == net.predict(x[0]).tobytes()


def test_a_rollout_through_it_is_the_rollout_through_the_checks(released_random64):
    net = released_random64.astype("float32").with_engine("numba")
    checked = _without_first_pass(net)
    w = _window()
    assert _first_pass(net, w, True, False) is not None
    assert net.rollout(w, 5).tobytes() == checked.rollout(w, 5).tobytes()
    x = np.stack([_window(cx=15 + i) for i in range(3)])
    assert net.rollout_batch(x, 4).tobytes() == checked.rollout_batch(x, 4).tobytes()
    with pytest.raises(ValueError, match="steps: expected a positive integer"):
        net.rollout(w, 0)


@settings(max_examples=60, deadline=None)
@given(frames=st.integers(1, 6), n=st.integers(1, 40), seed=st.integers(0, 2 ** 16),
       ties=st.booleans(), f32=st.booleans(), dim=st.sampled_from([2, 3]))
def test_the_compiled_sort_is_the_canonical_order(frames, n, seed, ties, f32, dim):
    from tpnet_ref.engines.numba_checks import Screen
    from tpnet_ref.point_order import canonical_order
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-1, 1, (frames * n, dim))
    if ties:                                # shared x (and y), shared rows, zeros of both signs
        pts = np.round(pts * 2) / 2
        pts[rng.random(len(pts)) < 0.2] = [-0.0, 0.0, -0.0][:dim]
        pts[rng.random(len(pts)) < 0.2] = [0.0, -0.0, 0.0][:dim]
    pts = pts.astype(np.float32 if f32 else np.float64)
    counts = np.full(frames, n)
    got = Screen().sorted(pts, counts)
    assert got.tobytes() == pts[canonical_order(pts, counts)].tobytes()
    assert Screen().sorted(pts[::2], counts) is None or len(pts[::2]) == len(pts)
    if frames > 1:
        ragged = counts.copy()
        ragged[0] += 1
        ragged[-1] -= 1
        assert Screen().sorted(pts, ragged) is None


@pytest.mark.parametrize("size", ["full", "half", "quarter"])
def test_every_shipped_size_gives_every_warning_and_error_through_the_default_engine(size):
    import tpnet_ref
    net = tpnet_ref.load(size=size)
    assert net.screen is not None                            # numba installed: the default
    stray = np.concatenate([_window(), _window()[:, :1] + [9.0, 0.0]], axis=1)
    cases = [(_window(), []), (_window(cx=60.0), [C.OutsideTrainingRangeWarning]),
             (np.random.default_rng(0).uniform(5.4, 39.6, (4, 30, 2)),
              [C.OutsideTrainingRangeWarning]),
             (_falling(1), [C.FrameSpacingWarning]), (stray, [C.NotOneBodyWarning]),
             ([f[:2] for f in _window()], [C.TooFewPointsWarning])]
    for w, kinds in cases:
        y, said = _record(lambda: net.predict(w))
        assert [k for k, _ in said] == kinds and y.shape == (30, 2) and np.isfinite(y).all()
        ys, said_b = _record(lambda: net.predict_batch([w, w]))
        assert ys.shape == (2, 30, 2)
    nan = _window()
    nan[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match=r"window\[1\]: contains 1 NaN"):
        net.predict(nan)
    big = _window()
    big[3, 0, 1] = 1e39
    with pytest.raises(ValueError, match=r"window\[3\]: values beyond the float32 range"):
        net.predict(big)
    with pytest.raises(ValueError, match="the model takes m=4 frames, got 3"):
        net.predict(_window()[:3])


def test_the_short_commands_run_the_first_pass_only_where_numba_has_it(net, monkeypatch):
    import numba

    from tpnet_ref.engines import compile_watch
    from tpnet_ref.engines.compile_watch import CompileWatch
    fresh = numba.njit(EC.screen.py_func)                   # compiled nowhere, cached nowhere
    monkeypatch.setattr(EC, "screen", fresh)
    monkeypatch.setattr(compile_watch, "TWO_THREAD_KERNELS_ON_DEMAND", False)
    screen = EC.Screen()
    with CompileWatch() as w:
        assert screen(net, _window(), True, False) is None  # the checks serve the call
        y = net.with_engine("numba").predict(_window())       # a new Screen, the same answer
    assert w.count == 0 and not fresh.signatures and np.isfinite(y).all()
    monkeypatch.setattr(compile_watch, "TWO_THREAD_KERNELS_ON_DEMAND", True)   # the default
    assert screen(net, _window(), True, False) is not None and fresh.signatures   # compiled


# ------------------------------------------------------------------ 3-D points (docs/spec.md §8)
SMALL3 = TPNetConfig(dim=3, n_out=42, mlp1=(8, 8), mlp2=(8, 8, 16), global_features=8,
                     lstm_units=(8, 8, 8))


@pytest.fixture(scope="module", params=["float32", "float64"])
def net3(request):
    return init_random(SMALL3, seed=1, dtype=request.param).with_engine("numba")


def test_3d_scene_windows_are_decided_and_say_what_the_checks_say(net3):
    pytest.importorskip("mujoco")
    from tpnet_ref.sim.cases3d import TEST_CASES3D
    from tpnet_ref.sim.scene3d import simulate3d
    wins = []
    for case in TEST_CASES3D[:3]:
        frames = simulate3d(*case, steps=300)[::4]
        wins += [frames[s:s + 4] for s in range(0, len(frames) - 4, 11)]
    decided = [_decided(net3, w.astype(dt)) for w in wins for dt in (np.float32, np.float64)]
    assert sum(decided) >= 0.95 * len(decided)


@pytest.mark.parametrize("name, make, normalized, verdict", [
    ("a throw", lambda: thrown_ball(), False, EC.VERDICT_CLEAR),
    ("model units", lambda: (thrown_ball() - 1.1438) / 42.7124, True, EC.VERDICT_CLEAR),
    ("out of the box, above", lambda: thrown_ball() + [0.0, 0.0, 20.0], False, EC.VERDICT_SPAN),
    ("world units as normalized", lambda: thrown_ball(), True, EC.VERDICT_SPAN),
    ("a large ball", lambda: thrown_ball(radius=6.0), False, EC.VERDICT_RADIUS),
    ("random points", lambda: np.random.default_rng(0).uniform(5.4, 39.6, (4, 42, 3)), False,
     EC.VERDICT_RADIUS),
    ("falling, consecutive rows", lambda: thrown_ball(1), False, EC.VERDICT_FALL),
    ("falling, every 8th row", lambda: thrown_ball(8), False, EC.VERDICT_FALL),
    ("at rest", lambda: np.stack([thrown_ball()[0]] * 4), False, EC.VERDICT_STEP),
    ("a stray point", lambda: np.concatenate([thrown_ball(), thrown_ball()[:, :1] + 6.0], axis=1),
     False, EC.VERDICT_CLEAR),          # the one-body test is the 2-D ring's only
    ("a NaN", lambda: np.where(np.arange(504).reshape(4, 42, 3) == 7, np.nan, thrown_ball()),
     False, EC.VERDICT_UNDECIDED),
    ("4 points a frame", lambda: thrown_ball()[:, :4], False, EC.VERDICT_UNDECIDED),
])
def test_each_3d_verdict_is_the_checks_warning_or_left_to_them(net3, name, make, normalized,
                                                               verdict):
    x = make()
    for dt in (np.float32, np.float64):
        w = x.astype(dt)
        decided = _decided(net3, w, normalized=normalized)
        assert decided == (verdict != EC.VERDICT_UNDECIDED), name
        if decided:
            _, said = _record(lambda: _first_pass(net3, w, True, normalized))
            assert [k for k, _ in said] == _WARNINGS[verdict], name
            if verdict == EC.VERDICT_RADIUS:
                assert "is a ball of radius 2" in said[0][1]


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(c=st.tuples(*[st.floats(-5, 50)] * 3), r=st.floats(0.05, 5.0),
       v=st.tuples(*[st.floats(-40, 40)] * 3), rows=st.sampled_from([1, 2, 3.9999, 4, 5, 8]),
       noise=st.sampled_from([0.0, 1e-3, 0.3]), seed=st.integers(0, 2 ** 16),
       normalized=st.booleans(), f32=st.booleans(), batch=st.booleans())
def test_whatever_it_decides_in_3d_is_what_the_checks_say(net3, c, r, v, rows, noise, seed,
                                                          normalized, f32, batch):
    rng = np.random.default_rng(seed)
    w = thrown_ball(rows, c, v, r) + noise * rng.standard_normal((4, 42, 3))
    w = w[:, rng.permutation(42)]
    if normalized:
        w = (w - 1.1438) / 42.7124
    w = w.astype(np.float32 if f32 else np.float64)
    _decided(net3, w[None] if batch else w, one=not batch, normalized=normalized)


def test_a_3d_prediction_and_rollout_through_it_are_those_through_the_checks(monkeypatch):
    import tpnet_ref
    from tpnet_ref.engines import numba_rollout
    from tpnet_ref.weights.shipped import REPO_WEIGHTS_DIR
    net = tpnet_ref.load(str(REPO_WEIGHTS_DIR / "tpnet3d-m4-quarter.h5"))
    checked = _without_first_pass(net)
    rng = np.random.default_rng(5)
    for w in (thrown_ball(), rng.uniform(5.4, 39.6, (4, 42, 3)), thrown_ball(1),
              thrown_ball() + [0, 0, 20.0]):
        for x in (w, w.astype(np.float32)):
            assert _first_pass(net, x, True, False) is not None
            fast, said = _record(lambda: net.predict(x))
            slow, said_slow = _record(lambda: checked.predict(x))
            assert fast.tobytes() == slow.tobytes() and said == said_slow
    x = np.stack([thrown_ball(centre=(15.0 + i, 22.0, 30.0)) for i in range(3)])
    assert net.predict_batch(x).tobytes() == checked.predict_batch(x).tobytes()
    # the rollout's steps in one compiled call (3-D too) are the step-by-step path's bits
    assert numba_rollout.fusable(net, 1)
    w = thrown_ball()
    fused, fused_batch = net.rollout(w, 30), net.rollout_batch(x, 12)
    monkeypatch.setattr(numba_rollout, "fusable", lambda model, batch: False)
    assert fused.tobytes() == checked.rollout(w, 30).tobytes()
    assert fused_batch.tobytes() == checked.rollout_batch(x, 12).tobytes()
