"""tpnet_ref.weights.hdf5: the guards every reader of an untrusted HDF5 file goes through, one by one --
links, outside storage, declared sizes before reading, dtypes and shapes, NaN, damaged files."""
from __future__ import annotations

import numpy as np
import pytest

h5py = pytest.importorskip("h5py")

from tpnet_ref.weights import hdf5  # noqa: E402


@pytest.fixture
def h5(tmp_path):
    """A file with a plain dataset, a group, a soft link, an external link, an external-storage
    dataset, a big attribute and a NaN dataset."""
    (tmp_path / "raw.bin").write_bytes(np.arange(4, dtype="<f8").tobytes())
    path = tmp_path / "f.h5"
    with h5py.File(path, "w") as f:
        f["w"] = np.ones((2, 3))
        g = f.create_group("g")
        g["b"] = np.zeros(3)
        g["ints"] = np.arange(3)
        f["soft"] = h5py.SoftLink("/w")
        f["g/soft"] = h5py.SoftLink("/g/b")
        f["ext"] = h5py.ExternalLink("other.h5", "/w")
        f.create_dataset("outside", shape=(4,), dtype="<f8",
                         external=[(str(tmp_path / "raw.bin"), 0, 32)])
        f["nan"] = np.array([1.0, np.nan])
        f.attrs["small"] = np.arange(3)
        f.attrs["big"] = np.zeros(10, dtype=np.uint8)
        f.attrs["name"] = b"bytes"
    return path


def test_attributes_are_plain_values_and_their_size_checked_before_reading(h5, monkeypatch):
    monkeypatch.setattr(hdf5, "MAX_ATTR_ELEMENTS", 5)              # read at call time: limit 5
    with h5py.File(h5, "r") as f:
        assert hdf5.py_value(hdf5.attr(f, "small", "f")) == (0, 1, 2)
        assert hdf5.py_str(hdf5.attr(f, "name", "f")) == "bytes"
        assert hdf5.attr(f, "absent", "f", default=7) == 7
        with pytest.raises(ValueError, match=r"f: attribute 'big' of / declares 10 elements"):
            hdf5.attr(f, "big", "f")
        with pytest.raises(ValueError, match="'big'"):
            hdf5.attrs(f, "f")                              # every attribute goes through attr


@pytest.mark.parametrize("value, plain", [(np.bool_(True), True), (np.int64(3), 3),
                                          (np.float32(0.5), 0.5), (b"x", "x"), ("y", "y")])
def test_py_value(value, plain):
    got = hdf5.py_value(value)
    assert got == plain and type(got) is type(plain)


def test_links_and_outside_storage_are_refused(h5):
    with h5py.File(h5, "r") as f:
        assert hdf5.safe_dataset(f, "w", "f").shape == (2, 3)
        assert hdf5.safe_child(f, "g/b", "f").shape == (3,)
        assert isinstance(hdf5.safe_group(f, "g", "f"), h5py.Group)
        for name, kind in (("soft", "SoftLink"), ("ext", "ExternalLink")):
            with pytest.raises(ValueError, match=f"'{name}' is a {kind}; links are not accepted"):
                hdf5.safe_dataset(f, name, "f")
        with pytest.raises(ValueError, match="/g/soft is a SoftLink"):
            hdf5.safe_child(f, "g/soft", "f")                # a link anywhere on the path
        for fn in (hdf5.safe_dataset, hdf5.safe_child):
            with pytest.raises(ValueError, match="'outside' stores its data outside the file"):
                fn(f, "outside", "f")
        with pytest.raises(KeyError, match="missing dataset 'nope'"):
            hdf5.safe_dataset(f, "nope", "f")
        with pytest.raises(ValueError, match="missing 'g/nope'"):
            hdf5.safe_child(f, "g/nope", "f")
        with pytest.raises(ValueError, match="'w' is not a group"):
            hdf5.safe_group(f, "w", "f")
        with pytest.raises(ValueError, match="'g' is not a dataset"):
            hdf5.safe_dataset(f, "g", "f")


def test_read_array_checks_dtype_shape_and_values(h5):
    with h5py.File(h5, "r") as f:
        np.testing.assert_array_equal(hdf5.read_array(f, "w", (2, 3), "f"), np.ones((2, 3)))
        with pytest.raises(ValueError, match=r"'w' has shape \(2, 3\), expected \(3, 2\)"):
            hdf5.read_array(f, "w", (3, 2), "f")
        with pytest.raises(ValueError, match="'ints' has dtype int64, expected floating point"):
            hdf5.read_array(f["g"], "ints", (3,), "f")
        with pytest.raises(ValueError, match="'nan' contains NaN or infinite values"):
            hdf5.read_array(f, "nan", (2,), "f")
    with pytest.raises(ValueError, match=r"x: shape \(2,\), expected \(3,\)"):
        hdf5.check_shape(np.zeros(2), (3,), "x")


def test_vectors_round_trip_and_refuse_other_content(h5):
    hdf5.write_vectors(h5, "masks", "tpnet-masks-1", {"a": [1, 2, 3]}, np.int32, layers=2)
    hdf5.write_vectors(h5, "masks", "tpnet-masks-1", {"b": [4]}, np.int32)     # replaced
    got = hdf5.read_vectors(h5, "masks", "tpnet-masks-1", "mask set")
    assert list(got) == ["b"] and got["b"].tolist() == [4] and got["b"].dtype == np.int32
    assert hdf5.read_vectors(h5, "absent", "tpnet-masks-1", "mask set") is None
    with pytest.raises(ValueError, match="group 'masks' is not a other-1 mask set"):
        hdf5.read_vectors(h5, "masks", "other-1", "mask set")
    hdf5.write_vectors(h5, "masks", "tpnet-masks-1", {"b": [0.5]}, np.float64)
    with pytest.raises(ValueError, match="masks/b is not a mask set"):          # not integers
        hdf5.read_vectors(h5, "masks", "tpnet-masks-1", "mask set")


def test_open_h5_and_damaged_files_give_one_documented_error(tmp_path, h5):
    with pytest.raises(FileNotFoundError, match="weights file not found"):
        hdf5.open_h5(tmp_path / "missing.h5")
    text = tmp_path / "t.h5"
    text.write_text("not hdf5")
    with pytest.raises(ValueError, match="not a readable HDF5 file"):
        hdf5.open_h5(text)
    with hdf5.open_h5(h5) as f:
        assert "w" in f

    @hdf5.damaged_file_is_value_error
    def reader(path):
        with h5py.File(path, "r"):
            pass

    damaged = tmp_path / "d.h5"
    damaged.write_bytes(hdf5.HDF5_MAGIC + b"\0" * 100)           # the magic, then nothing
    with pytest.raises(ValueError, match=r"d\.h5: damaged or unreadable file") as info:
        reader(damaged)
    assert "\n" not in str(info.value)
    with pytest.raises(FileNotFoundError):                        # a missing file stays missing
        reader(tmp_path / "missing.h5")


def test_compressed_datasets_gzip_and_shuffle_only_and_bounded(tmp_path):
    """gzip and shuffle are decoded here chunk by chunk, each chunk inflated to at most its
    declared size; any other filter is refused by name, and so is a chunk that inflates to more
    than its shape holds (a "gzip bomb")."""
    import zlib

    data = np.arange(1000, dtype="<f4").reshape(10, 100)
    p = tmp_path / "c.h5"
    with h5py.File(p, "w") as f:
        f.create_dataset("gz", data=data, chunks=(3, 40), compression="gzip", shuffle=True)
        f.create_dataset("plain_chunks", data=data, chunks=(5, 50))
        f.create_dataset("lzf", data=data, compression="lzf")
        f.create_dataset("fletcher", data=data, fletcher32=True)
        d = f.create_dataset("bomb", shape=(4,), dtype="<f8", chunks=(4,), compression="gzip")
        d.id.write_direct_chunk((0,), zlib.compress(bytes(1 << 20)))     # 1 MiB in a 32-byte chunk
    with hdf5.open_h5(p) as f:
        np.testing.assert_array_equal(hdf5.read(f["gz"], "gz"), data)
        np.testing.assert_array_equal(hdf5.read(f["plain_chunks"], "pc"), data)
        assert [name for _, name in hdf5.filters(f["gz"])] == ["shuffle", "deflate"] or \
            [code for code, _ in hdf5.filters(f["gz"])] == [2, 1]
        with pytest.raises(ValueError, match="^lzf: stored with the HDF5 filter lzf"):
            hdf5.read(f["lzf"], "lzf")
        with pytest.raises(ValueError, match="only gzip and shuffle are accepted"):
            hdf5.read(f["fletcher"], "fletcher")
        with pytest.raises(ValueError, match="^bomb: a compressed chunk holds more than its "
                                             "declared 32 bytes; refused"):
            hdf5.read(f["bomb"], "bomb")


# ------------------------------------------------------------------ pinned by mutation testing
# (tools/mutation.py: each of these was a surviving mutant of hdf5.py)
def test_chunks_that_store_too_much_skip_a_filter_or_end_early(tmp_path):
    """A chunk that stores more than twice its size is refused before inflating; a chunk whose
    writer skipped the gzip filter (its filter mask) is read without it; a deflate stream that
    holds the chunk's bytes but never ends is refused."""
    import zlib

    data = np.arange(8, dtype="<f4")
    shuffled = data.view(np.uint8).reshape(-1, 4).T.tobytes()           # shuffle's byte planes
    p = tmp_path / "c.h5"
    with h5py.File(p, "w") as f:
        d = f.create_dataset("big", shape=(8,), dtype="<f4", chunks=(8,), compression="gzip")
        d.id.write_direct_chunk((0,), np.random.default_rng(0).bytes(2 * 32 + 1025))
        d = f.create_dataset("raw", shape=(8,), dtype="<f4", chunks=(8,), compression="gzip",
                             shuffle=True)
        d.id.write_direct_chunk((0,), shuffled, filter_mask=0b10)     # gzip (filter 1) skipped
        d = f.create_dataset("open", shape=(8,), dtype="<f4", chunks=(8,), compression="gzip")
        z = zlib.compressobj()
        d.id.write_direct_chunk((0,), z.compress(data.tobytes()) + z.flush(zlib.Z_SYNC_FLUSH))
        d = f.create_dataset("short", shape=(8,), dtype="<f4", chunks=(8,), shuffle=True)
        d.id.write_direct_chunk((0,), shuffled[:5])                    # 5 bytes for 32
    with hdf5.open_h5(p) as f:
        assert [code for code, _ in hdf5.filters(f["raw"])] == [2, 1]    # shuffle, then gzip
        with pytest.raises(ValueError, match=r"^big: a chunk stores 1,089 bytes for 32$"):
            hdf5.read(f["big"], "big")
        np.testing.assert_array_equal(hdf5.read(f["raw"], "raw"), data)
        with pytest.raises(ValueError, match="^open: a compressed chunk holds more than"):
            hdf5.read(f["open"], "open")
        with pytest.raises(ValueError, match=r"^short: a chunk holds 5 bytes, expected 32$"):
            hdf5.read(f["short"], "short")


def test_a_chunk_missing_from_a_compressed_dataset_is_refused(tmp_path):
    """A chunk never written reads as uninitialised memory in the decoder: refused by count."""
    p = tmp_path / "c.h5"
    with h5py.File(p, "w") as f:
        d = f.create_dataset("holes", shape=(16,), dtype="<f4", chunks=(8,), compression="gzip")
        import zlib
        d.id.write_direct_chunk((0,), zlib.compress(np.ones(8, "<f4").tobytes()))
    with hdf5.open_h5(p) as f:
        with pytest.raises(ValueError, match=r"^holes: 1 chunks stored, the shape needs 2$"):
            hdf5.read(f["holes"], "holes")


def test_vectors_hold_up_to_2_to_the_20_values(h5):
    n = 1 << 20
    hdf5.write_vectors(h5, "masks", "tpnet-masks-1", {"a": np.arange(n)}, np.int32)
    assert hdf5.read_vectors(h5, "masks", "tpnet-masks-1", "mask set")["a"].size == n
    hdf5.write_vectors(h5, "masks", "tpnet-masks-1", {"a": np.arange(n + 1)}, np.int32)
    with pytest.raises(ValueError, match="masks/a is not a mask set"):
        hdf5.read_vectors(h5, "masks", "tpnet-masks-1", "mask set")


def test_the_size_limits_are_the_ones_the_docs_state():
    """docs/reliability.md, "Untrusted weight files", states the limits; these are they."""
    from pathlib import Path
    text = " ".join((Path(__file__).resolve().parents[1] / "docs" / "reliability.md")
                    .read_text().split())
    assert hdf5.MAX_TENSOR == 2 ** 25 and "tensors above 2^25 elements" in text
    assert hdf5.MAX_MEMBER_BYTES == 2 ** 30 and "archive members above 1 GiB" in text
    assert hdf5.MAX_CONFIG_BYTES == 16 * 2 ** 20 and "`config.json` above 16 MiB" in text
