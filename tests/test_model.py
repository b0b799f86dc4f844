"""The NumPy forward pass: layer semantics, exactness, API equivalences, weights round trip."""
from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest

import tpnet_ref
from tpnet_ref.config import NORM_HI, NORM_LO, TPNetConfig, param_shapes
from tpnet_ref import model as M
from tpnet_ref import point_order
from tpnet_ref.engines import reference
from tpnet_ref.model import init_random


TINY = TPNetConfig(m=3, n_out=3, input_tnet_mlp=(3, 2), input_tnet_fc=(2,), mlp1=(2, 3),
                   feature_tnet_mlp=(2,), feature_tnet_fc=(3, 2), mlp2=(3, 2), global_features=2,
                   lstm_units=(2, 1, 3), input_transform_trained=True,
                   feature_transform_trained=True)


def _window(rng, m=4, n=30, lo=5.0, hi=40.0):
    return rng.uniform(lo, hi, size=(m, n, 2))


@pytest.fixture(scope="module")
def model64(released_random64):
    return released_random64


@pytest.fixture(scope="module")
def model32(model64):
    return model64.astype("float32")


# --------------------------------------------------------------- layer semantics
@pytest.mark.parametrize("act", ["relu", "tanh"])
@pytest.mark.parametrize("transforms", [True, False])
def test_tiny_network_matches_the_reference(act, transforms):
    """The fast paths at a tiny shape with trained transform nets and ragged frames equal the
    readable forward pass (tpnet_ref.engines.reference, itself checked against the scalar code in
    tests/test_engines_reference.py)."""
    cfg = dataclasses.replace(TINY, lstm_activation=act, input_transform_trained=transforms,
                              feature_transform_trained=transforms, layer_norm_eps=0.37)
    model = init_random(cfg, seed=11, dtype="float64", transform_scale=0.5)
    rng = np.random.default_rng(5)
    window = [rng.uniform(-1, 2, size=(n, 2)) for n in (4, 1, 6)]  # ragged on purpose
    got = model.predict(window, normalized=True)
    want = reference.forward(cfg, model.params, window, normalized=True)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-13)


def test_the_model_sees_gate_order_and_eps():
    """Guard the guard: swapping two gates or changing eps must change the answer."""
    cfg = dataclasses.replace(TINY, layer_norm_eps=0.37)
    model = init_random(cfg, seed=2, dtype="float64", transform_scale=0.5)
    window = [np.random.default_rng(1).uniform(0, 1, size=(5, 2)) for _ in range(3)]
    base = model.predict(window, normalized=True)
    p = dict(model.params)
    u = cfg.lstm_units[0]
    for key in ("lstm1.fwd.kernel", "lstm1.fwd.recurrent", "lstm1.fwd.bias"):
        a = p[key].copy()
        a[..., 0:u], a[..., u:2 * u] = p[key][..., u:2 * u], p[key][..., 0:u]  # swap i and f
        p[key] = a
    swapped = type(model)(cfg, p, "float64").predict(window, normalized=True)
    assert np.abs(swapped - base).max() > 1e-6
    other_eps = type(model)(dataclasses.replace(cfg, layer_norm_eps=1e-5), model.params, "float64")
    assert np.abs(other_eps.predict(window, normalized=True) - base).max() > 1e-6


def test_bidirectional_last_output_uses_backward_state_at_first_step():
    """return_sequences=False: backward half = backward LSTM after the whole reversed sequence."""
    from tpnet_ref.engines import layers as L
    rng = np.random.default_rng(0)
    x = rng.normal(size=(2, 5, 3))
    w = [(rng.normal(size=(3, 8)), rng.normal(size=(2, 8)), rng.normal(size=8)) for _ in range(2)]
    full = L.bidirectional_lstm(x, w[0], w[1], "relu", return_sequences=True)
    last = L.bidirectional_lstm(x, w[0], w[1], "relu", return_sequences=False)
    np.testing.assert_array_equal(last[:, :2], full[:, -1, :2])
    np.testing.assert_array_equal(last[:, 2:], full[:, 0, 2:])
    # the backward direction equals a forward LSTM over the time-reversed input, re-aligned
    back = L.lstm(x[:, ::-1].copy(), *w[1], activation="relu")[:, ::-1]
    np.testing.assert_allclose(full[:, :, 2:], back, atol=1e-12)


def test_sigmoid_is_stable_at_extremes():
    from tpnet_ref.engines.layers import sigmoid
    x = np.array([-1e4, -50.0, 0.0, 50.0, 1e4], dtype=np.float32)
    with np.errstate(over="raise", invalid="raise", divide="raise"):
        y = sigmoid(x)
    assert y.dtype == np.float32
    np.testing.assert_allclose(y, [0.0, 1.9287e-22, 0.5, 1.0, 1.0], rtol=1e-4, atol=0)


# ------------------------------------------------------------------ the network
def test_released_shapes_and_parameter_count():
    full = TPNetConfig(input_transform_trained=True, feature_transform_trained=True)
    shapes = param_shapes(full)
    assert shapes["input_tnet.out.w"] == (128, 4) and shapes["feature_tnet.out.w"] == (128, 4096)
    assert shapes["lstm1.fwd.kernel"] == (128, 2048) and shapes["lstm1.fwd.recurrent"] == (512, 2048)
    assert shapes["lstm2.bwd.kernel"] == (1024, 1024) and shapes["lstm3.fwd.kernel"] == (512, 1024)
    assert shapes["ln1.gamma"] == (1024,) and shapes["head.w"] == (512, 60)
    n_full = sum(int(np.prod(s)) for s in shapes.values())
    assert n_full == 8_112_192  # docs/spec.md §2: "about 8.1 million"
    n_released = sum(int(np.prod(s)) for s in param_shapes(TPNetConfig()).values())
    assert n_released < n_full  # identity transform nets carry no parameters


def test_output_shape_range_and_units(model32):
    rng = np.random.default_rng(0)
    y = tpnet_ref.predict(_window(rng), model=model32)
    assert y.shape == (30, 2) and y.dtype == np.float32
    assert np.all(y >= NORM_LO - 1e-4) and np.all(y <= NORM_HI + 1e-4)  # sigmoid head, denormalised
    yn = model32.predict(model32.normalize(_window(np.random.default_rng(0))), normalized=True)
    np.testing.assert_allclose(model32.denormalize(yn), y, atol=1e-4)


def test_predict_batch_equals_predict(model32, model64):
    rng = np.random.default_rng(1)
    windows = np.stack([_window(rng) for _ in range(7)])
    for model, tol in ((model64, 1e-11), (model32, 5e-4)):
        batch = tpnet_ref.predict_batch(windows, model=model)
        single = np.stack([tpnet_ref.predict(w, model=model) for w in windows])
        assert batch.shape == (7, 30, 2)
        np.testing.assert_allclose(batch, single, rtol=0, atol=tol)


def test_blocked_feature_extractor_matches_per_window(model64):
    """Batches larger than one block of the extractor (2048 points) give the per-window result."""
    rng = np.random.default_rng(8)
    windows = [[rng.uniform(5, 40, size=(n, 2)) for n in rng.integers(1, 200, size=4)]
               for _ in range(12)]
    assert sum(len(f) for w in windows for f in w) > 2048
    batch = tpnet_ref.predict_batch(windows, model=model64)
    single = np.stack([tpnet_ref.predict(w, model=model64) for w in windows])
    np.testing.assert_allclose(batch, single, rtol=0, atol=1e-11)
    big = np.stack([_window(rng, n=64) for _ in range(20)])
    np.testing.assert_allclose(model64.predict_batch(big),
                               np.stack([model64.predict(w) for w in big]), rtol=0, atol=1e-11)


def test_ragged_windows_and_batches(model64):
    rng = np.random.default_rng(2)
    frames = [rng.uniform(5, 40, size=(n, 2)) for n in (30, 7, 1, 64)]
    y = tpnet_ref.predict(frames, model=model64)
    assert y.shape == (30, 2) and np.isfinite(y).all()
    # duplicating points leaves the max-pooled features, hence the prediction, unchanged
    dup = [np.concatenate([f, f[: max(1, len(f) // 2)]]) for f in frames]
    np.testing.assert_allclose(tpnet_ref.predict(dup, model=model64), y, rtol=0, atol=1e-11)
    other = _window(rng)
    batch = tpnet_ref.predict_batch([frames, other, dup], model=model64)
    np.testing.assert_allclose(batch[0], y, atol=1e-11)
    np.testing.assert_allclose(batch[1], tpnet_ref.predict(other, model=model64), atol=1e-11)


def test_float32_agrees_with_float64(model32, model64):
    rng = np.random.default_rng(4)
    windows = np.stack([_window(rng) for _ in range(16)])
    d1 = np.abs(model32.predict_batch(windows) - model64.predict_batch(windows)).max()
    assert d1 < 1e-3  # world units (1e-3 / 42.7 ~ 2.3e-5 in model coordinates)
    d80 = np.abs(model32.rollout(windows[0], 80) - model64.rollout(windows[0], 80)).max()
    assert d80 < 1e-2


def test_rollout_slides_the_window(model64):
    rng = np.random.default_rng(5)
    w = model64.normalize(_window(rng))
    out = tpnet_ref.rollout(w, 6, model=model64, normalized=True)
    assert out.shape == (6, 30, 2)
    frames = list(w)
    for s in range(6):
        want = model64.predict(np.stack(frames[-4:]), normalized=True)
        np.testing.assert_allclose(out[s], want, rtol=0, atol=1e-12)
        frames.append(want)
    np.testing.assert_allclose(tpnet_ref.rollout(model64.denormalize(w), 6, model=model64),
                               model64.denormalize(out), atol=1e-9)


def test_rollout_computes_each_frame_feature_once(model64, monkeypatch):
    calls = []
    orig = type(model64).frame_features

    def counting(self, points, counts, batch=None):
        calls.append(len(counts))
        return orig(self, points, counts, batch)

    monkeypatch.setattr(type(model64), "frame_features", counting)
    model64.rollout(_window(np.random.default_rng(6)), 10)
    assert sum(calls) == 4 + 10  # m initial frames + one per predicted frame (the last unused)


def test_rollout_projects_each_frame_into_the_first_lstm_once(model64, monkeypatch):
    """BiLSTM 1's input projection is a function of one frame: a rollout computes it once per
    frame and reuses it for the m - 1 frames its windows share (same output as predict)."""
    rows = []
    orig = type(model64).project_frames

    def counting(self, features, batch=1):
        rows.append(len(features))
        return orig(self, features, batch)

    monkeypatch.setattr(type(model64), "project_frames", counting)
    w = model64.normalize(_window(np.random.default_rng(8)))
    out = model64.rollout(w, 10, normalized=True)
    assert sum(rows) == 4 + 10 - 1          # m initial frames + each predicted frame but the last
    want = model64.predict(np.concatenate([w[2:], out[:2]]), normalized=True)
    np.testing.assert_allclose(out[2], want, rtol=0, atol=1e-12)


def test_canonical_order_small_and_large_paths_give_the_same_indices(monkeypatch):
    """Few points are sorted by one lexsort, many by row-wise argsorts: same indices, ties too."""
    rng = np.random.default_rng(9)
    for counts in (np.full(4, 30), np.array([5, 1, 40, 17])):
        pts = np.round(rng.uniform(0, 3, (int(counts.sum()), 2)), 0)     # many exact ties
        small = M.canonical_order(pts, counts)
        monkeypatch.setattr(point_order, "SMALL_SORT", 0)
        large = M.canonical_order(pts, counts)
        monkeypatch.undo()
        np.testing.assert_array_equal(small, large)
        ends = np.cumsum(counts)
        for f0, f1 in zip(np.concatenate(([0], ends[:-1])), ends):   # sorted within each frame
            seg = pts[small[f0:f1]]
            assert np.all(small[f0:f1] >= f0) and np.all(small[f0:f1] < f1)
            assert all(tuple(a) <= tuple(b) for a, b in zip(seg[:-1], seg[1:]))


def test_tanh_switch_changes_the_cell():
    cfg = TPNetConfig(lstm_activation="tanh")
    a = init_random(cfg, seed=1, dtype="float64")
    b = type(a)(TPNetConfig(), a.params, "float64")
    w = _window(np.random.default_rng(7))
    ya, yb = a.predict(w), b.predict(w)
    assert np.isfinite(ya).all() and np.abs(ya - yb).max() > 1e-6


# ------------------------------------------------------------- weights round trip
@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_native_round_trip_is_bit_exact(tmp_path, dtype):
    cfg = dataclasses.replace(TINY, lstm_activation="tanh", norm_lo=-3.0, norm_hi=7.5)
    model = init_random(cfg, seed=9, dtype=dtype)
    path = tmp_path / "w.h5"
    model.save(path, source="unit test")
    back = tpnet_ref.load(path, dtype=dtype, engine=model.engine)   # the same engine: same bits
    assert back.config == cfg
    assert back.meta["source"] == "unit test" and "created" in back.meta
    for k, v in model.params.items():
        assert back.params[k].dtype == v.dtype
        np.testing.assert_array_equal(back.params[k], v)
    w = [np.random.default_rng(0).uniform(-2, 6, size=(5, 2)) for _ in range(3)]
    np.testing.assert_array_equal(back.predict(w), model.predict(w))


def test_load_without_shipped_weights_says_so(tmp_path, monkeypatch):
    monkeypatch.setenv("TPNET_WEIGHTS_DIR", str(tmp_path))
    with pytest.raises(FileNotFoundError, match="no shipped weights"):
        tpnet_ref.load()


def test_load_refuses_a_foreign_hdf5(tmp_path):
    import h5py
    path = tmp_path / "foreign.h5"
    with h5py.File(path, "w") as f:
        f["x"] = np.zeros(3)
    with pytest.raises(ValueError, match="not a tpnet_ref weights file"):
        tpnet_ref.load(path)


# ------------------------------------------------------------------ bad input
@pytest.mark.parametrize("bad, exc, msg", [
    (np.zeros((3, 30, 2)), ValueError, "m=4"),
    (np.zeros((4, 30, 3)), ValueError, "shape"),
    (np.zeros((4, 0, 2)), ValueError, "empty"),
    (np.full((4, 30, 2), np.nan), ValueError, "NaN"),
    (np.full((4, 30, 2), "a"), TypeError, "real numbers"),
    (np.zeros((4, 30, 2), dtype=complex), TypeError, "real numbers"),
    ([np.zeros((3, 2))] * 3, ValueError, "m=4"),
    ([np.zeros((3, 2)), np.zeros((3, 2)), np.zeros((3, 2)), np.zeros(3)], ValueError, r"window\[3\]"),
])
def test_bad_windows_get_clear_errors(model32, bad, exc, msg):
    with pytest.raises(exc, match=msg):
        model32.predict(bad)


def test_bad_rollout_steps(model32):
    w = _window(np.random.default_rng(0))
    for steps in (0, -1, 2.5, True):
        with pytest.raises(ValueError, match="steps"):
            model32.rollout(w, steps)


def test_import_is_light():
    code = (
        "import sys, numpy as np, tpnet_ref\n"
        "from tpnet_ref.model import init_random\n"
        "m = init_random(seed=0)\n"
        "tpnet_ref.predict(np.random.default_rng(0).uniform(5, 40, (4, 30, 2)), model=m)\n"
        "tpnet_ref.rollout(np.random.default_rng(0).uniform(5, 40, (4, 30, 2)), 2, model=m)\n"
        "bad = [k for k in ('numba', 'torch', 'tensorflow', 'keras', 'jax', 'pymunk', 'scipy')\n"
        "       if k in sys.modules]\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"predict imported {out.stdout.strip()}"


def test_rollout_batch_equals_rollout_per_window(model64):
    rng = np.random.default_rng(12)
    windows = [_window(rng), [rng.uniform(5, 40, size=(n, 2)) for n in (3, 30, 9, 1)]]
    got = model64.rollout_batch(windows, 5)
    assert got.shape == (2, 5, 30, 2)
    for b, w in enumerate(windows):
        np.testing.assert_allclose(got[b], model64.rollout(w, 5), rtol=0, atol=1e-10)
    with pytest.raises(ValueError, match="steps"):
        model64.rollout_batch(windows, 0)


def test_large_batches_split_across_threads_give_the_unsplit_results(model32, model64):
    """A batch of SPLIT_MIN_BATCH windows or more runs in fixed chunks on threads (one-thread BLAS
    each): the same bits on one thread as on three (the chunks depend on the batch size alone),
    uneven chunks and ragged windows included, still exactly invariant to per-frame
    permutations, and the BLAS gets its threads back afterwards."""
    from threadpoolctl import threadpool_info

    from tpnet_ref.model import SPLIT_MIN_BATCH
    rng = np.random.default_rng(21)
    b = SPLIT_MIN_BATCH + 7
    wins = [_window(rng) for _ in range(b - 1)]
    wins.append([rng.uniform(5, 40, size=(n, 2)) for n in (3, 30, 9, 1)])
    blas_before = [d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"]
    for model in (model64, model32):
        one, three = model.astype(model.dtype), model.astype(model.dtype)
        one.threads, three.threads = 1, 3
        want = one.predict_batch(wins)
        got = three.predict_batch(wins)
        assert got.shape == (b, 30, 2)
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(three.rollout_batch(wins, 3), one.rollout_batch(wins, 3))
        shuffled = [[f[rng.permutation(len(f))] for f in w] for w in wins]
        assert np.array_equal(three.predict_batch(shuffled), got)
    assert [d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"] == blas_before
    # an overflow in one part reaches the caller as the documented error, not NaN
    from tpnet_ref.checks import NonFiniteResultError
    huge = np.stack([_window(rng) for _ in range(b)])
    huge[-1] *= 1e30
    with pytest.raises(NonFiniteResultError):
        model32.predict_batch(huge)


def test_the_model_warns_like_the_package_functions():
    """One behaviour: TPNet.predict / rollout / predict_batch give the warnings that
    tpnet_ref.predict gives, pointing at the caller's line."""
    import warnings
    from tpnet_ref.checks import NotOneBodyWarning, OutsideTrainingRangeWarning
    model = tpnet_ref.load()
    w = tpnet_ref.example_window()
    stray = w.copy()
    stray[2, 5] += 6.0                                  # one stray point in one frame
    calls = {"TPNet.predict": lambda x: model.predict(x),
             "tpnet_ref.predict": lambda x: tpnet_ref.predict(x, model=model),
             "TPNet.rollout": lambda x: model.rollout(x, 2)}
    for name, call in calls.items():
        for x, kind in ((w, None), (stray, NotOneBodyWarning), (w + 40, OutsideTrainingRangeWarning)):
            with warnings.catch_warnings(record=True) as got:
                warnings.simplefilter("always")
                call(x)
            assert [type(g.message) for g in got] == ([] if kind is None else [kind]), name
            assert all(g.filename == __file__ for g in got), name
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        model.predict_batch(np.stack([w, w + 40]))
    assert [type(g.message) for g in got] == [OutsideTrainingRangeWarning]
