"""The exported ONNX file in OpenVINO (docs/deployment.md, "OpenVINO"): with the precision hint
the page gives, OpenVINO's CPU device agrees with ``predict_batch`` within 1e-4 world units.
Skipped where OpenVINO is not installed (``pip install 'tpnet-ref[openvino]'``)."""
from __future__ import annotations

import numpy as np
import pytest

ov = pytest.importorskip("openvino")
pytest.importorskip("onnx")

import tpnet_ref  # noqa: E402
from tpnet_ref.conformance.onnx_peer import export_onnx  # noqa: E402

BOUND = 1e-4       # world units, as the onnxruntime check of tests/test_conformance_onnx_peer.py


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    model = tpnet_ref.load(engine="numpy")
    path = tmp_path_factory.mktemp("ov") / "tpnet.onnx"
    export_onnx(model, path)
    return model, path


def _windows(batch: int, n: int = 30) -> np.ndarray:
    rng = np.random.default_rng(batch + n)
    base = tpnet_ref.example_window()
    out = []
    for _ in range(batch):                    # the example window moved about the box, shuffled
        w = base + rng.uniform(-8, 8, 2)
        idx = np.sort(rng.choice(base.shape[1], n, replace=n > base.shape[1]))
        out.append(np.stack([f[rng.permutation(idx)] for f in w]))
    return np.asarray(out, dtype=np.float32)


@pytest.mark.parametrize("batch, n", [(1, 30), (64, 30), (4, 45)])
def test_openvino_with_the_f32_hint_agrees_with_predict_batch(exported, batch, n):
    model, path = exported
    core = ov.Core()
    compiled = core.compile_model(str(path), "CPU", {"INFERENCE_PRECISION_HINT": "f32"})
    assert str(compiled.get_property("INFERENCE_PRECISION_HINT")) in ("<Type: 'float32'>", "f32")
    x = _windows(batch, n)
    got = compiled({"window": x})[compiled.output(0)]
    want = model.predict_batch(x)
    assert got.shape == want.shape == (batch, 30, 2)
    assert np.abs(got - want).max() <= BOUND
