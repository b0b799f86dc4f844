"""What ships names no machine and a damaged file is caught by name.

- Every shipped weights file (``tpnet info --json``) and every tracked text file names no
  absolute path of a development machine; every shipped weights file carries a content digest.
- A bit flipped anywhere in a stored array (every parameter, the unit order, the masks, a config
  value) of a native file is refused by ``tpnet_ref.load`` and by ``tpnet info`` (exit 2), each
  error naming the file: plain and gzip storage, and the shipped quarter-size file.
- ``tpnet scrub-provenance`` rewrites a file's provenance and keeps every array bit-identical.
"""
from __future__ import annotations

import hashlib
import json
import re
import shutil
import subprocess
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

import tpnet_ref
from tpnet_ref.weights import native
from tpnet_ref.engines import specialised as S
from tpnet_ref.engines import unit_order as U
from tpnet_ref.cli import main
from tpnet_ref.model import init_random
from tpnet_ref.weights.provenance import absolute_paths, portable_path, scrub

from ring_helpers import SMALL, rings

REPO = Path(__file__).resolve().parents[1]
#: the roots of development machines' absolute paths (POSIX homes and work trees, Windows)
DEV_PATH = re.compile(r"(?<![\w.~/:-])/(?:work|home|Users|root|mnt|scratch|data|srv)/[\w.+@-]"
                      r"|\b[A-Za-z]:\\(?:Users|work)\\", re.IGNORECASE)
SCRUB = "tpnet scrub-provenance weights/{0} weights/{0}"


def _shipped_files() -> list[Path]:
    """The tracked weights files, and tpnet-m3/m5.h5 where restored into weights/."""
    return sorted((REPO / "weights").glob("*.h5"))


def _info_json(path: Path, capsys) -> dict:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", native.UnverifiedFileWarning)
        assert main(["info", "--json", str(path)]) == 0
    return json.loads(capsys.readouterr().out)


def _strings(x):
    if isinstance(x, str):
        yield x
        try:                                   # JSON inside an attribute (the chain of runs)
            inner = json.loads(x)
        except ValueError:
            return
        if not isinstance(inner, str):
            yield from _strings(inner)
    elif isinstance(x, dict):
        for k, v in x.items():
            yield from _strings(k)
            yield from _strings(v)
    elif isinstance(x, (list, tuple)):
        for v in x:
            yield from _strings(v)


@pytest.mark.parametrize("name", [p.name for p in _shipped_files()])
def test_shipped_weights_name_no_machine_path_and_carry_a_digest(name, capsys):
    """Fails for a file that records a machine's path, or lacks a digest, until it is rewritten with
    ``tpnet scrub-provenance weights/F weights/F`` (parameters bit-identical, checked)."""
    info = _info_json(REPO / "weights" / name, capsys)
    meta = {k: v for k, v in info["meta"].items() if k != "path"}    # path: where it was read
    found = sorted({p for s in _strings(meta) for p in absolute_paths(s)})
    assert not found, f"{name} records absolute paths {found}: run `{SCRUB.format(name)}`"
    if native.DIGEST_ATTR not in meta and name in _pinned():
        # tpnet-m3/m5.h5 are not tracked: tools/restore_weights.sh writes them back from git's
        # history, byte for byte, as they were shipped (before digests); the script's SHA-256
        # of the whole file stands in for the digest, and must match
        got = hashlib.sha256((REPO / "weights" / name).read_bytes()).hexdigest()
        assert got == _pinned()[name], (f"{name}: SHA-256 {got} is not the one "
                                        "tools/restore_weights.sh pins: damaged or replaced")
        return
    assert native.DIGEST_ATTR in meta, f"{name} has no content digest: run `{SCRUB.format(name)}`"


def _pinned() -> dict[str, str]:
    """The files tools/restore_weights.sh restores, with the SHA-256 it checks them against."""
    text = (REPO / "tools" / "restore_weights.sh").read_text()
    return dict(re.findall(r"\[(tpnet-m\d\.h5)\]=([0-9a-f]{64})", text))


def test_tracked_text_names_no_development_machine_path():
    try:
        files = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True,
                               check=True).stdout.decode().split("\0")
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    hits = []
    for name in filter(None, files):
        p = REPO / name
        if not p.is_file() or p.is_symlink():
            continue
        data = p.read_bytes()
        if b"\0" in data[:8192]:               # binary (the weights: the test above)
            continue
        for i, line in enumerate(data.decode("utf-8", "replace").splitlines(), 1):
            if DEV_PATH.search(line):
                hits.append(f"{name}:{i}: {line.strip()[:100]}")
    assert not hits, "absolute paths of a development machine:\n" + "\n".join(hits)


# ---------------------------------------------------------------------------------- flips
def _storage(path: Path) -> dict[str, list[tuple[int, int]]]:
    """``{group/dataset: [(file offset, bytes), ...]}`` of every dataset's stored bytes."""
    out = {}
    with h5py.File(path, "r") as f:
        def visit(name, obj):
            if not isinstance(obj, h5py.Dataset):
                return
            if obj.chunks is None:
                out[name] = [(obj.id.get_offset(), obj.id.get_storage_size())]
            else:
                out[name] = [(c.byte_offset, c.size) for c in
                             (obj.id.get_chunk_info(i) for i in range(obj.id.get_num_chunks()))]
        f.visititems(visit)
    return out


def _refused(path: Path, capsys, info: bool = True) -> None:
    """``load`` and (``info``) ``tpnet info`` both refuse ``path``, naming it, in one line."""
    with pytest.raises(ValueError) as err:
        with warnings.catch_warnings():
            warnings.simplefilter("error", native.UnverifiedFileWarning)
            tpnet_ref.load(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)
    if not info:
        return
    capsys.readouterr()
    assert main(["info", str(path)]) == 2
    e = capsys.readouterr().err
    assert e.startswith("tpnet info: error: ") and str(path) in e and e.count("\n") == 1


def _flip_every_array(src: Path, tmp: Path, capsys, rng, flips: int = 1) -> int:
    """Copies of ``src`` with one bit flipped at a random place of each dataset's stored bytes
    (``flips`` places each): every one refused by name by ``load`` (and every third also by
    ``tpnet info``, which reads the file through the same reader). Returns how many were tried."""
    n = 0
    for name, spans in _storage(src).items():
        for _ in range(flips):
            off, size = spans[rng.integers(len(spans))]
            at = off + int(rng.integers(size))
            bad = tmp / f"flip{n}.h5"
            shutil.copyfile(src, bad)
            with open(bad, "r+b") as fh:
                fh.seek(at)
                b = fh.read(1)[0]
                fh.seek(at)
                fh.write(bytes([b ^ (1 << int(rng.integers(8)))]))
            _refused(bad, capsys, info=n % 3 == 0)
            bad.unlink()
            n += 1
    return n


@pytest.fixture(scope="module")
def small_file(tmp_path_factory):
    """A small network with a unit order and a specialisation's masks, saved plain and gzip."""
    rng = np.random.default_rng(0)
    model = init_random(SMALL, seed=3)
    model = model.with_unit_order({k: rng.permutation(n) for k, n in U.sizes(SMALL).items()})
    model = model.specialize(rings(rng, 6))
    d = tmp_path_factory.mktemp("integrity")
    model.save(d / "plain.h5", source="unit test")
    native.convert_storage(d / "plain.h5", d / "gzip.h5", "gzip")
    return d


@pytest.mark.parametrize("kind", ["plain", "gzip"])
def test_a_bit_flipped_in_any_stored_array_is_refused_naming_the_file(small_file, kind, tmp_path,
                                                                      capsys):
    src = small_file / f"{kind}.h5"
    groups = {name.split("/")[0] for name in _storage(src)}
    assert groups == {"params", "unit_order", "specialization"}
    tpnet_ref.load(src)                                    # intact: loads, no warning
    n = _flip_every_array(src, tmp_path, capsys, np.random.default_rng(1 + (kind == "gzip")))
    # every array the file holds, counted through the reader, not through _storage's walk
    _, params, _ = native.read_native(src)
    unit_order, masks = U.read(src), S.read(src)
    assert unit_order and masks
    assert n == len(params) + len(unit_order) + len(masks)


def test_a_changed_config_value_or_provenance_is_refused(small_file, tmp_path, capsys):
    src = small_file / "plain.h5"
    data = src.read_bytes()
    for needle in (np.float64(SMALL.norm_hi).tobytes(), b"unit test"):
        at = data.find(needle)
        assert at > 0
        bad = tmp_path / "changed.h5"
        bad.write_bytes(data[:at] + bytes([data[at] ^ 0x01]) + data[at + 1:])
        _refused(bad, capsys)


def test_the_shipped_quarter_file_refuses_every_flip(tmp_path, capsys):
    """Fails until weights/tpnet-m4-quarter.h5 carries a digest (`tpnet scrub-provenance`):
    without one a flipped mask or unit-order bit can go unnoticed."""
    src = REPO / "weights" / "tpnet-m4-quarter.h5"
    if not src.is_file():
        pytest.skip("no weights/tpnet-m4-quarter.h5 here")
    with h5py.File(src, "r") as f:
        assert native.DIGEST_ATTR in f.attrs, f"no digest: run `{SCRUB.format(src.name)}`"
    _flip_every_array(src, tmp_path, capsys, np.random.default_rng(2))


def test_a_file_without_a_digest_loads_with_a_warning_naming_it(small_file, tmp_path, capsys):
    old = tmp_path / "old.h5"
    shutil.copyfile(small_file / "plain.h5", old)
    with h5py.File(old, "r+") as f:
        del f.attrs[native.DIGEST_ATTR]
    with pytest.warns(native.UnverifiedFileWarning, match=re.escape(str(old))):
        model = tpnet_ref.load(old)
    assert native.DIGEST_ATTR not in model.meta
    assert main(["info", str(old)]) == 0
    out = capsys.readouterr()
    assert str(old) in out.err and "no content digest" in out.out


# --------------------------------------------------------------------------- provenance
def test_scrub_keeps_every_array_and_removes_machine_paths(small_file, tmp_path, capsys):
    src = tmp_path / "abs.h5"
    model = tpnet_ref.load(small_file / "gzip.h5")
    runs = json.dumps([{"run": "/opt/someone/runs/m4", "data": "/opt/x/data/grid.h5",
                        "recipe": {"init_from": "/opt/someone/w.h5"}}])
    model.save(src, source="/opt/someone/runs/m4-faithful", data="/opt/project/data/grid-m4.h5",
               parent_runs=runs, note="read from /opt/someone/elsewhere/x.npy today")
    native.convert_storage(src, src, "gzip")
    data = tmp_path / "grid.h5"
    data.write_bytes(b"some training data")
    assert main(["scrub-provenance", str(src), str(tmp_path / "clean.h5"), "--data", str(data)]) == 0
    out = capsys.readouterr().out
    assert "bit-identical" in out and "source: /opt/someone/runs/m4-faithful -> runs/m4-faithful" in out
    _, p0, m0 = native.read_native(src)
    _, p1, m1 = native.read_native(tmp_path / "clean.h5")
    assert all(p0[k].tobytes() == p1[k].tobytes() for k in p0)
    assert U.read(src).keys() == U.read(tmp_path / "clean.h5").keys()
    assert all(np.array_equal(a, b) for a, b in zip(U.read(src).values(),
                                                    U.read(tmp_path / "clean.h5").values()))
    assert m1["source"] == "runs/m4-faithful" and m1["data"] == "data/grid-m4.h5"
    assert m1["note"] == "read from x.npy today" and m1["created"] == m0["created"]
    assert json.loads(m1["parent_runs"]) == [{"run": "runs/m4", "data": "data/grid.h5",
                                              "recipe": {"init_from": "w.h5"}}]
    assert m1["data_sha256"].startswith("sha256:") and m1["storage"] == "gzip"
    assert not [s for k, v in m1.items() if k != "path" for s in _strings(v) if absolute_paths(s)]
    again = scrub(tmp_path / "clean.h5", tmp_path / "clean.h5")       # in place: nothing left
    assert again["changed"] == {}          # no --data: data_sha256 kept as it is


def test_portable_path():
    assert portable_path("/x/y/runs/m4") == "runs/m4"
    assert portable_path("/x/y/data/grid-m4.h5") == "data/grid-m4.h5"
    assert portable_path("/tmp/w.h5") == "w.h5"
    assert portable_path("runs/m4") == "runs/m4" and portable_path("../a/b.h5") == "b.h5"
    assert portable_path(REPO / "weights" / "tpnet-m4.h5") == "weights/tpnet-m4.h5"
    assert portable_path("/a/b/c.h5", root="/a") == "b/c.h5"
    assert portable_path("C:\\Users\\me\\w.h5") == "w.h5"
