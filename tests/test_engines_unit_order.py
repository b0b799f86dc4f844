"""Unit order: the NumPy engine's layout with each layer's units most used first. The same
network on every input (any order), saved and loaded with the model, refused when malformed."""
from __future__ import annotations

import warnings

import h5py
import numpy as np
import pytest

import tpnet_ref
from tpnet_ref.engines import layers as L
from tpnet_ref.weights import native
from tpnet_ref.engines import specialised as S
from tpnet_ref.engines import unit_order as U
from tpnet_ref.model import TPNetConfig, init_random

from ring_helpers import SMALL, rings as _rings  # noqa: E402


def _random_order(cfg, rng):
    """A random order of every layer that has one (MLPs, global features, LSTM directions)."""
    return {name: rng.permutation(n) for name, n in U.sizes(cfg).items()}


def test_orders_cover_the_mlps_except_what_a_trained_transform_multiplies():
    assert "mlp1.1" in U.sizes(SMALL) and "mlp2.2" in U.sizes(SMALL)
    tn = TPNetConfig(feature_transform_trained=True)
    assert "mlp1.1" not in U.sizes(tn) and "mlp1.0" in U.sizes(tn)
    for cfg in (TPNetConfig(input_transform_trained=True, feature_transform_trained=True), tn):
        model = init_random(cfg, seed=0)
        use = U.measure(model, _rings(np.random.default_rng(0), 4))
        perm = model.with_unit_order(U.from_use(use))
        w = _rings(np.random.default_rng(1), 3)
        np.testing.assert_allclose(perm.predict_batch(w), model.predict_batch(w), rtol=0, atol=1e-3)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("apart", [False, True])
def test_any_unit_order_is_the_same_network(dtype, apart):
    model = init_random(SMALL, seed=3, dtype=dtype)
    rng = np.random.default_rng(0)
    order = _random_order(SMALL, rng)
    if apart:       # LSTM outputs ordered within each direction (no merge after the recurrence)
        for i, u in enumerate(SMALL.lstm_units, 1):
            order[f"lstm{i}"] = np.concatenate([rng.permutation(u), u + rng.permutation(u)])
    perm = model.with_unit_order(order)
    numpy_head = perm.heads[-1]
    assert numpy_head.name == "numpy"
    assert all((lay.merge is None) == apart for lay in numpy_head.layers)
    w = rng.uniform(0, 45, (16, 4, 30, 2))
    tol = 2e-5 if dtype == "float32" else 1e-11
    np.testing.assert_allclose(perm.predict_batch(w), model.predict_batch(w), rtol=0, atol=tol * 45)
    np.testing.assert_allclose(perm.predict(w[0]), model.predict(w[0]), rtol=0, atol=tol * 45)
    np.testing.assert_allclose(perm.rollout(w[1], 6), model.rollout(w[1], 6), rtol=0,
                               atol=10 * tol * 45)
    # the parameters keep the file's order (only the fast paths' layout follows the order)
    for name, p in model.params.items():
        np.testing.assert_array_equal(perm.params[name], p)


def test_sorted_shipped_model_equals_the_file_order_and_puts_used_units_first():
    try:
        full = tpnet_ref.load()
    except (FileNotFoundError, ValueError) as exc:
        pytest.skip(f"shipped weights not available: {exc}")
    base = full.with_unit_order(None)
    rng = np.random.default_rng(0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cal = _rings(rng, 64)
        srt = base.sort_units(cal)
        use = U.measure(base, cal)
        w = _rings(np.random.default_rng(1), 32)
        np.testing.assert_allclose(srt.predict_batch(w), base.predict_batch(w), rtol=0, atol=1e-4)
        np.testing.assert_allclose(srt.predict(w[0]), base.predict(w[0]), rtol=0, atol=1e-4)
        np.testing.assert_allclose(srt.rollout(w[1], 10), base.rollout(w[1], 10), rtol=0, atol=1e-3)
        far = rng.uniform(-500, 500, (4, 4, 30, 2))        # wakes units the order put last
        np.testing.assert_allclose(srt.predict_batch(far, normalized=False),
                                   base.predict_batch(far), rtol=0, atol=1e-3)
    assert set(srt.unit_order) == set(U.sizes(base.config))
    for name, order in srt.unit_order.items():   # most used units first
        assert np.all(np.diff(use[name][order]) <= 0)
    assert use["global"][srt.unit_order["global"]][-1] == 0    # never-used features last


def test_permutation_invariance_is_bit_identical_with_an_order():
    model = init_random(SMALL, seed=1).with_unit_order(_random_order(SMALL, np.random.default_rng(2)))
    rng = np.random.default_rng(5)
    w = _rings(rng, 1)[0]
    shuffled = np.stack([f[rng.permutation(30)] for f in w])
    assert np.array_equal(model.predict(w), model.predict(shuffled))


def test_unit_order_round_trips_through_the_native_file(tmp_path):
    model = init_random(SMALL, seed=2)
    order = _random_order(SMALL, np.random.default_rng(4))
    perm = model.with_unit_order(order)
    path = tmp_path / "w.h5"
    perm.save(path)
    back = tpnet_ref.load(path, engine=perm.engine)
    assert set(back.unit_order) == set(order)
    for k in order:
        np.testing.assert_array_equal(back.unit_order[k], order[k])
    w = np.random.default_rng(0).uniform(5, 40, (3, 4, 30, 2))
    np.testing.assert_array_equal(back.predict_batch(w), perm.predict_batch(w))
    for k in back.params:                      # the parameters stay in the file's order
        np.testing.assert_array_equal(back.params[k], model.params[k])
    # a specialised copy keeps the order, and saving it keeps both groups
    spec = back.specialize(_rings(np.random.default_rng(1), 16))
    assert spec.unit_order is not None
    spec.save(tmp_path / "s.h5")
    again = tpnet_ref.load(tmp_path / "s.h5")
    assert again.specialization is not None and again.unit_order is not None


@pytest.mark.parametrize("bad, msg", [
    ({"global": np.arange(5)}, "expected 24 integers"),
    ({"global": np.zeros(24, int)}, "not a permutation"),
    ({"lstm2": np.arange(1, 33)}, "not a permutation of 0..31"),
    ({"lstm9": np.arange(4)}, "unknown layers"),
    ({"global": np.linspace(0, 1, 24)}, "expected 24 integers"),
])
def test_a_malformed_order_is_refused_in_one_line(bad, msg):
    with pytest.raises(ValueError, match=msg) as err:
        init_random(SMALL, seed=0).with_unit_order(bad)
    assert "\n" not in str(err.value)


def test_a_malformed_order_group_in_a_file_is_refused(tmp_path):
    path = tmp_path / "w.h5"
    init_random(SMALL, seed=0).save(path)
    U.write(path, {"global": np.arange(24)[::-1].copy()})
    assert tpnet_ref.load(path).unit_order["global"][0] == 23
    with h5py.File(path, "a") as f:
        del f[U.GROUP]["global"]
        f[U.GROUP]["global"] = np.ones(24, np.int32)
    with pytest.raises(ValueError, match=f"^{path}: .*does not match its content_sha256"):
        tpnet_ref.load(path)                     # changed behind the writer's back: refused
    native.seal(path)                            # the same content with a matching digest
    with pytest.raises(ValueError, match=f"^{path}: unit order 'global': not a permutation"):
        tpnet_ref.load(path)
    with h5py.File(path, "a") as f:
        del f[U.GROUP]["global"]
        f[U.GROUP]["global"] = np.ones(24, np.float32)
    native.seal(path)
    with pytest.raises(ValueError, match=f"^{path}: unit_order/global is not a unit order"):
        tpnet_ref.load(path)


# ------------------------------------------------------------------ the layers it relies on
def test_used_columns():
    x = np.zeros((3, 10), np.float32)
    assert L.used_columns(x) == 0
    x[1, 6] = -0.5
    assert L.used_columns(x) == 7 and L.used_columns(x, 0, 5) == 0 and L.used_columns(x, 5) == 2
    x[2, 8] = np.nan                                  # NaN counts as non-zero
    assert L.used_columns(x) == 9
    assert L.used_columns(x[1:2]) == 7


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("rows", [1, 4, 300])
def test_project_spans_and_folded_layer_norm_equal_the_plain_products(dtype, rows):
    rng = np.random.default_rng(rows)
    c, u4 = 64, 128
    fused = L.fuse_bilstm(*[(rng.normal(0, 0.2, (c, u4)).astype(dtype),
                             rng.normal(0, 0.2, (u4 // 4, u4)).astype(dtype),
                             rng.normal(0, 0.1, u4).astype(dtype)) for _ in range(2)], block_rows=4)
    h = np.maximum(rng.normal(0, 1, (rows, c)), 0).astype(dtype)
    h[:, 10:32] = 0                                   # forward half used up to column 10
    h[:, 50:] = 0                                     # backward half up to column 50
    tol = 1e-4 if dtype == np.float32 else 1e-11
    spans = [(0, L.used_columns(h, 0, 32)), (32, 32 + L.used_columns(h, 32))]
    assert spans[0][1] <= 10 and spans[1][1] <= 50
    for blocks in (None, fused.blocks):
        got = L.project_spans(h, fused.kernel, blocks, spans)
        np.testing.assert_allclose(got, h @ fused.kernel, rtol=0, atol=tol)
        for sp in (spans, spans[:1], []):             # into a given buffer: the same bits
            out = np.full((rows, u4 * 2), np.nan, dtype)
            assert L.project_spans(h, fused.kernel, blocks, sp, out=out) is out
            np.testing.assert_array_equal(out, L.project_spans(h, fused.kernel, blocks, sp))
    gamma = rng.uniform(0.5, 1.5, c).astype(dtype)
    beta = rng.normal(0, 0.3, c).astype(dtype)
    gk, bk = gamma @ fused.kernel, beta @ fused.kernel
    want = L.layer_norm(h, gamma, beta, 1e-3) @ fused.kernel
    for fold_max in (0.85, 0.0):                      # the folded path and the plain one
        got = L.project_layer_norm(h, gamma, beta, 1e-3, fused.kernel, fused.blocks, gk, bk,
                                   ((0, 32), (32, 64)), fold_max=fold_max)
        assert got.dtype == dtype
        np.testing.assert_allclose(got, want, rtol=0, atol=10 * tol)
