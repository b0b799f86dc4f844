"""import_keras_h5 against committed files written by TF-Keras 2 and Keras 3 (see
tests/fixtures/make_keras_fixtures.py, which also wrote the frameworks' outputs)."""
from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from tpnet_ref.weights.keras import import_keras_h5

FIX = Path(__file__).parent / "fixtures"
BOUND = 1e-5
CASES = [  # file, outputs, transforms trained, what the report must say
    ("tf2_released.h5", "tf2_released", False, "TF-Keras 2 HDF5 whole model (model_weights/), "
                                                "names with ':0'"),
    ("tf2_released_weights.h5", "tf2_released", False, "TF-Keras 2 HDF5 save_weights"),
    ("tf2_trained_bn.h5", "tf2_trained_bn", True, "folded 15 BatchNorm"),
    ("tf2_trained_bn_weights.h5", "tf2_trained_bn", True, "folded 15 BatchNorm"),
    ("k3_trained.weights.h5", "k3_trained", True, "Keras 3 .weights.h5"),
    ("k3_trained.keras", "k3_trained", True, "Keras 3 .keras archive"),
    ("k3_legacy.h5", "k3_trained", True, "names without ':0'"),
]


@pytest.mark.parametrize("fname,outputs,trained,says", CASES)
def test_keras_fixture_matches_framework(fname, outputs, trained, says):
    model = import_keras_h5(FIX / fname)
    data = np.load(FIX / f"{outputs}.npz")
    cfg = model.config
    assert (cfg.m, cfg.n_out, cfg.lstm_activation, cfg.layer_norm_eps) == (4, 30, "relu", 1e-3)
    assert cfg.input_transform_trained is trained and cfg.feature_transform_trained is trained
    assert says in model.meta["import_report"]
    if not trained:
        assert "identity" in model.meta["import_report"] and model.meta["dropped_params"] > 0
    for dtype in ("float32", "float64"):
        m = model.astype(dtype)
        step = m.predict_batch(data["windows"], normalized=True)
        assert np.abs(step - data["step"]).max() <= BOUND, dtype
        roll = np.stack([m.rollout(w, 8, normalized=True) for w in data["windows"]])
        assert np.abs(roll - data["rollout"]).max() <= BOUND, dtype


def _copy(tmp_path, name="tf2_released_weights.h5"):
    dst = tmp_path / name
    shutil.copy(FIX / name, dst)
    return dst


def _drop_layer(path, layer):
    with h5py.File(path, "r+") as f:
        g = f["single_step_model"]
        names = [n.decode() if isinstance(n, bytes) else str(n) for n in g.attrs["weight_names"]]
        names = [n for n in names if not n.startswith(layer + "/")]
        g.attrs["weight_names"] = names
        del g[layer]


def test_missing_conv_layer_is_named(tmp_path):
    p = _copy(tmp_path)
    _drop_layer(p, "conv2d_4")
    with pytest.raises(ValueError, match="found 10 Conv2D layers"):
        import_keras_h5(p)


def test_missing_layernorm_and_dataset(tmp_path):
    p = _copy(tmp_path)
    _drop_layer(p, "layer_normalization_1")
    with pytest.raises(ValueError, match="3 Bidirectional layers but 2 LayerNormalization"):
        import_keras_h5(p)
    p = _copy(tmp_path, "tf2_released.h5")
    with h5py.File(p, "r+") as f:
        del f["model_weights/single_step_model/bidirectional_1/backward_lstm_1/lstm_cell/bias:0"]
    with pytest.raises(ValueError, match="missing 'bidirectional_1/backward_lstm_1/lstm_cell/bias:0'"):
        import_keras_h5(p)


def test_wrong_shape_is_named(tmp_path):
    p = _copy(tmp_path)
    with h5py.File(p, "r+") as f:
        g = f["single_step_model/bidirectional_2/forward_lstm_2/lstm_cell"]
        del g["recurrent_kernel:0"]
        g.create_dataset("recurrent_kernel:0", data=np.zeros((12, 40), np.float32))
    with pytest.raises(ValueError, match=r"bidirectional_2 \(fwd\) recurrent_kernel: shape \(12, 40\)"):
        import_keras_h5(p)
    p = _copy(tmp_path, "k3_trained.weights.h5")
    with h5py.File(p, "r+") as f:
        g = f["layers/functional/layers/dense/vars"]
        del g["0"]
        g.create_dataset("0", data=np.zeros((23, 60), np.float32))
    with pytest.raises(ValueError, match="head FC.*expected \\(24, any\\)"):
        import_keras_h5(p)


def test_unknown_layout_and_links_refused(tmp_path):
    p = tmp_path / "other.h5"
    with h5py.File(p, "w") as f:
        f.create_dataset("x", data=np.zeros(3))
    with pytest.raises(ValueError, match="unknown layout"):
        import_keras_h5(p)
    for link, msg in ((h5py.SoftLink("/single_step_model/dense_4/bias:0"),
                       "SoftLink; links are not accepted"),
                      (h5py.ExternalLink("elsewhere.h5", "/x"), "ExternalLink")):
        p = _copy(tmp_path)
        with h5py.File(p, "r+") as f:
            g = f["single_step_model/dense_5"]
            del g["bias:0"]
            g["bias:0"] = link
        with pytest.raises(ValueError, match=msg):
            import_keras_h5(p)
    with pytest.raises(FileNotFoundError):
        import_keras_h5(tmp_path / "nope.h5")


def _edit_config(path, fn):
    import json
    with h5py.File(path, "r+") as f:
        cfg = json.loads(f.attrs["model_config"])
        fn(cfg)
        f.attrs["model_config"] = json.dumps(cfg)


def _each(o, cls):
    if isinstance(o, dict):
        if o.get("class_name") == cls:
            yield o["config"]
        for v in o.values():
            yield from _each(v, cls)
    elif isinstance(o, list):
        for v in o:
            yield from _each(v, cls)


def test_config_facts_are_read(tmp_path):
    """m, LayerNorm eps and LSTM activation come from a whole-model file's config; keywords
    fill in for a save_weights file; unsupported LSTM settings are refused by name."""
    p = _copy(tmp_path, "tf2_released.h5")

    def edit(cfg):
        for c in _each(cfg, "LayerNormalization"):
            c["epsilon"] = 1e-5
        for c in _each(cfg, "InputLayer"):
            if len(c["batch_input_shape"]) == 4:
                c["batch_input_shape"][1] = 5

    _edit_config(p, edit)
    c = import_keras_h5(p).config
    assert (c.m, c.layer_norm_eps) == (5, 1e-5)
    c = import_keras_h5(FIX / "tf2_released_weights.h5", m=3, layer_norm_eps=1e-4,
                        lstm_activation="tanh").config
    assert (c.m, c.layer_norm_eps, c.lstm_activation) == (3, 1e-4, "tanh")
    p = _copy(tmp_path, "tf2_released.h5")

    def edit2(cfg):
        for c in _each(cfg, "LSTM"):
            c["recurrent_activation"] = "hard_sigmoid"

    _edit_config(p, edit2)
    with pytest.raises(ValueError, match="recurrent_activation='hard_sigmoid'"):
        import_keras_h5(p)


def test_file_without_transform_nets(tmp_path):
    """The released file with its dead transform-net layers removed imports to the same network:
    dead weights are exactly that."""
    p = _copy(tmp_path)
    for layer in ("conv2d", "conv2d_1", "conv2d_2", "dense", "dense_1",
                  "conv2d_5", "conv2d_6", "conv2d_7", "dense_2", "dense_3"):
        _drop_layer(p, layer)
    model = import_keras_h5(p)
    assert "no transform nets" in model.meta["import_report"]
    ref = import_keras_h5(FIX / "tf2_released_weights.h5")
    assert model.params.keys() == ref.params.keys()
    assert all(np.array_equal(model.params[k], ref.params[k]) for k in ref.params)
