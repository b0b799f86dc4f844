"""The NumPy forward pass against onnxruntime, an independent implementation of the same ops.

The graph is built by ``tpnet_ref.conformance.onnx_peer`` from the NumPy model's weights: onnxruntime's own
LSTM kernel (activations Sigmoid/Relu/Relu, gates converted to ONNX order i,o,f,c), its ReduceMax
and LayerNormalization. Agreement within 1e-5 checks gate order, the ReLU cell, the backward
direction's alignment, the final-output convention and LayerNorm eps against code we did not write.
"""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")

from tpnet_ref.model import TPNetConfig, init_random  # noqa: E402
from tpnet_ref.conformance.onnx_peer import onnx_session  # noqa: E402


@pytest.mark.parametrize("cfg", [
    TPNetConfig(),
    TPNetConfig(input_transform_trained=True, feature_transform_trained=True),
    TPNetConfig(m=3, lstm_activation="tanh", layer_norm_eps=1e-5, lstm_units=(64, 32, 16)),
], ids=["released", "trained-transforms", "tanh-small"])
def test_numpy_matches_onnxruntime(cfg):
    model = init_random(cfg, seed=4, dtype="float64")
    sess = onnx_session(model.astype("float32"))
    x = np.random.default_rng(0).uniform(0, 1, (5, cfg.m, 30, 2)).astype(np.float32)
    want = sess.run(None, {"window": x})[0]
    for dtype in ("float32", "float64"):
        got = model.astype(dtype).predict_batch(x.astype(dtype), normalized=True)
        assert np.abs(got - want).max() <= 1e-5, dtype
    # an 8-step recursive rollout, the prediction fed back as the newest frame each time
    frames = list(x[0].astype(np.float64))
    roll = model.rollout(x[0].astype(np.float64), 8, normalized=True)
    for s in range(8):
        nxt = sess.run(None, {"window": np.stack(frames[-cfg.m:])[None].astype(np.float32)})[0][0]
        frames.append(nxt.astype(np.float64))
        assert np.abs(roll[s] - nxt).max() <= 1e-5
