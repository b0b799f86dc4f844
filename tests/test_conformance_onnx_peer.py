"""``tpnet export onnx`` (tpnet_ref.cli.export, tpnet_ref.conformance.onnx_peer.export_onnx): the written
file, run by onnxruntime, gives what ``predict_batch`` gives, in world units, for any batch and
any number of points per frame."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")

import tpnet_ref  # noqa: E402
from tpnet_ref.cli import main  # noqa: E402
from tpnet_ref.model import TPNetConfig, init_random  # noqa: E402


def _session(path):
    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])


def _windows(batch: int, n: int, seed: int = 0) -> np.ndarray:
    """``batch`` windows of ``n`` points per frame in world units near the example window: its
    frames, moved and jittered, with points added between neighbours for ``n`` > 30."""
    rng = np.random.default_rng(seed)
    w = tpnet_ref.example_window().astype(np.float64)
    if n > 30:
        extra = 0.5 * (w[:, : n - 30] + w[:, 1: n - 29])
        w = np.concatenate([w, extra], axis=1)
    shift = rng.uniform(-3, 3, (batch, 1, 1, 2))
    return (w[None] + shift + rng.normal(0, 0.02, (batch,) + w.shape)).astype(np.float32)


@pytest.fixture(scope="module")
def shipped_onnx(tmp_path_factory):
    path = tmp_path_factory.mktemp("onnx") / "tpnet.onnx"
    assert main(["export", "onnx", "-o", str(path)]) == 0
    return path


@pytest.mark.parametrize("batch", [1, 64])
@pytest.mark.parametrize("n", [30, 45])
def test_shipped_export_matches_predict_batch(shipped_onnx, batch, n):
    model = tpnet_ref.load(engine="numpy")
    x = _windows(batch, n, seed=batch + n)
    got = _session(shipped_onnx).run(None, {"window": x})[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")      # NotOneBodyWarning for the added points
        want = model.predict_batch(x)
    assert got.shape == want.shape == (batch, 30, 2) and got.dtype == np.float32
    assert np.abs(got - want).max() <= 1e-4
    # the export's own output lies near the window's last frame, in world units
    assert np.abs(got - x[:, -1, :30].mean(axis=1, keepdims=True)).max() < 10


def test_export_declares_one_input_and_one_output_with_dynamic_batch_and_points(shipped_onnx, capsys):
    m = onnx.load(str(shipped_onnx))
    [inp], [out] = m.graph.input, m.graph.output

    def dims(v):
        return [d.dim_param or d.dim_value for d in v.type.tensor_type.shape.dim]
    assert (inp.name, dims(inp)) == ("window", ["batch", 4, "N", 2])
    assert (out.name, dims(out)) == ("prediction", ["batch", 30, 2])
    assert {n.op_type for n in m.graph.node} >= {"LSTM", "ReduceMax", "LayerNormalization"}
    assert sum(n.op_type == "LSTM" for n in m.graph.node) == 3
    props = {p.key: p.value for p in m.metadata_props}
    assert props["units"] == "world" and props["m"] == "4"


@pytest.mark.parametrize("cfg", [
    TPNetConfig(input_transform_trained=True, feature_transform_trained=True),
    TPNetConfig(m=3, lstm_activation="tanh", layer_norm_eps=1e-5, lstm_units=(64, 32, 16)),
    # bounds other than the shipped 1.1438 / 43.8562: the export must read the config's
    TPNetConfig(norm_lo=-20.0, norm_hi=75.0, lstm_units=(64, 32, 16)),
    # per-point layers of different widths, three of them, with a trained feature transform
    TPNetConfig(mlp1=(16, 24, 32), feature_transform_trained=True, lstm_units=(32, 16, 16)),
], ids=["trained-transforms", "tanh-small", "other-bounds", "uneven-widths"])
def test_export_of_a_weights_file(tmp_path, cfg):
    weights, path = tmp_path / "net.h5", tmp_path / "net.onnx"
    init_random(cfg, seed=3).save(str(weights))
    assert main(["export", "onnx", "--weights", str(weights), "-o", str(path)]) == 0
    model = tpnet_ref.load(str(weights), engine="numpy")
    x = np.random.default_rng(1).uniform(5, 40, (7, cfg.m, 17, 2)).astype(np.float32)
    got = _session(path).run(None, {"window": x})[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        want = model.predict_batch(x)
    assert np.abs(got - want).max() <= 1e-4
    props = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert (float(props["norm_lo"]), float(props["norm_hi"])) == (cfg.norm_lo, cfg.norm_hi)


@pytest.mark.parametrize("argv, msg", [
    (["export", "onnx", "-o", "OUT.txt"], "must end in .onnx"),
    (["export", "onnx", "-o", "no/such/dir/x.onnx"], "does not exist"),
    (["export", "onnx", "--weights", "missing.h5", "-o", "OUT.onnx"], "missing.h5"),
])
def test_export_errors_are_one_line(tmp_path, monkeypatch, argv, msg, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tpnet export: error:") and msg in err[0]
    assert not (tmp_path / "OUT.onnx").exists()


def test_export_without_onnx_names_the_extra(tmp_path, monkeypatch, capsys):
    import tpnet_ref.extras as X
    real = X.importlib.import_module

    def fake(name, *a, **k):
        if name.split(".")[0] == "onnx":
            raise ImportError("No module named 'onnx'")
        return real(name, *a, **k)
    monkeypatch.setattr(X.importlib, "import_module", fake)
    assert main(["export", "onnx", "-o", str(tmp_path / "m.onnx")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'tpnet-ref[onnx]'" in err[0]
    assert not (tmp_path / "m.onnx").exists()
