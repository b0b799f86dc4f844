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
from tpnet_ref.weights import native

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


def test_read_config_reads_the_config_alone_with_read_natives_checks(tmp_path):
    p = tmp_path / "w.h5"
    native.write_native(p, TINY, _params(TINY), "float32", {"source": "unit"})
    assert native.read_config(p) == native.read_native(p)[0] == TINY
    with h5py.File(p, "r+") as f:
        f.attrs["format_version"] = 99
    for reader in (native.read_config, native.read_native):
        with pytest.raises(ValueError, match="unsupported format_version 99") as exc:
            reader(p)
        assert "\n" not in str(exc.value)
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = np.zeros(3)
    with pytest.raises(ValueError, match="not a tpnet_ref weights file"):
        native.read_config(other)


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


def test_native_module_depends_only_on_config_the_guards_and_the_shipped_names():
    """native.py is what tpnet_ref.model is built on: it must not import the model (no cycle);
    besides the guards, only the bf16 / int8 grids (``quantize``, NumPy only)."""
    tree = ast.parse(Path(native.__file__).read_text())
    local = {("." * n.level) + (n.module or "") for n in ast.walk(tree)
             if isinstance(n, ast.ImportFrom) and n.level > 0}
    assert local == {"..config", ".", ".shipped"}       # ..config, . (hdf5, quantize), .shipped
    names = {a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.level == 1
             and not n.module for a in n.names}
    assert names == {"hdf5", "quantize"}


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
    assert f"stored as {dtype} (shuffle + gzip)\n" in native.describe(tmp_path / "gz.h5")


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_rounded_storage_changes_each_value_by_at_most_half_a_kept_ulp(tmp_path, dtype):
    """mantissa_bits=k (the reduced sizes' files): plain arrays of the compute dtype whose
    values have k significand bits (round half to even), relative change <= 2^-(k+1), and a
    smaller file; zeros, signs, subnormals and ties behave."""
    params = _params(TINY, dtype=np.dtype(dtype))
    params["head.b"][:4] = [0.0, -0.0, np.finfo(dtype).tiny / 8, -3.0]
    native.write_native(tmp_path / "gz.h5", TINY, params, dtype, storage="gzip")
    native.write_native(tmp_path / "r.h5", TINY, params, dtype, storage="gzip", mantissa_bits=10)
    _, back, meta = native.read_native(tmp_path / "r.h5")
    for k, v in params.items():
        assert back[k].dtype == np.dtype(dtype)
        nz = v != 0
        assert (np.abs(back[k] - v)[nz] <= 2.0 ** -11 * np.abs(v[nz])).all()
        assert (np.signbit(back[k]) == np.signbit(v)).all() and (back[k][~nz] == 0).all()
        np.testing.assert_array_equal(back[k], native.round_mantissa(v, 10))
    note = json.loads(meta["storage_rounding"])
    assert note["mantissa_bits"] == 10 and 0 < note["max_rel_change"] <= 2.0 ** -11
    assert (tmp_path / "r.h5").stat().st_size < (tmp_path / "gz.h5").stat().st_size
    assert "rounding     to 10 significand bits" in native.describe(tmp_path / "r.h5")
    # ties go to even: 1 + 2^-11 (halfway between 1 and 1 + 2^-10) -> 1; 1 + 3 * 2^-11 -> 1 + 2^-9
    x = np.array([1 + 2.0 ** -11, 1 + 3 * 2.0 ** -11, -(1 + 2.0 ** -11)], dtype=dtype)
    np.testing.assert_array_equal(native.round_mantissa(x, 10), [1, 1 + 2.0 ** -9, -1])


def test_rounded_storage_refusals(tmp_path):
    params = _params(TINY, dtype=np.float32)
    with pytest.raises(ValueError, match="^mantissa_bits: rounding only pays with storage='gzip'"):
        native.write_native(tmp_path / "h.h5", TINY, params, mantissa_bits=12)
    with pytest.raises(ValueError, match="^mantissa_bits: must be 1..22 for float32, got 23"):
        native.write_native(tmp_path / "h.h5", TINY, params, storage="gzip", mantissa_bits=23)
    with pytest.raises(ValueError, match="^mantissa_bits=1: a value rounds to infinity"):
        native.round_mantissa(np.array([np.finfo(np.float32).max]), 1)
    with pytest.raises(ValueError, match="storage must be None .* 'gzip', got 'int8'"):
        native.write_native(tmp_path / "h.h5", TINY, params, storage="int8")


def test_convert_storage_keeps_config_provenance_and_other_groups(tmp_path):
    params = _params(TINY)
    native.write_native(tmp_path / "p.h5", TINY, params, "float64", {"source": "unit"})
    with h5py.File(tmp_path / "p.h5", "a") as f:
        f.create_group("unit_order").create_dataset("lstm1", data=np.arange(5))
    native.seal(tmp_path / "p.h5")                        # a deliberate change: a new digest
    meta = native.convert_storage(tmp_path / "p.h5", tmp_path / "q.h5", "gzip", mantissa_bits=20)
    assert meta["source"] == "unit" and meta["storage"] == "gzip"
    assert meta["created"] == native.read_native(tmp_path / "p.h5")[2]["created"]
    assert (tmp_path / "q.h5").stat().st_mode & 0o777 == (tmp_path / "p.h5").stat().st_mode & 0o777
    cfg, back, _ = native.read_native(tmp_path / "q.h5")
    assert cfg == TINY and back["head.w"].dtype == np.float64
    with h5py.File(tmp_path / "q.h5") as f:
        np.testing.assert_array_equal(f["unit_order/lstm1"][()], np.arange(5))
    with h5py.File(tmp_path / "q.h5", "a") as f:
        f.attrs["storage"] = "bfloat8"                   # a newer writer's encoding
    with pytest.raises(ValueError, match="unknown storage 'bfloat8'"):
        native.read_native(tmp_path / "q.h5")


# ------------------------------------------------------------------ pinned by mutation testing
# (tools/mutation.py: each of these was a surviving mutant of native.py)
def test_describe_names_an_average_and_a_file_started_from_one(tmp_path):
    parent = [{"run": "runs/base", "steps": 10, "recipe": {
        "weights_file": "avg.h5", "source": "tpnet train average",
        "recipe": {"recipe": "average", "files": ["a.h5", "b.h5", "c.h5"]}, "parent_runs": []}},
        {"run": "runs/ft", "steps": 20, "recipe": {
            "weights_file": "ft.h5", "source": "runs/ft", "recipe": {"recipe": "curriculum",
                                                                     "lr": 0.0005}}}]
    meta = {"source": "runs/c", "parent_runs": json.dumps(parent),
            "average_of": json.dumps([{"weight": 0.25, "weights_file": "a.h5"},
                                      {"weight": 0.75, "weights_file": "b.h5"}])}
    p = tmp_path / "w.h5"
    native.write_native(p, TINY, _params(TINY), "float32", meta)
    text = native.describe(p)
    assert "written by tpnet train average (the mean of 3 files)" in text
    assert "written by runs/ft (curriculum recipe, lr 0.0005)" in text
    assert "  average of   0.25 x a.h5 + 0.75 x b.h5" in text.splitlines()


def test_the_digest_reads_a_string_the_same_whatever_type_h5py_gives():
    assert native._canon(b"abc") == native._canon(np.bytes_(b"abc")) == b"Babc"
    assert native._canon("abc") == b"sabc" != native._canon(b"abc")
    listed = native._canon(np.array([b"a", b"b"]))                     # a list of strings
    assert listed == b"l" + b"".join(len(x).to_bytes(8, "little") + x for x in (b"Ba", b"Bb"))
