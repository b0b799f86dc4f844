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


def import_torch(source: Any, m: int = 4, layer_norm_eps: float = 1e-3,
                 lstm_activation: str = "relu", dtype: Any = "float32") -> TPNet:
    """A :class:`TPNet` from the project's PyTorch model (:mod:`tpnet_ref.torch_model`).

    ``source``: a path to a ``torch.save``'d state dict (or a dict ``{"state_dict": ...}``), or
    the state dict itself. Files are read with ``torch.load(weights_only=True)``: no pickled
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
        try:
            obj = torch.load(source, map_location="cpu", weights_only=True)
        except Exception as exc:  # UnpicklingError, RuntimeError, ... from a refused payload
            raise ValueError(f"{where}: not a weights-only torch checkpoint ({type(exc).__name__}: "
                             f"{str(exc).splitlines()[0] if str(exc) else ''})") from None
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
