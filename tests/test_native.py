"""The native weights file on its own: write/read round trip without a TPNet, the shipped-weights
lookup order (TPNET_WEIGHTS_DIR, the wheel's copy, the repository), and the readable summary."""
from __future__ import annotations

import ast
import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from tpnet_ref.config import TPNetConfig, param_shapes
from tpnet_ref import native

TINY = TPNetConfig(mlp1=(4, 4), mlp2=(4, 8), global_features=6, lstm_units=(5, 3), n_out=7,
                   feature_transform_trained=True, feature_tnet_mlp=(4,), feature_tnet_fc=(3,))


def _params(cfg, seed=0, dtype=np.float64):
    rng = np.random.default_rng(seed)
    return {k: rng.standard_normal(s).astype(dtype) for k, s in param_shapes(cfg).items()}


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_write_read_round_trip_is_bit_exact_and_keeps_provenance(tmp_path, dtype):
    params = _params(TINY, dtype=np.dtype(dtype))
    p = tmp_path / "w.h5"
    native.write_native(p, TINY, params, dtype, {"source": "unit", "steps": 7, "path": "elsewhere"})
    cfg, back, meta = native.read_native(p)
    assert cfg == TINY
    assert list(back) == list(param_shapes(TINY))                    # stored in forward order
    for k, v in params.items():
        assert back[k].dtype == np.dtype(dtype)
        np.testing.assert_array_equal(back[k], v)
    assert meta["source"] == "unit" and meta["steps"] == 7 and meta["producer"] == "tpnet_ref"
    assert meta["path"] == str(p) and "created" in meta                # path is where it was read
    assert native.is_native(p)


def test_write_casts_to_the_requested_dtype_and_refuses_misfits(tmp_path):
    params = _params(TINY)
    native.write_native(tmp_path / "a.h5", TINY, params, "float32")
    _, back, _ = native.read_native(tmp_path / "a.h5")
    assert all(v.dtype == np.float32 for v in back.values())
    with h5py.File(tmp_path / "a.h5") as f:
        assert f.attrs["dtype"] == "float32"
    bad = dict(params, **{"head.w": np.zeros((2, 2))})
    with pytest.raises(ValueError, match="parameter 'head.w'"):
        native.write_native(tmp_path / "b.h5", TINY, bad)
    with pytest.raises(ValueError, match="missing \\['head.b'\\]"):
        native.write_native(tmp_path / "b.h5", TINY, {k: v for k, v in params.items() if k != "head.b"})
    with pytest.raises(ValueError, match="dtype"):
        native.write_native(tmp_path / "b.h5", TINY, params, "float16")


def test_native_module_depends_only_on_config_and_the_guards():
    """native.py is what tpnet_ref.model is built on: it must not import the model (no cycle)."""
    tree = ast.parse(Path(native.__file__).read_text())
    local = {("." * n.level) + (n.module or "") for n in ast.walk(tree)
             if isinstance(n, ast.ImportFrom) and n.level > 0}
    assert local == {".config", "."}                                    # .config, . (hdf5)
    names = {a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.level == 1
             and not n.module for a in n.names}
    assert names == {"hdf5"}


def _shipped(tmp_path, monkeypatch, wheel, repo):
    """A fake wheel dir holding ``wheel`` and a fake repository weights/ holding ``repo``."""
    w, r = tmp_path / "shipped", tmp_path / "weights"
    for d, ms in ((w, wheel), (r, repo)):
        d.mkdir()
        for m in ms:
            (d / f"tpnet-m{m}.h5").write_bytes(b"")
    monkeypatch.setattr(native, "SHIPPED_DIR", w)
    monkeypatch.setattr(native, "REPO_WEIGHTS_DIR", r)
    monkeypatch.delenv("TPNET_WEIGHTS_DIR", raising=False)
    return w, r


def test_shipped_lookup_prefers_env_then_wheel_then_repository(tmp_path, monkeypatch):
    w, r = _shipped(tmp_path, monkeypatch, wheel=[4], repo=[3, 4, 5])
    assert native.default_weights_path() == w / "tpnet-m4.h5"
    assert native.shipped_weights_path(3) == r / "tpnet-m3.h5"      # the wheel has m = 4 only
    assert native.weights_dir() == w
    env = tmp_path / "env"
    env.mkdir()
    (env / "tpnet-m4.h5").write_bytes(b"")
    monkeypatch.setenv("TPNET_WEIGHTS_DIR", str(env))
    assert native.default_weights_path() == env / "tpnet-m4.h5"
    assert native.weights_dir() == env
    with pytest.raises(FileNotFoundError, match="no shipped weights tpnet-m5.h5 in .*env"):
        native.shipped_weights_path(5)                                  # no silent fallback


def test_missing_model_in_a_wheel_install_is_one_line(tmp_path, monkeypatch):
    _shipped(tmp_path, monkeypatch, wheel=[4], repo=[])
    (tmp_path / "weights").rmdir()                                       # no repository checkout
    with pytest.raises(FileNotFoundError) as exc:
        native.shipped_weights_path(3)
    msg = str(exc.value)
    assert "\n" not in msg and "pass the path" in msg and "TPNET_WEIGHTS_DIR" in msg
    assert native.shipped_weights_path(4).parent.name == "shipped"
    with pytest.raises(ValueError, match="m = 3, 4 and 5"):
        native.shipped_weights_path(6)


def test_reduced_sizes_and_untracked_files_are_found_or_named(tmp_path, monkeypatch):
    w, r = _shipped(tmp_path, monkeypatch, wheel=[4], repo=[4])
    for size in native.SHIPPED_SIZES:
        (r / f"tpnet-m4-{size}.h5").write_bytes(b"")
        assert native.shipped_weights_path(4, size) == r / f"tpnet-m4-{size}.h5"
        with pytest.raises(ValueError, match="m = 4 only"):
            native.shipped_weights_path(3, size)
    assert native.shipped_weights_path(4, "full") == w / "tpnet-m4.h5"
    with pytest.raises(ValueError, match="no model is shipped at size='huge'"):
        native.shipped_weights_path(4, "huge")
    with pytest.raises(FileNotFoundError, match="tools/restore_weights.sh") as exc:
        native.shipped_weights_path(5)                  # not tracked by git: the command says how
    assert "\n" not in str(exc.value)


def test_load_by_size_reads_the_shipped_file(tmp_path, monkeypatch):
    import tpnet_ref
    _shipped(tmp_path, monkeypatch, wheel=[], repo=[])
    cfg = TINY
    size = native.SHIPPED_SIZES[0]
    native.write_native(tmp_path / "weights" / f"tpnet-m4-{size}.h5", cfg, _params(cfg))
    model = tpnet_ref.load(size=size)
    assert model.config == cfg
    with pytest.raises(ValueError, match="either a path or m= / size="):
        tpnet_ref.load(tmp_path / "weights" / f"tpnet-m4-{size}.h5", size=size)


def test_describe_is_a_short_readable_summary(tmp_path):
    runs = [{"run": "runs/a", "data": "d.h5", "steps": 100, "epochs": 1.5, "wall_s": 7200.0,
             "windows_seen": 12800, "recipe": {"recipe": "curriculum", "lr": 0.001}}]
    meta = {"source": "runs/b", "producer": "tpnet_ref.training", "training_steps": 250,
            "epochs": 3.0, "wall_time_s": 10800.0, "parent_runs": json.dumps(runs),
            "recipe": json.dumps({"x": "y" * 5000}), "val": json.dumps({"val_cd1": 0.123456})}
    p = tmp_path / "w.h5"
    native.write_native(p, TINY, _params(TINY), "float32", meta)
    text = native.describe(p)
    lines = text.splitlines()
    n = sum(int(np.prod(s)) for s in param_shapes(TINY).values())
    assert f"{n:,} parameters stored as float32" in lines[0]
    assert "m=4 frames in, N=7 points out" in text and "feature trained" in text
    assert "val_cd1 0.1235" in text
    assert any(line.strip() == "1. runs/a: curriculum recipe, lr 0.001, 100 steps, 1.50 epochs, "
               "2.00 h on d.h5" for line in lines)
    assert any(line.strip().startswith("2. runs/b: this file, total 250 steps") for line in lines)
    assert max(len(line) for line in lines) < 200                      # no KB-long JSON line


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_gzip_storage_is_lossless_and_smaller(tmp_path, dtype):
    """storage="gzip" (the shipped paper-size file): the same bits as the plain file, read back
    in the compute dtype, with shuffle + gzip on every parameter."""
    params = {k: np.round(v, 2).astype(dtype) for k, v in _params(TINY, dtype=np.dtype(dtype)).items()}
    native.write_native(tmp_path / "plain.h5", TINY, params, dtype)
    native.write_native(tmp_path / "gz.h5", TINY, params, dtype, storage="gzip")
    _, back, meta = native.read_native(tmp_path / "gz.h5")
    for k, v in params.items():
        assert back[k].dtype == np.dtype(dtype)
        np.testing.assert_array_equal(back[k], v)
    assert meta["storage"] == "gzip" and "storage_rounding" not in meta
    with h5py.File(tmp_path / "gz.h5") as f:
        assert f["params/head.w"].compression == "gzip" and f["params/head.w"].shuffle
    assert "(shuffle + gzip, lossless)" in native.describe(tmp_path / "gz.h5")


def test_float16_storage_rounds_once_and_reads_back_the_stored_values(tmp_path):
    params = _params(TINY)
    params["head.b"][:7] = [1e-9, 3e-6, 1.0, -2.5, 0.1, 7.0, 0.0]    # to 0, subnormal, exact
    native.write_native(tmp_path / "h.h5", TINY, params, "float32", storage="float16")
    _, back, meta = native.read_native(tmp_path / "h.h5")
    for k, v in params.items():
        assert back[k].dtype == np.float32                              # computed as float32
        np.testing.assert_array_equal(back[k], v.astype(np.float32).astype(np.float16))
    rounding = json.loads(meta["storage_rounding"])
    assert rounding["nonzero_to_zero"] >= 1 and rounding["subnormal"] >= 1
    assert 0 < rounding["max_rel_change_normal"] <= 2.0 ** -11                # half an ulp
    assert "float16 (shuffle + gzip; lossy" in native.describe(tmp_path / "h.h5")
    # converting keeps the config, provenance and the other groups
    native.write_native(tmp_path / "p.h5", TINY, params, "float64", {"source": "unit"})
    with h5py.File(tmp_path / "p.h5", "a") as f:
        f.create_group("unit_order").create_dataset("lstm1", data=np.arange(5))
    meta = native.convert_storage(tmp_path / "p.h5", tmp_path / "q.h5", "float16")
    assert meta["source"] == "unit" and meta["storage"] == "float16"
    assert (tmp_path / "q.h5").stat().st_mode & 0o777 == (tmp_path / "p.h5").stat().st_mode & 0o777
    with h5py.File(tmp_path / "q.h5") as f:
        assert f.attrs["dtype"] == "float64"
        np.testing.assert_array_equal(f["unit_order/lstm1"][()], np.arange(5))


def test_float16_storage_refuses_what_it_cannot_hold(tmp_path):
    params = _params(TINY)
    params["head.w"] = params["head.w"] * 1e5
    with pytest.raises(ValueError, match="^parameter 'head.w': .* beyond float16's range"):
        native.write_native(tmp_path / "h.h5", TINY, params, storage="float16")
    with pytest.raises(ValueError, match="storage must be None .* 'gzip', 'float16', got 'int8'"):
        native.write_native(tmp_path / "h.h5", TINY, _params(TINY), storage="int8")


def test_a_file_whose_storage_attribute_lies_is_refused(tmp_path):
    native.write_native(tmp_path / "a.h5", TINY, _params(TINY), "float32")
    with h5py.File(tmp_path / "a.h5", "a") as f:
        f.attrs["storage"] = "float16"                   # but the arrays are float32
    with pytest.raises(ValueError, match="storage says float16 but '[^']+' is float32"):
        native.read_native(tmp_path / "a.h5")
    with h5py.File(tmp_path / "a.h5", "a") as f:
        f.attrs["storage"] = "bfloat8"
    with pytest.raises(ValueError, match="unknown storage 'bfloat8'"):
        native.read_native(tmp_path / "a.h5")
