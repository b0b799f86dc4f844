"""tpnet_ref.engines.reference, the readable forward pass, is the oracle: first checked against the
scalar implementation of tests/reference_python.py, then every fast path the model runs
(NumPy engine, Numba engine, scene-specialised network; units in the file's order and in the
shipped unit order; float32 and float64) is compared with it at the released shape."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import reference_python as scalar
import tpnet_ref
from tpnet_ref.engines import reference
from tpnet_ref.config import TPNetConfig
from tpnet_ref.model import init_random

TINY = TPNetConfig(m=3, n_out=4, mlp1=(3, 2), mlp2=(3, 2), global_features=2,
                   input_tnet_mlp=(2, 3), input_tnet_fc=(3, 2), feature_tnet_mlp=(2, 3),
                   feature_tnet_fc=(3, 2), lstm_units=(2, 3, 2))


@pytest.mark.parametrize("act", ["relu", "tanh"])
@pytest.mark.parametrize("transforms", [True, False])
def test_reference_equals_the_scalar_implementation(act, transforms):
    cfg = dataclasses.replace(TINY, lstm_activation=act, input_transform_trained=transforms,
                              feature_transform_trained=transforms, layer_norm_eps=0.37)
    model = init_random(cfg, seed=11, dtype="float64", transform_scale=0.5)
    window = [np.random.default_rng(5).uniform(-1, 2, size=(n, 2)) for n in (4, 1, 6)]
    lists = {k: v.tolist() for k, v in model.params.items()}
    want = np.array(scalar.predict_normalized([w.tolist() for w in window], lists, cfg))
    got = reference.forward(cfg, model.params, window, normalized=True)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-13)


def test_reference_refuses_a_window_of_the_wrong_length():
    model = init_random(TINY, seed=1, dtype="float64")
    with pytest.raises(ValueError, match="m=3 frames, got 2"):
        reference.forward(TINY, model.params, [np.zeros((3, 2))] * 2)


def _rings(rng: np.random.Generator, count: int) -> np.ndarray:
    """``count`` windows of a drifting, slightly deformed ring of 30 points (world units)."""
    t = np.linspace(0, 2 * np.pi, 30, endpoint=False)
    out = []
    for _ in range(count):
        c, v = rng.uniform(8, 36, 2), rng.uniform(-0.6, 0.6, 2)
        out.append([np.stack([(2 + 0.1 * rng.standard_normal(30)) * np.cos(t),
                              (2 + 0.1 * rng.standard_normal(30)) * np.sin(t)], 1) + c + i * v
                    for i in range(4)])
    return np.array(out)


@pytest.fixture(scope="module")
def shipped64():
    return tpnet_ref.load(dtype="float64")


@pytest.fixture(scope="module")
def truth(shipped64):
    wins = _rings(np.random.default_rng(3), 6)
    return wins, np.stack([reference.forward(shipped64.config, shipped64.params, w) for w in wins])


@pytest.mark.parametrize("dtype,atol", [("float64", 1e-9), ("float32", 2e-4)])
@pytest.mark.parametrize("order", ["shipped order", "file order"])
@pytest.mark.parametrize("specialised", [False, True])
@pytest.mark.parametrize("engine", ["numpy", "numba"])
def test_every_head_equals_the_reference(shipped64, truth, engine, specialised, order, dtype, atol):
    wins, want = truth
    model = shipped64 if order == "shipped order" else shipped64.with_unit_order(None)
    assert (model.unit_order is None) == (order == "file order")
    model = model.astype(dtype).with_engine(engine)
    if specialised:
        model = model.specialize(_rings(np.random.default_rng(4), 40))
    names = [h.name for h in model.heads]
    assert names == ["numba"] * (engine == "numba") + ["specialised"] * specialised + ["numpy"]
    # each of the model's heads, called through the interface on the same features
    feats = model.window_features(wins)
    for head in model.heads:
        y = model.denormalize(head(feats))
        np.testing.assert_allclose(y, want, rtol=0, atol=atol, err_msg=head.name)
    got = model.predict_batch(wins)
    np.testing.assert_allclose(got, want, rtol=0, atol=atol)
    for w, y in zip(wins[:2], want[:2]):
        np.testing.assert_allclose(model.predict(w), y, rtol=0, atol=atol)
