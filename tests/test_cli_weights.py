"""``tpnet import`` (tpnet_ref.cli.weights): a Keras, torch or native checkpoint in, a native
weights file out that predicts what the source does; one-line errors for what is no checkpoint."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("h5py")

from tpnet_ref import load  # noqa: E402
from tpnet_ref.cli import main  # noqa: E402
from tpnet_ref.model import TPNetConfig, init_random  # noqa: E402
from tpnet_ref.weights import import_checkpoint  # noqa: E402

FIX = Path(__file__).parent / "fixtures"
BOUND = 1e-5


def test_import_keras_archive(tmp_path, capsys):
    assert main(["import", str(FIX / "k3_trained.keras"), str(tmp_path / "n.h5")]) == 0
    out = capsys.readouterr().out
    assert "Keras 3 .keras archive" in out and "m=4" in out and "trained" in out
    assert f"wrote {tmp_path / 'n.h5'}" in out
    model = load(tmp_path / "n.h5")
    data = np.load(FIX / "k3_trained.npz")
    assert np.abs(model.predict_batch(data["windows"], normalized=True)
                  - data["step"]).max() <= BOUND
    assert import_checkpoint(tmp_path / "n.h5").config == model.config  # native passes through
    assert model.meta["source_format"] == "Keras 3 .keras archive"      # provenance kept


def test_flags_fill_what_the_file_does_not_say(tmp_path, capsys):
    """A save_weights file has no model config: --m, --layer-norm-eps, --lstm-activation and
    --dtype decide."""
    out = tmp_path / "n.h5"
    assert main(["import", str(FIX / "tf2_released_weights.h5"), str(out), "--m", "3",
                 "--layer-norm-eps", "1e-4", "--lstm-activation", "tanh",
                 "--dtype", "float64"]) == 0
    text = capsys.readouterr().out
    assert "activation=tanh" in text and "layer_norm_eps=0.0001" in text
    model = load(out)
    c = model.config
    assert (c.m, c.layer_norm_eps, c.lstm_activation) == (3, 1e-4, "tanh")
    import h5py
    with h5py.File(out, "r") as f:                  # the parameters are written as float64
        dtypes = set()
        f.visititems(lambda n, o: dtypes.add(o.dtype) if isinstance(o, h5py.Dataset) else None)
    assert np.dtype("float64") in dtypes


def test_import_torch_state_dict(tmp_path, capsys):
    torch = pytest.importorskip("torch")
    from tpnet_ref.training.torch_model import TorchTPNet
    cfg = TPNetConfig(mlp1=(8, 8), mlp2=(8, 16), global_features=16, lstm_units=(8, 8, 8),
                      input_tnet_mlp=(4,), input_tnet_fc=(4,), feature_tnet_mlp=(4,),
                      feature_tnet_fc=(4,))
    net = TorchTPNet.from_numpy(init_random(cfg, seed=2, dtype="float32"))
    torch.save(net.state_dict(), tmp_path / "a.pt")
    assert main(["import", str(tmp_path / "a.pt"), str(tmp_path / "a.h5")]) == 0
    assert "torch state dict" in capsys.readouterr().out
    w = np.random.default_rng(0).uniform(0.2, 0.8, (2, 4, 30, 2)).astype(np.float32)
    with torch.no_grad():
        want = net(torch.from_numpy(w)).numpy()
    assert np.abs(load(tmp_path / "a.h5").predict_batch(w, normalized=True) - want).max() <= BOUND


@pytest.mark.parametrize("content, says", [
    (b"just some text\n", "not a checkpoint at all"),
    (b"\x89HDF\r\n\x1a\n" + b"\0" * 64, "HDF5"),
])
def test_what_is_no_checkpoint_is_one_line(tmp_path, capsys, content, says):
    src = tmp_path / "src.bin"
    src.write_bytes(content)
    assert main(["import", str(src), str(tmp_path / "o.h5")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tpnet import: error:") and says in err[0]
    assert not (tmp_path / "o.h5").exists()


def test_missing_source_and_usage_errors(tmp_path, capsys):
    assert main(["import", str(tmp_path / "nope.pt"), str(tmp_path / "o.h5")]) == 2
    assert "checkpoint not found" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        main(["import", "only-one-path"])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the following arguments are required: dst" in err[0]
    with pytest.raises(SystemExit):
        main(["import", "a", "b", "--lstm-activation", "gelu"])
    assert "invalid choice: 'gelu'" in capsys.readouterr().err


def test_compress_is_lossless_or_rounds_as_asked(tmp_path, capsys):
    """``tpnet compress``: the shipped files' storage (docs/weights.md) from the command line."""
    model = init_random(TPNetConfig(mlp1=(8, 8), mlp2=(8, 16), global_features=16,
                                    lstm_units=(8, 8, 8)), seed=1, dtype="float32")
    model.save(tmp_path / "a.h5")
    assert main(["compress", str(tmp_path / "a.h5"), str(tmp_path / "b.h5")]) == 0
    assert "shuffle + gzip, lossless)" in capsys.readouterr().out
    b = load(tmp_path / "b.h5")
    assert all(np.array_equal(b.params[k], model.params[k]) for k in model.params)
    assert main(["compress", str(tmp_path / "a.h5"), str(tmp_path / "c.h5"),
                 "--mantissa-bits", "12"]) == 0
    out = capsys.readouterr().out
    assert "rounded to 12 significand bits, largest relative change 0.00012)" in out
    assert main(["compress", str(tmp_path / "a.h5"), str(tmp_path / "d.h5"),
                 "--mantissa-bits", "30"]) == 2
    assert capsys.readouterr().err.strip() == ("tpnet compress: error: mantissa_bits: must be "
                                               "1..22 for float32, got 30")
