"""tpnet_ref.weights.convert.import_checkpoint: the kind of a checkpoint is told by its content,
not its name, and each kind goes to its importer; what is none of them is refused in one line."""
from __future__ import annotations

import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("h5py")

from tpnet_ref.model import TPNetConfig, init_random  # noqa: E402
from tpnet_ref.weights import import_checkpoint  # noqa: E402
from tpnet_ref.weights.keras import import_keras_h5  # noqa: E402

FIX = Path(__file__).parent / "fixtures"
SMALL = TPNetConfig(mlp1=(8, 8), mlp2=(8, 16), global_features=16, lstm_units=(8, 8, 8),
                    input_tnet_mlp=(4,), input_tnet_fc=(4,), feature_tnet_mlp=(4,),
                    feature_tnet_fc=(4,))


def _same_params(a, b) -> bool:
    return a.config == b.config and all(np.array_equal(a.params[k], b.params[k]) for k in a.params)


def test_native_file_passes_through_whatever_its_name(tmp_path):
    ref = init_random(SMALL, seed=1, dtype="float32")
    path = tmp_path / "weights.pt"                          # a misleading suffix
    ref.save(str(path), note="kept")
    model = import_checkpoint(path)
    assert _same_params(model, ref)
    assert model.meta["import_report"] == "native tpnet_ref weights file"
    assert model.meta["note"] == "kept"
    assert import_checkpoint(path, dtype="float64").dtype == np.float64


@pytest.mark.parametrize("name, rename", [("tf2_released_weights.h5", "w.bin"),
                                          ("k3_trained.keras", "model.zip")])
def test_keras_files_go_to_the_keras_importer(tmp_path, name, rename):
    src = tmp_path / rename
    shutil.copy(FIX / name, src)
    model = import_checkpoint(src, m=3)
    want = import_keras_h5(FIX / name, m=3)
    assert _same_params(model, want) and model.config.m == 3


def test_torch_state_dict_goes_to_the_torch_importer(tmp_path):
    torch = pytest.importorskip("torch")
    from tpnet_ref.training.torch_model import TorchTPNet
    ref = init_random(SMALL, seed=2, dtype="float32")
    torch.save(TorchTPNet.from_numpy(ref).state_dict(), tmp_path / "net.h5")   # not HDF5
    model = import_checkpoint(tmp_path / "net.h5", m=None, layer_norm_eps=None)
    assert model.config == ref.config
    assert model.meta["import_report"].startswith("torch state dict; m=4, N=30")
    w = np.random.default_rng(0).uniform(0.2, 0.8, (2, 4, 30, 2)).astype(np.float32)
    np.testing.assert_allclose(model.predict_batch(w, normalized=True),
                               ref.predict_batch(w, normalized=True), atol=1e-6)


def test_what_is_no_checkpoint_is_refused_in_one_line(tmp_path):
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    with pytest.raises(ValueError, match="not a checkpoint at all") as info:
        import_checkpoint(text)
    assert "\n" not in str(info.value) and "never read" in str(info.value)
    with pytest.raises(FileNotFoundError, match="checkpoint not found"):
        import_checkpoint(tmp_path / "missing.pt")
    with pytest.raises(FileNotFoundError):
        import_checkpoint(tmp_path)                          # a directory is no file
    damaged = tmp_path / "damaged.h5"
    damaged.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 64)
    with pytest.raises(ValueError, match="damaged.h5"):
        import_checkpoint(damaged)


def test_a_zip_that_is_no_keras_archive_is_read_as_torch_and_refused(tmp_path):
    pytest.importorskip("torch")
    z = tmp_path / "other.zip"
    with zipfile.ZipFile(z, "w") as f:
        f.writestr("readme.txt", "no weights here")
    with pytest.raises(ValueError) as info:
        import_checkpoint(z)
    assert "\n" not in str(info.value) and "other.zip" in str(info.value)
