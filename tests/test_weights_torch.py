"""PyTorch model and import_torch, checked live against PyTorch (skipped without torch)."""
from __future__ import annotations

import pickle

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tpnet_ref.engines import layers as L  # noqa: E402
from tpnet_ref.model import TPNetConfig, init_random, param_shapes  # noqa: E402
from tpnet_ref import load  # noqa: E402
from tpnet_ref.training.torch_model import TorchTPNet  # noqa: E402
from tpnet_ref.weights.torch import import_torch  # noqa: E402

SMALL = dict(input_tnet_mlp=(8, 16, 32), input_tnet_fc=(16, 8), mlp1=(16, 16),
             feature_tnet_mlp=(16, 16, 32), feature_tnet_fc=(16, 8), mlp2=(16, 32, 64),
             global_features=32, lstm_units=(48, 32, 32), n_out=12)
BOUND = 1e-5


def _windows(b=3, n=30, seed=0):
    return np.random.default_rng(seed).uniform(0.2, 0.8, (b, 4, n, 2))


@pytest.mark.parametrize("dtype,trained,size", [("float32", False, "full"), ("float64", False, "small"),
                                                ("float32", True, "small"), ("float64", True, "small")])
def test_torch_roundtrip_matches_numpy(tmp_path, dtype, trained, size):
    """torch forward + 8-step rollout == NumPy forward after import_torch (released sizes once)."""
    kw = {} if size == "full" else SMALL
    cfg = TPNetConfig(input_transform_trained=trained, feature_transform_trained=trained, **kw)
    ref = init_random(cfg, seed=3, dtype=dtype)
    net = TorchTPNet.from_numpy(ref)
    path = tmp_path / "ckpt.pt"
    torch.save(net.state_dict(), path)
    model = import_torch(path, dtype=dtype)
    assert model.config == cfg
    w = _windows(n=cfg.n_out).astype(dtype)
    with torch.no_grad():
        yt = net(torch.from_numpy(w)).numpy()
        rt = net.rollout(torch.from_numpy(w[:1]), 8).numpy()[0]
    assert np.abs(model.predict_batch(w, normalized=True) - yt).max() <= BOUND
    assert np.abs(model.rollout(w[0], 8, normalized=True) - rt).max() <= BOUND


def test_bare_state_dict_and_eps(tmp_path):
    """A state dict without _extra_state: config read from shapes, eps/m from arguments."""
    cfg = TPNetConfig(m=3, layer_norm_eps=1e-5, feature_transform_trained=True, **SMALL)
    net = TorchTPNet(cfg).double()
    sd = {k: v for k, v in net.state_dict().items() if k != "_extra_state"}
    model = import_torch(sd, m=3, layer_norm_eps=1e-5, dtype="float64")
    assert param_shapes(model.config) == param_shapes(cfg)
    assert (model.config.m, model.config.layer_norm_eps) == (3, 1e-5)
    w = _windows(2, 17)[:, :3]
    with torch.no_grad():
        yt = net(torch.from_numpy(w)).numpy()
    assert np.abs(model.predict_batch(w, normalized=True) - yt).max() <= 1e-12
    # with the config in _extra_state the eps travels with the weights
    model2 = import_torch(net, dtype="float64")
    assert model2.config.layer_norm_eps == 1e-5 and model2.config.m == 3


def test_gate_order_against_nn_lstm():
    """nn.LSTM (tanh; (4u, in) kernels, gates i,f,g,o, two biases) loaded into our model and
    converted to the Keras layout: the NumPy LSTM gives nn.LSTM's output."""
    torch.manual_seed(0)
    ref = torch.nn.LSTM(6, 7, batch_first=True, bidirectional=True).double()
    for p in ref.parameters():  # every gate's weights and both biases distinct, non-trivial
        torch.nn.init.uniform_(p, -0.8, 0.8)
    x = torch.randn(3, 4, 6, dtype=torch.float64)
    with torch.no_grad():
        yref, _ = ref(x)
    cfg = TPNetConfig(mlp1=(4,), mlp2=(4,), global_features=6, lstm_units=(7,),
                      lstm_activation="tanh", n_out=3)
    net = TorchTPNet(cfg).double()
    net.lstm1.return_sequences = True
    net.lstm1.load_state_dict(ref.state_dict())
    with torch.no_grad():
        assert torch.allclose(net.lstm1(x), yref, atol=1e-12)
    p = net.to_numpy("float64").params
    y = L.bidirectional_lstm(x.numpy(), tuple(p[f"lstm1.fwd.{k}"] for k in ("kernel", "recurrent", "bias")),
                             tuple(p[f"lstm1.bwd.{k}"] for k in ("kernel", "recurrent", "bias")), "tanh")
    assert np.abs(y - yref.numpy()).max() < 1e-12
    b = ref.state_dict()
    assert np.array_equal(p["lstm1.bwd.bias"], (b["bias_ih_l0_reverse"] + b["bias_hh_l0_reverse"]).numpy())


def test_refuses_pickled_payload(tmp_path):
    """weights_only=True: a pickle that would run code is refused, nothing executes."""
    class Evil:
        def __reduce__(self):
            return (exec, ("open(%r, 'w').write('pwned')" % str(tmp_path / "pwned"),))

    path = tmp_path / "evil.pt"
    with open(path, "wb") as f:
        pickle.dump({"mlp1.0.weight": Evil()}, f, protocol=2)
    with pytest.raises(ValueError, match="weights-only"):
        import_torch(path)
    assert not (tmp_path / "pwned").exists()
    torch.save({"mlp1.0.weight": torch.zeros(2, 2), "note": 3}, tmp_path / "odd.pt")
    with pytest.raises(ValueError, match="not a tensor"):
        import_torch(tmp_path / "odd.pt")


def test_errors_name_the_problem():
    net = TorchTPNet(TPNetConfig(**SMALL))
    sd = dict(net.state_dict())
    del sd["lstm2.weight_hh_l0_reverse"]
    with pytest.raises(ValueError, match="lstm2.weight_hh_l0_reverse"):
        import_torch(sd)
    sd = dict(net.state_dict())
    sd["head.bias"] = torch.zeros(5)
    with pytest.raises(ValueError, match="head.bias"):
        import_torch(sd)
    with pytest.raises(ValueError, match="missing"):
        import_torch({"foo": torch.zeros(1)})


def test_training_step_and_cli_roundtrip(tmp_path):
    """The 8-step loss is differentiable; import CLI writes a native file that loads back."""
    from tpnet_ref.cli import main

    cfg = TPNetConfig(**SMALL)
    net = TorchTPNet(cfg)
    w = torch.from_numpy(_windows(2, 12).astype(np.float32))
    tgt = torch.rand(2, 8, 12, 2)
    loss = net.recursive_loss(w, tgt)
    loss.backward()
    assert torch.isfinite(loss) and net.lstm1.weight_hh_l0.grad is not None
    torch.save(net.state_dict(), tmp_path / "a.pt")
    assert main(["import", str(tmp_path / "a.pt"), str(tmp_path / "a.h5")]) == 0
    model = load(tmp_path / "a.h5")
    with torch.no_grad():
        assert np.abs(model.predict_batch(w.numpy(), normalized=True) - net(w).numpy()).max() <= BOUND


@pytest.mark.parametrize("trained", [False, True])
def test_torch_names_are_derived_from_param_shapes(trained):
    """The torch key map follows param_shapes one to one, in order, and covers exactly the
    module's state dict (plus the hh biases folded into the native LSTM bias)."""
    from tpnet_ref.weights.torch import infer_torch_config, torch_key_map

    cfg = TPNetConfig(input_transform_trained=trained, feature_transform_trained=trained, **SMALL)
    rows = torch_key_map(cfg)
    assert [n for _, n, _ in rows] == list(param_shapes(cfg))
    sd = TorchTPNet(cfg).state_dict()
    hh = {t.replace("bias_ih", "bias_hh") for t, _, how in rows if how == "+"}
    assert {t for t, _, _ in rows} | hh | {"_extra_state"} == set(sd)
    bare = {k: v.numpy() for k, v in sd.items() if k != "_extra_state"}
    assert param_shapes(infer_torch_config(bare, 4, 1e-3, "relu")) == param_shapes(cfg)
