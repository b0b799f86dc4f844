"""Import a state dict of the PyTorch TP-Net (:mod:`tpnet_ref.training.torch_model`).

PyTorch names follow one rule from the native names of :func:`~tpnet_ref.config.param_shapes`
(:func:`torch_name`), so the key map of a config is derived, never spelled out:

    mlp1.0.w (2, 64)                 <-> mlp1.0.weight (64, 2)              (transposed)
    global.w                         <-> global_fc.weight                   (transposed)
    lstm1.fwd.kernel (in, 4u)        <-> lstm1.weight_ih_l0 (4u, in)        (transposed)
    lstm1.fwd.recurrent (u, 4u)      <-> lstm1.weight_hh_l0 (4u, u)         (transposed)
    lstm1.fwd.bias (4u,)             <-> lstm1.bias_ih_l0 + lstm1.bias_hh_l0
    lstm1.bwd.*                      <-> lstm1.*_l0_reverse
    ln1.gamma / ln1.beta             <-> ln1.weight / ln1.bias

PyTorch's LSTM gate order i, f, g, o is Keras's i, f, c, o: no reordering. Files are read with
``torch.load(weights_only=True)`` after the zip archive's declared sizes are checked: no pickled
code runs. torch is needed (``train`` extra) only to read a file or a module, not for the
NumPy-level conversions.
"""
from __future__ import annotations

import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ..config import TPNetConfig, param_shapes
from ..extras import require
from ..model import TPNet
from .provenance import portable_path
from . import hdf5
from .hdf5 import check_shape

#: tag stored in ``_extra_state`` of :class:`~tpnet_ref.training.torch_model.TorchTPNet`
TORCH_FORMAT = "tpnet_ref-torch"


def torch_name(name: str) -> tuple[str, str]:
    """PyTorch name of native parameter ``name`` and how the tensor converts: ``T`` (transpose),
    ``=`` (copy) or ``+`` (the native LSTM bias is ``bias_ih + bias_hh``)."""
    parts = name.split(".")
    if parts[0].startswith("lstm"):
        layer, direction, var = parts
        sfx = "_l0" if direction == "fwd" else "_l0_reverse"
        return {"kernel": (f"{layer}.weight_ih{sfx}", "T"),
                "recurrent": (f"{layer}.weight_hh{sfx}", "T"),
                "bias": (f"{layer}.bias_ih{sfx}", "+")}[var]
    if parts[0].startswith("ln"):
        return f"{parts[0]}.{'weight' if parts[1] == 'gamma' else 'bias'}", "="
    block = "global_fc" if parts[0] == "global" else parts[0]
    leaf = parts[-1]
    return ".".join([block, *parts[1:-1], "weight" if leaf == "w" else "bias"]), \
        ("T" if leaf == "w" else "=")


def torch_key_map(cfg: TPNetConfig) -> list[tuple[str, str, str]]:
    """``(torch name, native name, how)`` for every parameter of ``cfg``, in forward order."""
    rows = []
    for n in param_shapes(cfg):
        tname, how = torch_name(n)
        rows.append((tname, n, how))
    return rows


def _hh(tname: str) -> str:
    return tname.replace("bias_ih", "bias_hh")


def _describe(cfg: TPNetConfig) -> str:
    return (f"m={cfg.m}, n_out={cfg.n_out}, lstm_units={cfg.lstm_units}, transforms "
            f"{'trained' if cfg.input_transform_trained else 'identity'}/"
            f"{'trained' if cfg.feature_transform_trained else 'identity'}")


def torch_state_to_native(sd: dict[str, np.ndarray], cfg: TPNetConfig) -> dict[str, np.ndarray]:
    """PyTorch-layout tensors (NumPy arrays) -> native parameters, every shape asserted.

    Linear ``weight (out, in)`` -> ``w (in, out)``; LSTM ``weight_ih (4u, in)`` ->
    ``kernel (in, 4u)``, ``weight_hh (4u, u)`` -> ``recurrent (u, 4u)``, ``bias_ih + bias_hh``
    -> ``bias (4u,)``. Raises ``ValueError`` naming every missing or unexpected key.
    """
    shapes = param_shapes(cfg)
    rows = torch_key_map(cfg)
    expected = {t for t, _, _ in rows} | {_hh(t) for t, _, h in rows if h == "+"}
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
            out[nname] = check_shape(a, shape[::-1], tname).T
        elif how == "+":
            out[nname] = (check_shape(a, shape, tname)
                          + check_shape(np.asarray(sd[_hh(tname)]), shape, _hh(tname)))
        else:
            out[nname] = check_shape(a, shape, tname)
    return out


def native_to_torch_state(params: dict[str, np.ndarray], cfg: TPNetConfig) -> dict[str, np.ndarray]:
    """Native parameters -> PyTorch-layout arrays (the LSTM bias goes to ``bias_ih``,
    ``bias_hh`` is zero)."""
    out: dict[str, np.ndarray] = {}
    for tname, nname, how in torch_key_map(cfg):
        a = np.asarray(params[nname])
        if how == "T":
            out[tname] = np.ascontiguousarray(a.T)
        elif how == "+":
            out[tname] = a.copy()
            out[_hh(tname)] = np.zeros_like(a)
        else:
            out[tname] = a.copy()
    return out


def _out_width(sd: dict[str, Any], native: str) -> int:
    """Output width of the dense layer with native weight name ``native`` (``...w``)."""
    return int(sd[torch_name(native)[0]].shape[0])


def _stack_widths(sd: dict[str, Any], prefix: str) -> tuple[int, ...]:
    """Output widths of the native stack ``prefix.0``, ``prefix.1``, ... present in ``sd``."""
    widths: list[int] = []
    while torch_name(f"{prefix}.{len(widths)}.w")[0] in sd:
        widths.append(_out_width(sd, f"{prefix}.{len(widths)}.w"))
    return tuple(widths)


def infer_torch_config(sd: dict[str, Any], m: int, layer_norm_eps: float,
                       lstm_activation: str) -> TPNetConfig:
    """Config of a bare state dict (no ``_extra_state``), read from its shapes; the result is
    checked key by key against :func:`param_shapes` when the tensors are converted."""
    need = [torch_name(n)[0] for n in ("mlp1.0.w", "mlp2.0.w", "global.w", "lstm1.fwd.recurrent",
                                       "head.w")]
    missing = [k for k in need if k not in sd]
    if missing:
        raise ValueError(f"not a TP-Net torch state dict: missing {missing} "
                         f"(keys present: {sorted(sd)[:8]}...)")
    dim = int(sd[torch_name("mlp1.0.w")[0]].shape[1])
    kw: dict[str, Any] = {"dim": dim, "mlp1": _stack_widths(sd, "mlp1"),
                          "mlp2": _stack_widths(sd, "mlp2"),
                          "global_features": _out_width(sd, "global.w")}
    units: list[int] = []
    while torch_name(f"lstm{len(units) + 1}.fwd.recurrent")[0] in sd:
        units.append(int(sd[torch_name(f"lstm{len(units) + 1}.fwd.recurrent")[0]].shape[1]))
    kw["lstm_units"] = tuple(units)
    n2 = _out_width(sd, "head.w")
    if n2 % dim:
        raise ValueError(f"head.weight has {n2} outputs, not a multiple of dim={dim}")
    kw["n_out"] = n2 // dim
    for prefix, flag in (("input_tnet", "input_transform_trained"),
                         ("feature_tnet", "feature_transform_trained")):
        if torch_name(f"{prefix}.out.w")[0] in sd:
            kw[flag] = True
            kw[f"{prefix}_mlp"] = _stack_widths(sd, f"{prefix}.mlp")
            kw[f"{prefix}_fc"] = _stack_widths(sd, f"{prefix}.fc")
    return TPNetConfig(m=m, layer_norm_eps=layer_norm_eps, lstm_activation=lstm_activation, **kw)


def _check_torch_archive(p: Path) -> None:
    """A torch file must be the zip format of ``torch.save`` (torch >= 1.6) whose members are
    of sane declared sizes; checked before ``torch.load`` allocates anything."""
    if not zipfile.is_zipfile(p):
        raise ValueError(f"{p}: not a weights-only torch checkpoint: not a torch.save zip "
                         "archive (the legacy pre-1.6 format and plain pickles are not read)")
    try:
        with zipfile.ZipFile(p) as z:
            infos = z.infolist()
    except (zipfile.BadZipFile, EOFError, OSError) as exc:
        raise ValueError(f"{p}: damaged torch archive ({exc})") from None
    total = sum(i.file_size for i in infos)
    if len(infos) > 100_000 or total > hdf5.MAX_MEMBER_BYTES:
        raise ValueError(f"{p}: torch archive declares {len(infos):,} members / {total:,} bytes; "
                         "refused before reading")
    big = [i.filename for i in infos if i.file_size > hdf5.MAX_MEMBER_BYTES]
    if big:
        raise ValueError(f"{p}: torch archive member(s) {big[:3]} declare more than "
                         f"{hdf5.MAX_MEMBER_BYTES:,} bytes; refused before reading")


def import_torch(source: Any, m: int = 4, layer_norm_eps: float = 1e-3,
                 lstm_activation: str = "relu", dtype: Any = "float32") -> TPNet:
    """A :class:`TPNet` from the project's PyTorch model.

    ``source``: a path to a ``torch.save``'d state dict (or a dict ``{"state_dict": ...}``), the
    state dict itself, or a :class:`~tpnet_ref.training.torch_model.TorchTPNet`. Files are read
    with ``torch.load(weights_only=True)``: no pickled code runs, and anything but tensors and
    plain containers is refused. The config (including the LayerNorm eps) comes from the state
    dict's ``_extra_state`` when present (what ``TorchTPNet.state_dict()`` writes); otherwise it
    is read from the shapes, with ``m``, ``layer_norm_eps`` and ``lstm_activation`` from the
    keyword arguments.
    """
    torch = require("torch", "train", "reading a PyTorch checkpoint")
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
    if isinstance(extra, dict) and extra.get("format") == TORCH_FORMAT:
        cfg = TPNetConfig.from_dict(dict(extra["config"]))
        how = "config from _extra_state"
    else:
        cfg = infer_torch_config(sd, m, layer_norm_eps, lstm_activation)
        how = f"config read from shapes (m={m}, layer_norm_eps={layer_norm_eps} given)"
    params = torch_state_to_native(sd, cfg)
    for k, v in params.items():
        if not np.isfinite(v).all():
            raise ValueError(f"{where}: parameter {k!r} contains NaN or infinite values")
    meta = {"source": portable_path(where) if where != "state dict" else where,
            "source_format": "torch state dict", "import_note": how}
    return TPNet(cfg, params, dtype, meta)


__all__ = ["import_torch", "torch_name", "torch_key_map", "torch_state_to_native",
           "native_to_torch_state", "infer_torch_config", "TORCH_FORMAT"]
