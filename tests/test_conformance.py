"""Conformance vectors and ``tpnet crosscheck``: the reference's trace, the vectors files read
back by a plain NumPy reader, the honest PyTorch / ONNX / Keras / engine paths raising no alarm
(on the vectors and on hypothesis-drawn windows), seven seeded port bugs each named at its own
first layer, and the one-line errors for bad input."""
from __future__ import annotations

import io
import json
import zipfile
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pytest

import tpnet_ref
from tpnet_ref.engines import reference
from tpnet_ref.cli import main
from tpnet_ref.conformance.compare import compare, compare_case, first_divergence
from tpnet_ref.conformance.layer_names import layer_names, layer_shapes
from tpnet_ref.conformance.tolerances import measure_tolerances, trace
from tpnet_ref.conformance.vectors import (Vectors, read_conformance_vectors, save_trace,
                                           write_conformance_vectors)
from tpnet_ref.model import TPNet, TPNetConfig, init_random
from conformance_helpers import SEEDED, crosscheck_seeded_bug, run_cli

ROOT = Path(__file__).resolve().parent.parent
QUARTER = ROOT / "weights" / "tpnet-m4-quarter.h5"


@pytest.fixture(scope="module")
def quarter() -> TPNet:
    return tpnet_ref.load(QUARTER, engine="numpy")


@pytest.fixture(scope="module")
def vectors_dir(tmp_path_factory, quarter) -> Path:
    pytest.importorskip("pymunk")
    d = tmp_path_factory.mktemp("vectors") / "q"
    rc, out, err = run_cli("vectors", "--weights", QUARTER, "-o", d)
    assert rc == 0, err
    assert "9 cases" in out
    return d


# --------------------------------------------------------------------------- the trace
@pytest.mark.parametrize("cfg", [TPNetConfig(lstm_units=(16, 8, 8)),
                                 TPNetConfig(lstm_units=(8, 8, 8), input_transform_trained=True,
                                             feature_transform_trained=True)],
                         ids=["identity-transforms", "trained-transforms"])
@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_trace_names_in_order_and_result_unchanged(cfg, dtype):
    model = init_random(cfg, seed=3, dtype=dtype)
    rng = np.random.default_rng(0)
    window = [rng.uniform(5, 40, (n, 2)) for n in (30, 17, 30, 4)]
    tr: dict = {}
    y = reference.forward(cfg, model.params, window, trace=tr)
    assert list(tr) == layer_names(cfg)
    assert np.array_equal(y, reference.forward(cfg, model.params, window))
    assert np.array_equal(tr["output"], y)
    assert all(v.dtype == np.dtype(dtype) for v in tr.values())
    P = 30 + 17 + 30 + 4
    for name, shape in layer_shapes(cfg).items():
        want = tuple(P if d == "P" else cfg.m if d == "m" else d for d in shape)
        assert tr[name].shape == want, name
    # the named intermediates are what the layers compute
    assert np.array_equal(tr["pooled"][1], tr["mlp2.2"][30:47].max(axis=0))
    u = cfg.lstm_units[-1]
    assert np.array_equal(tr["lstm3.concat"][:u], tr["lstm3.fwd"][-1])
    assert np.array_equal(tr["lstm3.concat"][u:], tr["lstm3.bwd"][0])


# --------------------------------------------------------------------------- the vectors files
def plain_npz(path: Path) -> dict[str, np.ndarray]:
    """Read an .npz as any port would: a zip of .npy files, nothing of tpnet_ref."""
    out = {}
    with zipfile.ZipFile(path) as z:
        for name in z.namelist():
            with z.open(name) as fh:
                out[name[:-4]] = np.lib.format.read_array(fh, allow_pickle=False)
    return out


def test_vectors_read_back_by_a_plain_numpy_reader(vectors_dir, quarter):
    man = json.loads((vectors_dir / "manifest.json").read_text())
    arrays = plain_npz(vectors_dir / "vectors.npz")
    layers = [e["name"] for e in man["layers"]]
    assert layers == layer_names(quarter.config)
    assert [c["name"] for c in man["cases"]] == ["scene1", "scene2", "shuffled", "ragged",
                                                 "edge_low", "edge_high", "rollout1",
                                                 "rollout2", "rollout3"]
    assert len(arrays) == len(layers) * len(man["cases"])
    params64 = {k: v.astype(np.float64) for k, v in quarter.params.items()}
    for c in man["cases"]:
        for e in man["layers"]:
            a = arrays[f"{c['name']}.{e['name']}"]
            assert a.dtype == np.float64 and list(a.shape) == c["shapes"][e["name"]]
            assert e["tolerance"] > e["float32_gap"] >= 0
        frames = np.split(arrays[f"{c['name']}.input"], np.cumsum(c["counts"])[:-1])
        assert np.array_equal(arrays[f"{c['name']}.output"],
                              reference.forward(quarter.config, params64, frames))
    assert sorted(set(c["counts"][0] for c in man["cases"])) == [30]
    assert len(set(next(c for c in man["cases"] if c["name"] == "ragged")["counts"])) > 1
    # the shuffled case is scene1 with its points permuted: the same prediction in float64
    np.testing.assert_allclose(arrays["shuffled.output"], arrays["scene1.output"], atol=1e-12)
    lo, hi = quarter.config.norm_lo, quarter.config.norm_hi
    assert np.isclose(arrays["edge_low.input"].min(), lo)
    assert np.isclose(arrays["edge_high.input"].max(), hi)
    # a rollout step's newest frame is the previous step's output
    assert np.array_equal(arrays["rollout2.input"][-30:], arrays["rollout1.output"])


def test_the_readers_own_vectors(vectors_dir, quarter):
    v = read_conformance_vectors(vectors_dir)
    assert v.config == quarter.config
    res = compare(v, {c: v.arrays[c] for c in v.cases})
    assert first_divergence(res, v.layers) is None
    assert all(r.layers[-1].max_abs == 0 for r in res)


# --------------------------------------------------------------------------- honest paths
def crosscheck_json(vectors_dir: Path, *src: str) -> tuple[int, dict]:
    rc, out, err = run_cli("crosscheck", "--vectors", vectors_dir, *src, "--json")
    assert rc in (0, 1), err
    return rc, json.loads(out)


def test_native_file_engines_agree(vectors_dir):
    for engine in ("numpy", "numba"):
        if engine == "numba":
            pytest.importorskip("numba")
        rc, rep = crosscheck_json(vectors_dir, "--model", QUARTER, "--engine", engine)
        assert rc == 0 and rep["first_divergence"] is None, rep


def test_torch_state_dict_agrees(vectors_dir, quarter, tmp_path):
    torch = pytest.importorskip("torch")
    from tpnet_ref.training.torch_model import TorchTPNet
    torch.save(TorchTPNet.from_numpy(quarter).state_dict(), tmp_path / "q.pt")
    rc, rep = crosscheck_json(vectors_dir, "--model", tmp_path / "q.pt")
    assert rc == 0 and rep["first_divergence"] is None, rep
    assert all(c["layers_missing"] == [] for c in rep["cases"].values())


def test_onnx_export_agrees(vectors_dir, quarter, tmp_path):
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from tpnet_ref.conformance.onnx_peer import export_onnx
    export_onnx(quarter, tmp_path / "q.onnx")
    rc, out, err = run_cli("crosscheck", "--vectors", vectors_dir, "--model", tmp_path / "q.onnx")
    assert rc == 0, out + err
    assert "all 9 case(s) agree" in out and "not in the trace" not in out


def test_keras_checkpoint_agrees(tmp_path):
    """A Keras checkpoint of the released structure (committed fixture), traced by a Keras 3
    model built from it, against vectors of the same checkpoint."""
    import os
    os.environ.setdefault("KERAS_BACKEND", "torch")      # the keras extra: Keras 3 on torch
    pytest.importorskip("keras")
    pytest.importorskip("pymunk")
    from tpnet_ref.weights.keras import import_keras_h5
    src = ROOT / "tests" / "fixtures" / "tf2_released.h5"
    model = import_keras_h5(src)
    write_conformance_vectors(model.config, model.params, tmp_path / "v")
    rc, out, err = run_cli("crosscheck", "--vectors", tmp_path / "v", "--model", src)
    assert rc == 0, out + err
    assert "Keras" in out and "all 9 case(s) agree" in out


def _window_vectors(model: TPNet, window: list[np.ndarray]) -> Vectors:
    """Vectors of one window with tolerances measured on it (the same rule as tpnet vectors)."""
    want = trace(model.config, model.params, window)
    tol, _ = measure_tolerances(model.config, model.params, [window], [want])
    return Vectors(Path("."), {}, model.config, layer_names(model.config), tol,
                     {"w": {"counts": [len(f) for f in window]}}, {"w": want})


def test_honest_paths_on_hypothesis_windows(quarter):
    torch = pytest.importorskip("torch")
    pytest.importorskip("onnxruntime")
    from hypothesis import HealthCheck, given, settings

    from tpnet_ref.conformance.onnx_peer import build_onnx
    from tpnet_ref.testing import windows
    from tpnet_ref.training.torch_model import TorchTPNet
    from tpnet_ref.conformance.traces import onnx_trace, onnx_trace_session, torch_trace

    torch.set_num_threads(1)
    net = TorchTPNet.from_numpy(quarter).eval()
    sess = onnx_trace_session(build_onnx(quarter, n_points=None, world_units=True),
                              quarter.config)

    @settings(max_examples=15, deadline=None, derandomize=True,
              suppress_health_check=list(HealthCheck))
    @given(windows(m=4, n=(3, 40), scales=(0.5, 2.0, 6.0), centre=(8.0, 37.0),
                   step=(0.0, 0.8)))
    def check(window):
        v = _window_vectors(quarter, window)
        for label, tr in (("torch", torch_trace(net, window)),
                          ("onnx", onnx_trace(None, window, quarter.config, sess))):
            r = compare_case(v, "w", tr)
            assert r.first is None, (label, r.first)

    check()


# --------------------------------------------------------------------------- seeded bugs
@pytest.mark.parametrize("bug", list(SEEDED))
def test_seeded_bug_named_at_its_first_layer(bug, vectors_dir, quarter, tmp_path):
    pytest.importorskip("torch")
    rep = crosscheck_seeded_bug(quarter, bug, vectors_dir, tmp_path)
    assert rep["first_divergence"]["max_abs"] > 0
    layer = SEEDED[bug][0]
    # the report names it too, with the layers after it
    rc, out, _ = run_cli("crosscheck", "--vectors", vectors_dir, "--trace", tmp_path / "port.npz")
    assert rc == 1 and f"DIVERGES at {layer}:" in out and "then:" in out


def test_honest_port_trace_file_agrees(vectors_dir, quarter, tmp_path):
    pytest.importorskip("torch")
    from tpnet_ref.training.torch_model import TorchTPNet
    from tpnet_ref.conformance.traces import torch_trace

    net = TorchTPNet.from_numpy(quarter).eval()
    v = read_conformance_vectors(vectors_dir)
    traces = {c: torch_trace(net, v.window(c)) for c in v.cases}
    # a port may leave layers out and give per-point layers as (m, N, C) with a batch axis
    for t in traces.values():
        del t["lstm1.concat"]
    traces["scene1"]["mlp1.0"] = traces["scene1"]["mlp1.0"].reshape(1, 4, 30, -1)
    save_trace(tmp_path / "port.npz", traces)
    rc, out, err = run_cli("crosscheck", "--vectors", vectors_dir, "--trace",
                           tmp_path / "port.npz")
    assert rc == 0, out + err
    assert "not in the trace (any case): lstm1.concat" in out


# --------------------------------------------------------------------------- bad input
def _one_line_error(rc: int, err: str, *words: str) -> None:
    assert rc == 2
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, err


def test_bad_input_is_one_line(vectors_dir, tmp_path):
    v = read_conformance_vectors(vectors_dir)
    good = {c: dict(v.arrays[c]) for c in v.cases}

    save_trace(tmp_path / "unknown.npz", {"scene1": {"mlp9.0": np.zeros(3)}})
    _one_line_error(*run_cli("crosscheck", "--vectors", vectors_dir, "--trace",
                             tmp_path / "unknown.npz")[::2], "unknown key", "scene1.mlp9.0")
    save_trace(tmp_path / "case.npz", {"scene9": {"output": np.zeros((30, 2))}})
    _one_line_error(*run_cli("crosscheck", "--vectors", vectors_dir, "--trace",
                             tmp_path / "case.npz")[::2], "unknown key", "scene9.output")
    bad = {"scene1": {"mlp1.0": good["scene1"]["mlp1.0"][:, :3]}}
    save_trace(tmp_path / "shape.npz", bad)
    _one_line_error(*run_cli("crosscheck", "--vectors", vectors_dir, "--trace",
                             tmp_path / "shape.npz")[::2], "scene1.mlp1.0", "shape")
    _one_line_error(*run_cli("crosscheck", "--vectors", vectors_dir, "--trace",
                             tmp_path / "missing.npz")[::2], "not found")
    _one_line_error(*run_cli("crosscheck", "--vectors", tmp_path / "nowhere", "--trace",
                             tmp_path / "shape.npz")[::2], "not found")
    (tmp_path / "text.npz").write_text("not a zip")
    _one_line_error(*run_cli("crosscheck", "--vectors", vectors_dir, "--trace",
                             tmp_path / "text.npz")[::2], "not an .npz")
    with open(tmp_path / "obj.npz", "wb") as fh:
        np.savez(fh, **{"scene1.output": np.array([object()], dtype=object)})
    _one_line_error(*run_cli("crosscheck", "--vectors", vectors_dir, "--trace",
                             tmp_path / "obj.npz")[::2], "obj.npz")
    # a model of another network size or m than the vectors
    other = init_random(TPNetConfig(m=3, lstm_units=(16, 8, 8)), seed=0)
    other.save(tmp_path / "m3.h5")
    _one_line_error(*run_cli("crosscheck", "--vectors", vectors_dir, "--model",
                             tmp_path / "m3.h5")[::2], "another network than the one the vectors "
                    "in", "were made for: m=3")
    # a vectors folder whose manifest is not one
    (tmp_path / "fake").mkdir()
    (tmp_path / "fake" / "manifest.json").write_text("{\"format\": \"other\"}")
    _one_line_error(*run_cli("crosscheck", "--vectors", tmp_path / "fake", "--trace",
                             tmp_path / "shape.npz")[::2], "manifest")
    _one_line_error(*run_cli("vectors", "--weights", QUARTER, "-o",
                             tmp_path / "no" / "such" / "dir")[::2], "does not exist")


def test_crosscheck_help_lists_every_option():
    with pytest.raises(SystemExit):
        with redirect_stdout(io.StringIO()) as buf:
            main(["crosscheck", "--help"])
    text = buf.getvalue()
    for opt in ("--vectors", "--trace", "--model", "--engine", "--json", "--after"):
        assert opt in text
    assert text.count("default") >= 5
