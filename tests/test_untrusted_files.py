"""Untrusted weight files: the native loader, the Keras importer and the torch importer
refuse damaged, oversized, linked or code-carrying files with a clear error, run no code and
allocate nothing absurd (the guards of tpnet_ref.weights.hdf5). Also covered elsewhere: a foreign
HDF5 (test_model), Keras soft / external links and unknown layouts (test_weights_keras), a plain
pickle with ``exec`` (test_weights_torch).
"""
from __future__ import annotations

import io
import os
import resource
import shutil
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pytest

from tpnet_ref.cli import main
from tpnet_ref.model import TPNetConfig, init_random
from tpnet_ref import load
from tpnet_ref.weights import import_checkpoint
from tpnet_ref.weights.keras import import_keras_h5

FIX = Path(__file__).parent / "fixtures"
SMALL = dict(input_tnet_mlp=(8,), input_tnet_fc=(8,), mlp1=(8, 8), feature_tnet_mlp=(8,),
             feature_tnet_fc=(8,), mlp2=(8, 16), global_features=8, lstm_units=(8, 6), n_out=5)
DOCUMENTED = (ValueError, KeyError, FileNotFoundError)


@pytest.fixture()
def native(tmp_path):
    p = tmp_path / "net.h5"
    init_random(TPNetConfig(**SMALL), seed=0).save(p)
    return p


def _peak_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _replace(path, name, **kw):
    with h5py.File(path, "r+") as f:
        del f[name]
        f.create_dataset(name, **kw)


# ------------------------------------------------------------------------ native loader
def test_native_truncated(native):
    data = native.read_bytes()
    for n in (0, 8, 100, 2000, len(data) // 2, len(data) - 1):
        native.write_bytes(data[:n])
        with pytest.raises(ValueError, match="not a readable HDF5"):
            load(native)


def test_native_byte_corruption_fuzz(native, tmp_path):
    """Random byte damage anywhere: a documented error or a finite model, never another
    exception (h5py's RuntimeError from damaged metadata included)."""
    data = native.read_bytes()
    rng = np.random.default_rng(0)
    bad = tmp_path / "c.h5"
    for _ in range(120):
        b = bytearray(data)
        off = int(rng.integers(0, len(b) - 16))
        n = int(rng.integers(1, 16))
        b[off:off + n] = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        bad.write_bytes(bytes(b))
        try:
            model = load(bad)
        except DOCUMENTED:
            continue
        assert all(np.isfinite(p).all() for p in model.params.values())


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_native_nonfinite_weights(native, value):
    with h5py.File(native, "r+") as f:
        f["params/lstm1.fwd.recurrent"][0, 0] = value
    with pytest.raises(ValueError, match="'lstm1.fwd.recurrent' contains NaN or infinite"):
        load(native)


def test_native_wrong_shape_and_dtype(native):
    _replace(native, "params/head.w", data=np.zeros((12, 11), np.float32))
    with pytest.raises(ValueError, match=r"'head.w' has shape \(12, 11\), expected \(12, 10\)"):
        load(native)
    _replace(native, "params/head.w", data=np.zeros((12, 10), np.int32))
    with pytest.raises(ValueError, match="'head.w' has dtype int32"):
        load(native)


def test_native_absurd_declared_size_refused_before_allocation(native):
    """A dataset declaring 10^12 elements (chunked, never written: the file stays tiny)."""
    _replace(native, "params/head.b", shape=(10**12,), dtype="f8", chunks=(1024,))
    assert native.stat().st_size < 1 << 20
    before = _peak_mb()
    with pytest.raises(ValueError, match=r"'head.b' has shape \(1000000000000,\)"):
        load(native)
    assert _peak_mb() - before < 100


def test_native_absurd_config_refused(native):
    with h5py.File(native, "r+") as f:
        f["config"].attrs["n_out"] = 10**9
    with pytest.raises(ValueError, match="parameters .*limit"):
        load(native)
    with h5py.File(native, "r+") as f:
        f["config"].attrs["n_out"] = "many"
    with pytest.raises(ValueError):
        load(native)


def test_native_oversized_attribute_refused(native, monkeypatch):
    """Attribute sizes are checked before reading (limit lowered: HDF5 keeps attributes in the
    64 KiB object header unless written with dense storage)."""
    import tpnet_ref.weights.hdf5 as W
    monkeypatch.setattr(W, "MAX_ATTR_ELEMENTS", 1000)
    with h5py.File(native, "r+") as f:
        f.attrs.create("note", data=np.zeros(5000, np.uint8))
    with pytest.raises(ValueError, match="attribute 'note' .* declares 5,000 elements"):
        load(native)


def test_native_links_external_storage_virtual(native, tmp_path):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = np.zeros((12, 10), np.float32)
    raw = tmp_path / "raw.bin"
    raw.write_bytes(np.zeros(120, np.float32).tobytes())
    cases = {
        "SoftLink": lambda f: f.__setitem__("params/head.w", h5py.SoftLink("/params/ln1.gamma")),
        "ExternalLink": lambda f: f.__setitem__("params/head.w", h5py.ExternalLink(str(other), "/x")),
        "outside the file": lambda f: f["params"].create_dataset(
            "head.w", shape=(12, 10), dtype="f4", external=[(str(raw), 0, 480)]),
    }

    def virtual(f):
        layout = h5py.VirtualLayout(shape=(12, 10), dtype="f4")
        layout[:] = h5py.VirtualSource(str(other), "x", shape=(12, 10))
        f["params"].create_virtual_dataset("head.w", layout)
    cases["outside the file "] = virtual
    for msg, make in cases.items():
        p = tmp_path / "case.h5"
        shutil.copy(native, p)
        with h5py.File(p, "r+") as f:
            del f["params/head.w"]
            make(f)
        with pytest.raises(ValueError, match=msg.strip()):
            load(p)
    p = tmp_path / "case.h5"
    shutil.copy(native, p)
    with h5py.File(p, "r+") as f:  # a whole group replaced by a link
        g = f["params"]
        f.move("params", "params_real")
        f["params"] = h5py.SoftLink("/params_real")
        del g
    with pytest.raises(ValueError, match="'params' is a SoftLink; links are not accepted"):
        load(p)


# ------------------------------------------------------------------------ Keras importer
KERAS = FIX / "tf2_released.h5"


def _keras_copy(tmp_path, src=KERAS):
    p = tmp_path / src.name
    shutil.copy(src, p)
    return p


def _first_kernel(f):
    out = []
    f.visititems(lambda n, o: out.append(n) if isinstance(o, h5py.Dataset)
                 and n.endswith(("kernel:0", "kernel")) and "lstm" in n else None)
    return out[0]


def test_keras_nonfinite_weights(tmp_path):
    p = _keras_copy(tmp_path)
    with h5py.File(p, "r+") as f:
        f[_first_kernel(f)][0, 0] = np.nan
    with pytest.raises(ValueError, match="contains NaN or infinite"):
        import_keras_h5(p)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_keras_truncated_and_corrupted(tmp_path):
    p = _keras_copy(tmp_path)
    data = p.read_bytes()
    for n in (16, 4096, len(data) // 2):
        p.write_bytes(data[:n])
        with pytest.raises(ValueError):
            import_keras_h5(p)
    rng = np.random.default_rng(1)
    for _ in range(40):
        b = bytearray(data)
        off = int(rng.integers(0, len(b) - 16))
        b[off:off + 8] = rng.integers(0, 256, 8, dtype=np.uint8).tobytes()
        p.write_bytes(bytes(b))
        try:
            import_keras_h5(p)
        except DOCUMENTED:
            pass


def test_keras_absurd_declared_size_and_storage(tmp_path):
    p = _keras_copy(tmp_path)
    with h5py.File(p, "r+") as f:
        name = _first_kernel(f)
        shape = f[name].shape
        del f[name]
        f.create_dataset(name, shape=(10**6, 10**6), dtype="f4", chunks=(64, 64))
    before = _peak_mb()
    with pytest.raises(ValueError, match="implausibly large .*refused before reading"):
        import_keras_h5(p)
    assert _peak_mb() - before < 100
    raw = tmp_path / "raw.bin"
    raw.write_bytes(np.zeros(int(np.prod(shape)), np.float32).tobytes())
    p = _keras_copy(tmp_path)
    with h5py.File(p, "r+") as f:
        del f[name]
        f.create_dataset(name, shape=shape, dtype="f4",
                         external=[(str(raw), 0, raw.stat().st_size)])
    with pytest.raises(ValueError, match="outside the file"):
        import_keras_h5(p)


def test_keras_config_json_bombs(tmp_path):
    p = _keras_copy(tmp_path)
    with h5py.File(p, "r+") as f:
        f.attrs["model_config"] = "[" * 100_000 + "]" * 100_000
    with pytest.raises(ValueError, match="not valid JSON"):
        import_keras_h5(p)
    with h5py.File(p, "r+") as f:
        f.attrs["model_config"] = "{not json"
    with pytest.raises(ValueError, match="not valid JSON"):
        import_keras_h5(p)


def _keras_zip(tmp_path, members, name="m.keras", method=zipfile.ZIP_DEFLATED):
    p = tmp_path / name
    with zipfile.ZipFile(p, "w", method) as z:
        for k, v in members.items():
            z.writestr(k, v)
    return p


def test_keras_archives(tmp_path, monkeypatch):
    import tpnet_ref.weights.hdf5 as W

    good = (FIX / "k3_trained.keras").read_bytes()
    with zipfile.ZipFile(io.BytesIO(good)) as z:
        weights = z.read("model.weights.h5")
        config = z.read("config.json")
    # truncated archive: no central directory -> not a zip -> not HDF5 either
    p = tmp_path / "t.keras"
    p.write_bytes(good[: len(good) // 2])
    with pytest.raises(ValueError):
        import_keras_h5(p)
    with pytest.raises(ValueError):
        import_checkpoint(p)
    # damaged member (CRC / deflate stream)
    p = _keras_zip(tmp_path, {"config.json": config, "model.weights.h5": weights})
    b = bytearray(p.read_bytes())
    i = b.find(b"model.weights.h5") + 60
    b[i:i + 64] = bytes(64)
    p.write_bytes(bytes(b))
    with pytest.raises(ValueError, match="damaged|not readable"):
        import_keras_h5(p)
    # member that is not HDF5
    p = _keras_zip(tmp_path, {"model.weights.h5": b"hello"})
    with pytest.raises(ValueError, match="not readable HDF5"):
        import_keras_h5(p)
    # deflate bomb: 64 MiB of zeros in ~64 KiB; refused from the declared size, not read
    monkeypatch.setattr(W, "MAX_MEMBER_BYTES", 1 << 20)
    p = _keras_zip(tmp_path, {"model.weights.h5": bytes(64 << 20)}, "bomb.keras")
    assert p.stat().st_size < 1 << 20
    before = _peak_mb()
    with pytest.raises(ValueError, match="refused before reading"):
        import_keras_h5(p)
    assert _peak_mb() - before < 32
    monkeypatch.setattr(W, "MAX_CONFIG_BYTES", 1 << 16)
    p = _keras_zip(tmp_path, {"config.json": b" " * (1 << 20), "model.weights.h5": weights})
    with pytest.raises(ValueError, match="config.json declares"):
        import_keras_h5(p)
    # a zip that is no .keras file
    p = _keras_zip(tmp_path, {"a.txt": b"x"})
    with pytest.raises(ValueError, match="not a .keras file"):
        import_keras_h5(p)


# ------------------------------------------------------------------------ torch importer
torch = pytest.importorskip("torch")


class _Payload:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_torch_pickle_payload_never_runs(tmp_path, capsys):
    """A real torch.save zip whose pickle calls os.system: refused by every entry point."""
    from tpnet_ref.weights.torch import import_torch

    marker = tmp_path / "PWNED"
    p = tmp_path / "evil.pt"
    torch.save({"mlp1.0.weight": torch.zeros(8, 2), "x": _Payload(marker)}, p)
    assert zipfile.is_zipfile(p) and not marker.exists()
    with pytest.raises(ValueError, match="weights-only"):
        import_torch(p)
    with pytest.raises(ValueError, match="weights-only"):
        import_checkpoint(p)
    assert main(["import", str(p), str(tmp_path / "out.h5")]) == 2
    assert "weights-only" in capsys.readouterr().err
    # the legacy / plain-pickle form of the same payload
    import pickle
    q = tmp_path / "evil_plain.pt"
    q.write_bytes(pickle.dumps({"x": _Payload(marker)}))
    with pytest.raises(ValueError, match="weights-only"):
        import_torch(q)
    assert not marker.exists()
    assert not (tmp_path / "out.h5").exists()


def test_torch_damaged_and_oversized(tmp_path, monkeypatch):
    import tpnet_ref.weights.hdf5 as H
    from tpnet_ref.training.torch_model import TorchTPNet
    from tpnet_ref.weights.torch import import_torch

    p = tmp_path / "a.pt"
    torch.save(TorchTPNet(TPNetConfig(**SMALL)).state_dict(), p)
    data = p.read_bytes()
    q = tmp_path / "t.pt"
    for n in (10, len(data) // 2, len(data) - 30):
        q.write_bytes(data[:n])
        with pytest.raises(ValueError, match="weights-only|damaged"):
            import_torch(q)
    # NaN weights
    sd = TorchTPNet(TPNetConfig(**SMALL)).state_dict()
    sd["head.weight"][0, 0] = float("inf")
    torch.save(sd, q)
    with pytest.raises(ValueError, match="'head.w' contains NaN or infinite"):
        import_torch(q)
    # a member declaring more than the limit is refused before torch.load
    monkeypatch.setattr(H, "MAX_MEMBER_BYTES", 1024)
    called = []
    monkeypatch.setattr(torch, "load", lambda *a, **k: called.append(1))
    with pytest.raises(ValueError, match="refused before reading"):
        import_torch(p)
    assert not called
