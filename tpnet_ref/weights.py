"""Weights I/O: the native HDF5 file (read and write).

Native format (``format = "tpnet_ref-weights"``, ``format_version = 1``), one HDF5 file:

    /                 attrs: format, format_version, dtype, created (UTC ISO time), producer,
                             plus any provenance given to ``save`` (source, recipe, ...)
    /config           attrs: every field of :class:`~tpnet_ref.model.TPNetConfig`
                             (including norm_lo / norm_hi, the world-unit normalisation)
    /params/<name>    one dataset per tensor, names and shapes from
                      :func:`~tpnet_ref.model.param_shapes`

Weight files are untrusted input: nothing is unpickled, links (soft, external), external
storage and virtual datasets are refused, every dataset's shape and dtype is checked against the
config *before* its data is read (so a file cannot make us allocate an absurd amount), and NaN or
Inf values are refused.
"""
from __future__ import annotations

import datetime as _dt
import os
from pathlib import Path
from typing import Any

import numpy as np

from .model import TPNet, TPNetConfig, param_shapes

FORMAT = "tpnet_ref-weights"
FORMAT_VERSION = 1
#: the shipped model that ``load()`` uses when no path is given
DEFAULT_WEIGHTS = "tpnet-m4.h5"
#: a config larger than this many parameters is refused as implausible (the paper's is ~8.1M)
MAX_PARAMS = 200_000_000


def weights_dir() -> Path:
    """Where the shipped weights live: ``$TPNET_WEIGHTS_DIR`` or the repository's ``weights/``."""
    env = os.environ.get("TPNET_WEIGHTS_DIR")
    return Path(env) if env else Path(__file__).resolve().parent.parent / "weights"


def default_weights_path() -> Path:
    """The file ``load()`` reads when called without a path."""
    return weights_dir() / DEFAULT_WEIGHTS


def save_native(model: TPNet, path: str | os.PathLike, **provenance: Any) -> None:
    """Write ``model`` to ``path`` in the native format, in the model's dtype (bit-exact)."""
    import h5py

    with h5py.File(path, "w") as f:
        f.attrs["format"] = FORMAT
        f.attrs["format_version"] = FORMAT_VERSION
        f.attrs["dtype"] = model.dtype.name
        meta = {**model.meta, **provenance}
        meta.setdefault("producer", "tpnet_ref")
        meta["created"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
        for k, v in meta.items():
            f.attrs[k] = _attr_value(v)
        g = f.create_group("config")
        for k, v in model.config.to_dict().items():
            g.attrs[k] = np.asarray(v) if isinstance(v, tuple) else v
        pg = f.create_group("params")
        for name, arr in model.params.items():
            pg.create_dataset(name, data=arr)


def _attr_value(v: Any) -> Any:
    if isinstance(v, (str, int, float, bool, np.generic)):
        return v
    return str(v)


def _py(v: Any) -> Any:
    """An HDF5 attribute value as a plain Python value."""
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


def _safe_dataset(group: Any, name: str, where: str):
    """The dataset ``group[name]`` if it is a plain, internal, non-virtual dataset."""
    import h5py

    link = group.get(name, getlink=True)
    if link is None:
        raise KeyError(f"{where}: missing dataset {name!r}")
    if not isinstance(link, h5py.HardLink):
        raise ValueError(f"{where}: {name!r} is a {type(link).__name__}; links are not accepted")
    ds = group[name]
    if not isinstance(ds, h5py.Dataset):
        raise ValueError(f"{where}: {name!r} is not a dataset")
    if ds.is_virtual or ds.external:
        raise ValueError(f"{where}: {name!r} stores its data outside the file; refused")
    return ds


def read_array(group: Any, name: str, shape: tuple[int, ...], where: str) -> np.ndarray:
    """Read ``group[name]`` after checking it is a safe float dataset of exactly ``shape``."""
    ds = _safe_dataset(group, name, where)
    if ds.dtype.kind != "f":
        raise ValueError(f"{where}: {name!r} has dtype {ds.dtype}, expected floating point")
    if tuple(ds.shape) != tuple(shape):
        raise ValueError(f"{where}: {name!r} has shape {tuple(ds.shape)}, expected {tuple(shape)}")
    arr = ds[()]
    if not np.isfinite(arr).all():
        raise ValueError(f"{where}: {name!r} contains NaN or infinite values")
    return arr


def _open_h5(path: str | os.PathLike):
    import h5py

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"weights file not found: {p}")
    try:
        return h5py.File(p, "r")
    except OSError as exc:
        raise ValueError(f"{p}: not a readable HDF5 file ({exc})") from None


def load_native(path: str | os.PathLike, dtype: Any = "float32") -> TPNet:
    """Read a native weights file (see the module docstring) into a :class:`TPNet`."""
    where = str(path)
    with _open_h5(path) as f:
        fmt = _py(f.attrs.get("format", ""))
        if fmt != FORMAT:
            raise ValueError(f"{where}: not a tpnet_ref weights file (format attribute {fmt!r}); "
                             "convert framework checkpoints with `tpnet import SRC DST`")
        version = _py(f.attrs.get("format_version", -1))
        if version != FORMAT_VERSION:
            raise ValueError(f"{where}: unsupported format_version {version!r} "
                             f"(this reader knows {FORMAT_VERSION})")
        if "config" not in f or "params" not in f:
            raise ValueError(f"{where}: missing group 'config' or 'params'")
        try:
            cfg = TPNetConfig.from_dict({k: _py(v) for k, v in f["config"].attrs.items()})
        except TypeError as exc:
            raise ValueError(f"{where}: bad config ({exc})") from None
        shapes = param_shapes(cfg)
        total = sum(int(np.prod(s)) for s in shapes.values())
        if total > MAX_PARAMS:
            raise ValueError(f"{where}: config declares {total:,} parameters (limit {MAX_PARAMS:,})")
        group = f["params"]
        extra = sorted(set(group.keys()) - set(shapes))
        if extra:
            raise ValueError(f"{where}: unexpected parameter(s) {extra} for this config")
        params = {name: read_array(group, name, shape, where) for name, shape in shapes.items()}
        meta = {k: _py(v) for k, v in f.attrs.items()
                if k not in ("format", "format_version", "dtype")}
    meta["path"] = where
    return TPNet(cfg, params, dtype, meta)


def load(path: str | os.PathLike | None = None, dtype: Any = "float32") -> TPNet:
    """Load a native weights file; ``path=None`` loads the shipped m = 4 model."""
    if path is None:
        path = default_weights_path()
        if not Path(path).is_file():
            raise FileNotFoundError(
                f"no shipped weights at {path}: trained weights have not been produced yet "
                "(see the training recipe), or set TPNET_WEIGHTS_DIR; pass a path to load "
                "another file, or use tpnet_ref.model.init_random() for a random network")
    return load_native(path, dtype)
