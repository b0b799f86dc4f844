"""The scene-specialised network: exact against the full one on every input, guards that trip
and fall back, an exact round trip through the native weights file."""
from __future__ import annotations

import threading
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import tpnet_ref
from tpnet_ref.sim import dataset as D
from tpnet_ref.engines import layers as L
from tpnet_ref.weights import native
from tpnet_ref.engines import specialised as S
from tpnet_ref.engines import unit_order as U
from tpnet_ref.checks import NonFiniteResultError
from tpnet_ref.engines.numpy_engine import file_order_lstms
from tpnet_ref.model import TPNet, TPNetConfig, init_random

from ring_helpers import SMALL, rings  # noqa: E402


def _rings(rng, n, m=4):
    """Drifting rings with a little noise on every point (:func:`ring_helpers.rings`)."""
    return rings(rng, n, m, wobble=0.05)


@pytest.fixture(scope="module")
def shipped():
    try:
        return tpnet_ref.load()
    except (FileNotFoundError, ValueError) as exc:
        pytest.skip(f"shipped weights not available: {exc}")


@pytest.fixture(scope="module")
def scene(shipped):
    rng = np.random.default_rng(0)
    cal = _rings(rng, 300)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return shipped.specialize(cal)


def _quiet(fn, *a, **k):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fn(*a, **k)


def test_specialised_drops_units_and_equals_the_full_model_on_the_scene(shipped, scene):
    used = S.fraction_used(scene.specialization.used)
    assert used["lstm1"][0] < used["lstm1"][1] and used["global"][0] < used["global"][1]
    assert scene.specialization.num_params() < 0.6 * shipped.num_params
    w = _rings(np.random.default_rng(1), 64)
    scene.counts.update(windows=0, fallbacks=0)
    np.testing.assert_allclose(_quiet(scene.predict_batch, w), _quiet(shipped.predict_batch, w),
                               rtol=0, atol=1e-4)
    assert scene.counts["windows"] == 64
    np.testing.assert_allclose(_quiet(scene.predict, w[0]), _quiet(shipped.predict, w[0]),
                               rtol=0, atol=1e-4)
    np.testing.assert_allclose(_quiet(scene.rollout, w[1], 12), _quiet(shipped.rollout, w[1], 12),
                               rtol=0, atol=1e-3)


@pytest.mark.parametrize("kind", ["random points", "ring far outside the box", "tiny ring",
                                  "huge ring"])
def test_inputs_built_to_trip_the_guards_fall_back_and_stay_exact(shipped, scene, kind):
    rng = np.random.default_rng(2)
    w = _rings(rng, 16)
    centre = w.mean(axis=2, keepdims=True)
    w = {"random points": rng.uniform(0, 45, w.shape),
         "ring far outside the box": w + 300.0,
         "tiny ring": centre + (w - centre) * 0.01,
         "huge ring": centre + (w - centre) * 10}[kind]
    scene.counts.update(windows=0, fallbacks=0)
    np.testing.assert_allclose(_quiet(scene.predict_batch, w), _quiet(shipped.predict_batch, w),
                               rtol=0, atol=1e-4)
    if kind == "ring far outside the box":
        assert scene.counts["fallbacks"] > 0


def test_a_guard_that_trips_sends_exactly_that_window_to_the_full_network(shipped, scene):
    """Force a dropped LSTM-1 unit awake through its bias: the specialised head must flag the
    window (cell pre-activation > 0) and the model must give the full network's answer."""
    used = scene.specialization.used
    dead = int(np.flatnonzero(~used["lstm1"][:512])[0])
    params = dict(shipped.params)
    b = params["lstm1.fwd.bias"].copy()
    b[2 * 512 + dead] = 50.0          # Keras gate order i, f, c, o: the cell candidate
    params["lstm1.fwd.bias"] = b
    full = type(shipped)(shipped.config, params, shipped.dtype)
    spec = full.with_specialization(used)
    w = _rings(np.random.default_rng(3), 5)
    y, ok = spec.specialization(_quiet(full.window_features, w))
    assert not ok.any()
    np.testing.assert_allclose(_quiet(spec.predict_batch, w), _quiet(full.predict_batch, w),
                               rtol=0, atol=1e-4)
    assert spec.counts["fallbacks"] == 5


def test_a_nonzero_dropped_global_feature_falls_back(shipped, scene):
    drop = scene.specialization.g_drop
    w = _rings(np.random.default_rng(6), 1)
    f = _quiet(scene.window_features, w)
    feats = np.concatenate([f, f])
    feats[1, 2, drop[0]] = 1e-3
    _, ok = scene.specialization(feats)
    assert ok[0] and not ok[1]


def test_native_round_trip_is_exact(tmp_path, scene):
    path = tmp_path / "scene.h5"
    scene.save(path)
    back = S.attach(tpnet_ref.load(path), path)
    assert back.specialization is not None
    for k, v in scene.specialization.used.items():
        np.testing.assert_array_equal(back.specialization.used[k], v)
    w = _rings(np.random.default_rng(4), 8)
    assert np.array_equal(_quiet(back.predict_batch, w), _quiet(scene.predict_batch, w))
    plain = tmp_path / "plain.h5"
    tpnet_ref.load().save(plain)
    assert S.read(plain) is None
    again = tmp_path / "again.h5"
    scene.save(again)                                   # TPNet.save keeps the masks too
    assert tpnet_ref.load(again).specialization is not None


def test_hostile_specialisation_groups_are_refused(tmp_path, scene):
    import h5py
    path = tmp_path / "scene.h5"
    scene.save(path)
    name = next(iter(scene.specialization.used))
    with h5py.File(path, "r+") as f:                    # a mask replaced by a link
        f.move(f"{S.GROUP}/{name}", "elsewhere")
        f[f"{S.GROUP}/{name}"] = h5py.SoftLink("/elsewhere")
    with pytest.raises(ValueError, match=f"^{path}: .*links are not accepted"):
        tpnet_ref.load(path)
    with h5py.File(path, "r+") as f:                    # a mask of values other than 0/1
        del f[f"{S.GROUP}/{name}"], f["elsewhere"]
        f[f"{S.GROUP}/{name}"] = np.full(8, 7, np.uint8)
    with pytest.raises(ValueError, match=f"^{path}: .*does not match its content_sha256"):
        tpnet_ref.load(path)                            # not what the writer wrote
    native.seal(path)                                   # and with a digest that matches it
    with pytest.raises(ValueError, match=f"^{path}: .*other than 0 and 1"):
        tpnet_ref.load(path)


def test_float64_specialisation_and_tanh_refused():
    model = init_random(TPNetConfig(lstm_units=(16, 8, 8), mlp2=(16, 32), global_features=16),
                        seed=1, dtype="float64")
    rng = np.random.default_rng(5)
    w = rng.uniform(0.2, 0.8, (20, 4, 30, 2))
    spec = model.specialize(w, normalized=True)
    np.testing.assert_allclose(spec.predict_batch(w, normalized=True),
                               model.predict_batch(w, normalized=True), rtol=0, atol=1e-12)
    assert spec.astype("float32").specialization is not None
    tanh = init_random(TPNetConfig(lstm_activation="tanh", lstm_units=(8, 8, 8)), seed=1)
    with pytest.raises(ValueError, match="ReLU"):
        tanh.specialize(w, normalized=True)


def test_calibration_windows_are_training_grid_windows_and_own_rollouts(monkeypatch):
    """Every window of each picked training-grid trajectory, then every window of the model's own
    rollout from its first m frames; no held-out test case is ever simulated."""
    from tpnet_ref.sim.dataset import train_grid
    from tpnet_ref.sim.protocol import FRAME_EVERY
    from tpnet_ref.sim import TEST_CASES, scene
    small = dict(input_tnet_mlp=(4, 8), input_tnet_fc=(8,), mlp1=(8, 8), feature_tnet_mlp=(8,),
                 feature_tnet_fc=(8,), mlp2=(16, 32), global_features=16, lstm_units=(16, 8, 8))
    model = init_random(TPNetConfig(m=4, **small), seed=0, dtype="float32")
    simulated = []
    real = scene.simulate

    def record(*case, **kw):
        simulated.append(case)
        return real(*case, **kw)
    monkeypatch.setattr(D, "simulate", record)
    w = _quiet(D.calibration_windows, model, n_trajectories=2, seed=5, rollout=3)
    grid = {tuple(c) for c in train_grid()}
    test = {tuple(map(float, c)) for c in TEST_CASES}
    assert len(simulated) == 2 and len(set(simulated)) == 2
    assert all(tuple(c) in grid and tuple(c) not in test for c in simulated)
    np.testing.assert_array_equal(np.array(simulated), D.calibration_cases(2, seed=5))
    traj = real(*simulated[1])[::FRAME_EVERY]                      # (150, 30, 2)
    n_sim, n_own = len(traj) - 3, 4                                # m = 4, rollout 3: 7 frames
    assert w.shape == (2 * (n_sim + n_own), 4, 30, 2)
    second = w[n_sim + n_own:]
    np.testing.assert_array_equal(second[:n_sim], np.stack([traj[s:s + 4] for s in range(n_sim)]))
    own = np.concatenate([traj[:4], _quiet(model.rollout_batch, traj[None, :4], 3)[0]])
    np.testing.assert_allclose(second[n_sim:], np.stack([own[s:s + 4] for s in range(n_own)]),
                               rtol=0, atol=1e-5)     # rolled out in a batch of 2: BLAS rounding
    with pytest.raises(ValueError, match="n_trajectories"):
        D.calibration_cases(0)


# ------------------------------------------------------------ exact on every input
def _units(model, feats):
    """Per window, the largest |value| of every unit of the full network (file order): global
    features ``(B, k)`` and each BiLSTM's outputs ``(B, 2u)`` over all steps."""
    out = {"global": np.abs(feats).max(axis=1)}
    h = feats.transpose(1, 0, 2)
    with np.errstate(over="ignore", invalid="ignore"):
        for i, (fused, gamma, beta) in enumerate(file_order_lstms(model.config, model.params), 1):
            y = L.bilstm_fused(h, *fused, activation="relu", return_sequences=True)
            out[f"lstm{i}"] = np.abs(y).max(axis=0)
            h = L.layer_norm(y, gamma, beta, model.config.layer_norm_eps)
    return out


def _check_head(model, used, feats, tol):
    """The specialised head on ``feats (B, m, k)`` in one batch and window by window: both agree,
    every window it accepts equals the full head, and every window in which a dropped unit is
    clearly awake in the full network (or a dropped global feature is not 0) is flagged."""
    spec = model.with_specialization(used)
    head = spec.specialization
    full = _quiet(model.sequence_head, feats).reshape(len(feats), -1)
    y, ok = _quiet(head, feats)
    one = [_quiet(head, feats[b:b + 1]) for b in range(len(feats))]
    ok1 = np.array([o[0] for _, o in one])
    np.testing.assert_array_equal(ok1, ok)
    np.testing.assert_allclose(np.array([v[0] for v, _ in one])[ok], full[ok], rtol=0, atol=tol)
    np.testing.assert_allclose(y[ok], full[ok], rtol=0, atol=tol)
    units = _units(model, feats)
    awake = (units["global"][:, ~used["global"]] != 0).any(axis=1)
    for name, u in units.items():
        if name != "global":
            awake |= (u[:, ~used[name]] > 1e-3).any(axis=1)
    assert not (ok & awake).any()
    return ok


def _features(model, windows):
    return _quiet(model.window_features, windows, True)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2 ** 16), dtype=st.sampled_from(["float32", "float64"]),
       ordered=st.booleans(), n_cal=st.integers(1, 6), extra=st.floats(0.0, 0.5))
def test_any_masks_any_order_exact_on_accepted_windows_and_flags_woken_units(seed, dtype, ordered,
                                                                            n_cal, extra):
    """Masks calibrated on a few windows, some more units kept at random (any superset is a valid
    specialisation), with or without a random unit order: on fresh windows (many of which wake
    dropped units) the head agrees with the full network wherever it does not flag."""
    rng = np.random.default_rng(seed)
    model = init_random(SMALL, seed=seed % 7, dtype=dtype)
    if ordered:
        model = model.with_unit_order({k: rng.permutation(n) for k, n in U.sizes(SMALL).items()})
    cal = rng.uniform(0.2, 0.8, (n_cal, 4, 30, 2))
    used = {k: v | (rng.random(v.shape) < extra)
            for k, v in S.calibrate(model, cal, normalized=True).items()}
    wins = np.concatenate([rng.uniform(0.2, 0.8, (3, 4, 30, 2)),     # like the calibration
                           rng.uniform(-1.0, 2.0, (3, 4, 30, 2)),    # most wake dropped units
                           cal[:2]])
    ok = _check_head(model, used, _features(model, wins), 2e-5 if dtype == "float32" else 1e-12)
    assert ok[-min(2, n_cal):].all()          # the calibration windows themselves never fall back


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_every_unit_kept_or_dropped(dtype):
    """Extremes: all units kept (nothing guarded) and only one unit per direction kept."""
    model = init_random(SMALL, seed=2, dtype=dtype)
    rng = np.random.default_rng(1)
    feats = _features(model, rng.uniform(0.2, 0.8, (5, 4, 30, 2)))
    tol = 2e-5 if dtype == "float32" else 1e-12
    everything = {k: np.ones(n, bool) for k, n in U.sizes(SMALL).items() if not k.startswith("mlp")}
    assert _check_head(model, everything, feats, tol).all()
    nothing = {k: np.zeros_like(v) for k, v in everything.items()}
    _check_head(model, nothing, feats, tol)


@pytest.mark.parametrize("ordered", [True, False])
@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_shipped_model_with_and_without_unit_order(shipped, scene, ordered, dtype):
    """The shipped model's masks on its unit-ordered layout and on the file's order, float32 and
    float64: predictions, batches and rollouts equal the full model's, trip inputs included."""
    base = shipped if ordered else TPNet(shipped.config, shipped.params)
    assert (base.unit_order is not None) == ordered
    base = base.astype(dtype)
    spec = base.with_specialization(scene.specialization.used)
    rng = np.random.default_rng(7)
    w = _rings(rng, 24)
    w[-4:] = rng.uniform(0, 45, (4, 4, 30, 2))                      # random points
    w[-6:-4] += 300.0                                               # far outside the box
    tol = 1e-4 if dtype == "float32" else 1e-9
    spec.counts.update(windows=0, fallbacks=0)
    np.testing.assert_allclose(_quiet(spec.predict_batch, w), _quiet(base.predict_batch, w),
                               rtol=0, atol=tol)
    assert 0 < spec.counts["fallbacks"] < spec.counts["windows"]
    for b in (0, 20, 22):
        np.testing.assert_allclose(_quiet(spec.predict, w[b]), _quiet(base.predict, w[b]),
                                   rtol=0, atol=tol)
    np.testing.assert_allclose(_quiet(spec.rollout, w[1], 8), _quiet(base.rollout, w[1], 8),
                               rtol=0, atol=10 * tol)
    np.testing.assert_allclose(_quiet(spec.rollout_batch, w[:3], 5),
                               _quiet(base.rollout_batch, w[:3], 5), rtol=0, atol=10 * tol)


def test_one_window_path_equals_the_batch_path_on_the_scene(shipped, scene):
    feats = _features(shipped, shipped.normalize(_rings(np.random.default_rng(8), 40)))
    _check_head(shipped, scene.specialization.used, feats, 2e-6)


def test_a_network_that_overflows_raises_through_the_specialised_one_too():
    """An LSTM output beyond the full network's bound makes it refuse (NonFiniteResultError); the
    specialised network flags the window and so refuses the same way."""
    model = init_random(SMALL, seed=1, dtype="float32")
    w = np.random.default_rng(0).uniform(0.2, 0.8, (3, 4, 30, 2))
    spec = model.specialize(w, normalized=True)
    big = {k: (v * 1e20 if k.startswith("lstm1") and "kernel" in k else v)
           for k, v in model.params.items()}
    huge = TPNet(SMALL, big, "float32")
    with pytest.raises(NonFiniteResultError):
        _quiet(huge.predict, w[0], normalized=True)
    everything = {k: np.ones_like(v) for k, v in spec.specialization.used.items()}
    for used in (spec.specialization.used, everything):     # no guard: the bound must catch it
        s = huge.with_specialization(used)
        with pytest.raises(NonFiniteResultError):
            _quiet(s.predict, w[0], normalized=True)
        with pytest.raises(NonFiniteResultError):
            _quiet(s.predict_batch, w, normalized=True)


def test_windows_from_many_threads_at_once(shipped, scene):
    """One window at a time runs on per-thread buffers: threads do not disturb each other."""
    feats = _features(shipped, shipped.normalize(_rings(np.random.default_rng(9), 12)))
    head = scene.specialization
    want = [_quiet(head, feats[b:b + 1]) for b in range(len(feats))]
    got = {}

    def work(i):
        for rep in range(5):
            for b in range(len(feats)):
                y, ok = _quiet(head, feats[b:b + 1])
                got.setdefault((i, b), []).append((y.copy(), ok.copy()))
    threads = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for (i, b), runs in got.items():
        for y, ok in runs:
            np.testing.assert_array_equal(ok, want[b][1])
            np.testing.assert_array_equal(y, want[b][0])


def test_non_contiguous_features_and_other_dtypes_are_accepted(shipped, scene):
    feats = _features(shipped, shipped.normalize(_rings(np.random.default_rng(10), 3)))
    head = scene.specialization
    wide = np.full(feats.shape[:2] + (2 * feats.shape[2],), 7.0, feats.dtype)
    wide[..., ::2] = feats
    for f in (wide[..., ::2], feats.astype(np.float64), np.asfortranarray(feats)):
        for b in range(len(feats)):
            y, ok = _quiet(head, f[b:b + 1])
            y0, ok0 = _quiet(head, feats[b:b + 1])
            np.testing.assert_array_equal(ok, ok0)
            np.testing.assert_allclose(y, y0, rtol=0, atol=1e-6)


def test_the_saved_masks_are_in_the_file_order_of_units(tmp_path, shipped, scene):
    """The masks the file keeps are the calibration's, unit by unit in the file's order, however
    the model lays its units out (the unit order is the layout's business only)."""
    rng = np.random.default_rng(11)
    cal = _rings(rng, 50)
    plain = TPNet(shipped.config, shipped.params)
    a = _quiet(S.calibrate, shipped, cal)
    b = _quiet(S.calibrate, plain, cal)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    spec = shipped.with_specialization(a)
    path = tmp_path / "s.h5"
    spec.save(path)
    back = S.read(path)
    for k in a:
        np.testing.assert_array_equal(back[k], a[k])


def test_stage_marks_copy_and_pickle_change_nothing(shipped, scene):
    """The profiling hook (bench/bench_specialize.py) marks every stage of one window in order
    and leaves the result alone; a copied or pickled head (no per-thread buffers) agrees."""
    import copy
    import pickle
    feats = _features(shipped, shipped.normalize(_rings(np.random.default_rng(12), 2)))
    head = scene.specialization
    marks = []
    y, ok = _quiet(head, feats[:1], marks)
    y0, ok0 = _quiet(head, feats[:1])
    np.testing.assert_array_equal(y, y0)
    assert ok[0] and ok0[0]
    labels = [label for label, _ in marks]
    assert labels[0] == "BiLSTM 1 input" and labels[-1] == "LayerNorm and dense head"
    assert len(labels) == 4 * len(shipped.config.lstm_units) + 1
    assert all(b >= a for (_, a), (_, b) in zip(marks, marks[1:]))
    for other in (copy.deepcopy(head), pickle.loads(pickle.dumps(head))):
        y1, ok1 = _quiet(other, feats[:1])
        np.testing.assert_array_equal(y1, y0)
        np.testing.assert_array_equal(_quiet(other, feats)[1], _quiet(head, feats)[1])
