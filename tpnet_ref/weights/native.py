"""The native weights file: one HDF5 file holding a TP-Net's config, parameters and provenance.

Format (``format = "tpnet_ref-weights"``, ``format_version = 1``):

    /                 attrs: format, format_version, dtype (the compute dtype), created (UTC
                             ISO time), producer, plus any provenance given when writing
                             (source, recipe, ...); compressed files also storage ("gzip")
                             and, when rounded, storage_rounding (what the rounding did, JSON)
    /config           attrs: every field of :class:`~tpnet_ref.config.TPNetConfig`
                             (including norm_lo / norm_hi, the world-unit normalisation)
    /params/<name>    one dataset per tensor, names and shapes from
                      :func:`~tpnet_ref.config.param_shapes`
    /unit_order, /specialization   optional groups of 1-D integer datasets
                      (:mod:`tpnet_ref.engines.unit_order`, :mod:`tpnet_ref.engines.specialised`)

Integrity. The root attribute ``content_sha256`` is a SHA-256 digest of everything else the file
stores: every root attribute (the provenance), every group's attributes (the config) and every
dataset's name, dtype, shape and values (the parameters as decoded, the unit order, the masks),
in a canonical order (:func:`content_digest`). Every writer here puts it last
(:func:`write_native`, :func:`seal`); :func:`read_native` (and so ``tpnet_ref.load`` and
``tpnet info``) recomputes it and refuses a file whose content differs, naming the file. A file
written before digests existed loads with a one-line :class:`UnverifiedFileWarning` naming it
(nothing can tell whether it was damaged); ``tpnet scrub-provenance SRC DST`` adds one. The
digest is not a signature: whoever can write the file can write a matching digest.

Storage. By default each parameter is stored in the compute ``dtype`` (float32 or float64),
uncompressed, and reads back bit for bit. ``storage="gzip"`` stores the same values with HDF5's
standard shuffle + gzip filters (lossless, ~15 % smaller; the shipped paper-size file).
``mantissa_bits=k`` (with gzip; an explicit, lossy choice for the small files of the reduced
network sizes) first rounds every value to ``k`` significand bits (round half to even, relative
change at most 2^-(k+1)): the dropped low bits are zeros, which gzip all but removes. The file
still holds plain arrays of the compute dtype, so any HDF5 reader reads it; ``storage_rounding``
records the bits and the largest change. :func:`convert_storage` rewrites a file (its unit
order and other groups kept) in another storage.

:func:`write_native` / :func:`read_native` work on plain ``(config, {name: array}, meta)``;
:class:`tpnet_ref.model.TPNet` is built on them (``TPNet.save``, ``tpnet_ref.load``). A file is
untrusted input: it is read through the guards of :mod:`tpnet_ref.weights.hdf5` (no links, sizes
checked before reading, no NaN/Inf, nothing unpickled).

Weights of fewer bits. A file whose root attribute ``quantization`` is "bf16" or "int8"
(``tpnet quantize``, or ``save`` of a model loaded with ``weights=``) stores the BiLSTM matrices
as their codes: ``/params/<name>`` int8 or uint16 (bf16 bits), and for int8 ``/scales/<name>``
the float32 scale of each output column; ``quantized_from`` names the source file and its digest
(:mod:`tpnet_ref.weights.quantize`). The digest covers the codes and the scales as stored;
:func:`read_native` checks the scheme and every scale and returns the exact float32 weights.

The shipped models and where they are looked up: :mod:`tpnet_ref.weights.shipped`.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ..config import TPNetConfig, param_shapes
from . import hdf5
from . import quantize as Q
from .shipped import RESTORE_COMMAND, UNTRACKED

FORMAT = "tpnet_ref-weights"
FORMAT_VERSION = 1
#: root attribute holding the SHA-256 digest of everything else in the file
DIGEST_ATTR = "content_sha256"
#: root attributes that describe the file itself, not the model's provenance
_FILE_ATTRS = ("format", "format_version", "dtype", DIGEST_ATTR)
#: root attributes that describe how this file stores the parameters: set by
#: :func:`write_native` from its ``storage`` / ``mantissa_bits`` arguments only
_STORAGE_ATTRS = ("storage", "storage_rounding")
#: the storages :func:`write_native` knows besides the plain compute dtype (``None``)
STORAGES = ("gzip",)

# ----------------------------------------------------------------------------- digest
class UnverifiedFileWarning(UserWarning):
    """A native weights file without a content digest (written before digests existed) was
    read: whether it is intact cannot be checked."""


def _canon(v: Any) -> bytes:
    """An attribute value as tagged bytes: the same value gives the same bytes whatever type
    h5py returns it as (Python or NumPy scalar, variable or fixed-length string)."""
    if isinstance(v, (bytes, np.bytes_)):
        return b"B" + bytes(v)
    if isinstance(v, str):
        return b"s" + v.encode("utf-8", "surrogatepass")
    if isinstance(v, (bool, np.bool_)):
        return b"?" + (b"1" if v else b"0")
    if isinstance(v, (int, np.integer)):
        return b"i" + str(int(v)).encode()
    if isinstance(v, (float, np.floating)):
        return b"f" + float(v).hex().encode()
    if isinstance(v, np.ndarray):
        if v.dtype.kind in "OSU":
            return b"l" + b"".join(_frame(_canon(x)) for x in v.ravel().tolist())
        a = np.ascontiguousarray(v, dtype=v.dtype.newbyteorder("<"))
        return b"a" + _frame(a.dtype.str.encode()) + _frame(repr(a.shape).encode()) + a.tobytes()
    return b"r" + repr(v).encode()


def _frame(b: bytes) -> bytes:
    return len(b).to_bytes(8, "little") + b


def content_digest(f: Any, where: str, params: dict[str, np.ndarray] | None = None) -> str:
    """``sha256:<hex>`` of everything an open native file ``f`` stores except the digest
    itself: the root attributes, then each root group by name (its attributes, then each of its
    datasets: name, dtype, shape, values), all in sorted order. ``params``: the decoded
    ``/params`` arrays when already read (else they are read here, sizes checked first).
    Anything that is not a group at the root, or not a dataset in a group, is refused."""
    h = hashlib.sha256(b"tpnet_ref-weights content digest 1\0")

    def put(*parts: bytes) -> None:
        for b in parts:
            h.update(_frame(b))

    def put_attrs(obj: Any) -> None:
        for k in sorted(hdf5.attrs(obj, where)):
            if obj.name == "/" and k == DIGEST_ATTR:
                continue
            put(b"attr", k.encode(), _canon(hdf5.attr(obj, k, where)))

    import h5py

    put_attrs(f)
    names = sorted(f.keys())
    loose = [n for n in names if isinstance(f.get(n, getlink=True), h5py.HardLink)
             and not isinstance(f[n], h5py.Group)]
    for name in [n for n in names if n not in loose] + loose:   # what is wrong inside first
        g = hdf5.safe_group(f, name, where)
        put(b"group", name.encode())
        put_attrs(g)
        for ds in sorted(g.keys()):
            if name == "params" and params is not None and ds in params:
                a = params[ds]
            else:
                d = hdf5.safe_dataset(g, ds, where)
                if d.size > hdf5.MAX_TENSOR:
                    raise ValueError(f"{where}: {name}/{ds} declares {d.size:,} values "
                                     f"(limit {hdf5.MAX_TENSOR:,}); refused")
                a = np.asarray(hdf5.read(d, f"{where}: {name}/{ds}"))
            a = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<"))
            put(b"dataset", ds.encode(), a.dtype.str.encode(), repr(a.shape).encode())
            h.update(a.nbytes.to_bytes(8, "little"))
            h.update(a)                                  # C-contiguous: hashed in place
    return "sha256:" + h.hexdigest()


def seal(path: str | os.PathLike) -> str:
    """Compute the content digest of the native file ``path`` and store it (replacing any);
    returns it. Every writer in this package calls it after its last change to a file."""
    import h5py

    where = str(path)
    with h5py.File(path, "r+") as f:
        digest = content_digest(f, where)
        f.attrs[DIGEST_ATTR] = digest
    return digest


def _verify(f: Any, where: str, params: dict[str, np.ndarray]) -> str | None:
    """The file's digest after checking it against its content (None: the file has none, a
    one-line :class:`UnverifiedFileWarning`)."""
    stored = hdf5.py_value(hdf5.attr(f, DIGEST_ATTR, where, None))
    if stored is None:
        warnings.warn(UnverifiedFileWarning(
            f"{where}: no content digest (written before tpnet_ref stored one), so damage to it "
            "cannot be detected; `tpnet scrub-provenance SRC DST` writes a copy with one"),
            stacklevel=4)
        return None
    computed = content_digest(f, where, params)
    if stored != computed:
        raise ValueError(f"{where}: the file's content does not match its {DIGEST_ATTR} digest "
                         "(damaged, or changed after it was written); refused")
    return stored


# ------------------------------------------------------------------------------ write
def _attr_value(v: Any) -> Any:
    if isinstance(v, (str, int, float, bool, np.generic)):
        return v
    return str(v)


def round_mantissa(a: np.ndarray, bits: int) -> np.ndarray:
    """``a`` (float32 or float64) with every value rounded to ``bits`` significand bits (round
    half to even on the bit pattern; zeros, signs and subnormals handled by the same integer
    arithmetic). Relative change at most 2^-(bits+1); a value that would round to infinity
    (beyond the dtype's largest number at that precision) is a one-line ``ValueError``."""
    a = np.ascontiguousarray(a)
    word, full = {4: (np.uint32, 23), 8: (np.uint64, 52)}[a.dtype.itemsize]
    if not 1 <= bits < full:
        raise ValueError(f"mantissa_bits: must be 1..{full - 1} for {a.dtype}, got {bits}")
    drop = word(full - bits)
    b = a.view(word)
    odd = (b >> drop) & word(1)
    r = ((b + (word(1) << (drop - word(1))) - word(1) + odd) >> drop) << drop
    out = r.view(a.dtype)
    if not np.isfinite(out).all():
        raise ValueError(f"mantissa_bits={bits}: a value rounds to infinity")
    return out


def _rounded(params: dict[str, np.ndarray], bits: int) -> tuple[dict[str, np.ndarray], str]:
    """Every parameter rounded by :func:`round_mantissa`, and a JSON note of what changed."""
    out, max_abs, max_rel = {}, 0.0, 0.0
    for name, a in params.items():
        out[name] = r = round_mantissa(a, bits)
        if a.size:
            diff = np.abs(r - a)
            max_abs = max(max_abs, float(diff.max()))
            nz = a != 0
            if nz.any():
                max_rel = max(max_rel, float((diff[nz] / np.abs(a[nz])).max()))
    note = {"mantissa_bits": bits, "values": sum(int(a.size) for a in params.values()),
            "max_abs_change": max_abs, "max_rel_change": max_rel}
    return out, json.dumps(note)


def write_native(path: str | os.PathLike, config: TPNetConfig, params: dict[str, np.ndarray],
                 dtype: Any = "float32", meta: dict[str, Any] | None = None,
                 storage: str | None = None, mantissa_bits: int | None = None,
                 groups: dict[str, tuple[dict[str, Any], dict[str, np.ndarray]]] | None = None,
                 created: str | None = None, rounding_note: str | None = None) -> str:
    """Write a native weights file: ``params`` (``{name: array}``, exactly the names and shapes
    of ``param_shapes(config)``) in the compute ``dtype`` (float32 or float64), ``meta`` as
    root attributes (strings, numbers; anything else as ``str``), plus ``producer`` (default
    ``tpnet_ref``) and ``created`` (now, or the ``created`` given), then ``groups``
    (``{name: (attrs, {dataset: 1-D array})}``: the unit order, the masks) and last the content
    digest (:func:`seal`), which it returns.

    ``storage=None`` (the default) stores each parameter uncompressed (bit-exact for arrays
    already in ``dtype``); ``storage="gzip"``: the same values with shuffle + gzip (lossless).
    ``mantissa_bits`` (gzip only; lossy, explicit): round every value to that many significand
    bits first (:func:`round_mantissa`); ``storage_rounding`` records it (``rounding_note``:
    the note of an earlier rounding these values already had, kept when rewriting them)."""
    import h5py

    dt = np.dtype(dtype)
    if dt not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
    if storage is not None and storage not in STORAGES:
        raise ValueError(f"storage must be None (uncompressed) or one of "
                         f"{', '.join(repr(s) for s in STORAGES)}, got {storage!r}")
    if mantissa_bits is not None and storage != "gzip":
        raise ValueError("mantissa_bits: rounding only pays with storage='gzip'")
    shapes = param_shapes(config)
    if set(params) != set(shapes):
        raise ValueError(f"params do not fit the config: missing {sorted(set(shapes) - set(params))}, "
                         f"unexpected {sorted(set(params) - set(shapes))}")
    for name, shape in shapes.items():
        hdf5.check_shape(np.asarray(params[name]), shape, f"parameter {name!r}")
    stored = {name: np.asarray(params[name], dtype=dt) for name in shapes}
    rounding = None
    if mantissa_bits is not None:
        if (meta or {}).get(Q.ATTR) is not None:
            raise ValueError("mantissa_bits: a quantized model's file stores its codes as they are")
        stored, rounding = _rounded(stored, int(mantissa_bits))
    groups = _encoded(config, stored, meta or {}, groups or {})
    info = {k: v for k, v in (meta or {}).items()
            if k not in _FILE_ATTRS and k not in _STORAGE_ATTRS and k != "path"}
    info.setdefault("producer", "tpnet_ref")
    info["created"] = created or _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    if rounding is None and mantissa_bits is None and rounding_note and storage is not None:
        rounding = rounding_note
    with h5py.File(path, "w") as f:
        f.attrs["format"] = FORMAT
        f.attrs["format_version"] = FORMAT_VERSION
        f.attrs["dtype"] = dt.name
        if storage is not None:
            f.attrs["storage"] = storage
        if rounding is not None:
            f.attrs["storage_rounding"] = rounding
        for k, v in info.items():
            f.attrs[k] = _attr_value(v)
        g = f.create_group("config")
        for k, v in config.to_dict().items():
            g.attrs[k] = np.asarray(v) if isinstance(v, tuple) else v
        pg = f.create_group("params")
        for name in shapes:                                   # forward order
            if storage is None:
                pg.create_dataset(name, data=stored[name])
            else:                    # one chunk per tensor: smallest file (one gzip stream)
                pg.create_dataset(name, data=stored[name], chunks=stored[name].shape or None,
                                  shuffle=True, compression="gzip", compression_opts=9)
        for gname, (gattrs, arrays) in (groups or {}).items():
            if gname in ("config", "params"):
                raise ValueError(f"groups: {gname!r} is written from the config and params")
            eg = f.create_group(gname)
            for k, v in gattrs.items():
                eg.attrs[k] = v
            for k, a in arrays.items():
                eg.create_dataset(k, data=np.asarray(a))
        digest = content_digest(f, str(path), stored)
        f.attrs[DIGEST_ATTR] = digest
    return digest


def _encoded(config: TPNetConfig, stored: dict[str, np.ndarray], meta: dict[str, Any],
             groups: dict[str, Any]) -> dict[str, Any]:
    """For a quantized model (``meta["quantization"]``), its BiLSTM matrices in ``stored``
    replaced by their codes (exact: :func:`tpnet_ref.weights.quantize.codes_of`) and the int8
    scales added to ``groups`` as ``/scales``; ``groups`` as they are otherwise."""
    scheme = meta.get(Q.ATTR)
    groups = {k: v for k, v in groups.items() if k != Q.SCALES}
    if scheme is None:
        return groups
    scales, wide = {}, Q.wide_of(config, meta)
    for name in Q.quantized_names(config):
        stored[name], sc = Q.codes_of(stored[name], scheme, f"parameter {name!r}", name in wide)
        if sc is not None:
            scales[name] = sc
    return {**groups, Q.SCALES: ({}, scales)} if scales else groups


def _decoded(f: Any, where: str, cfg: TPNetConfig, group: Any,
             shapes: dict[str, tuple[int, ...]]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """``(stored, params)``: the ``/params`` arrays as stored and as the model computes with
    them (a quantized file's codes decoded and checked with their scales; the same arrays
    otherwise)."""
    scheme = hdf5.py_value(hdf5.attr(f, Q.ATTR, where, None))
    names = set() if scheme is None else set(Q.quantized_names(cfg))
    wide = set() if scheme is None else set(Q.wide_of(cfg, {
        Q.ATTR: scheme, Q.WIDE_ATTR: hdf5.py_value(hdf5.attr(f, Q.WIDE_ATTR, where, None))},
        where))
    stored = {name: hdf5.read_array(group, name, shape, where) for name, shape in shapes.items()
              if name not in names}
    params = dict(stored)
    sg = hdf5.safe_group(f, Q.SCALES, where) if scheme == "int8" and Q.SCALES in f else None
    for name in sorted(names):
        ds = hdf5.safe_dataset(group, name, where)
        if ds.size > hdf5.MAX_TENSOR:
            raise ValueError(f"{where}: {name!r} declares {ds.size:,} values; refused")
        stored[name] = codes = np.asarray(hdf5.read(ds, f"{where}: {name!r}"))
        scale = None
        if scheme == "int8":
            if sg is None or name not in sg:
                raise ValueError(f"{where}: int8 file without the scales of {name!r}")
            scale = np.asarray(hdf5.read(hdf5.safe_dataset(sg, name, where), f"{where}: scales"))
        params[name] = Q.check_codes(codes, scale, scheme, shapes[name], f"{where}: {name!r}",
                                     name in wide)
    return stored, {name: params[name] for name in shapes}            # the file's order


# ------------------------------------------------------------------------------- read
def is_native(path: str | os.PathLike) -> bool:
    """Whether ``path`` is an HDF5 file whose ``format`` attribute says it is a native file."""
    with hdf5.open_h5(path) as f:
        return hdf5.py_value(hdf5.attr(f, "format", str(path), "")) == FORMAT


def _header(f: Any, where: str) -> TPNetConfig:
    """An open native file's format, version and storage checked, and its config."""
    fmt = hdf5.py_value(hdf5.attr(f, "format", where, ""))
    if fmt != FORMAT:
        raise ValueError(f"{where}: not a tpnet_ref weights file (format attribute {fmt!r}); "
                         "convert framework checkpoints with `tpnet import SRC DST`")
    version = hdf5.py_value(hdf5.attr(f, "format_version", where, -1))
    if version != FORMAT_VERSION:
        raise ValueError(f"{where}: unsupported format_version {version!r} "
                         f"(this reader knows {FORMAT_VERSION})")
    if "config" not in f or "params" not in f:
        raise ValueError(f"{where}: missing group 'config' or 'params'")
    storage = hdf5.py_value(hdf5.attr(f, "storage", where, None))
    if storage is not None and storage not in STORAGES:       # a newer writer's encoding
        raise ValueError(f"{where}: unknown storage {storage!r} (this reader knows "
                         f"{', '.join(STORAGES)})")
    cfg_group = hdf5.safe_group(f, "config", where)
    try:
        return TPNetConfig.from_dict({k: hdf5.py_value(v)
                                      for k, v in hdf5.attrs(cfg_group, where).items()})
    except (TypeError, OverflowError) as exc:
        raise ValueError(f"{where}: bad config ({exc})") from None


@hdf5.damaged_file_is_value_error
def read_config(path: str | os.PathLike) -> TPNetConfig:
    """A native weights file's config alone, checked as :func:`read_native` checks it (its
    parameters and digest are not read: ``tpnet eval`` learns a file's dim from it)."""
    where = str(path)
    with hdf5.open_h5(path) as f:
        return _header(f, where)


@hdf5.damaged_file_is_value_error
def read_native(path: str | os.PathLike) -> tuple[TPNetConfig, dict[str, np.ndarray], dict[str, Any]]:
    """Read a native weights file -> ``(config, {name: array in the stored dtype}, meta)``
    (compressed or not: :mod:`tpnet_ref.weights.hdf5` decodes gzip and shuffle).

    ``meta``: the root attributes (provenance, and ``storage`` / ``storage_rounding`` when the
    file has them) as plain Python values, plus ``path`` and, when the file has one, its
    ``content_sha256`` digest, checked against everything read (a file without one: a one-line
    :class:`UnverifiedFileWarning`). Raises
    ``FileNotFoundError`` for a missing file and ``ValueError`` (or ``KeyError`` for a missing
    parameter) naming what is wrong for anything else.
    """
    where = str(path)
    try:
        h = hdf5.open_h5(path)
    except FileNotFoundError as exc:
        name = Path(path).name
        if name in UNTRACKED:          # weights/tpnet-m3.h5 in a checkout that lacks it
            raise FileNotFoundError(f"{exc} (git does not track {name}: `{RESTORE_COMMAND}` in "
                                    "the repository restores it)") from None
        raise
    with h as f:
        cfg = _header(f, where)
        group = hdf5.safe_group(f, "params", where)
        shapes = param_shapes(cfg)
        total = sum(int(np.prod(s)) for s in shapes.values())
        if total > hdf5.MAX_PARAMS:
            raise ValueError(f"{where}: config declares {total:,} parameters "
                             f"(limit {hdf5.MAX_PARAMS:,})")
        extra = sorted(set(group.keys()) - set(shapes))
        if extra:
            raise ValueError(f"{where}: unexpected parameter(s) {extra} for this config")
        stored, params = _decoded(f, where, cfg, group, shapes)
        digest = _verify(f, where, stored)
        meta = {k: hdf5.py_value(v) for k, v in hdf5.attrs(f, where).items()
                if k not in _FILE_ATTRS}
    meta["path"] = where
    if digest is not None:
        meta[DIGEST_ATTR] = digest              # checked against the content just read
    return cfg, params, meta


# ---------------------------------------------------------------------------- convert
def extra_groups(path: str | os.PathLike) -> dict[str, tuple[dict[str, Any], dict[str, np.ndarray]]]:
    """Every root group of a native file other than ``config`` and ``params`` (``unit_order``,
    ``specialization``), read through the guards: ``{group: (attrs, {dataset: 1-D integer
    array})}``. Anything else there (a dataset, a link, a nested group, a non-integer or
    oversized dataset) is refused in one line."""
    where, out = str(path), {}
    with hdf5.open_h5(path) as f:
        for name in f:
            if name not in ("config", "params", Q.SCALES):    # scales: rewritten from meta
                g = hdf5.safe_group(f, name, where)
                out[name] = (hdf5.attrs(g, where), hdf5.group_vectors(
                    g, name, where, "1-D integer dataset (convert_storage copies only those)"))
    return out


def convert_storage(src: str | os.PathLike, dst: str | os.PathLike,
                    storage: str | None = None, mantissa_bits: int | None = None) -> dict[str, Any]:
    """Rewrite the native file ``src`` as ``dst`` (which may be ``src``) in ``storage`` with
    ``mantissa_bits`` (:func:`write_native`), the same config, provenance (``created``
    included) and compute dtype, and the same other groups (the unit order, a specialisation's
    masks: exact whatever the weights, :mod:`tpnet_ref.engines.specialised`). Returns the new file's
    ``meta`` (:func:`read_native`)."""
    cfg, params, meta = read_native(src)
    return write_replacing(dst, cfg, params, meta, extra_groups(src), storage, mantissa_bits)


def write_replacing(dst: str | os.PathLike, cfg: TPNetConfig, params: dict[str, np.ndarray],
                    meta: dict[str, Any],
                    groups: dict[str, tuple[dict[str, Any], dict[str, np.ndarray]]],
                    storage: str | None = None, mantissa_bits: int | None = None,
                    rounding_note: str | None = None) -> dict[str, Any]:
    """Write a native file (:func:`write_native`, in the dtype of ``params``, keeping
    ``meta["created"]``) to a temporary file beside ``dst`` and move it over ``dst`` (which may
    be the file the values were read from); returns the new file's ``meta``."""
    import tempfile

    compute = params["head.w"].dtype                         # what the file computes in
    dst = Path(dst)
    fd, tmp = tempfile.mkstemp(suffix=".h5", dir=dst.parent)
    os.close(fd)
    try:
        write_native(tmp, cfg, params, compute, meta, storage, mantissa_bits, groups,
                     created=meta.get("created") or None, rounding_note=rounding_note)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)                # as open() would create it, not mkstemp's 0600
        os.replace(tmp, dst)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return read_native(dst)[2]


# --------------------------------------------------------------------------- describe
def _runs(runs: Any) -> list[str]:
    """Short lines for a ``parent_runs`` list, oldest first: a training run with its recipe and
    counters, or a weights file it started from (whose own runs are listed before it)."""
    lines: list[str] = []
    for run in runs if isinstance(runs, list) else []:
        if not isinstance(run, dict):
            continue
        rec = run.get("recipe") if isinstance(run.get("recipe"), dict) else {}
        name = run.get("run", "?")
        if "weights_file" in rec:
            lines.extend(_runs(rec.get("parent_runs")))
            inner = rec.get("recipe") if isinstance(rec.get("recipe"), dict) else {}
            how = (f"the mean of {len(inner.get('files') or [])} files"
                   if inner.get("recipe") == "average" else
                   f"{inner.get('recipe', '?')} recipe, lr {inner.get('lr', '?')}")
            lines.append(f"{name}: written by {rec.get('source') or '?'} ({how}); chain "
                         f"total {int(run.get('steps', 0)):,} steps, "
                         f"{float(run.get('epochs', 0.0)):.2f} epochs, "
                         f"{float(run.get('wall_s', 0.0)) / 3600:.2f} h")
        else:
            lines.append(f"{name}: {rec.get('recipe', '?')} recipe, lr {rec.get('lr', '?')}, "
                         f"{int(run.get('steps', 0)):,} steps, {float(run.get('epochs', 0.0)):.2f} "
                         f"epochs, {float(run.get('wall_s', 0.0)) / 3600:.2f} h on {run.get('data', '?')}")
    return lines


def _chain(meta: dict[str, Any]) -> list[str]:
    """The training runs that made the weights, one short line each, oldest first, ending with
    the run that wrote this file."""
    try:
        lines = _runs(json.loads(meta.get("parent_runs", "[]") or "[]"))
    except (TypeError, ValueError):
        lines = ["(parent_runs is not valid JSON)"]
    if "training_steps" in meta:
        lines.append(f"{meta.get('source', '?')}: this file, total {int(meta['training_steps']):,} "
                     f"steps, {float(meta.get('epochs', 0.0)):.2f} epochs, "
                     f"{float(meta.get('wall_time_s', 0.0)) / 3600:.2f} h")
    # the inputs of an average share their chain: each run once, where it first appears
    lines = list(dict.fromkeys(lines))
    return [f"{i}. {line}" for i, line in enumerate(lines, start=1)]


def describe(path: str | os.PathLike) -> str:
    """A readable multi-line summary of a native weights file: the network, the parameter count,
    the stored dtype, the normalisation, what produced it and when, validation figures, and the
    chain of training runs that made the weights, one short line each. (The full provenance is
    in the file's root attributes: ``tpnet info --json``.)"""
    cfg, params, meta = read_native(path)
    dtypes = sorted({a.dtype.name for a in params.values()})
    n = sum(int(a.size) for a in params.values())
    tr = {True: "trained", False: "identity"}
    stored = "/".join(dtypes) + (" (shuffle + gzip)" if meta.get("storage") == "gzip" else "")
    if meta.get(Q.ATTR):
        stored += (f"; BiLSTM matrices as {meta[Q.ATTR]} codes, quantized from "
                   f"{meta.get(Q.FROM_ATTR, '?')}"
                   + (f", rounded {meta[Q.ROUNDING_ATTR]}" if meta.get(Q.ROUNDING_ATTR)
                      else ""))
    out = [f"{meta['path']}: native tpnet_ref weights, {n:,} parameters stored as {stored}",
           f"  network      m={cfg.m} frames in, N={cfg.n_out} points out, lstm {cfg.lstm_units} "
           f"({cfg.lstm_activation}), global features {cfg.global_features}, "
           f"layer_norm_eps {cfg.layer_norm_eps:g}",
           f"  transforms   input {tr[cfg.input_transform_trained]}, feature "
           f"{tr[cfg.feature_transform_trained]}",
           f"  coordinates  world units -> (x - {cfg.norm_lo}) / ({cfg.norm_hi} - {cfg.norm_lo})"]
    for key, label in (("producer", "producer"), ("created", "created"), ("hardware", "hardware"),
                       ("data", "data"), ("source", "source"), ("source_format", "source kind"),
                       ("import_report", "import"), ("units_sorted_on", "unit order")):
        if meta.get(key) not in (None, ""):
            pre = "most used first on " if key == "units_sorted_on" else ""
            out.append(f"  {label:13s}{pre}{meta[key]}")
    digest = meta.get(DIGEST_ATTR)
    out.append(f"  integrity    {digest} (checked against the content)" if digest else
               "  integrity    no content digest (an older file): damage cannot be detected")
    try:
        rnd = json.loads(meta.get("storage_rounding", "{}") or "{}")
    except (TypeError, ValueError):
        rnd = {}
    if isinstance(rnd, dict) and rnd:
        out.append(f"  rounding     to {rnd.get('mantissa_bits', '?')} significand bits before "
                   f"compressing (lossy): largest change {rnd.get('max_abs_change', float('nan')):.3g}"
                   f", relative {rnd.get('max_rel_change', float('nan')):.3g}")
    try:
        val = json.loads(meta.get("val", "{}") or "{}")
    except (TypeError, ValueError):
        val = {}
    if isinstance(val, dict) and val:
        out.append("  validation   " + ", ".join(
            f"{k} {v:.4g}" if isinstance(v, (int, float)) else f"{k} {v}"
            for k, v in sorted(val.items())))
    try:
        parts = json.loads(meta.get("average_of", "[]") or "[]")
    except (TypeError, ValueError):
        parts = []
    if isinstance(parts, list) and parts:
        out.append("  average of   " + " + ".join(
            f"{float(q.get('weight', 0.0)):.3g} x {q.get('weights_file', '?')}"
            for q in parts if isinstance(q, dict)))
    chain = _chain(meta)
    if chain:
        out.append("  training runs (oldest first):")
        out.extend(f"    {line}" for line in chain)
    return "\n".join(out)


__all__ = ["FORMAT", "FORMAT_VERSION", "STORAGES", "write_native", "read_native", "read_config",
           "is_native", "convert_storage", "write_replacing", "extra_groups", "content_digest",
           "seal", "DIGEST_ATTR", "UnverifiedFileWarning", "describe"]
