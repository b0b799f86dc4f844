"""tpnet_ref.sim.protocol: frame indexing of the protocol, the two baselines, the input orderings.
"""
from __future__ import annotations


import numpy as np
import pytest

pytest.importorskip("h5py")

from tpnet_ref import evaluation as E  # noqa: E402
from tpnet_ref.sim import protocol as P  # noqa: E402



def test_protocol_constants():
    """One model frame every 4 simulator rows of dt = 1/45 s, 600 rows, the paper's horizons."""
    assert (P.FRAME_EVERY, P.SIM_ROWS, P.HORIZONS) == (4, 600, (40, 80))
    assert P.REFERENCE_DT == pytest.approx(1 / 45)
    assert P.ORDERINGS[0] == "given" and len(set(P.ORDERINGS)) == 4
    assert E.copy_last is P.copy_last and E.FRAME_EVERY == P.FRAME_EVERY   # re-exported


def test_split_protocol_frame_indexing():
    C, F = 2, 20
    frames = np.broadcast_to(np.arange(F, dtype=float)[None, :, None, None], (C, F, 5, 2))
    for m in (3, 4, 5):
        inputs, targets = P.split_protocol(frames, m, 7)
        assert inputs[0, :, 0, 0].tolist() == list(range(m))              # frames 0..m-1
        assert targets[0, :, 0, 0].tolist() == list(range(m, m + 7))      # h-th -> frame m-1+h
    with pytest.raises(ValueError, match="too short"):
        P.split_protocol(frames, 4, 17)


def uniform_motion(C=2, F=12, N=6, v=(0.01, -0.02)):
    """Points 1 apart on a line, all moving by ``v`` per frame."""
    base = np.stack([np.arange(N, dtype=float), np.zeros(N)], axis=1)
    base = base[None] + np.arange(C)[:, None, None] * 3.0
    return base[:, None] + np.arange(F)[None, :, None, None] * np.asarray(v)


def test_constant_velocity_exact_on_uniform_motion():
    frames = uniform_motion()
    inputs, targets = P.split_protocol(frames, 4, 8)
    pred = P.constant_velocity(inputs, 8)
    np.testing.assert_allclose(pred, targets, atol=1e-12)
    err = E.errors(targets, pred)
    for k, v in err.items():
        assert v.shape == (2, 8) and np.abs(v).max() < 1e-10, k


def test_copy_last_error_equals_displacement():
    v = np.array([0.01, -0.02])
    N, H = 6, 8
    frames = uniform_motion(N=N, v=v)
    inputs, targets = P.split_protocol(frames, 4, H)
    pred = P.copy_last(inputs, H)
    np.testing.assert_array_equal(pred, np.broadcast_to(inputs[:, -1:], pred.shape))
    err = E.errors(targets, pred)
    d = np.arange(1, H + 1) * np.linalg.norm(v)        # displacement after h frames
    # every point's nearest neighbour is its own displaced copy (spacing 1 >> displacement)
    np.testing.assert_allclose(err["Ep_released"], np.broadcast_to(2 * N * d, (2, H)), rtol=1e-12)
    np.testing.assert_allclose(err["Ep_squared"], np.broadcast_to(2 * N * d ** 2, (2, H)),
                               rtol=1e-12)
    np.testing.assert_allclose(err["Ep_paper"], np.broadcast_to(2 * d ** 2, (2, H)), rtol=1e-12)
    assert np.abs(err["Es_released"]).max() < 1e-12        # a translation keeps the shape


def test_orderings_really_permute():
    rng = np.random.default_rng(5)
    w = rng.random((3, 4, 30, 2))
    key = lambda a: np.sort(a.view([("x", float), ("y", float)])[..., 0], axis=-1)  # noqa: E731
    assert np.array_equal(P.order_points(w, "given"), w)
    for o in P.ORDERINGS:
        got = P.order_points(w, o, seed=1)
        assert got.shape == w.shape
        assert np.array_equal(key(got), key(w))             # same points in every frame
    ax = P.order_points(w, "ascending_x")
    assert (np.diff(ax[..., 0], axis=-1) >= 0).all() and not np.array_equal(ax, w)
    dy = P.order_points(w, "descending_y")
    assert (np.diff(dy[..., 1], axis=-1) <= 0).all() and not np.array_equal(dy, w)
    sh = P.order_points(w, "shuffle", seed=1)
    assert not np.array_equal(sh, w)
    perms = [tuple(np.argsort(np.argsort(sh[0, f, :, 0]))) for f in range(4)]
    assert len(set(perms)) > 1                               # frames shuffled independently
    assert np.array_equal(sh, P.order_points(w, "shuffle", seed=1))      # deterministic
    with pytest.raises(ValueError, match="ordering"):
        P.order_points(w, "sideways")
