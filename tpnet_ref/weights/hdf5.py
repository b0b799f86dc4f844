"""Guards for reading untrusted HDF5 (and zip) weight files.

Every reader in :mod:`tpnet_ref.weights` goes through these: links (soft, external), external
storage and virtual datasets are refused, the declared size of an attribute or dataset is checked
*before* its data is read (a file cannot make us allocate an absurd amount), NaN and Inf values
are refused, and h5py's low-level errors on a damaged file become one ``ValueError`` naming it.
Compressed datasets are accepted with HDF5's standard gzip (deflate) and shuffle filters only, and
are decoded here chunk by chunk, each chunk inflated to at most its declared size: a "gzip bomb"
cannot make a reader allocate more than the dataset's declared (and checked) shape; any other
filter is refused by name. Nothing here unpickles anything. h5py is imported at first use, so that ``import tpnet_ref``
stays NumPy-only.

The ``MAX_*`` limits are read at call time, so a test may lower them with ``monkeypatch``.
"""
from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Any, Callable

import numpy as np

#: a config larger than this many parameters is refused as implausible (the paper's is ~8.1M)
MAX_PARAMS = 200_000_000
#: one imported tensor larger than this many elements is refused before it is read (the
#: released network's largest is 1M; a Keras 3 or torch file's declared sizes are checked too)
MAX_TENSOR = 1 << 25
#: an HDF5 attribute declaring more elements than this is refused before it is read
MAX_ATTR_ELEMENTS = 1 << 16
#: bytes: the largest member of a ``.keras`` archive or torch zip that is decompressed
MAX_MEMBER_BYTES = 1 << 30
#: bytes: the largest ``config.json`` of a ``.keras`` archive
MAX_CONFIG_BYTES = 16 << 20

HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"


def py_value(v: Any) -> Any:
    """An HDF5 attribute value as a plain Python value (arrays become tuples of ints)."""
    if isinstance(v, bytes):
        return v.decode()
    if isinstance(v, np.ndarray):
        return tuple(int(x) for x in v.tolist())
    if isinstance(v, np.bool_):
        return bool(v)
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.floating):
        return float(v)
    return v


def py_str(x: Any) -> str:
    return x.decode() if isinstance(x, bytes) else str(x)


def attr(obj: Any, name: str, where: str, default: Any = None) -> Any:
    """Attribute ``name`` of an HDF5 object, its declared size checked before it is read."""
    if name not in obj.attrs:
        return default
    shape = obj.attrs.get_id(name).shape
    n = int(np.prod(shape)) if shape else 1
    if n > MAX_ATTR_ELEMENTS:
        raise ValueError(f"{where}: attribute {name!r} of {obj.name} declares {n:,} elements "
                         f"(limit {MAX_ATTR_ELEMENTS:,}); refused")
    try:
        return obj.attrs[name]
    except (OSError, RuntimeError) as exc:
        raise ValueError(f"{where}: attribute {name!r} of {obj.name} cannot be read ({exc})") from None


def attrs(obj: Any, where: str) -> dict[str, Any]:
    """Every attribute of an HDF5 object, each checked by :func:`attr`."""
    names = list(obj.attrs.keys())
    if len(names) > MAX_ATTR_ELEMENTS:
        raise ValueError(f"{where}: {obj.name} has {len(names):,} attributes; refused")
    return {k: attr(obj, k, where) for k in names}


#: HDF5 filters a dataset may use: the standard ones every h5py build has (id -> name)
FILTERS = {1: "gzip", 2: "shuffle"}


def filters(ds: Any) -> list[tuple[int, str]]:
    """The filter pipeline of a dataset, in writing order: ``[(id, name), ...]``."""
    plist = ds.id.get_create_plist()
    out = []
    for i in range(plist.get_nfilters()):
        code, _flags, _values, name = plist.get_filter(i)
        out.append((int(code), py_str(name)))
    return out


def _decode_chunks(ds: Any, pipeline: list[tuple[int, str]], what: str) -> np.ndarray:
    """Read a chunked, filtered dataset chunk by chunk with the inverse of ``pipeline`` (gzip,
    shuffle) done here: each chunk is inflated to at most its declared byte size, so a chunk
    that claims more (a "gzip bomb") or less is refused before anything more is allocated."""
    import zlib

    shape, chunks, dt = tuple(ds.shape), tuple(ds.chunks), ds.dtype
    if len(chunks) != len(shape) or any(c < 1 or c > max(n, 1) for c, n in zip(chunks, shape)):
        raise ValueError(f"{what}: chunk shape {chunks} does not fit the dataset's {shape}")
    chunk_bytes = int(np.prod(chunks)) * dt.itemsize
    grid = tuple(-(-n // c) for n, c in zip(shape, chunks))
    out = np.empty(shape, dt)
    n_stored = ds.id.get_num_chunks()
    if n_stored != int(np.prod(grid)):
        raise ValueError(f"{what}: {n_stored} chunks stored, the shape needs {int(np.prod(grid))}")
    for i in range(n_stored):
        info = ds.id.get_chunk_info(i)
        off = tuple(int(o) for o in info.chunk_offset)
        if any(o % c or o >= max(n, 1) for o, c, n in zip(off, chunks, shape)):
            raise ValueError(f"{what}: chunk at {off} is outside the dataset")
        if info.size > 2 * chunk_bytes + 1024:
            raise ValueError(f"{what}: a chunk stores {info.size:,} bytes for {chunk_bytes:,}")
        mask, data = ds.id.read_direct_chunk(off)
        for j in reversed(range(len(pipeline))):
            if mask & (1 << j):                           # the writer skipped this filter here
                continue
            if pipeline[j][0] == 1:                       # gzip: inflate, at most chunk_bytes
                z = zlib.decompressobj()
                try:
                    data = z.decompress(data, chunk_bytes)
                except zlib.error as exc:
                    raise ValueError(f"{what}: cannot be read, the file is damaged ({exc})") from None
                if not z.eof or z.unconsumed_tail:
                    raise ValueError(f"{what}: a compressed chunk holds more than its declared "
                                     f"{chunk_bytes:,} bytes; refused")
            else:                                         # shuffle: byte planes back to items
                if len(data) != chunk_bytes:
                    break                                 # reported below
                data = np.frombuffer(data, np.uint8).reshape(dt.itemsize, -1).T.tobytes()
        if len(data) != chunk_bytes:
            raise ValueError(f"{what}: a chunk holds {len(data):,} bytes, expected {chunk_bytes:,}")
        block = np.frombuffer(data, dt).reshape(chunks)
        sl = tuple(slice(o, min(o + c, n)) for o, c, n in zip(off, chunks, shape))
        out[sl] = block[tuple(slice(0, s.stop - s.start) for s in sl)]
    return out


def read(ds: Any, what: str) -> np.ndarray:
    """The data of a checked dataset (its shape already checked by the caller); a corrupted file
    gives ``ValueError`` naming it. A dataset with filters is accepted with gzip and shuffle
    only (:data:`FILTERS`) and decoded by :func:`_decode_chunks`, bounded by its shape."""
    try:
        pipeline = filters(ds)
        unknown = [f"{name or '?'} ({code})" for code, name in pipeline if code not in FILTERS]
        if unknown:
            raise ValueError(f"{what}: stored with the HDF5 filter {', '.join(unknown)}; only "
                             "gzip and shuffle are accepted")
        if pipeline:
            return _decode_chunks(ds, pipeline, what)
        return ds[()]
    except (OSError, RuntimeError) as exc:
        raise ValueError(f"{what}: cannot be read, the file is damaged ({exc})") from None


def damaged_file_is_value_error(fn: Callable) -> Callable:
    """Decorator: a reader's ``RuntimeError``/``OSError`` from h5py parsing a damaged file (other
    than a missing file) becomes ``ValueError`` naming the file, so that callers see only the
    documented exceptions (ValueError, TypeError, KeyError, FileNotFoundError)."""

    @functools.wraps(fn)
    def wrapper(path: Any, *args: Any, **kwargs: Any) -> Any:
        try:
            return fn(path, *args, **kwargs)
        except FileNotFoundError:
            raise
        except (RuntimeError, OSError) as exc:
            raise ValueError(f"{path}: damaged or unreadable file ({type(exc).__name__}: "
                             f"{str(exc)[:160]})") from None
    return wrapper


def _hard_child(parent: Any, name: str, where: str, kind: str, missing: type) -> Any:
    """``parent[name]`` if it is reached by a hard link and is an h5py ``kind``
    ("Dataset" or "Group"); ``missing`` is the exception raised when there is none."""
    import h5py

    link = parent.get(name, getlink=True)
    if link is None:
        raise missing(f"{where}: missing {kind.lower()} {name!r}")
    if not isinstance(link, h5py.HardLink):
        raise ValueError(f"{where}: {name!r} is a {type(link).__name__}; links are not accepted")
    obj = parent[name]
    if not isinstance(obj, getattr(h5py, kind)):
        raise ValueError(f"{where}: {name!r} is not a {kind.lower()}")
    return obj


def safe_dataset(group: Any, name: str, where: str) -> Any:
    """The dataset ``group[name]`` if it is a plain, internal, non-virtual dataset."""
    ds = _hard_child(group, name, where, "Dataset", KeyError)
    if ds.is_virtual or ds.external:
        raise ValueError(f"{where}: {name!r} stores its data outside the file; refused")
    return ds


def safe_group(parent: Any, name: str, where: str) -> Any:
    """The group ``parent[name]`` if it is reached by a hard link."""
    return _hard_child(parent, name, where, "Group", ValueError)


def safe_child(group: Any, name: str, where: str) -> Any:
    """``group[name]`` for a path ``a/b/c``, refusing any soft or external link on the way."""
    import h5py

    obj = group
    for part in name.split("/"):
        if not part:
            continue
        link = obj.get(part, getlink=True)
        if link is None:
            raise ValueError(f"{where}: missing {name!r} (no {part!r} in {obj.name})")
        if not isinstance(link, h5py.HardLink):
            raise ValueError(f"{where}: {obj.name}/{part} is a {type(link).__name__}; "
                             "links are not accepted")
        obj = obj[part]
    if isinstance(obj, h5py.Dataset) and (obj.is_virtual or obj.external):
        raise ValueError(f"{where}: {name!r} stores its data outside the file; refused")
    return obj


def read_array(group: Any, name: str, shape: tuple[int, ...], where: str) -> np.ndarray:
    """Read ``group[name]`` after checking it is a safe float dataset of exactly ``shape``."""
    ds = safe_dataset(group, name, where)
    if ds.dtype.kind != "f":
        raise ValueError(f"{where}: {name!r} has dtype {ds.dtype}, expected floating point")
    if tuple(ds.shape) != tuple(shape):
        raise ValueError(f"{where}: {name!r} has shape {tuple(ds.shape)}, expected {tuple(shape)}")
    arr = read(ds, f"{where}: {name!r}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{where}: {name!r} contains NaN or infinite values")
    return arr


def write_vectors(path: str | os.PathLike, group: str, fmt: str, vectors: dict[str, Any],
                  dtype: Any, **attrs: Any) -> None:
    """Add ``vectors`` (name -> 1-D array, stored as ``dtype``) as group ``group`` with attribute
    ``format = fmt`` (and ``attrs``) to an existing HDF5 file, replacing a group of that name."""
    import h5py
    with h5py.File(path, "a") as f:
        if group in f:
            del f[group]
        g = f.create_group(group)
        g.attrs["format"] = fmt
        for k, v in attrs.items():
            g.attrs[k] = v
        for k, v in vectors.items():
            g.create_dataset(k, data=np.asarray(v, dtype=dtype))


def read_vectors(path: str | os.PathLike, group: str, fmt: str, what: str,
                 kinds: str = "iu") -> dict[str, np.ndarray] | None:
    """The 1-D integer datasets (dtype kinds ``kinds``) of group ``group`` of an untrusted HDF5
    file whose ``format`` attribute is ``fmt``, or None without the group. Links, external
    storage, other formats, other dtypes and more than 2^20 values are refused (``what`` names
    the content in the one-line error)."""
    import h5py
    where = str(path)
    with h5py.File(path, "r") as f:
        if group not in f:
            return None
        g = safe_group(f, group, where)
        if attr(g, "format", where) not in (fmt, fmt.encode()):
            raise ValueError(f"{path}: group {group!r} is not a {fmt} {what}")
        return group_vectors(g, group, where, what, kinds)


def group_vectors(g: Any, group: str, where: str, what: str,
                  kinds: str = "iu") -> dict[str, np.ndarray]:
    """Every dataset of the open group ``g`` (named ``group`` in ``where``) as a 1-D array, each
    checked to be a safe 1-D dataset of dtype kinds ``kinds`` with at most 2^20 values."""
    out = {}
    for k in g:
        d = safe_dataset(g, k, where)
        if d.ndim != 1 or d.size > 1 << 20 or d.dtype.kind not in kinds:
            raise ValueError(f"{where}: {group}/{k} is not a {what}")
        out[k] = np.asarray(read(d, f"{where}: {group}/{k}"))
    return out


def open_h5(path: str | os.PathLike) -> Any:
    """``h5py.File(path, "r")``; a missing file is ``FileNotFoundError``, anything unreadable
    ``ValueError``."""
    import h5py

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"weights file not found: {p}")
    try:
        return h5py.File(p, "r")
    except OSError as exc:
        raise ValueError(f"{p}: not a readable HDF5 file ({exc})") from None


def check_shape(arr: np.ndarray, shape: tuple[int, ...], what: str) -> np.ndarray:
    """``arr`` if its shape is ``shape``, else ``ValueError`` naming ``what``."""
    if tuple(arr.shape) != tuple(shape):
        raise ValueError(f"{what}: shape {tuple(arr.shape)}, expected {tuple(shape)}")
    return arr


__all__ = ["MAX_PARAMS", "MAX_TENSOR", "MAX_ATTR_ELEMENTS", "MAX_MEMBER_BYTES",
           "MAX_CONFIG_BYTES", "HDF5_MAGIC", "attr", "attrs", "read", "read_array",
           "safe_dataset", "safe_group", "safe_child", "open_h5", "damaged_file_is_value_error",
           "FILTERS", "filters", "group_vectors", "py_value", "py_str", "check_shape"]
