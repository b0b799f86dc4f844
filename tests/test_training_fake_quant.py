"""Quantization-aware fine-tuning: the forward pass's rounding is `tpnet quantize`'s, bit for bit;
the gradient passes it; a run's exported file holds the network it computed."""
from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import tpnet_ref  # noqa: E402
from tpnet_ref import cli  # noqa: E402
from tpnet_ref.training import checkpoint as C  # noqa: E402
from tpnet_ref.training import fake_quant as FQ  # noqa: E402
from tpnet_ref.training import loop as L  # noqa: E402
from tpnet_ref.training import native_export as NE  # noqa: E402
from tpnet_ref.training import recipe as R  # noqa: E402
from tpnet_ref.training.torch_model import TorchTPNet  # noqa: E402
from tpnet_ref.weights import quantize as Q  # noqa: E402
from training_helpers import dataset, tiny_recipe  # noqa: E402,F401


def _matrices():
    rng = np.random.default_rng(5)
    w = (rng.standard_normal((48, 40)) * rng.uniform(1e-3, 2.0, 40)).astype(np.float32)
    w[:, 3] = 0.0                                  # a column of zeros: scale 1, codes 0
    w[:, 7] = 1e-35                                # below TINY
    w[5, 9] = -np.abs(w[:, 9]).max() * 1.5         # a column's largest weight negative
    w[:, 11] = np.float32(2.0 ** -120)             # subnormal-adjacent scales
    return [w, tpnet_ref.load(size="quarter").params["lstm2.fwd.recurrent"]]


@pytest.mark.parametrize("scheme", ["int8", "bf16"])
def test_the_forward_rounding_is_tpnet_quantize_s(scheme):
    for w in _matrices():                           # native (C, N); torch holds (N, C)
        got = FQ.rounded(torch.from_numpy(np.ascontiguousarray(w.T)), scheme).numpy().T
        want = Q.round_to(w, scheme, False)
        assert got.dtype == np.float32
        np.testing.assert_array_equal(got, want)


def test_the_gradient_passes_the_rounding():
    w = torch.randn(16, 8, requires_grad=True)
    c = torch.randn(16, 8)
    (FQ.straight_through(w, "int8") * c).sum().backward()
    assert torch.equal(w.grad, c)
    assert FQ.straight_through(w, "") is w
    assert not torch.equal(FQ.straight_through(w, "int8"), w)


def test_a_quantize_aware_run_exports_the_network_it_computed(dataset, tmp_path):
    L.train(dataset, tmp_path / "parent", tiny_recipe(epochs=1), threads=1, progress=False)
    assert cli.main(["train", "run", dataset, "-o", str(tmp_path / "qat"), "--recipe", "paper",
                     "--init-from", str(tmp_path / "parent"), "--quantize-aware", "int8",
                     "--epochs", "1", "--batch", "16", "--lr", "1e-3", "--warmup-steps", "2",
                     "--val-fraction", "0.2", "--threads", "1", "--quiet"]) == 0
    r = R.Recipe.from_dict(C.load_checkpoint(tmp_path / "qat")[1]["recipe"])
    assert r.quantize_aware == "int8" and r.init_from == str(tmp_path / "parent")
    out = tmp_path / "q.h5"
    NE.export(tmp_path / "qat", out)
    # the NumPy engine: the Numba engine's int8 kernels compile in the lane's child, not here
    model = tpnet_ref.load(out, engine="numpy")
    assert model.meta[Q.ATTR] == "int8" and model.meta[Q.WIDE_ATTR] == ""
    assert "quantization-aware" in model.meta[Q.ROUNDING_ATTR]
    for n in Q.quantized_names(model.config):      # every matrix on the grid, one plane
        Q.codes_of(model.params[n], "int8", n)
    net = TorchTPNet(model.config)
    net.load_state_dict(C.load_checkpoint(tmp_path / "qat")[0]["model"])
    net.set_fake_quant("int8")
    net.eval()
    data = R.WindowData(dataset, r.val_fraction, r.split_seed)
    x, _ = data.gather(data.val_win[:8])
    with torch.no_grad():
        yt = net(torch.from_numpy(x)).numpy()
        y_float = TorchTPNet.from_numpy(tpnet_ref.load(out))(torch.from_numpy(x)).numpy()
    assert np.abs(model.predict_batch(x, normalized=True) - yt).max() <= 1e-5
    np.testing.assert_allclose(y_float, yt, atol=1e-5)
    net.set_fake_quant("")                         # the float weights themselves differ
    with torch.no_grad():
        assert np.abs(net(torch.from_numpy(x)).numpy() - yt).max() > 0


def test_bad_settings_are_refused(dataset, tmp_path, capsys):
    with pytest.raises(ValueError, match="quantize_aware must be"):
        tiny_recipe(quantize_aware="int4")
    assert cli.main(["train", "run", dataset, "-o", str(tmp_path / "r"), "--size", "tiny",
                     "--quantize-aware", "int8"]) != 0
    assert "--quantize-aware fine-tunes a trained network" in capsys.readouterr().err
