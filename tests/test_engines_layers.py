"""The layers: the fused BiLSTM kernel the model runs equals the readable LSTM that specifies it."""
from __future__ import annotations

import numpy as np
import pytest

from tpnet_ref.engines import layers as L
from tpnet_ref.engines.blas import BLOCK_COLUMNS, SMALL_PRODUCT, one_thread


def _direction(rng, c, u, dtype):
    return (rng.normal(size=(c, 4 * u)).astype(dtype) / np.sqrt(c),
            rng.normal(size=(u, 4 * u)).astype(dtype) / np.sqrt(u),
            rng.normal(scale=0.3, size=4 * u).astype(dtype))


@pytest.mark.parametrize("act", ["relu", "tanh"])
@pytest.mark.parametrize("return_sequences", [True, False])
@pytest.mark.parametrize("dtype, atol", [(np.float64, 1e-12), (np.float32, 2e-5)])
@pytest.mark.parametrize("steps, batch", [(1, 1), (4, 1), (4, 3), (5, 2)])
def test_fused_bilstm_equals_the_readable_lstm(act, return_sequences, dtype, atol, steps, batch):
    """bilstm_fused (gates reordered and negated, both directions stepped together, input
    projections in column blocks) gives the readable bidirectional_lstm's numbers."""
    rng = np.random.default_rng(steps * 10 + batch)
    c, u = 96, 40
    fwd, bwd = _direction(rng, c, u, dtype), _direction(rng, c, u, dtype)
    x = rng.normal(size=(batch, steps, c)).astype(dtype)
    want = L.bidirectional_lstm(x, fwd, bwd, act, return_sequences)
    for block_rows in (None, steps * batch):
        fused = L.fuse_bilstm(fwd, bwd, block_rows=block_rows)
        for small in (False, True):
            got = L.bilstm_fused(x.transpose(1, 0, 2), *fused, activation=act,
                                 return_sequences=return_sequences, small=small)
            if return_sequences:
                got = got.transpose(1, 0, 2)
            assert got.dtype == dtype
            np.testing.assert_allclose(got, want, rtol=0, atol=atol)


@pytest.mark.parametrize("act", ["relu", "tanh"])
@pytest.mark.parametrize("return_sequences", [True, False])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_one_direction_after_the_other_gives_the_same_bits(monkeypatch, act, return_sequences,
                                                           dtype):
    """One window whose recurrent weights are large runs one direction after the other
    (DIRECTION_MAJOR_BYTES): the same operations on every number, so the same bits as both
    directions stepped together -- and that path is taken (the threshold decides, not luck)."""
    rng = np.random.default_rng(7)
    c, u, steps = 64, 48, 4
    fused = L.fuse_bilstm(_direction(rng, c, u, dtype), _direction(rng, c, u, dtype))
    xp = rng.normal(size=(steps, c)).astype(dtype) @ fused.kernel
    run = lambda: L.bilstm_steps(xp, fused.recurrent, fused.bias, steps, 1, act,  # noqa: E731
                                 return_sequences)
    monkeypatch.setattr(L, "DIRECTION_MAJOR_BYTES", fused.recurrent[0].nbytes + 1)
    together = run()
    calls = []
    real = L.used_prefixes
    monkeypatch.setattr(L, "used_prefixes", lambda x: calls.append(x.shape[0]) or real(x))
    monkeypatch.setattr(L, "DIRECTION_MAJOR_BYTES", fused.recurrent[0].nbytes)
    apart = run()
    assert calls == [1] * (2 * (steps - 1))          # each direction's steps on its own
    np.testing.assert_array_equal(apart, together)
    assert np.abs(together).max() > 0


def test_readable_bidirectional_lstm_is_two_lstm_directions():
    """The spec itself: forward states, and backward states re-aligned to the input's time."""
    rng = np.random.default_rng(1)
    fwd, bwd = _direction(rng, 5, 3, np.float64), _direction(rng, 5, 3, np.float64)
    x = rng.normal(size=(2, 4, 5))
    y = L.bidirectional_lstm(x, fwd, bwd)
    np.testing.assert_array_equal(y[..., :3], L.lstm(x, *fwd))
    back = L.lstm(x[:, ::-1], *bwd)[:, ::-1]        # run on the reversed sequence, re-align
    np.testing.assert_allclose(y[..., 3:], back, rtol=0, atol=1e-15)
    last = L.bidirectional_lstm(x, fwd, bwd, return_sequences=False)
    np.testing.assert_array_equal(last, np.concatenate([y[:, -1, :3], y[:, 0, 3:]], axis=-1))


def test_column_blocks_fit_the_small_product_bound_and_give_the_product():
    rng = np.random.default_rng(2)
    c, u = 512, 256
    fwd, bwd = _direction(rng, c, u, np.float32), _direction(rng, c, u, np.float32)
    fused = L.fuse_bilstm(fwd, bwd, block_rows=4)
    nblocks, c_in, nb = fused.blocks.shape
    assert c_in == c and nblocks * nb == 8 * u and 4 * c * nb <= SMALL_PRODUCT and nb <= BLOCK_COLUMNS
    np.testing.assert_array_equal(fused.blocks.transpose(1, 0, 2).reshape(c, -1), fused.kernel)
    x = rng.normal(size=(4, c)).astype(np.float32)
    np.testing.assert_allclose(L.project(x, fused.kernel, fused.blocks), x @ fused.kernel,
                               rtol=0, atol=1e-4)
    big = rng.normal(size=(64, c)).astype(np.float32)     # too many rows: the plain product
    np.testing.assert_array_equal(L.project(big, fused.kernel, fused.blocks), big @ fused.kernel)


def test_one_thread_restores_the_blas_threads_after_nesting():
    threadpoolctl = pytest.importorskip("threadpoolctl")

    def blas_threads():
        return [d["num_threads"] for d in threadpoolctl.threadpool_info() if d["user_api"] == "blas"]

    before = blas_threads()
    with one_thread():
        assert all(n == 1 for n in blas_threads())
        with one_thread():
            assert all(n == 1 for n in blas_threads())
        assert all(n == 1 for n in blas_threads())
    assert blas_threads() == before


def test_mlp_max_equals_pool_after_the_last_layer_bit_for_bit():
    """Bias and ReLU moved after the max-pool give the very same bits (monotone rounding)."""
    rng = np.random.default_rng(0)
    for dtype in (np.float32, np.float64):
        x = rng.normal(size=(7 * 13, 5)).astype(dtype)
        layers = [(rng.normal(size=(5, 8)).astype(dtype), rng.normal(size=8).astype(dtype)),
                  (rng.normal(size=(8, 6)).astype(dtype), rng.normal(size=6).astype(dtype))]
        for counts in (np.full(7, 13), np.array([1, 20, 30, 40])):
            want = L.segment_max(L.pointwise_mlp(x, layers), counts)
            assert np.array_equal(L.mlp_max(x, layers, counts), want)


def test_layer_norm_uses_biased_variance_and_eps_inside_the_sqrt():
    x = np.array([[1.0, 2.0, 4.0]])
    eps = 0.5
    d = x - x.mean()
    want = d / np.sqrt((d * d).mean() + eps) * 2.0 + 1.0
    np.testing.assert_allclose(L.layer_norm(x.copy(), np.full(3, 2.0), np.ones(3), eps), want,
                               rtol=0, atol=1e-15)


# ------------------------------------------------------------------ pinned by mutation testing
# (tools/mutation.py: each of these was a surviving mutant of layers.py)
@pytest.mark.parametrize("counts", [[3, 1, 4, 2], [2, 2, 2], [5]])
def test_segment_max_and_apply_transform_per_frame(counts):
    """Ragged frames (np.maximum.reduceat, a loop over frames) and equal ones (one reshape):
    each frame pooled and transformed on its own points alone."""
    rng = np.random.default_rng(len(counts))
    x = rng.normal(size=(sum(counts), 3))
    t = rng.normal(size=(len(counts), 3, 3))
    bounds = np.cumsum([0] + counts)
    frames = [x[a:b] for a, b in zip(bounds[:-1], bounds[1:])]
    assert np.array_equal(L.segment_max(x, np.array(counts)), np.stack([f.max(0) for f in frames]))
    got = L.apply_transform(x, t, np.array(counts))
    want = np.concatenate([f @ tf for f, tf in zip(frames, t)])
    assert got.shape == x.shape and np.allclose(got, want, rtol=1e-12, atol=1e-12)


def test_bilstm_steps_defaults_to_relu_and_every_step():
    rng = np.random.default_rng(5)
    u, steps, bsz = 4, 3, 2
    xp = rng.normal(size=(steps * bsz, 8 * u))
    rec, bias = rng.normal(size=(2, u, 4 * u)), rng.normal(size=8 * u)
    default = L.bilstm_steps(xp, rec, bias, steps, bsz)
    assert default.shape == (steps, bsz, 2 * u)
    assert np.array_equal(default, L.bilstm_steps(xp, rec, bias, steps, bsz, "relu", True))


def test_column_blocks_are_the_widest_that_fit():
    """fuse_bilstm's blocks: the largest divisor nb of the columns with nb <= BLOCK_COLUMNS and
    block_rows * C * nb <= SMALL_PRODUCT (here the product bound binds)."""
    rng = np.random.default_rng(0)
    c, u = 600, 64
    d = [(rng.normal(size=(c, 4 * u)), rng.normal(size=(u, 4 * u)), rng.normal(size=4 * u))
         for _ in range(2)]
    for rows in (4, 40, 400):
        fused = L.fuse_bilstm(*d, block_rows=rows)
        want = max((nb for nb in range(1, BLOCK_COLUMNS + 1)
                    if (8 * u) % nb == 0 and rows * c * nb <= SMALL_PRODUCT), default=None)
        got = None if fused.blocks is None else fused.blocks.shape[2]
        assert got == want, (rows, got, want)


# ------------------------------------------------------------------ found by a fresh mutation sample
# (tools/mutation.py layers --sample 40 --fresh-seed: seed 479556107; docs/testing.md)
@pytest.mark.parametrize("name", ["elu", "gelu", "linear", "RELU", "Tanh", "sigmoid", "swish", ""])
def test_an_unknown_lstm_activation_is_refused_by_name(name):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(1, 3, 2))
    k, r, b = rng.normal(size=(2, 8)), rng.normal(size=(2, 8)), np.zeros(8)
    with pytest.raises(ValueError, match=f"^unknown LSTM activation {name!r}: expected 'relu' "
                                         "or 'tanh'$"):
        L.lstm(x, k, r, b, activation=name)
    for good in ("relu", "tanh"):
        assert L.lstm(x, k, r, b, activation=good).shape == (1, 3, 2)


@pytest.mark.parametrize("spans", [[], [(3, 3)], [(5, 2), (0, 0)]])
def test_a_projection_of_all_zero_columns_is_zero_in_the_given_buffer_too(spans):
    rng = np.random.default_rng(1)
    x, kernel = np.zeros((3, 6), np.float32), rng.normal(size=(6, 5)).astype(np.float32)
    got = L.project_spans(x, kernel, None, spans)
    assert got.dtype == np.float32 and got.shape == (3, 5) and not got.any()
    buf = np.full((3, 5), 7.0, np.float32)
    assert L.project_spans(x, kernel, None, spans, out=buf) is buf
    np.testing.assert_array_equal(buf, np.zeros((3, 5)))


# ------------------------------------------------------------------ found by a fresh mutation sample
# (tools/mutation.py layers --sample 40 --fresh-seed: seed 226287594; docs/testing.md)
@pytest.mark.parametrize("row, used", [([0.0, 0.0, 0.0, 0.0], 0), ([3.0, 0.0, 0.0, 0.0], 1),
                                       ([0.0, -2.0, 0.0, 0.0], 2), ([0.0, 0.0, 0.0, np.nan], 4)])
def test_used_columns_is_one_past_the_last_column_that_is_not_zero(row, used):
    """``used_columns``: one past the last column with a non-zero (or NaN) entry in any row, 0 when
    every entry is zero; with ``start``, counted from ``start``."""
    x = np.array([row, np.zeros(4)])
    assert L.used_columns(x) == used and L.used_columns(x[:1]) == used
    assert L.used_columns(np.concatenate([np.ones((2, 3)), x], axis=1), 3) == used
    assert L.used_columns(np.concatenate([x, np.ones((2, 2))], axis=1), 0, 4) == used


def test_the_folded_layer_norm_product_reads_each_column_once_at_a_range_boundary():
    """Each direction's columns cut after its last non-zero one: non-zeros in the last column of
    one range and the first of the next are each multiplied once, the product equal to
    ``layer_norm(h) @ K``."""
    rng = np.random.default_rng(4)
    h = np.zeros((3, 16))
    h[:, [2, 7, 8]] = rng.normal(size=(3, 3))
    gamma, beta = rng.normal(size=16), rng.normal(size=16)
    kernel = rng.normal(size=(16, 5))
    want = L.layer_norm(h, gamma, beta, 1e-3) @ kernel
    got = L.project_layer_norm(h, gamma, beta, 1e-3, kernel, None, gamma @ kernel, beta @ kernel,
                               [(0, 8), (8, 16)])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
