"""A 3-D TP-Net (``dim = 3``) through the ONNX export, ``tpnet vectors`` and ``tpnet crosscheck``:
the export run by onnxruntime agrees with the float64 reference to float32 tolerance, the
conformance cases are windows of the 3-D scene (the ``sim3d`` extra), the honest PyTorch / ONNX /
engine paths raise no alarm, and the seven seeded port bugs are named at the layer they are
named at in 2-D (tests/test_conformance.py).

The network is a random one of the quarter structure (tests/property_helpers.py) with 3
coordinates per point and 42 predicted points (the 3-D ball's); expected values come from the
readable forward pass, :func:`tpnet_ref.engines.reference.forward`, which is written for any dim.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from conformance_helpers import SEEDED, crosscheck_seeded_bug, run_cli
from property_helpers import QUARTER
from tpnet_ref.conformance.compare import compare_case, locate
from tpnet_ref.conformance.layer_names import layer_names
from tpnet_ref.conformance.tolerances import measure_tolerances, trace
from tpnet_ref.conformance.vectors import Vectors, read_conformance_vectors
from tpnet_ref.engines import reference
from tpnet_ref.model import TPNet, TPNetConfig, init_random

pytestmark = pytest.mark.lane("3-D")   # in a second test process (tests/lane.py)

CONFIG3D = dataclasses.replace(QUARTER, dim=3, n_out=42)
#: the float32 tolerance of the export against the float64 reference, world units (the box is 45
#: wide; float32 rounds 45 to 4e-6, and the measured gaps of tpnet vectors stay below 1e-4)
ONNX_TOL = 2e-4


@pytest.fixture(scope="module")
def model3d() -> TPNet:
    return init_random(CONFIG3D, seed=5)


@pytest.fixture(scope="module")
def weights3d(tmp_path_factory, model3d) -> Path:
    path = tmp_path_factory.mktemp("w3d") / "net3d.h5"
    model3d.save(str(path))
    return path


@pytest.fixture(scope="module")
def vectors3d(tmp_path_factory, weights3d) -> Path:
    pytest.importorskip("mujoco")
    d = tmp_path_factory.mktemp("vectors3d") / "v"
    rc, out, err = run_cli("vectors", "--weights", weights3d, "-o", d)
    assert rc == 0, err
    assert "9 cases" in out
    return d


def _params64(model: TPNet) -> dict[str, np.ndarray]:
    return {k: np.asarray(v, np.float64) for k, v in model.params.items()}


def _scene_windows(batch: int, n: int, seed: int = 0) -> np.ndarray:
    """``batch`` 3-D windows of ``n`` points per frame in world units: a ball of radius 2 that
    moves through the box, jittered."""
    rng = np.random.default_rng(seed)
    ball = rng.standard_normal((n, 3))
    ball *= 2.0 / np.linalg.norm(ball, axis=1, keepdims=True)
    centre = rng.uniform(10, 35, (batch, 1, 1, 3))
    step = rng.uniform(-1, 1, (batch, 1, 1, 3)) * np.arange(CONFIG3D.m)[None, :, None, None]
    x = centre + step + ball[None, None] + rng.normal(0, 0.02, (batch, CONFIG3D.m, n, 3))
    return x.astype(np.float32)


# --------------------------------------------------------------------------- the ONNX export
def test_export_of_a_3d_model_matches_the_reference(weights3d, model3d, tmp_path):
    onnx = pytest.importorskip("onnx")
    ort = pytest.importorskip("onnxruntime")
    path = tmp_path / "net3d.onnx"
    rc, out, err = run_cli("export", "onnx", "--weights", weights3d, "-o", path)
    assert rc == 0, err
    assert "window (batch, 4, N, 3)" in out and "prediction (batch, 42, 3)" in out
    proto = onnx.load(str(path))
    [inp], [outp] = proto.graph.input, proto.graph.output

    def dims(v):
        return [d.dim_param or d.dim_value for d in v.type.tensor_type.shape.dim]
    assert dims(inp) == ["batch", 4, "N", 3] and dims(outp) == ["batch", 42, 3]
    props = {p.key: p.value for p in proto.metadata_props}
    assert props["dim"] == "3" and props["n_out"] == "42" and props["units"] == "world"
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    p64 = _params64(model3d)
    for batch, n in ((1, 42), (5, 17)):
        x = _scene_windows(batch, n, seed=batch)
        got = sess.run(None, {"window": x})[0]
        want = np.stack([reference.forward(CONFIG3D, p64, list(w.astype(np.float64)))
                         for w in x])
        assert got.shape == (batch, 42, 3) and got.dtype == np.float32
        assert np.abs(got - want).max() <= ONNX_TOL


@pytest.mark.parametrize("cfg", [
    TPNetConfig(dim=3, n_out=42, input_transform_trained=True, feature_transform_trained=True,
                lstm_units=(32, 16, 16)),
    TPNetConfig(dim=3, m=3, lstm_activation="tanh", layer_norm_eps=1e-5, lstm_units=(64, 32, 16)),
], ids=["trained-transforms", "tanh-small"])
def test_onnx_graph_in_model_coordinates_at_dim_3(cfg):
    """The graph on normalised windows against the float64 reference, and an 8-step rollout fed
    back through it (the 2-D tests/test_conformance_onnx.py in 3-D): a 3 x 3 input transform,
    tanh cells, another m."""
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from tpnet_ref.conformance.onnx_peer import onnx_session
    model = init_random(cfg, seed=4, dtype="float64")
    sess = onnx_session(model.astype("float32"), n_points=cfg.n_out)
    x = np.random.default_rng(0).uniform(0, 1, (3, cfg.m, cfg.n_out, 3)).astype(np.float32)
    want = np.stack([reference.forward(cfg, model.params, list(w.astype(np.float64)),
                                       normalized=True) for w in x])
    assert np.abs(sess.run(None, {"window": x})[0] - want).max() <= 1e-5
    frames = list(x[0].astype(np.float64))
    for _ in range(8):
        ref = reference.forward(cfg, model.params, frames[-cfg.m:], normalized=True)
        got = sess.run(None, {"window": np.stack(frames[-cfg.m:])[None].astype(np.float32)})
        assert got[0][0].shape == (cfg.n_out, 3)
        assert np.abs(got[0][0] - ref).max() <= 1e-5
        frames.append(ref)


# --------------------------------------------------------------------------- the vectors
def test_3d_vectors_are_windows_of_the_3d_scene(vectors3d, model3d):
    v = read_conformance_vectors(vectors3d)
    assert v.config == CONFIG3D and v.layers == layer_names(CONFIG3D)
    assert list(v.cases) == ["scene1", "scene2", "shuffled", "ragged", "edge_low", "edge_high",
                             "rollout1", "rollout2", "rollout3"]
    assert "azimuth, elevation, x, y, z" in v.cases["scene1"]["description"]
    assert "x, y and z" in v.cases["edge_low"]["description"]
    p64 = _params64(model3d)
    for c in v.cases:
        a = v.arrays[c]
        assert a["input"].shape[1] == 3 and a["output"].shape == (42, 3)
        assert np.array_equal(a["output"], reference.forward(CONFIG3D, p64, v.window(c)))
    assert v.cases["scene1"]["counts"] == [42] * 4
    assert len(set(v.cases["ragged"]["counts"])) > 1
    np.testing.assert_allclose(v.arrays["shuffled"]["output"], v.arrays["scene1"]["output"],
                               atol=1e-12)
    assert np.allclose(v.arrays["edge_low"]["input"].min(axis=0), CONFIG3D.norm_lo)
    assert np.allclose(v.arrays["edge_high"]["input"].max(axis=0), CONFIG3D.norm_hi)
    assert np.array_equal(v.arrays["rollout2"]["input"][-42:], v.arrays["rollout1"]["output"])
    # the scene windows: a ball of radius about 2 in the box, moving between frames
    for f in v.window("scene1"):
        r = np.linalg.norm(f - f.mean(axis=0), axis=1)
        assert 1.0 < r.mean() < 3.0 and ((f > 0) & (f < 45)).all()
    assert (v.cases["scene1"]["shapes"]["head.sigmoid"], v.cases["scene1"]["shapes"]["input"]) \
        == ([42, 3], [168, 3])


def test_a_2d_model_is_another_network_than_3d_vectors(vectors3d, tmp_path):
    init_random(dataclasses.replace(CONFIG3D, dim=2), seed=5).save(str(tmp_path / "w2.h5"))
    rc, _, err = run_cli("crosscheck", "--vectors", vectors3d, "--model", tmp_path / "w2.h5")
    assert rc == 2 and err.count("\n") == 1
    assert "were made for: dim=2 (vectors: 3)" in err


# --------------------------------------------------------------------------- honest paths
def _crosscheck(vectors: Path, *src) -> tuple[int, dict]:
    rc, out, err = run_cli("crosscheck", "--vectors", vectors, *src, "--json")
    assert rc in (0, 1), err
    return rc, json.loads(out)


def test_3d_onnx_export_and_torch_state_dict_agree(vectors3d, weights3d, model3d, tmp_path):
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    torch = pytest.importorskip("torch")
    from tpnet_ref.training.torch_model import TorchTPNet
    assert run_cli("export", "onnx", "--weights", weights3d, "-o", tmp_path / "n.onnx")[0] == 0
    torch.save(TorchTPNet.from_numpy(model3d).state_dict(), tmp_path / "n.pt")
    for src in (tmp_path / "n.onnx", tmp_path / "n.pt"):
        rc, rep = _crosscheck(vectors3d, "--model", src)
        assert rc == 0 and rep["first_divergence"] is None, (src, rep)
        assert all(c["layers_missing"] == [] for c in rep["cases"].values())


def test_3d_native_file_numpy_engine_agrees(vectors3d, weights3d):
    """The engine's trace runs ``TPNet.predict`` on the 3-D windows."""
    rc, rep = _crosscheck(vectors3d, "--model", weights3d, "--engine", "numpy")
    assert rc == 0 and rep["first_divergence"] is None, rep


def _window_vectors(model: TPNet, window: list[np.ndarray]) -> Vectors:
    want = trace(model.config, model.params, window)
    tol, _ = measure_tolerances(model.config, model.params, [window], [want])
    return Vectors(Path("."), {}, model.config, layer_names(model.config), tol,
                   {"w": {"counts": [len(f) for f in window]}}, {"w": want})


def test_honest_paths_on_3d_hypothesis_windows(model3d):
    torch = pytest.importorskip("torch")
    pytest.importorskip("onnxruntime")
    from hypothesis import HealthCheck, given, settings

    from tpnet_ref.conformance.onnx_peer import build_onnx
    from tpnet_ref.conformance.traces import onnx_trace, onnx_trace_session, torch_trace
    from tpnet_ref.testing import windows
    from tpnet_ref.training.torch_model import TorchTPNet

    torch.set_num_threads(1)
    net = TorchTPNet.from_numpy(model3d).eval()
    sess = onnx_trace_session(build_onnx(model3d, n_points=None, world_units=True), CONFIG3D)

    @settings(max_examples=10, deadline=None, derandomize=True,
              suppress_health_check=list(HealthCheck))
    @given(windows(m=4, n=(3, 40), scales=(0.5, 2.0, 6.0), centre=(8.0, 37.0),
                   step=(0.0, 0.8), dim=3))
    def check(window):
        assert all(f.shape[1] == 3 for f in window)
        v = _window_vectors(model3d, window)
        for label, tr in (("torch", torch_trace(net, window)),
                          ("onnx", onnx_trace(None, window, CONFIG3D, sess))):
            r = compare_case(v, "w", tr)
            assert r.first is None, (label, r.first)

    check()


# --------------------------------------------------------------------------- seeded bugs
@pytest.mark.parametrize("bug", list(SEEDED))
def test_seeded_bug_named_at_its_first_layer_in_3d(bug, vectors3d, model3d, tmp_path):
    pytest.importorskip("torch")
    crosscheck_seeded_bug(model3d, bug, vectors3d, tmp_path)


def test_an_error_in_z_is_located_at_its_coordinate():
    err = np.zeros((42, 3))
    err[7, 2] = 1.0
    for layer in ("head.sigmoid", "output"):
        assert locate(layer, err, 0.5, [42] * 4, CONFIG3D) == {"point": 7, "coordinate": "z"}
    err = np.zeros((168, 16))
    err[42 + 5, 3] = 1.0                         # frame 1, point 5 of the per-point layer
    assert locate("mlp1.0", err, 0.5, [42] * 4, CONFIG3D) == {"frame": 1, "point": 5,
                                                             "channel": 3}


def test_cases_name_the_dims_they_have_scenes_for():
    from tpnet_ref.conformance.cases import make_cases
    cfg = dataclasses.replace(CONFIG3D, dim=4)
    with pytest.raises(ValueError, match="the scenes are 2-D and 3-D, the network takes "
                                         "points of dim=4"):
        make_cases(cfg, {})

