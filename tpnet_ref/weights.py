"""Weights I/O: the native HDF5 file (read and write) and the importers of framework checkpoints.

- :func:`load` / :func:`load_native` / :func:`save_native`: the native file (below).
- :func:`import_keras_h5`: Keras checkpoints of the released architecture (TF-Keras 2 HDF5 as
  the authors' code writes them, Keras 3 ``.weights.h5`` / ``.keras`` / legacy ``.h5``).
- :func:`import_torch`: state dicts of :mod:`tpnet_ref.torch_model` (``weights_only`` loading).
- :func:`import_checkpoint`: any of these, told apart by content; ``tpnet import SRC DST``.

Mapping tables and measured differences: ``docs/weights.md``.

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

from .config import TPNetConfig, param_shapes
from .model import TPNet

FORMAT = "tpnet_ref-weights"
FORMAT_VERSION = 1
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


def weights_dir() -> Path:
    """Where the shipped weights live: ``$TPNET_WEIGHTS_DIR`` or the repository's ``weights/``."""
    env = os.environ.get("TPNET_WEIGHTS_DIR")
    return Path(env) if env else Path(__file__).resolve().parent.parent / "weights"


def default_weights_path() -> Path:
    """The file ``load()`` reads when called without a path (the m = 4 model)."""
    return shipped_weights_path(4)


def shipped_weights_path(m: int = 4) -> Path:
    """The shipped model for windows of ``m`` frames: ``tpnet-m{m}.h5`` in :func:`weights_dir`
    (m = 4 is the default model; m = 3 and 5 are fine-tuned from it, ``weights/MODEL_CARD.md``)."""
    if m not in (3, 4, 5):
        raise ValueError(f"no model is shipped for m={m!r}: there are m = 3, 4 and 5")
    return weights_dir() / f"tpnet-m{m}.h5"


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


def _attr(obj: Any, name: str, where: str, default: Any = None) -> Any:
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


def _attrs(obj: Any, where: str) -> dict[str, Any]:
    """Every attribute of an HDF5 object, each checked by :func:`_attr`."""
    names = list(obj.attrs.keys())
    if len(names) > MAX_ATTR_ELEMENTS:
        raise ValueError(f"{where}: {obj.name} has {len(names):,} attributes; refused")
    return {k: _attr(obj, k, where) for k in names}


def _read(ds: Any, what: str) -> np.ndarray:
    """The data of a checked dataset; a corrupted file gives ``ValueError`` naming it."""
    try:
        return ds[()]
    except (OSError, RuntimeError) as exc:
        raise ValueError(f"{what}: cannot be read, the file is damaged ({exc})") from None


def _damaged_file_is_value_error(fn: Any) -> Any:
    """Decorator: a reader's ``RuntimeError``/``OSError`` from h5py parsing a damaged file (other
    than a missing file) becomes ``ValueError`` naming the file, so that callers see only the
    documented exceptions (ValueError, TypeError, KeyError, FileNotFoundError)."""
    import functools

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
    arr = _read(ds, f"{where}: {name!r}")
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


@_damaged_file_is_value_error
def load_native(path: str | os.PathLike, dtype: Any = "float32") -> TPNet:
    """Read a native weights file (see the module docstring) into a :class:`TPNet`."""
    where = str(path)
    with _open_h5(path) as f:
        fmt = _py(_attr(f, "format", where, ""))
        if fmt != FORMAT:
            raise ValueError(f"{where}: not a tpnet_ref weights file (format attribute {fmt!r}); "
                             "convert framework checkpoints with `tpnet import SRC DST`")
        version = _py(_attr(f, "format_version", where, -1))
        if version != FORMAT_VERSION:
            raise ValueError(f"{where}: unsupported format_version {version!r} "
                             f"(this reader knows {FORMAT_VERSION})")
        if "config" not in f or "params" not in f:
            raise ValueError(f"{where}: missing group 'config' or 'params'")
        import h5py
        for name in ("config", "params"):
            if not isinstance(f.get(name, getlink=True), h5py.HardLink):
                raise ValueError(f"{where}: {name!r} is a link; links are not accepted")
            if not isinstance(f[name], h5py.Group):
                raise ValueError(f"{where}: {name!r} is not a group")
        try:
            cfg = TPNetConfig.from_dict({k: _py(v) for k, v in _attrs(f["config"], where).items()})
        except (TypeError, OverflowError) as exc:
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
        meta = {k: _py(v) for k, v in _attrs(f, where).items()
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


# =============================================================================== importers
# Shared by every importer: a flat ``{native name: array}`` built with explicit, shape-asserting
# key maps, then handed to TPNet (which checks every shape against the config once more).

def _check_shape(arr: np.ndarray, shape: tuple[int, ...], what: str) -> np.ndarray:
    if tuple(arr.shape) != tuple(shape):
        raise ValueError(f"{what}: shape {tuple(arr.shape)}, expected {tuple(shape)}")
    return arr


def _torch_key_map(cfg: TPNetConfig) -> list[tuple[str, str, str]]:
    """``(torch name, native name, how)`` for every parameter; how is ``T`` (transpose),
    ``=`` (copy) or ``+`` (the native tensor is the sum of this and the ``_hh`` bias)."""
    rows: list[tuple[str, str, str]] = []

    def stack(tprefix: str, nprefix: str, n: int) -> None:
        for i in range(n):
            rows.append((f"{tprefix}.{i}.weight", f"{nprefix}.{i}.w", "T"))
            rows.append((f"{tprefix}.{i}.bias", f"{nprefix}.{i}.b", "="))

    def tnet(prefix: str, nmlp: int, nfc: int) -> None:
        stack(f"{prefix}.mlp", f"{prefix}.mlp", nmlp)
        stack(f"{prefix}.fc", f"{prefix}.fc", nfc)
        rows.append((f"{prefix}.out.weight", f"{prefix}.out.w", "T"))
        rows.append((f"{prefix}.out.bias", f"{prefix}.out.b", "="))

    if cfg.input_transform_trained:
        tnet("input_tnet", len(cfg.input_tnet_mlp), len(cfg.input_tnet_fc))
    stack("mlp1", "mlp1", len(cfg.mlp1))
    if cfg.feature_transform_trained:
        tnet("feature_tnet", len(cfg.feature_tnet_mlp), len(cfg.feature_tnet_fc))
    stack("mlp2", "mlp2", len(cfg.mlp2))
    rows.append(("global_fc.weight", "global.w", "T"))
    rows.append(("global_fc.bias", "global.b", "="))
    for i in range(1, len(cfg.lstm_units) + 1):
        for sfx, d in (("_l0", "fwd"), ("_l0_reverse", "bwd")):
            rows.append((f"lstm{i}.weight_ih{sfx}", f"lstm{i}.{d}.kernel", "T"))
            rows.append((f"lstm{i}.weight_hh{sfx}", f"lstm{i}.{d}.recurrent", "T"))
            rows.append((f"lstm{i}.bias_ih{sfx}", f"lstm{i}.{d}.bias", "+"))
        rows.append((f"ln{i}.weight", f"ln{i}.gamma", "="))
        rows.append((f"ln{i}.bias", f"ln{i}.beta", "="))
    rows.append(("head.weight", "head.w", "T"))
    rows.append(("head.bias", "head.b", "="))
    return rows


def torch_state_to_native(sd: dict[str, np.ndarray], cfg: TPNetConfig) -> dict[str, np.ndarray]:
    """PyTorch-layout tensors (NumPy arrays) -> native parameters, every shape asserted.

    Linear ``weight (out, in)`` -> ``w (in, out)``; LSTM ``weight_ih (4u, in)`` ->
    ``kernel (in, 4u)``, ``weight_hh (4u, u)`` -> ``recurrent (u, 4u)``, ``bias_ih + bias_hh``
    -> ``bias (4u,)``. PyTorch's gate order i, f, g, o is Keras's i, f, c, o: no reordering.
    Raises ``ValueError`` naming every missing or unexpected key.
    """
    shapes = param_shapes(cfg)
    rows = _torch_key_map(cfg)
    expected = {t for t, _, _ in rows} | {t.replace("bias_ih", "bias_hh") for t, _, h in rows
                                          if h == "+"}
    missing = sorted(expected - set(sd))
    extra = sorted(set(sd) - expected - {"_extra_state"})
    if missing or extra:
        raise ValueError(f"torch state dict does not fit {_describe(cfg)}: missing {missing}, "
                         f"unexpected {extra}")
    out: dict[str, np.ndarray] = {}
    for tname, nname, how in rows:
        shape = shapes[nname]
        a = np.asarray(sd[tname])
        if how == "T":
            out[nname] = _check_shape(a, shape[::-1], tname).T
        elif how == "+":
            b = np.asarray(sd[tname.replace("bias_ih", "bias_hh")])
            out[nname] = (_check_shape(a, shape, tname)
                          + _check_shape(b, shape, tname.replace("bias_ih", "bias_hh")))
        else:
            out[nname] = _check_shape(a, shape, tname)
    return out


def native_to_torch_state(params: dict[str, np.ndarray], cfg: TPNetConfig) -> dict[str, np.ndarray]:
    """Native parameters -> PyTorch-layout arrays (the LSTM bias goes to ``bias_ih``,
    ``bias_hh`` is zero)."""
    out: dict[str, np.ndarray] = {}
    for tname, nname, how in _torch_key_map(cfg):
        a = np.asarray(params[nname])
        if how == "T":
            out[tname] = np.ascontiguousarray(a.T)
        elif how == "+":
            out[tname] = a.copy()
            out[tname.replace("bias_ih", "bias_hh")] = np.zeros_like(a)
        else:
            out[tname] = a.copy()
    return out


def _describe(cfg: TPNetConfig) -> str:
    return (f"m={cfg.m}, n_out={cfg.n_out}, lstm_units={cfg.lstm_units}, transforms "
            f"{'trained' if cfg.input_transform_trained else 'identity'}/"
            f"{'trained' if cfg.feature_transform_trained else 'identity'}")


def _stack_widths(sd: dict[str, Any], prefix: str) -> tuple[int, ...]:
    widths = []
    while f"{prefix}.{len(widths)}.weight" in sd:
        widths.append(int(sd[f"{prefix}.{len(widths)}.weight"].shape[0]))
    return tuple(widths)


def _infer_torch_config(sd: dict[str, Any], m: int, layer_norm_eps: float,
                        lstm_activation: str) -> TPNetConfig:
    """Config of a bare state dict (no ``_extra_state``), read from its shapes."""
    need = ("mlp1.0.weight", "mlp2.0.weight", "global_fc.weight", "lstm1.weight_hh_l0",
            "head.weight")
    missing = [k for k in need if k not in sd]
    if missing:
        raise ValueError(f"not a TP-Net torch state dict: missing {missing} "
                         f"(keys present: {sorted(sd)[:8]}...)")
    kw: dict[str, Any] = {}
    dim = int(sd["mlp1.0.weight"].shape[1])
    kw["dim"] = dim
    kw["mlp1"] = _stack_widths(sd, "mlp1")
    kw["mlp2"] = _stack_widths(sd, "mlp2")
    kw["global_features"] = int(sd["global_fc.weight"].shape[0])
    units = []
    while f"lstm{len(units) + 1}.weight_hh_l0" in sd:
        units.append(int(sd[f"lstm{len(units) + 1}.weight_hh_l0"].shape[1]))
    kw["lstm_units"] = tuple(units)
    n2 = int(sd["head.weight"].shape[0])
    if n2 % dim:
        raise ValueError(f"head.weight has {n2} outputs, not a multiple of dim={dim}")
    kw["n_out"] = n2 // dim
    for prefix, flag in (("input_tnet", "input_transform_trained"),
                         ("feature_tnet", "feature_transform_trained")):
        if f"{prefix}.out.weight" in sd:
            kw[flag] = True
            kw[f"{prefix}_mlp"] = _stack_widths(sd, f"{prefix}.mlp")
            kw[f"{prefix}_fc"] = _stack_widths(sd, f"{prefix}.fc")
    return TPNetConfig(m=m, layer_norm_eps=layer_norm_eps, lstm_activation=lstm_activation, **kw)


def _check_torch_archive(p: Path) -> None:
    """A torch file must be the zip format of ``torch.save`` (torch >= 1.6) whose members are
    of sane declared sizes; checked before ``torch.load`` allocates anything."""
    import zipfile

    if not zipfile.is_zipfile(p):
        raise ValueError(f"{p}: not a weights-only torch checkpoint: not a torch.save zip "
                         "archive (the legacy pre-1.6 format and plain pickles are not read)")
    try:
        with zipfile.ZipFile(p) as z:
            infos = z.infolist()
    except (zipfile.BadZipFile, EOFError, OSError) as exc:
        raise ValueError(f"{p}: damaged torch archive ({exc})") from None
    total = sum(i.file_size for i in infos)
    if len(infos) > 100_000 or total > MAX_MEMBER_BYTES:
        raise ValueError(f"{p}: torch archive declares {len(infos):,} members / {total:,} bytes; "
                         "refused before reading")
    big = [i.filename for i in infos if i.file_size > MAX_MEMBER_BYTES]
    if big:
        raise ValueError(f"{p}: torch archive member(s) {big[:3]} declare more than "
                         f"{MAX_MEMBER_BYTES:,} bytes; refused before reading")


def import_torch(source: Any, m: int = 4, layer_norm_eps: float = 1e-3,
                 lstm_activation: str = "relu", dtype: Any = "float32") -> TPNet:
    """A :class:`TPNet` from the project's PyTorch model (:mod:`tpnet_ref.torch_model`).

    ``source``: a path to a ``torch.save``'d state dict (or a dict ``{"state_dict": ...}``), the
    state dict itself, or a :class:`~tpnet_ref.torch_model.TorchTPNet`. Files are read with ``torch.load(weights_only=True)``: no pickled
    code runs, and anything but tensors and plain containers is refused. The config (including
    the LayerNorm eps) comes from the state dict's ``_extra_state`` when present (what
    ``TorchTPNet.state_dict()`` writes); otherwise it is read from the shapes, with ``m``,
    ``layer_norm_eps`` and ``lstm_activation`` from the keyword arguments.
    """
    import torch

    where = "state dict"
    if isinstance(source, (str, os.PathLike)):
        where = str(source)
        if not Path(source).is_file():
            raise FileNotFoundError(f"torch checkpoint not found: {source}")
        _check_torch_archive(Path(source))
        try:
            obj = torch.load(source, map_location="cpu", weights_only=True)
        except Exception as exc:  # UnpicklingError, RuntimeError, ... from a refused payload
            raise ValueError(f"{where}: not a weights-only torch checkpoint: "
                             f"torch.load(weights_only=True) refused it ({type(exc).__name__}); "
                             "only tensors and plain containers are read, never pickled objects"
                             ) from None
    elif isinstance(source, torch.nn.Module):
        obj = source.state_dict()
    else:
        obj = source
    if isinstance(obj, dict) and "state_dict" in obj and isinstance(obj["state_dict"], dict):
        obj = obj["state_dict"]
    if not isinstance(obj, dict):
        raise ValueError(f"{where}: expected a state dict, got {type(obj).__name__}")
    sd: dict[str, np.ndarray] = {}
    extra = obj.get("_extra_state")
    for k, v in obj.items():
        if k == "_extra_state":
            continue
        if not isinstance(v, torch.Tensor):
            raise ValueError(f"{where}: entry {k!r} is a {type(v).__name__}, not a tensor")
        if not v.is_floating_point():
            raise ValueError(f"{where}: entry {k!r} has dtype {v.dtype}, expected floating point")
        sd[k] = v.detach().cpu().double().numpy()
    if isinstance(extra, dict) and extra.get("format") == "tpnet_ref-torch":
        cfg = TPNetConfig.from_dict(dict(extra["config"]))
        how = "config from _extra_state"
    else:
        cfg = _infer_torch_config(sd, m, layer_norm_eps, lstm_activation)
        how = f"config read from shapes (m={m}, layer_norm_eps={layer_norm_eps} given)"
    params = torch_state_to_native(sd, cfg)
    for k, v in params.items():
        if not np.isfinite(v).all():
            raise ValueError(f"{where}: parameter {k!r} contains NaN or infinite values")
    meta = {"source": where, "source_format": "torch state dict", "import_note": how}
    return TPNet(cfg, params, dtype, meta)


# ------------------------------------------------------------------------------- Keras HDF5
_KERAS_TYPES = ("conv2d", "dense", "bidirectional", "layer_normalization", "batch_normalization")
#: layer depths of the released architecture (widths are read from the file)
_DEPTHS = TPNetConfig()
#: vars/<i> order in Keras 3 files, per layer kind
_VARS_ORDER = {"conv2d": ("kernel", "bias"), "dense": ("kernel", "bias"),
               "lstm": ("kernel", "recurrent_kernel", "bias"),
               "layer_normalization": ("gamma", "beta"),
               "batch_normalization": ("gamma", "beta", "moving_mean", "moving_variance")}


class _KLayer:
    """One Keras layer found in a file: kind, name, variables (datasets, read lazily)."""

    def __init__(self, kind: str, name: str, order: tuple) -> None:
        self.kind, self.name, self.order = kind, name, order
        self.vars: dict[str, Any] = {}

    def get(self, var: str, where: str) -> np.ndarray:
        if var not in self.vars:
            raise ValueError(f"{where}: layer {self.name!r} ({self.kind}) has no variable {var!r} "
                             f"(found {sorted(self.vars)})")
        ds = self.vars[var]
        if ds.dtype.kind != "f":
            raise ValueError(f"{where}: {self.name}/{var} has dtype {ds.dtype}, expected float")
        if int(np.prod(ds.shape, dtype=np.float64)) > MAX_TENSOR:
            raise ValueError(f"{where}: {self.name}/{var} is implausibly large {ds.shape} "
                             f"(limit {MAX_TENSOR:,} elements); refused before reading")
        arr = np.asarray(_read(ds, f"{where}: {self.name}/{var}"), dtype=np.float64)
        if not np.isfinite(arr).all():
            raise ValueError(f"{where}: {self.name}/{var} contains NaN or infinite values")
        return arr

    def shape(self, var: str) -> tuple[int, ...]:
        return tuple(self.vars[var].shape) if var in self.vars else ()


def _safe_child(group: Any, name: str, where: str) -> Any:
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


def _layer_kind(name: str) -> tuple[str, int] | None:
    """``conv2d_12`` -> ("conv2d", 12); ``dense`` -> ("dense", 0); other names -> None."""
    import re

    mt = re.fullmatch(r"(conv2d|dense|bidirectional|layer_normalization|batch_normalization)"
                      r"(?:_(\d+))?", name)
    if not mt:
        return None
    return mt.group(1), int(mt.group(2) or 0)


def _named_layout(root: Any, where: str) -> list[_KLayer]:
    """TF-Keras 2 (and legacy-h5) layout: ``layer_names`` / ``weight_names`` attributes, datasets
    named ``<layer>/<var>:0`` (or without ``:0``), nested models flattened into their group.
    Layers are returned in the file's weight order (the model's forward/creation order)."""
    layers: dict[str, _KLayer] = {}
    n = 0
    for lname in [_py_str(x) for x in _attr(root, "layer_names", where)]:
        g = _safe_child(root, lname, where)
        for wname in [_py_str(x) for x in _attr(g, "weight_names", where, [])]:
            ds = _safe_child(g, wname, where)
            parts = wname[:-2].split("/") if wname.endswith(":0") else wname.split("/")
            var = parts[-1]
            bidi = [i for i, p in enumerate(parts) if p.startswith("bidirectional")]
            if bidi:
                i = bidi[-1]
                key = "/".join(parts[:i + 1])
                if i + 1 >= len(parts) - 1 or not parts[i + 1].startswith(("forward", "backward")):
                    raise ValueError(f"{where}: cannot tell the direction of {wname!r}")
                var = ("fwd." if parts[i + 1].startswith("forward") else "bwd.") + var
                kind = "bidirectional"
            else:
                key = "/".join(parts[:-1])
                kind = _kind_from_vars(parts[-2] if len(parts) > 1 else "", var, ds.shape)
            if key not in layers:
                layers[key] = _KLayer(kind, key, (n,))
                n += 1
            if var in layers[key].vars:
                raise ValueError(f"{where}: variable {wname!r} appears twice")
            layers[key].vars[var] = ds
    return list(layers.values())


def _kind_from_vars(lname: str, var: str, shape: tuple) -> str:
    k = _layer_kind(lname.split("/")[-1])
    if k is not None:
        return k[0]
    if var in ("moving_mean", "moving_variance"):
        return "batch_normalization"
    if var in ("gamma", "beta"):
        return "layer_normalization"
    if var == "kernel":
        return "conv2d" if len(shape) == 4 else "dense"
    return "unknown"


def _vars_layout(root: Any, where: str) -> list[_KLayer]:
    """Keras 3 layout (``.weights.h5`` / inside ``.keras``): ``layers/<name>/vars/<i>``, nested
    models as ``layers/<model>/layers/...``, Bidirectional as ``<name>/forward_layer/cell/vars``.
    Keras 3 names groups by class with a counter per model, in the model's layer order, so layers
    are ordered by (model path, counter)."""
    import h5py

    out: list[_KLayer] = []

    def read_vars(g: Any, path: str) -> list[Any]:
        vg = _safe_child(g, "vars", where)
        keys = sorted(vg.keys(), key=lambda s: int(s) if s.isdigit() else 1 << 30)
        return [_safe_child(vg, k, where) for k in keys]

    def walk(g: Any, container: str) -> None:
        lg = _safe_child(g, "layers", where)
        for name in list(lg.keys()):
            sub = _safe_child(lg, name, where)
            if not isinstance(sub, h5py.Group):
                continue
            path = f"{container}/{name}"
            kn = _layer_kind(name)
            if "layers" in sub:
                walk(sub, path)
            if kn is None:
                continue
            kind, idx = kn
            layer = _KLayer(kind, path, (container, idx))
            if kind == "bidirectional":
                for d, sfx in (("forward_layer", "fwd."), ("backward_layer", "bwd.")):
                    cell = _safe_child(_safe_child(sub, d, where), "cell", where)
                    vs = read_vars(cell, path)
                    names = _VARS_ORDER["lstm"]
                    if len(vs) != len(names):
                        raise ValueError(f"{where}: {path}/{d} has {len(vs)} variables, "
                                         f"expected {len(names)} (kernel, recurrent_kernel, bias)")
                    layer.vars.update({sfx + v: ds for v, ds in zip(names, vs)})
            else:
                vs = read_vars(sub, path)
                names = _VARS_ORDER[kind]
                if len(vs) != len(names):
                    raise ValueError(f"{where}: {path} has {len(vs)} variables, expected "
                                     f"{len(names)} {names}")
                layer.vars.update(dict(zip(names, vs)))
            out.append(layer)

    walk(root, "")
    return out


def _py_list(x: Any) -> list[str]:
    return [_py_str(v) for v in x]


def _py_str(x: Any) -> str:
    return x.decode() if isinstance(x, bytes) else str(x)


def _config_facts(cfg_json: Any) -> dict[str, Any]:
    """m (first 4-D input), LayerNorm/BatchNorm eps and LSTM activation from a Keras model config."""
    facts: dict[str, Any] = {"ln_eps": set(), "bn_eps": set(), "lstm_act": set(),
                             "unsupported": []}

    def visit(o: Any) -> None:
        if isinstance(o, dict):
            cls, c = o.get("class_name"), o.get("config")
            if isinstance(c, dict):
                if cls == "InputLayer" and "m" not in facts:
                    shape = c.get("batch_input_shape") or c.get("batch_shape")
                    if isinstance(shape, list) and len(shape) == 4 and isinstance(shape[1], int):
                        facts["m"] = shape[1]
                elif cls == "LayerNormalization" and "epsilon" in c:
                    facts["ln_eps"].add(float(c["epsilon"]))
                elif cls == "BatchNormalization" and "epsilon" in c:
                    facts["bn_eps"].add(float(c["epsilon"]))
                elif cls == "LSTM":
                    if "activation" in c:
                        facts["lstm_act"].add(str(c["activation"]))
                    if c.get("recurrent_activation", "sigmoid") != "sigmoid":
                        facts["unsupported"].append(
                            f"LSTM recurrent_activation={c['recurrent_activation']!r} (only sigmoid)")
                elif cls == "Bidirectional" and c.get("merge_mode", "concat") != "concat":
                    facts["unsupported"].append(
                        f"Bidirectional merge_mode={c['merge_mode']!r} (only concat)")
            for v in o.values():
                visit(v)
        elif isinstance(o, list):
            for v in o:
                visit(v)

    visit(cfg_json)
    return facts


def _dense_kernel(layer: _KLayer, where: str) -> tuple[np.ndarray, np.ndarray]:
    """A Conv2D (1, kw, cin, cout) with kw == 1 or cin == 1, or a Dense (cin, cout) layer
    -> dense ``(w (in, out), b (out,))``."""
    k = layer.get("kernel", where)
    if k.ndim == 4:
        kh, kw, cin, cout = k.shape
        if kh != 1 or (kw != 1 and cin != 1):
            raise ValueError(f"{where}: Conv2D {layer.name!r} has kernel {k.shape}; a point-wise "
                             "layer needs (1, K, 1, C) or (1, 1, Cin, C)")
        k = k.reshape(kw * cin, cout)
    elif k.ndim != 2:
        raise ValueError(f"{where}: {layer.name!r} has a kernel of rank {k.ndim}")
    b = layer.get("bias", where) if "bias" in layer.vars else np.zeros(k.shape[1])
    return k, _check_shape(b, (k.shape[1],), f"{where}: {layer.name}/bias")


def _fold_bn(w: np.ndarray, b: np.ndarray, bn: _KLayer, eps: float,
             where: str) -> tuple[np.ndarray, np.ndarray]:
    """``BN(x @ w + b)`` as one dense layer: ``w * s``, ``(b - mean) * s + beta``,
    ``s = gamma / sqrt(var + eps)``."""
    c = (w.shape[1],)
    gamma = _check_shape(bn.get("gamma", where), c, f"{where}: {bn.name}/gamma")
    beta = _check_shape(bn.get("beta", where), c, f"{where}: {bn.name}/beta")
    mean = _check_shape(bn.get("moving_mean", where), c, f"{where}: {bn.name}/moving_mean")
    var = _check_shape(bn.get("moving_variance", where), c, f"{where}: {bn.name}/moving_variance")
    s = gamma / np.sqrt(var + eps)
    return w * s, (b - mean) * s + beta


def _open_keras(path: str | os.PathLike):
    """-> (h5 file, config JSON or None, layout name). ``.keras`` zips are read in memory."""
    import io
    import zipfile

    import h5py

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"Keras checkpoint not found: {p}")
    if zipfile.is_zipfile(p):
        try:
            with zipfile.ZipFile(p) as z:
                names = set(z.namelist())
                if "model.weights.h5" not in names:
                    raise ValueError(f"{p}: a zip without model.weights.h5 is not a .keras file "
                                     f"(members: {sorted(names)[:6]})")
                info = z.getinfo("model.weights.h5")
                if info.file_size > MAX_MEMBER_BYTES:
                    raise ValueError(f"{p}: model.weights.h5 declares {info.file_size:,} bytes "
                                     f"(limit {MAX_MEMBER_BYTES:,}); refused before reading")
                cfg = None
                if "config.json" in names:
                    if z.getinfo("config.json").file_size > MAX_CONFIG_BYTES:
                        raise ValueError(f"{p}: config.json declares "
                                         f"{z.getinfo('config.json').file_size:,} bytes "
                                         f"(limit {MAX_CONFIG_BYTES:,}); refused before reading")
                    cfg = _json(z.read("config.json"), f"{p}: config.json")
                data = z.read("model.weights.h5")
        except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, NotImplementedError,
                RuntimeError, OSError) as exc:
            # zlib.error is an Exception subclass that zipfile lets through
            raise ValueError(f"{p}: damaged or unsupported .keras archive ({exc})") from None
        except Exception as exc:
            if type(exc).__name__ != "error":  # zlib.error
                raise
            raise ValueError(f"{p}: damaged .keras archive ({exc})") from None
        try:
            return h5py.File(io.BytesIO(data), "r"), cfg, "Keras 3 .keras archive"
        except OSError as exc:
            raise ValueError(f"{p}: model.weights.h5 in the archive is not readable HDF5 "
                             f"({exc})") from None
    f = _open_h5(p)
    cfg = None
    try:
        cfg = _json(_attr(f, "model_config", str(p)), str(p))
    except BaseException:
        f.close()
        raise
    return f, cfg, None


def _json(text: Any, where: str) -> Any:
    """Parse a model config; malformed or absurdly nested JSON gives ``ValueError``."""
    import json

    if text is None:
        return None
    try:
        return json.loads(_py_str(text) if isinstance(text, bytes) else str(text))
    except (ValueError, RecursionError) as exc:
        raise ValueError(f"{where}: model config is not valid JSON "
                         f"({type(exc).__name__}: {str(exc)[:80]})") from None


@_damaged_file_is_value_error
def import_keras_h5(path: str | os.PathLike, m: int | None = None,
                    layer_norm_eps: float | None = None, lstm_activation: str | None = None,
                    dtype: Any = "float32") -> TPNet:
    """A :class:`TPNet` from a Keras checkpoint of the released architecture (SPEC §2).

    Reads TF-Keras 2 HDF5 (``model.save`` with ``model_weights/`` and ``save_weights`` files,
    names with or without ``:0``) and Keras 3 (``.weights.h5``, ``.keras``); nested models.
    Layers are mapped to roles by creation order and kernel shapes, every shape is asserted:

    - Conv2D point layers (kernels ``(1, K, 1, C)`` or ``(1, 1, Cin, C)``, converted to dense
      ``(in, out)``): 11 with transform nets (input T-Net 3, MLP1 2, feature T-Net 3, MLP2 3),
      or 5 without (MLP1 2, MLP2 3); BatchNorm, if present, is folded into its layer.
    - Dense: T-Net FCs (2 each), each T-Net's output FC ``(fc, K*K)`` *if saved*, the global
      FC, the head ``(2u, N*dim)``. The released code's T-Net output FC is an untracked variable,
      not in the file: that transform is then the identity, and its branch (dead weight) is
      dropped (``meta['dropped_params']``).
    - Bidirectional LSTMs (kernel, recurrent_kernel, bias per direction), each followed by a
      LayerNormalization.

    ``m`` / ``layer_norm_eps`` / ``lstm_activation``: read from the model config when the file
    has one (whole-model files, ``.keras``); otherwise the keyword (defaults 4, 1e-3, relu).
    ``meta['import_report']`` says what was found. Raises ``ValueError`` naming what is
    missing or unexpected for a file that does not fit.
    """
    where = str(path)
    f, cfg_json, layout = _open_keras(path)
    with f:
        root = f["model_weights"] if "model_weights" in f else f
        if "layer_names" in root.attrs:
            layers = _named_layout(root, where)
            ver = _py_str(_attr(f, "keras_version", where,
                                _attr(root, "keras_version", where, "?")))
            fw = "TF-Keras 2" if ver.startswith("2") else f"Keras {ver}"
            colon = any(_py_str(n).endswith(":0")
                        for ln in _py_list(_attr(root, "layer_names", where))
                        for n in _py_list(_attr(_safe_child(root, ln, where), "weight_names",
                                                where, [])))
            layout = layout or (f"{fw} HDF5 " + ("whole model (model_weights/)" if "model_weights"
                                                  in f else "save_weights")
                                + f", names {'with' if colon else 'without'} ':0'")
            ordered = True
        elif "layers" in root:
            layers = _vars_layout(root, where)
            layout = layout or "Keras 3 .weights.h5"
            ordered = False
        else:
            raise ValueError(f"{where}: unknown layout: neither a TF-Keras HDF5 weights file "
                             "(attribute layer_names) nor a Keras 3 weights file (group layers/); "
                             f"top-level keys {sorted(f.keys())[:8]}")
        unknown = [ln.name for ln in layers if ln.kind not in _KERAS_TYPES]
        if unknown:
            raise ValueError(f"{where}: unexpected layer(s) with weights {unknown}")
        try:
            facts = _config_facts(cfg_json or {})
        except RecursionError:
            raise ValueError(f"{where}: model config is nested too deeply") from None
        model, report = _keras_to_native(layers, ordered, facts,
                                         m, layer_norm_eps, lstm_activation, where, dtype)
    report = f"{layout}; " + report
    model.meta.update({"source": where, "source_format": layout, "import_report": report})
    return model


def _keras_to_native(layers: list[_KLayer], ordered: bool, facts: dict[str, Any],
                     m: int | None, ln_eps: float | None, act: str | None, where: str,
                     dtype: Any) -> tuple[TPNet, str]:
    if facts["unsupported"]:
        raise ValueError(f"{where}: the model config uses what TP-Net does not: "
                         f"{sorted(set(facts['unsupported']))}")
    by = {k: [ln for ln in layers if ln.kind == k] for k in _KERAS_TYPES}
    if not ordered:
        # Keras 3: counters per model; frame layers live in the model that holds the convs
        conv_box = by["conv2d"][0].order[0] if by["conv2d"] else None
        for k in by:
            by[k].sort(key=lambda ln: (ln.order[0] != conv_box, ln.order))
    convs, denses, bilstms, lns, bns = (by["conv2d"], by["dense"], by["bidirectional"],
                                        by["layer_normalization"], by["batch_normalization"])
    notes: list[str] = []

    def pick(name: str, given: Any, found: set, default: Any) -> Any:
        if given is not None:
            return given
        if len(found) > 1:
            raise ValueError(f"{where}: the model config has several {name} values {sorted(found)}")
        if found:
            return next(iter(found))
        notes.append(f"{name}={default} (not in file, default)")
        return default

    ln_eps = float(pick("layer_norm_eps", ln_eps, facts["ln_eps"], 1e-3))
    act = pick("lstm_activation", act, facts["lstm_act"], "relu")
    bn_eps = float(next(iter(facts["bn_eps"]))) if len(facts["bn_eps"]) == 1 else 1e-3
    if m is None:
        m = facts.get("m")
        if m is None:
            m = 4
            notes.append("m=4 (not in file, default)")

    # ---- per-frame layers: counts decide whether transform nets are present
    d = _DEPTHS
    n_tnet = len(d.input_tnet_mlp) + len(d.mlp1) + len(d.feature_tnet_mlp) + len(d.mlp2)
    n_plain = len(d.mlp1) + len(d.mlp2)
    if len(convs) == n_tnet:
        has_tnets = True
    elif len(convs) == n_plain:
        has_tnets = False
    else:
        raise ValueError(f"{where}: found {len(convs)} Conv2D layers {[c.name for c in convs]}; "
                         f"the released layout has {n_tnet} (with transform nets) or {n_plain}")
    if not bilstms:
        raise ValueError(f"{where}: no Bidirectional LSTM layer found")
    if len(lns) != len(bilstms):
        raise ValueError(f"{where}: {len(bilstms)} Bidirectional layers but {len(lns)} "
                         "LayerNormalization layers; expected one after each")
    conv_w = [_dense_kernel(c, where) for c in convs]
    dim = conv_w[0][0].shape[0]
    queue_c = list(zip(convs, conv_w))
    queue_d = list(denses)

    def take_convs(n: int, cin: int, what: str) -> list[tuple[_KLayer, tuple]]:
        got = [queue_c.pop(0) for _ in range(n)]
        for layer, (w, _) in got:
            if w.shape[0] != cin:
                raise ValueError(f"{where}: {what}: {layer.name!r} takes {w.shape[0]} inputs, "
                                 f"expected {cin} (kernel {layer.shape('kernel')})")
            cin = w.shape[1]
        return got

    def take_dense(cin: int, what: str, cout: int | None = None) -> tuple[_KLayer, tuple]:
        if not queue_d:
            raise ValueError(f"{where}: missing Dense layer for {what}")
        layer = queue_d.pop(0)
        w, b = _dense_kernel(layer, where)
        if w.shape[0] != cin or (cout is not None and w.shape[1] != cout):
            raise ValueError(f"{where}: {what}: {layer.name!r} has kernel {w.shape}, expected "
                             f"({cin}, {cout if cout is not None else 'any'})")
        return layer, (w, b)

    roles: list[tuple[str, _KLayer, tuple, bool]] = []  # (native prefix, layer, (w, b), may_bn)
    cfg_kw: dict[str, Any] = {"dim": dim}
    dropped = 0

    def tnet(prefix: str, k: int, nmlp: int, nfc: int) -> bool:
        nonlocal dropped
        mlp = take_convs(nmlp, k, f"{prefix} MLP")
        c = mlp[-1][1][0].shape[1]
        fcs = []
        for i in range(nfc):
            fcs.append(take_dense(c, f"{prefix} FC {i}"))
            c = fcs[-1][1][0].shape[1]
        trained = bool(queue_d) and queue_d[0].shape("kernel") == (c, k * k)
        rows = ([(f"{prefix}.mlp.{i}", ly, wb, True) for i, (ly, wb) in enumerate(mlp)]
                + [(f"{prefix}.fc.{i}", ly, wb, True) for i, (ly, wb) in enumerate(fcs)])
        if trained:
            ly, wb = take_dense(c, f"{prefix} output", k * k)
            rows.append((f"{prefix}.out", ly, wb, False))
            cfg_kw[f"{prefix}_mlp"] = tuple(wb_[0].shape[1] for _, wb_ in mlp)
            cfg_kw[f"{prefix}_fc"] = tuple(wb_[0].shape[1] for _, wb_ in fcs)
        else:
            dropped += sum(w.size + b.size for _, _, (w, b), _ in rows)
        roles.extend([(r[0] if trained else "dead." + r[0], *r[1:]) for r in rows])
        return trained

    if has_tnets:
        cfg_kw["input_transform_trained"] = tnet("input_tnet", dim, len(d.input_tnet_mlp),
                                                 len(d.input_tnet_fc))
    mlp1 = take_convs(len(d.mlp1), dim, "MLP1")
    roles.extend((f"mlp1.{i}", ly, wb, True) for i, (ly, wb) in enumerate(mlp1))
    c1 = mlp1[-1][1][0].shape[1]
    if has_tnets:
        cfg_kw["feature_transform_trained"] = tnet("feature_tnet", c1, len(d.feature_tnet_mlp),
                                                   len(d.feature_tnet_fc))
    mlp2 = take_convs(len(d.mlp2), c1, "MLP2")
    roles.extend((f"mlp2.{i}", ly, wb, True) for i, (ly, wb) in enumerate(mlp2))
    ly, wb = take_dense(mlp2[-1][1][0].shape[1], "global feature FC")
    roles.append(("global", ly, wb, True))
    k = wb[0].shape[1]

    # ---- BatchNorm: folded, in order, into the layer whose width it has
    if bns:
        queue_bn = list(bns)
        folded = []
        for i, (prefix, ly, (w, b), may_bn) in enumerate(roles):
            if may_bn and queue_bn and queue_bn[0].shape("gamma") == (w.shape[1],):
                bn = queue_bn.pop(0)
                roles[i] = (prefix, ly, _fold_bn(w, b, bn, bn_eps, where), may_bn)
                folded.append(bn.name)
        if queue_bn:
            raise ValueError(f"{where}: BatchNormalization layer(s) {[x.name for x in queue_bn]} "
                             "do not follow any point-wise or FC layer of matching width")
        notes.append(f"folded {len(folded)} BatchNorm layers (eps {bn_eps})")

    params: dict[str, np.ndarray] = {}
    for prefix, _, (w, b), _ in roles:
        if not prefix.startswith("dead."):
            params[f"{prefix}.w"], params[f"{prefix}.b"] = w, b

    # ---- sequence network
    c = k
    units = []
    for i, (bl, ln) in enumerate(zip(bilstms, lns), start=1):
        u = None
        for dname in ("fwd", "bwd"):
            kern = bl.get(f"{dname}.kernel", where)
            rec = bl.get(f"{dname}.recurrent_kernel", where)
            u = rec.shape[0]
            what = f"{bl.name} ({dname})"
            params[f"lstm{i}.{dname}.kernel"] = _check_shape(kern, (c, 4 * u), f"{where}: {what} kernel")
            params[f"lstm{i}.{dname}.recurrent"] = _check_shape(rec, (u, 4 * u),
                                                                f"{where}: {what} recurrent_kernel")
            params[f"lstm{i}.{dname}.bias"] = _check_shape(bl.get(f"{dname}.bias", where), (4 * u,),
                                                           f"{where}: {what} bias")
        units.append(u)
        c = 2 * u
        params[f"ln{i}.gamma"] = _check_shape(ln.get("gamma", where), (c,), f"{where}: {ln.name}/gamma")
        params[f"ln{i}.beta"] = _check_shape(ln.get("beta", where), (c,), f"{where}: {ln.name}/beta")
    ly, (w, b) = take_dense(c, "head FC")
    if w.shape[1] % dim:
        raise ValueError(f"{where}: head {ly.name!r} has {w.shape[1]} outputs, not N*{dim}")
    params["head.w"], params["head.b"] = w, b
    if queue_d:
        raise ValueError(f"{where}: unexpected Dense layer(s) {[x.name for x in queue_d]} "
                         f"with kernels {[x.shape('kernel') for x in queue_d]}")
    cfg = TPNetConfig(
        m=int(m), n_out=w.shape[1] // dim, mlp1=tuple(x[1][0].shape[1] for x in mlp1),
        mlp2=tuple(x[1][0].shape[1] for x in mlp2), global_features=k, lstm_units=tuple(units),
        lstm_activation=act, layer_norm_eps=ln_eps, **cfg_kw)
    model = TPNet(cfg, params, dtype)
    tr = {False: "identity (output FC not saved)", True: "trained"}
    report = (f"m={cfg.m}, N={cfg.n_out}, params={model.num_params:,}; "
              + (f"input transform {tr[cfg.input_transform_trained]}, feature transform "
                 f"{tr[cfg.feature_transform_trained]}" if has_tnets else "no transform nets")
              + (f"; dropped {dropped:,} dead transform-net parameters" if dropped else "")
              + (f"; {'; '.join(notes)}" if notes else ""))
    model.meta["dropped_params"] = int(dropped)
    return model, report


# ----------------------------------------------------------------------------------- dispatch
@_damaged_file_is_value_error
def import_checkpoint(path: str | os.PathLike, dtype: Any = "float32", **kw: Any) -> TPNet:
    """Any supported checkpoint -> :class:`TPNet`: a native file, a Keras HDF5 / ``.keras``
    file (:func:`import_keras_h5`) or a torch state dict (:func:`import_torch`), told apart by
    content, not by name."""
    import zipfile

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"checkpoint not found: {p}")
    with open(p, "rb") as fh:
        head = fh.read(8)
    if head == b"\x89HDF\r\n\x1a\n":
        with _open_h5(p) as f:
            native = _py(_attr(f, "format", str(p), "")) == FORMAT
        if native:
            model = load_native(p, dtype)
            model.meta["import_report"] = "native tpnet_ref weights file"
            return model
        return import_keras_h5(p, dtype=dtype, **kw)
    if zipfile.is_zipfile(p):
        try:
            with zipfile.ZipFile(p) as z:
                is_keras = "model.weights.h5" in z.namelist()
        except (zipfile.BadZipFile, EOFError, OSError) as exc:
            raise ValueError(f"{p}: damaged zip archive ({exc})") from None
        if is_keras:
            return import_keras_h5(p, dtype=dtype, **kw)
    torch_kw = {k: v for k, v in kw.items() if v is not None}
    try:
        import torch  # noqa: F401
    except ImportError:
        raise ValueError(f"{p}: neither HDF5 nor a .keras archive; reading it as a PyTorch "
                         "checkpoint needs torch (pip install 'tpnet-ref[train]')") from None
    model = import_torch(p, dtype=dtype, **torch_kw)
    model.meta["import_report"] = (f"torch state dict; m={model.config.m}, N={model.config.n_out}, "
                                   f"params={model.num_params:,}; {model.meta['import_note']}")
    return model


def add_cli(sub: Any) -> None:
    p = sub.add_parser("import", help="convert a Keras (.h5, .weights.h5, .keras) or PyTorch "
                                      "(.pt) checkpoint to the native weights file")
    p.add_argument("src", help="checkpoint to read (kind told by content)")
    p.add_argument("dst", help="native HDF5 weights file to write")
    p.add_argument("--m", type=int, default=None,
                   help="input frames, where the file does not say (default 4)")
    p.add_argument("--layer-norm-eps", type=float, default=None,
                   help="LayerNorm eps, where the file does not say (default 1e-3)")
    p.add_argument("--lstm-activation", choices=("relu", "tanh"), default=None,
                   help="LSTM activation, where the file does not say (default relu)")
    p.add_argument("--dtype", choices=("float32", "float64"), default="float32",
                   help="dtype of the written parameters (default float32, as trained)")
    p.set_defaults(func=_cli_import)


def _cli_import(args: Any) -> int:
    model = import_checkpoint(args.src, dtype=args.dtype, m=args.m,
                              layer_norm_eps=args.layer_norm_eps,
                              lstm_activation=args.lstm_activation)
    c = model.config
    print(f"read {args.src}: {model.meta.get('import_report', '')}")
    print(f"  {model}")
    print(f"  m={c.m} N={c.n_out} lstm_units={c.lstm_units} activation={c.lstm_activation} "
          f"layer_norm_eps={c.layer_norm_eps}")
    print(f"  transforms: input {'trained' if c.input_transform_trained else 'identity'}, "
          f"feature {'trained' if c.feature_transform_trained else 'identity'}")
    meta = {k: v for k, v in model.meta.items() if k in ("source", "source_format", "import_report")}
    model.save(args.dst, **meta)
    print(f"wrote {args.dst}")
    return 0
