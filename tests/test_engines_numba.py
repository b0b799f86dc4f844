"""The optional Numba engine equals the NumPy engine (the reference), is deterministic, keeps
permutation invariance bit for bit, and without numba says which extra to install."""
from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("numba")

import tpnet_ref  # noqa: E402
from tpnet_ref.engines import blas  # noqa: E402
from tpnet_ref import model as M  # noqa: E402
from tpnet_ref.config import TPNetConfig  # noqa: E402
from tpnet_ref.extras import MissingExtraError  # noqa: E402
from tpnet_ref.model import init_random  # noqa: E402
from background import early, private_cache  # noqa: E402

SMALL = TPNetConfig(m=3, n_out=5, mlp1=(8, 8), mlp2=(8, 8, 16), global_features=12,
                    lstm_units=(6, 5, 7), input_tnet_mlp=(4, 6), input_tnet_fc=(5,),
                    feature_tnet_mlp=(6,), feature_tnet_fc=(5,))


@pytest.fixture(scope="module")
def released64(released_random64):
    return released_random64


@pytest.fixture(scope="module")
def released_nb64(released64):
    return released64.with_engine("numba")


def _windows(rng, b, m=4, n=30):
    return rng.uniform(5.0, 40.0, size=(b, m, n, 2))


@pytest.mark.parametrize("act", ["relu", "tanh"])
@pytest.mark.parametrize("transforms", [False, True])
@pytest.mark.parametrize("dtype,atol", [("float64", 1e-12), ("float32", 2e-5)])
def test_engine_equals_numpy_on_small_random_nets(act, transforms, dtype, atol):
    cfg = dataclasses.replace(SMALL, lstm_activation=act, input_transform_trained=transforms,
                              feature_transform_trained=transforms)
    ref = init_random(cfg, seed=7, dtype=dtype, transform_scale=0.5)
    nb = ref.with_engine("numba")
    assert nb.engine == "numba" and ref.engine == "numpy"
    rng = np.random.default_rng(1)
    ragged = [rng.uniform(0, 1, size=(n, 2)) for n in (4, 1, 9)]
    np.testing.assert_allclose(nb.predict(ragged, normalized=True),
                               ref.predict(ragged, normalized=True), rtol=0, atol=atol)
    wins = rng.uniform(0, 1, size=(5, 3, 7, 2))
    np.testing.assert_allclose(nb.predict_batch(wins, normalized=True),
                               ref.predict_batch(wins, normalized=True), rtol=0, atol=atol)
    np.testing.assert_allclose(nb.rollout(wins[0], 6, normalized=True),
                               ref.rollout(wins[0], 6, normalized=True), rtol=0, atol=10 * atol)


def test_engine_equals_numpy_float64_on_the_released_shape(released64, released_nb64):
    rng = np.random.default_rng(2)
    wins = _windows(rng, 3)
    for w in wins:
        np.testing.assert_allclose(released_nb64.predict(w), released64.predict(w), rtol=0, atol=1e-10)
    np.testing.assert_allclose(released_nb64.predict_batch(wins), released64.predict_batch(wins),
                               rtol=0, atol=1e-10)
    np.testing.assert_allclose(released_nb64.rollout(wins[0], 8), released64.rollout(wins[0], 8),
                               rtol=0, atol=1e-10)
    np.testing.assert_allclose(released_nb64.rollout_batch(wins, 3),
                               released64.rollout_batch(wins, 3), rtol=0, atol=1e-10)


def test_engine_float32_agrees_with_the_float64_reference(released64, released_nb64):
    nb32 = released_nb64.astype("float32")
    assert nb32.engine == "numba"
    rng = np.random.default_rng(4)
    for w in _windows(rng, 3):
        assert np.abs(nb32.predict(w) - released64.predict(w)).max() < 1e-3   # world units
    w = _windows(rng, 1)[0]
    assert np.abs(nb32.rollout(w, 20) - released64.rollout(w, 20)).max() < 1e-2


def test_engine_result_does_not_depend_on_the_thread_count(released_nb64):
    """Each number is computed by one thread in a fixed order: serial and parallel kernels give
    the same bits, and so does a rollout's first step. Inside a batch the NumPy feature extractor
    multiplies the companions' points in the same BLAS product, which some kernels (OpenBLAS
    Haswell, float32) round differently: equal up to rounding there."""
    nb32 = released_nb64.astype("float32")
    rng = np.random.default_rng(5)
    wins = _windows(rng, 3).astype(np.float32)
    for model in (released_nb64, nb32):
        par = model.predict(wins[0])                    # outside one_thread
        with blas.one_thread():                         # inside (where the model may ask for
            ser = model.predict(wins[0])                # the two-thread kernels)
        assert np.array_equal(par, ser)
        assert np.array_equal(model.rollout(wins[0], 4)[0], par)
        atol = 1e-4 if model.dtype == np.float32 else 1e-10
        np.testing.assert_allclose(model.predict_batch(wins)[0], par, rtol=0, atol=atol)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_permutation_invariance_is_bit_identical_under_the_engine(released_nb64, dtype):
    model = released_nb64.astype(dtype)
    rng = np.random.default_rng(6)
    w = _windows(rng, 1)[0]
    base = model.predict(w)
    for _ in range(3):
        perm = np.stack([f[rng.permutation(len(f))] for f in w])
        assert np.array_equal(model.predict(perm), base)
    roll = model.rollout(w, 3)
    perm = np.stack([f[rng.permutation(len(f))] for f in w])
    assert np.array_equal(model.rollout(perm, 3), roll)


def test_large_batches_take_the_engine_head_and_numpys_features_and_agree(released64,
                                                                           released_nb64):
    """Every batch runs on the engine's head and its feature extractor (a split one's chunks
    too), and agrees with the NumPy engine."""
    rng = np.random.default_rng(8)
    wins = _windows(rng, M.ENGINE_MAX_BATCH + 1)
    for b in (1, len(wins), M.SPLIT_MIN_BATCH + 3):
        assert released_nb64.head_for(b).name == "numba"
    np.testing.assert_allclose(released_nb64.predict_batch(wins), released64.predict_batch(wins),
                               rtol=0, atol=1e-10)
    split = _windows(rng, M.SPLIT_MIN_BATCH + 3)
    np.testing.assert_allclose(released_nb64.predict_batch(split),
                               released64.predict_batch(split), rtol=0, atol=1e-10)
    np.testing.assert_allclose(released_nb64.rollout_batch(wins, 3),
                               released64.rollout_batch(wins, 3), rtol=0, atol=1e-9)


def test_engine_reports_overflow_like_numpy():
    cfg = dataclasses.replace(SMALL, lstm_units=(4, 4, 4))
    ref = init_random(cfg, seed=1, dtype="float32")
    big = {k: (v * 1e20 if k.startswith("lstm1") and "kernel" in k else v)
           for k, v in ref.params.items()}
    ref = M.TPNet(cfg, big, "float32")
    nb = ref.with_engine("numba")
    w = np.random.default_rng(0).uniform(0, 1, size=(3, 7, 2))
    with pytest.raises(tpnet_ref.checks.NonFiniteResultError) as e_ref:
        ref.predict(w, normalized=True)
    with pytest.raises(tpnet_ref.checks.NonFiniteResultError) as e_nb:
        nb.predict(w, normalized=True)
    assert str(e_nb.value).split(" at ")[1].split(" (")[0] == \
        str(e_ref.value).split(" at ")[1].split(" (")[0]


def test_specialised_model_under_the_engine_runs_the_engines_full_network(released64):
    """The numba engine skips zero rows itself and is faster than the specialised NumPy head:
    batches it runs go to its full network (the specialisation is kept, e.g. for saving), larger
    ones to the specialised head."""
    from tpnet_ref.model import ENGINE_MAX_BATCH
    rng = np.random.default_rng(9)
    wins = _windows(rng, 4).astype(np.float32)
    model = released64.astype("float32")
    nb = model.with_engine("numba")
    spec = model.specialize(wins).with_engine("numba")
    assert spec.engine == "numba" and spec.specialization is not None
    np.testing.assert_array_equal(spec.predict(wins[0]), nb.predict(wins[0]))
    np.testing.assert_array_equal(spec.rollout(wins[1], 3), nb.rollout(wins[1], 3))
    assert spec.counts["windows"] == 0
    big = np.concatenate([wins] * (ENGINE_MAX_BATCH // len(wins) + 1))
    np.testing.assert_allclose(spec.predict_batch(big), model.predict_batch(big), atol=1e-3)
    assert spec.counts["windows"] == len(big)


def test_unknown_engine_is_one_line_error(released64):
    with pytest.raises(ValueError, match="engine must be one of"):
        released64.with_engine("torch")


def test_missing_numba_names_the_extra(released64, monkeypatch):
    import tpnet_ref.extras as X
    real = X.importlib.import_module

    def fake(name, *a, **k):
        if name.split(".")[0] == "numba":
            raise ImportError("No module named 'numba'")
        return real(name, *a, **k)

    monkeypatch.setattr(X.importlib, "import_module", fake)
    with pytest.raises(MissingExtraError) as e:
        released64.with_engine("numba")
    msg = str(e.value)
    assert "\n" not in msg and "tpnet-ref[metrics]" in msg and "engine='numba'" in msg


def test_auto_engine_is_numba_when_installed(released64):
    assert released64.with_engine("auto").engine == "numba"


def test_load_runs_the_numba_engine_by_default_where_numba_is_installed():
    assert tpnet_ref.load().engine == "numba"
    assert tpnet_ref.load(engine="numpy").engine == "numpy"


def test_numpy_engine_imports_no_numba(tmp_path):
    path = tmp_path / "w.h5"
    init_random(seed=0).save(path)
    code = ("import sys, numpy as np, tpnet_ref\n"
            f"m = tpnet_ref.load({str(path)!r}, engine='numpy')\n"
            "m.predict(np.random.default_rng(0).uniform(5, 40, (4, 30, 2)))\n"
            "print('numba' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# ------------------------------------------------------------------ the zero-skipping engine
# (products over the non-zero inputs only, LayerNorm folded into BiLSTM 2/3's projections)

from tpnet_ref.engines import numba_engine as EN  # noqa: E402
from tpnet_ref.engines import numba_lstm as NL  # noqa: E402
from tpnet_ref.engines import numba_products as NP  # noqa: E402
from tpnet_ref.engines import numba_tiles as NT  # noqa: E402


@pytest.fixture(scope="module")
def shipped():
    return tpnet_ref.load(engine="numpy")


@pytest.fixture(scope="module")
def scene():
    """Frames of two simulated held-out test cases (world units, one frame every 4 rows): the
    inputs the shipped model sees, with their ReLU zeros."""
    from tpnet_ref.sim import simulate
    from tpnet_ref.sim.cases import TEST_CASES
    return np.stack([simulate(*case, steps=81)[::4] for case in TEST_CASES[:2]])   # (2, 21, 30, 2)


def _scene_windows(scene, n, m=4):
    starts = np.linspace(0, scene.shape[1] - m, n // 2).astype(int)
    return np.stack([traj[s:s + m] for traj in scene for s in starts])


@pytest.mark.parametrize("dtype,atol,roll_atol",
                         [("float32", 1e-4, 2e-3), ("float64", 1e-10, 1e-8)])
def test_shipped_model_on_scene_windows_equals_numpy(shipped, scene, dtype, atol, roll_atol):
    ref = shipped.astype(dtype)
    nb = ref.with_engine("numba")
    wins = _scene_windows(scene, 8)
    # the engine reads zeros out of its products: there must be zeros to skip on these windows
    feats = ref.window_features(wins[:1])
    assert (feats == 0).mean() > 0.5
    for w in wins:
        np.testing.assert_allclose(nb.predict(w), ref.predict(w), rtol=0, atol=atol)
    np.testing.assert_allclose(nb.predict_batch(wins), ref.predict_batch(wins), rtol=0, atol=atol)
    np.testing.assert_allclose(nb.rollout(wins[0], 20), ref.rollout(wins[0], 20), rtol=0,
                               atol=roll_atol)
    np.testing.assert_allclose(nb.rollout_batch(wins[:3], 5), ref.rollout_batch(wins[:3], 5),
                               rtol=0, atol=roll_atol)


def _with_order(model, order):
    """``model`` (engine numba) with its engine laid out in ``order`` (what model.py passes once
    it hands the engine its unit order)."""
    out = model.with_engine("numba")
    out.heads[0] = EN.NumbaHead(out.config, out.params, out.dtype, order, M.ENGINE_MAX_BATCH)
    return out


@pytest.mark.parametrize("dtype,atol", [("float32", 1e-4), ("float64", 1e-10)])
def test_unit_order_layout_equals_the_file_order(shipped, scene, dtype, atol):
    """The engine laid out in the model's unit order (units most used first: the weight rows it
    reads are clustered) computes the same function; a window alone as in the batch (up to the
    feature extractor's rounding, see test_every_window_of_a_batch_...)."""
    assert shipped.unit_order is not None
    ref = shipped.astype(dtype)
    plain = _with_order(ref, None)
    ordered = _with_order(ref, ref.unit_order)
    assert ordered.heads[0].feature_order is not None and plain.heads[0].feature_order is None
    wins = _scene_windows(scene, 6)
    y = ordered.predict_batch(wins)
    np.testing.assert_allclose(y, plain.predict_batch(wins), rtol=0, atol=atol)
    np.testing.assert_allclose(y, ref.predict_batch(wins), rtol=0, atol=atol)
    for w, yb in zip(wins, y):
        np.testing.assert_allclose(ordered.predict(w), yb, rtol=0, atol=atol)


@pytest.mark.parametrize("dtype,atol", [("float32", 2e-4), ("float64", 1e-10)])
def test_random_released_shape_equals_numpy(dtype, atol):
    ref = init_random(seed=11, dtype=dtype)
    nb = ref.with_engine("numba")
    rng = np.random.default_rng(12)
    wins = _windows(rng, 4)
    np.testing.assert_allclose(nb.predict_batch(wins), ref.predict_batch(wins), rtol=0, atol=atol)
    np.testing.assert_allclose(nb.rollout(wins[1], 6), ref.rollout(wins[1], 6), rtol=0,
                               atol=10 * atol)


@pytest.mark.parametrize("dtype,atol", [("float32", 2e-4), ("float64", 1e-10)])
def test_tanh_released_shape_equals_numpy(dtype, atol):
    """tanh: no exact zeros (every weight row read), LayerNorm applied, then the plain product."""
    ref = init_random(dataclasses.replace(TPNetConfig(), lstm_activation="tanh"), seed=13,
                      dtype=dtype)
    nb = ref.with_engine("numba")
    assert nb.heads[0].name == "numba" and not nb.heads[0].relu
    wins = _windows(np.random.default_rng(14), 3)
    np.testing.assert_allclose(nb.predict_batch(wins), ref.predict_batch(wins), rtol=0, atol=atol)
    for w in wins:
        np.testing.assert_allclose(nb.predict(w), ref.predict(w), rtol=0, atol=atol)


@pytest.mark.parametrize("dtype,scale", [("float32", 1e20), ("float64", 1e160)])
def test_far_out_input_overflows_like_numpy(shipped, scene, dtype, scale):
    """A window far outside the training range overflows the ReLU LSTM's state: both engines
    raise NonFiniteResultError naming the same layer (alone and inside a batch)."""
    ref = shipped.astype(dtype)
    nb = ref.with_engine("numba")
    w = scene[0, :4] * scale
    msgs = []
    for model in (ref, nb):
        with pytest.raises(tpnet_ref.checks.NonFiniteResultError) as e:
            model.predict(w)
        msgs.append(str(e.value).split(" at ")[1].split(" (")[0])
        with pytest.raises(tpnet_ref.checks.NonFiniteResultError):
            model.predict_batch(np.stack([scene[0, 4:8], w]))
    assert msgs[0] == msgs[1] and msgs[0].startswith("BiLSTM")


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_every_window_of_a_batch_is_bit_identical_to_it_alone(shipped, scene, dtype):
    """The engine's network computes each window on its own (a row's sums add exactly its own
    non-zero inputs, whatever the rows beside it): from the same features, every batch size the
    engine runs gives each window the bits it gets alone. The features come from the NumPy
    extractor, which multiplies a batch's points in one BLAS product; some kernels (OpenBLAS
    Haswell) round a row differently with other rows beside it, so whole predictions and batched
    rollouts agree with the window alone up to rounding."""
    nb = _with_order(shipped.astype(dtype), shipped.unit_order)
    wins = _scene_windows(scene, M.ENGINE_MAX_BATCH)
    feats = np.stack([nb.frame_features(*_canonical(nb, w)) for w in wins])     # (B, m, k)
    alone = np.stack([nb.sequence_head(f[None])[0] for f in feats])
    atol = 1e-4 if dtype == "float32" else 1e-10
    for b in range(2, M.ENGINE_MAX_BATCH + 1):
        assert nb.head_for(b).name == "numba"
        with blas.one_thread():
            assert np.array_equal(nb.sequence_head(feats[:b]), alone[:b]), b
            assert np.array_equal(nb.sequence_head(feats[::-1][:b]), alone[::-1][:b]), b
        np.testing.assert_allclose(nb.predict_batch(wins[:b]),
                                   np.stack([nb.predict(w) for w in wins[:b]]), rtol=0, atol=atol)
    rolls = nb.rollout_batch(wins[:3], 4)
    for w, r in zip(wins[:3], rolls):
        np.testing.assert_allclose(nb.rollout(w, 4), r, rtol=0,
                                   atol=1e-3 if dtype == "float32" else 1e-9)


def _canonical(model, window):
    """A window's points in the model's canonical order, normalised, and the points per frame."""
    pts = model.normalize(np.concatenate(window).astype(model.dtype))
    counts = np.array([len(f) for f in window])
    return pts[M.canonical_order(pts, counts)], counts


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_serial_and_parallel_kernels_and_thread_counts_give_the_same_bits(shipped, scene, dtype):
    import numba
    head = EN.NumbaHead(shipped.config, shipped.params, np.dtype(dtype), shipped.unit_order)
    wins = _scene_windows(scene, 4)
    feats = shipped.astype(dtype).window_features(wins)
    rows = feats.transpose(1, 0, 2).reshape(16, -1)            # time-major, 4 windows
    base = head.run(head.project_rows(rows, batch=4), 4, 4, parallel=False)
    assert base[1] == 0
    threads = numba.get_num_threads()
    try:
        for n in sorted({1, threads}):
            numba.set_num_threads(n)
            for parallel in (False, True):
                with blas.one_thread():         # where the two-thread kernels run
                    y, bad = head.run(head.project_rows(rows, parallel, batch=4), 4, 4, parallel)
                assert bad == 0 and np.array_equal(y, base[0]), (n, parallel)
    finally:
        numba.set_num_threads(threads)
    # the rows' grouping in project() does not change them either
    assert np.array_equal(head.project_rows(rows, batch=4), head.project_rows(rows))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("rows,steps", [(7, 7), (12, 3), (1, 1)])
def test_product_reads_only_non_zero_inputs_and_rows_are_independent(dtype, rows, steps):
    """The product kernel: equal to the float64 product; a row's result is the same bits whatever
    the other rows of its group (zeros elsewhere, NaN elsewhere) and however the rows are
    grouped; an all-zero input row gives +0; the padding columns stay 0."""
    rng = np.random.default_rng(20)
    c_in, n = 37, 4 * 13                               # 52 columns: padded to whole vectors
    w = rng.standard_normal((c_in, n))
    kern = EN.pad_columns(w, dtype)
    assert kern.shape == (c_in, EN.padded_columns(n, dtype)) and np.all(kern[:, n:] == 0)
    x = rng.standard_normal((rows, c_in)) * (rng.uniform(size=(rows, c_in)) < 0.4)
    x[rows // 2] = 0.0
    x = x.astype(dtype)
    bsz = rows // steps
    out = np.empty((rows, 2, kern.shape[1]), dtype=dtype)
    NT.project_dir(x, kern, out[:, 1], steps, bsz)
    got = out[:, 1]
    tol = 1e-4 if dtype == np.float32 else 1e-12
    np.testing.assert_allclose(got[:, :n], x.astype(float) @ w.astype(dtype).astype(float),
                               atol=tol)
    assert np.all(got[:, n:] == 0)
    assert np.all(got[rows // 2] == 0) and not np.signbit(got[rows // 2]).any()
    for r in range(rows):
        alone = np.empty((1, 2, kern.shape[1]), dtype=dtype)
        NT.project_dir(x[r:r + 1], kern, alone[:, 1], 1, 1)
        assert np.array_equal(alone[0, 1], got[r]), r
    other = np.empty_like(out)                          # grouped as one window of R steps
    NT.project_dir(x, kern, other[:, 1], rows, 1)
    assert np.array_equal(other[:, 1], got)
    poisoned = x.copy()
    poisoned[0, 3] = np.nan
    NT.project_dir(poisoned, kern, other[:, 1], steps, bsz)
    assert np.isnan(other[0, 1]).any()
    assert np.array_equal(other[1:, 1], got[1:])


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_vectorised_exp_and_sigmoid_are_within_a_few_ulp(dtype):
    """The gates' exp (a polynomial, vectorised) within 1.5 ulp of exp where exp(t) is a normal
    number (0 below), the sigmoid within 4 ulp (NumPy's float32 1 / (1 + exp(-x)): 3.3)."""
    from numba import njit

    @njit
    def run(t, e, s, one):
        for i in range(t.shape[0]):
            e[i] = NL._exp_neg(-abs(t[i]))
            s[i] = NL._sigmoid(t[i], one)

    rng = np.random.default_rng(22)
    t = np.concatenate([rng.standard_normal(20000) * 3, rng.uniform(-800, 800, 20000),
                        [0.0, -0.0, 1e-30, 30.0, 87.3, 708.3, np.inf, -np.inf]]).astype(dtype)
    e, s = np.empty_like(t), np.empty_like(t)
    run(t, e, s, dtype(1))
    ref_e = np.exp(-np.abs(t.astype(np.float64)))
    with np.errstate(over="ignore"):
        ref_s = 1.0 / (1.0 + np.exp(-t.astype(np.float64)))
    tiny = np.finfo(dtype).tiny
    normal = ref_e >= 2 * tiny
    ulp = np.spacing(ref_e.astype(dtype)).astype(np.float64)
    assert np.all(np.abs(e - ref_e)[normal] <= 1.5 * ulp[normal])
    assert np.all(e[~normal] <= 2 * tiny) and np.all(e[~normal] >= 0)
    assert np.all(np.abs(s - ref_s) <= 4 * np.spacing(ref_s.astype(dtype)) + 2 * tiny)
    nan = np.array([np.nan], dtype=dtype)
    run(nan, e[:1], s[:1], dtype(1))
    assert np.isnan(e[0]) and np.isnan(s[0])


def _serial_then_parallel(tmp_path: Path) -> None:
    """The serial and parallel kernels are separate functions: numba's cache keeps one compiled
    version per function and signature whatever its ``parallel`` flag, so one function compiled
    both ways would load the serial version for the parallel call. Fresh cache, serial call
    first, then the parallel one must start numba's threads."""
    code = ("import numpy as np, numba\n"
            "from tpnet_ref.model import init_random\n"
            "from tpnet_ref.config import TPNetConfig\n"
            "cfg = TPNetConfig(m=3, n_out=5, mlp1=(8, 8), mlp2=(8, 16), global_features=12,\n"
            "                  lstm_units=(6, 5, 7))\n"
            "head = init_random(cfg, seed=1).with_engine('numba').heads[0]\n"
            "g = np.random.default_rng(0).uniform(0, 1, (3, 12)).astype(np.float32)\n"
            "from tpnet_ref.engines.blas import one_thread\n"
            "a = head.run(head.project_rows(g), 3, 1, parallel=False)\n"
            "with one_thread():\n"
            "    b = head.run(head.project_rows(g, True), 3, 1, parallel=True)\n"
            "assert np.array_equal(a[0], b[0])\n"
            "print(numba.threading_layer())\n")
    env = private_cache(tmp_path)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() in ("omp", "tbb", "workqueue")


@early(_serial_then_parallel)            # a child process compiling in a cache of its own
def test_parallel_kernels_run_on_threads_after_a_cached_serial_compile(early_result):
    """The serial and parallel kernels cached apart (``_serial_then_parallel``)."""


def test_two_threads_only_beside_a_one_thread_blas():
    """The two-thread kernels run only inside blas.one_thread() (beside a multi-threaded BLAS,
    whose threads spin between calls, numba's second thread waits for a core), one call at a
    time."""
    from tpnet_ref.engines.two_thread_gate import LOCK, take
    assert not take(True)
    with blas.one_thread():
        assert not take(False)
        assert take(True)                       # takes the lock ...
        try:
            assert not take(True)               # ... so a second caller runs serially
        finally:
            LOCK.release()
        assert take(True)
        LOCK.release()


@pytest.mark.parametrize("dtype,rtol", [("float32", 1e-5), ("float64", 1e-13)])
def test_compiled_feature_extractor_equals_numpy_and_each_frame_is_its_own(shipped, scene, dtype,
                                                                         rtol):
    """The numba engine's feature extractor: NumPy's numbers up to rounding on scene frames and
    on ragged ones (1 point, more points than a chunk); each frame the same bits alone, in a
    batch, on one thread or two; a NaN point gives its frame NaN features (the head then raises)."""
    import numba

    model = shipped.astype(dtype)
    fx = EN.NumbaFeatures(model.config, model.params, dtype)
    rng = np.random.default_rng(31)
    frames = [f for f in _scene_windows(scene, 4).reshape(-1, 30, 2)]
    frames += [rng.uniform(10, 30, size=(n, 2)) for n in (1, 2, EN.FEATURE_CHUNK + 37, 5)]
    pts, counts = _canonical(model, frames)
    got = fx(pts, counts)
    want = model.features(pts, counts)
    assert got.shape == want.shape == (len(frames), model.config.global_features)
    assert (want == 0).mean() > 0.3                       # zeros to skip, as on the scene
    np.testing.assert_allclose(got, want, rtol=rtol, atol=rtol * np.abs(want).max())
    starts = np.concatenate(([0], np.cumsum(counts)[:-1]))
    for f in range(len(frames)):
        alone = fx(pts[starts[f]:starts[f] + counts[f]], counts[f:f + 1])
        assert np.array_equal(alone[0], got[f]), f
    threads = numba.get_num_threads()
    try:
        for n in sorted({1, threads}):
            numba.set_num_threads(n)
            with blas.one_thread():
                assert np.array_equal(fx(pts, counts, parallel=True), got), n
    finally:
        numba.set_num_threads(threads)
    bad = pts.copy()
    bad[counts[0] + 3] = np.nan
    y = fx(bad, counts)
    assert np.isnan(y[1]).any() and np.array_equal(y[0], got[0]) and np.array_equal(y[2:], got[2:])


def test_the_engine_takes_its_feature_extractor_for_the_batches_its_head_runs(shipped, scene):
    nb = shipped.with_engine("numba")
    assert isinstance(nb.engine_features, EN.NumbaFeatures)
    assert shipped.with_engine("numpy").engine_features is None
    cfg = dataclasses.replace(SMALL, feature_transform_trained=True)
    assert init_random(cfg, seed=1).with_engine("numba").engine_features is None
    w = _scene_windows(scene, 2)[0]
    pts, counts = _canonical(nb, w)
    assert np.array_equal(nb.frame_features(pts, counts, 1), nb.engine_features(pts, counts))
    for batch in (M.ENGINE_MAX_BATCH + 1, 10_000):
        assert np.array_equal(nb.frame_features(pts, counts, batch),
                              nb.engine_features(pts, counts))


_CACHED_RUN = """
import os, sys, numpy as np
from tpnet_ref.config import TPNetConfig
from tpnet_ref.model import init_random
cfg = TPNetConfig(lstm_units=tuple(int(u) for u in sys.argv[1].split(",")), n_out=7,
                  mlp1=(8, 8), mlp2=(8, 16), global_features=12)
w = np.random.default_rng(1).uniform(5, 30, (3, cfg.m, 7, 2))
model = init_random(cfg, seed=0).with_engine("numba")
out = []
for plan in ("1", "2"):            # the one-thread head, then the two-thread one
    os.environ["TPNET_THREADS"] = plan
    out.append(model.predict_batch(w).tobytes().hex())
assert out[0] == out[1], "one and two threads differ"
print(out[0])
"""


def _three_processes(tmp_path: Path) -> list[str]:
    """The three processes of the test below, one after another in one empty cache."""
    env = private_cache(tmp_path)
    got = []
    for units in ("6,5,7", "6,5", "6,5"):
        r = subprocess.run([sys.executable, "-c", _CACHED_RUN, units], env=env,
                           capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, f"{units}: exit {r.returncode}: {r.stderr[-800:]}"
        got.append(r.stdout.strip())
    return got


@early(_three_processes)
def test_numbas_cache_serves_networks_of_any_depth_in_later_processes(early_result):
    """Numba caches each compiled kernel on disk. A cached kernel that called a parallel one
    crashed the next process (numba issues 4807, 10128) once networks of two depths had been
    compiled: here a three-layer network, then a two-layer one, then the two-layer one again
    from the cache (it was a segmentation fault), each in a new process and each on one and
    on two threads; all give what the same networks give in this process."""
    got = early_result
    assert got[1] == got[2]
    for units, hexed in zip(("6,5,7", "6,5"), got[:2]):
        cfg = TPNetConfig(lstm_units=tuple(int(u) for u in units.split(",")), n_out=7,
                          mlp1=(8, 8), mlp2=(8, 16), global_features=12)
        w = np.random.default_rng(1).uniform(5, 30, (3, cfg.m, 7, 2))
        want = init_random(cfg, seed=0).with_engine("numba").predict_batch(w)
        assert np.frombuffer(bytes.fromhex(hexed), dtype=want.dtype).tobytes() == want.tobytes()


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("vectors", [1, 2, 3, 5, 8])
def test_product_kernel_columns_do_not_depend_on_the_others_or_the_grouping(dtype, vectors):
    """``numba_products.product``: each output column is its own chain of multiply-adds over
    the non-zero inputs in order, however many vectors of columns a row has (odd counts take the
    kernel's last single vector after its pairs) and however the rows are grouped (1-4 rows
    per group): a matrix's first columns give the same bits alone and inside a wider matrix, a
    row the same bits in every grouping, and the sums are the products' to rounding."""
    lanes = 64 // np.dtype(dtype).itemsize
    n, c, rows = vectors * lanes, 37, 11
    rng = np.random.default_rng(vectors)
    x = rng.standard_normal((rows, c)).astype(dtype)
    x[rng.random(x.shape) < 0.4] = 0                              # ReLU-like zeros to skip
    w = rng.standard_normal((c, n + lanes)).astype(dtype)         # one vector more

    def run(weights, group_rows):
        grp = np.array([[r, 1, min(group_rows, rows - r)] for r in range(0, rows, group_rows)],
                       dtype=np.intp)
        act = np.empty((len(grp), c), dtype=np.intp)
        ns = np.empty(len(grp), dtype=np.intp)
        NP.active(x, grp, act, ns)
        out = np.empty((rows, weights.shape[1]), dtype=dtype)
        NP.product(x, np.ascontiguousarray(weights), grp, act, ns, out)
        return out

    alone = run(w[:, :n], 4)
    np.testing.assert_array_equal(run(w, 4)[:, :n], alone)
    for g in (1, 2, 3):
        np.testing.assert_array_equal(run(w[:, :n], g), alone)
    tol = 1e-4 if dtype == "float32" else 1e-12
    np.testing.assert_allclose(alone, x.astype(np.float64) @ w[:, :n], rtol=0, atol=tol)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("vectors", [1, 2, 3, 4, 5, 7, 8])
@pytest.mark.parametrize("narrow", [False, True], ids=["wide", "narrow"])
def test_tiled_product_gives_product_s_bits_in_every_tile(dtype, vectors, narrow):
    """``numba_tiles.tiled_plan`` (the feature extractor's tiles, sums held in registers), in
    both register plans: every row and column the bits of ``product`` (one chain over the
    non-zero inputs in order), dense tiles (one to three vectors) and sparse ones (four or more,
    each 4-row tile reading only its non-zero inputs) alike, for any number of rows (the last
    tile's rows past them are computed and ignored), whatever the neighbouring rows hold (NaN
    and inf included)."""
    lanes = 64 // np.dtype(dtype).itemsize
    n, c = vectors * lanes, 37
    rng = np.random.default_rng(100 + vectors)
    w = rng.standard_normal((c, n)).astype(dtype)
    for rows in (1, 3, 4, 7, 8, 13):
        x = np.zeros((-(-rows // NT.TILE_ROWS) * NT.TILE_ROWS, c), dtype=dtype)
        x[:rows] = rng.standard_normal((rows, c))
        x[:rows][rng.random((rows, c)) < 0.5] = 0                   # ReLU-like zeros
        x[:rows][rng.random((rows, c)) < 0.05] = -0.0               # signed zeros are skipped too
        want = np.empty((rows, n), dtype=dtype)
        grp = np.array([[r, 1, 1] for r in range(rows)], dtype=np.intp)
        act, ns = np.empty((rows, c), dtype=np.intp), np.empty(rows, dtype=np.intp)
        NP.active(x[:rows], grp, act, ns)
        NP.product(x[:rows], w, grp, act, ns, want)
        for fill in (0.0, np.nan, np.inf):
            xt = x.copy()
            xt[rows:] = fill                                             # rows past the last
            out = np.full((xt.shape[0], n), 7.0, dtype=dtype)
            NT.tiled_plan(xt, w, rows, np.empty(c, dtype=np.intp), out, narrow)
            np.testing.assert_array_equal(out[:rows].view(np.uint8), want.view(np.uint8))


def test_the_tile_plan_follows_the_cpus_vector_registers():
    """The wide plan only where the host has AVX-512's 32 registers (numba's target here: no
    NUMBA_CPU_NAME or NUMBA_CPU_FEATURES set by the suite); both plans give the same bits
    (above)."""
    from llvmlite import binding as llvm

    from tpnet_ref.engines import numba_codegen as CG
    avx512 = "+avx512f" in llvm.get_host_cpu_features().flatten().split(",")
    assert CG.TILE_PLAN == ("wide" if avx512 else "narrow")
    assert CG.NARROW == (CG.TILE_PLAN == "narrow")


_FEWER_BITS = pytest.mark.lane("fewer-bits")     # their kernels compile there (tests/lane.py)


@pytest.mark.parametrize("codes", ["float32", "float64"] + [
    pytest.param(c, marks=_FEWER_BITS) for c in ("int8", "bf16", "bf16 planes")])
@pytest.mark.parametrize("narrow", [False, True], ids=["wide", "narrow"])
def test_product_rows_gives_product_s_bits_for_every_row_count(codes, narrow):
    """``numba_tiles.rows_plan`` (the prediction network's tiles for batches), in both register
    plans: whole 4-row tiles and the rows left over give, row by row, the bits of ``product`` on
    the same weights, float or codes (int8, bf16 in one plane or two), for 1 to 9 rows."""
    dtype = "float64" if codes == "float64" else "float32"
    lanes = 64 // np.dtype(dtype).itemsize
    rng = np.random.default_rng(len(codes))
    c, n = 29, 5 * lanes
    if codes == "int8":
        w = rng.integers(-127, 128, size=(c, n)).astype(np.int8)
    elif codes.startswith("bf16"):
        w = (rng.standard_normal((2 * c if "planes" in codes else c, n)).astype(np.float32)
             .view(np.uint32) >> 16).astype(np.uint16)
    else:
        w = rng.standard_normal((c, n)).astype(dtype)
    for rows in range(1, 10):
        x = rng.standard_normal((rows, c)).astype(dtype)
        x[rng.random(x.shape) < 0.5] = 0
        grp = np.array([[r, 1, 1] for r in range(rows)], dtype=np.intp)
        act, ns = np.empty((rows, c), dtype=np.intp), np.empty(rows, dtype=np.intp)
        NP.active(x, grp, act, ns)
        want = np.empty((rows, n), dtype=dtype)
        NP.product(x, w, grp, act, ns, want)
        got = np.full((rows, n), 7.0, dtype=dtype)
        NT.rows_plan(x, w, np.empty(c, dtype=np.intp), got, narrow)
        np.testing.assert_array_equal(got.view(np.uint8), want.view(np.uint8))
        got2 = np.full((rows, n), 7.0, dtype=dtype)
        NT.product_rows(x, w, np.empty(c, dtype=np.intp), got2)
        np.testing.assert_array_equal(got2.view(np.uint8), want.view(np.uint8))


def test_a_window_gets_the_same_bits_alone_and_in_a_batch_of_any_size(shipped):
    """The Numba engine's feature extractor serves every batch and its network computes each
    row on its own (tiles of 4 rows across windows included): a window's prediction and rollout
    are the same bits alone and in batches of 2, 9 and 70 windows (a split batch's chunks)."""
    nb = shipped.with_engine("numba")
    rng = np.random.default_rng(70)
    wins = _windows(rng, 70).astype(np.float32)
    alone = np.stack([nb.predict(w) for w in wins[:9]])
    for b in (2, 9, 70):
        np.testing.assert_array_equal(nb.predict_batch(wins[:b])[:min(b, 9)], alone[:min(b, 9)])
    np.testing.assert_array_equal(nb.rollout_batch(wins[:9], 3)[4], nb.rollout(wins[4], 3))


def test_the_directions_go_apart_only_for_batches_with_weight_reads_to_pay_for_it(monkeypatch):
    """``NumbaHead.apart``: two threads for the prediction network's directions only when the
    call's plan offers them and the directions' weight reads reach ``NETWORK_APART_BYTES``."""
    cfg = dataclasses.replace(SMALL, lstm_units=(16, 8, 8))
    head = init_random(cfg, seed=3, dtype="float32").with_engine("numba").head_for(1)
    per = head.direction_bytes
    assert per == sum(a[0].nbytes for a in (*head.kernels, *head.recs))
    monkeypatch.setattr(EN, "NETWORK_APART_BYTES", 3 * per)
    monkeypatch.setattr(EN, "two_threads", lambda: True)
    assert [head.apart(b) for b in (1, 2, 3, 8)] == [False, False, True, True]
    # int8 codes count as the floats they stand for (a quarter of the bytes, the same work)
    from tpnet_ref.weights.convert import with_weights
    q = with_weights(init_random(cfg, seed=3, dtype="float32"), "int8")
    head8 = q.with_engine("numba").head_for(1)
    assert head8.weights == "int8" and head8.recs[0].dtype == np.int8
    assert head8.direction_bytes >= per and [head8.apart(b) for b in (2, 3)] == [False, True]
    monkeypatch.setattr(EN, "two_threads", lambda: False)
    assert not head.apart(8)
