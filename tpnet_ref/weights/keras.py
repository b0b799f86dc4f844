"""Import Keras checkpoints of the released architecture (docs/spec.md §2).

Reads TF-Keras 2 HDF5 as the authors' code writes them (``model.save`` with ``model_weights/`` and
``save_weights`` files, names with or without ``:0``) and Keras 3 (``.weights.h5``, ``.keras``),
nested models included. Layers are told apart by kind, creation order and kernel shapes, their
tensors are collected in forward order, and :func:`~tpnet_ref.config.param_shapes` of the config
read from them names every tensor (each shape asserted). Mapping tables: ``docs/weights.md``.
Everything is read through the untrusted-file guards of :mod:`tpnet_ref.weights.hdf5`.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ..config import TPNetConfig, param_shapes
from ..model import TPNet
from .provenance import portable_path
from . import hdf5
from .hdf5 import (attr, check_shape, damaged_file_is_value_error, open_h5, py_str, read,
                   safe_child)

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
        if int(np.prod(ds.shape, dtype=np.float64)) > hdf5.MAX_TENSOR:
            raise ValueError(f"{where}: {self.name}/{var} is implausibly large {ds.shape} "
                             f"(limit {hdf5.MAX_TENSOR:,} elements); refused before reading")
        arr = np.asarray(read(ds, f"{where}: {self.name}/{var}"), dtype=np.float64)
        if not np.isfinite(arr).all():
            raise ValueError(f"{where}: {self.name}/{var} contains NaN or infinite values")
        return arr

    def shape(self, var: str) -> tuple[int, ...]:
        return tuple(self.vars[var].shape) if var in self.vars else ()


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
    for lname in [py_str(x) for x in attr(root, "layer_names", where)]:
        g = safe_child(root, lname, where)
        for wname in [py_str(x) for x in attr(g, "weight_names", where, [])]:
            ds = safe_child(g, wname, where)
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
        vg = safe_child(g, "vars", where)
        keys = sorted(vg.keys(), key=lambda s: int(s) if s.isdigit() else 1 << 30)
        return [safe_child(vg, k, where) for k in keys]

    def walk(g: Any, container: str) -> None:
        lg = safe_child(g, "layers", where)
        for name in list(lg.keys()):
            sub = safe_child(lg, name, where)
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
                    cell = safe_child(safe_child(sub, d, where), "cell", where)
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
    return [py_str(v) for v in x]


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
    return k, check_shape(b, (k.shape[1],), f"{where}: {layer.name}/bias")


def _fold_bn(w: np.ndarray, b: np.ndarray, bn: _KLayer, eps: float,
             where: str) -> tuple[np.ndarray, np.ndarray]:
    """``BN(x @ w + b)`` as one dense layer: ``w * s``, ``(b - mean) * s + beta``,
    ``s = gamma / sqrt(var + eps)``."""
    c = (w.shape[1],)
    gamma = check_shape(bn.get("gamma", where), c, f"{where}: {bn.name}/gamma")
    beta = check_shape(bn.get("beta", where), c, f"{where}: {bn.name}/beta")
    mean = check_shape(bn.get("moving_mean", where), c, f"{where}: {bn.name}/moving_mean")
    var = check_shape(bn.get("moving_variance", where), c, f"{where}: {bn.name}/moving_variance")
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
                if info.file_size > hdf5.MAX_MEMBER_BYTES:
                    raise ValueError(f"{p}: model.weights.h5 declares {info.file_size:,} bytes "
                                     f"(limit {hdf5.MAX_MEMBER_BYTES:,}); refused before reading")
                cfg = None
                if "config.json" in names:
                    if z.getinfo("config.json").file_size > hdf5.MAX_CONFIG_BYTES:
                        raise ValueError(f"{p}: config.json declares "
                                         f"{z.getinfo('config.json').file_size:,} bytes "
                                         f"(limit {hdf5.MAX_CONFIG_BYTES:,}); refused before reading")
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
    f = open_h5(p)
    cfg = None
    try:
        cfg = _json(attr(f, "model_config", str(p)), str(p))
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
        return json.loads(py_str(text) if isinstance(text, bytes) else str(text))
    except (ValueError, RecursionError) as exc:
        raise ValueError(f"{where}: model config is not valid JSON "
                         f"({type(exc).__name__}: {str(exc)[:80]})") from None


@damaged_file_is_value_error
def import_keras_h5(path: str | os.PathLike, m: int | None = None,
                    layer_norm_eps: float | None = None, lstm_activation: str | None = None,
                    dtype: Any = "float32") -> TPNet:
    """A :class:`TPNet` from a Keras checkpoint of the released architecture (docs/spec.md §2).

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
        layers, layout, ordered = _find_layers(f, layout, where)
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
    model.meta.update({"source": portable_path(where), "source_format": layout,
                       "import_report": report})
    return model


def _find_layers(f: Any, layout: str | None, where: str) -> tuple[list[_KLayer], str, bool]:
    """``(layers, layout, ordered)`` of an open Keras file: TF-Keras HDF5 (``layer_names``,
    creation-ordered) or Keras 3 (``layers/``, counters per model)."""
    root = f["model_weights"] if "model_weights" in f else f
    if "layer_names" in root.attrs:
        layers = _named_layout(root, where)
        ver = py_str(attr(f, "keras_version", where, attr(root, "keras_version", where, "?")))
        fw = "TF-Keras 2" if ver.startswith("2") else f"Keras {ver}"
        colon = any(py_str(n).endswith(":0")
                    for ln in _py_list(attr(root, "layer_names", where))
                    for n in _py_list(attr(safe_child(root, ln, where), "weight_names",
                                           where, [])))
        layout = layout or (f"{fw} HDF5 " + ("whole model (model_weights/)" if "model_weights"
                                              in f else "save_weights")
                            + f", names {'with' if colon else 'without'} ':0'")
        return layers, layout, True
    if "layers" in root:
        return _vars_layout(root, where), layout or "Keras 3 .weights.h5", False
    raise ValueError(f"{where}: unknown layout: neither a TF-Keras HDF5 weights file "
                     "(attribute layer_names) nor a Keras 3 weights file (group layers/); "
                     f"top-level keys {sorted(f.keys())[:8]}")


#: one point-wise or FC layer in forward order: (layer, (w, b)); see _PointLayers.rows
_Row = tuple[_KLayer, tuple[np.ndarray, np.ndarray], bool, bool]


def _keras_to_native(layers: list[_KLayer], ordered: bool, facts: dict[str, Any],
                     m: int | None, ln_eps: float | None, act: str | None, where: str,
                     dtype: Any) -> tuple[TPNet, str]:
    """The :class:`TPNet` of the layers found, and the import report: settings from the config
    facts or the keywords, then the per-frame layers (transform nets, MLPs, global FC) with any
    BatchNorm folded in, the BiLSTMs with their layer norms and the head, in the forward order
    of :func:`~tpnet_ref.config.param_shapes`."""
    if facts["unsupported"]:
        raise ValueError(f"{where}: the model config uses what TP-Net does not: "
                         f"{sorted(set(facts['unsupported']))}")
    by = _layers_by_kind(layers, ordered)
    notes: list[str] = []
    m, ln_eps, act, bn_eps = _settings(facts, m, ln_eps, act, where, notes)
    convs, bilstms, lns = by["conv2d"], by["bidirectional"], by["layer_normalization"]
    has_tnets = _has_transform_nets(convs, where)
    if not bilstms:
        raise ValueError(f"{where}: no Bidirectional LSTM layer found")
    if len(lns) != len(bilstms):
        raise ValueError(f"{where}: {len(bilstms)} Bidirectional layers but {len(lns)} "
                         "LayerNormalization layers; expected one after each")
    pts = _PointLayers(convs, by["dense"], where)
    pts.frame_network(has_tnets)
    if by["batch_normalization"]:
        pts.fold_batchnorms(by["batch_normalization"], bn_eps, notes)
    # tensors in forward order (the order of param_shapes), with what each one is
    tensors = [t for ly, (w, b), _, kept in pts.rows if kept
               for t in ((w, f"{ly.name}/kernel"), (b, f"{ly.name}/bias"))]
    seq, units = _sequence_tensors(bilstms, lns, pts.global_features, where)
    tensors += seq
    ly, (w, b) = pts.take_dense(2 * units[-1], "head FC")
    if w.shape[1] % pts.dim:
        raise ValueError(f"{where}: head {ly.name!r} has {w.shape[1]} outputs, not N*{pts.dim}")
    tensors += [(w, f"{ly.name}/kernel"), (b, f"{ly.name}/bias")]
    if pts.dense:
        raise ValueError(f"{where}: unexpected Dense layer(s) {[x.name for x in pts.dense]} "
                         f"with kernels {[x.shape('kernel') for x in pts.dense]}")
    cfg = TPNetConfig(
        m=int(m), n_out=w.shape[1] // pts.dim, global_features=pts.global_features,
        lstm_units=tuple(units), lstm_activation=act, layer_norm_eps=ln_eps, **pts.cfg_kw)
    shapes = param_shapes(cfg)
    if len(shapes) != len(tensors):   # cannot happen for a layout accepted above
        raise ValueError(f"{where}: found {len(tensors)} tensors, the network needs {len(shapes)}")
    params = {name: check_shape(arr, shape, f"{where}: {what}")
              for (name, shape), (arr, what) in zip(shapes.items(), tensors)}
    model = TPNet(cfg, params, dtype)
    model.meta["dropped_params"] = int(pts.dropped)
    return model, _report(model, has_tnets, pts.dropped, notes)


def _layers_by_kind(layers: list[_KLayer], ordered: bool) -> dict[str, list[_KLayer]]:
    """The layers of each kind in creation order (Keras 3 counts per model: the frame layers
    live in the model that holds the convs, which comes first)."""
    by = {k: [ln for ln in layers if ln.kind == k] for k in _KERAS_TYPES}
    if not ordered:
        conv_box = by["conv2d"][0].order[0] if by["conv2d"] else None
        for k in by:
            by[k].sort(key=lambda ln: (ln.order[0] != conv_box, ln.order))
    return by


def _settings(facts: dict[str, Any], m: int | None, ln_eps: float | None, act: str | None,
              where: str, notes: list[str]) -> tuple[int, float, str, float]:
    """``(m, layer_norm_eps, lstm_activation, batchnorm_eps)``: the keyword where given, else
    the model config's value, else the default (noted in ``notes``)."""
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
    return int(m), ln_eps, act, bn_eps


def _has_transform_nets(convs: list[_KLayer], where: str) -> bool:
    """Whether the file has transform nets, from the number of Conv2D point layers."""
    d = _DEPTHS
    n_tnet = len(d.input_tnet_mlp) + len(d.mlp1) + len(d.feature_tnet_mlp) + len(d.mlp2)
    n_plain = len(d.mlp1) + len(d.mlp2)
    if len(convs) not in (n_tnet, n_plain):
        raise ValueError(f"{where}: found {len(convs)} Conv2D layers {[c.name for c in convs]}; "
                         f"the released layout has {n_tnet} (with transform nets) or {n_plain}")
    return len(convs) == n_tnet


class _PointLayers:
    """The per-frame network read from the Conv2D and Dense layers in creation order.

    ``rows``: every point-wise / FC layer in forward order as ``(layer, (w, b), may carry
    BatchNorm, kept)``; the names come from ``param_shapes`` of the config read, never spelled
    here. ``cfg_kw``: the config fields found (``dim``, widths, transform-net flags);
    ``dropped``: parameters of untrained transform-net branches. ``dense`` holds the Dense
    layers not taken yet (the head's comes last)."""

    def __init__(self, convs: list[_KLayer], dense: list[_KLayer], where: str) -> None:
        self.where = where
        conv_w = [_dense_kernel(c, where) for c in convs]
        self.dim = conv_w[0][0].shape[0]
        self.convs = list(zip(convs, conv_w))
        self.dense = list(dense)
        self.rows: list[_Row] = []
        self.cfg_kw: dict[str, Any] = {"dim": self.dim}
        self.dropped = 0
        self.global_features = 0

    def take_convs(self, n: int, cin: int, what: str) -> list[tuple[_KLayer, tuple]]:
        """The next ``n`` point layers, each taking the previous one's width (``cin`` first)."""
        got = [self.convs.pop(0) for _ in range(n)]
        for layer, (w, _) in got:
            if w.shape[0] != cin:
                raise ValueError(f"{self.where}: {what}: {layer.name!r} takes {w.shape[0]} "
                                 f"inputs, expected {cin} (kernel {layer.shape('kernel')})")
            cin = w.shape[1]
        return got

    def take_dense(self, cin: int, what: str, cout: int | None = None) -> tuple[_KLayer, tuple]:
        """The next Dense layer, asserted to map ``cin`` to ``cout`` (any, if None) features."""
        if not self.dense:
            raise ValueError(f"{self.where}: missing Dense layer for {what}")
        layer = self.dense.pop(0)
        w, b = _dense_kernel(layer, self.where)
        if w.shape[0] != cin or (cout is not None and w.shape[1] != cout):
            raise ValueError(f"{self.where}: {what}: {layer.name!r} has kernel {w.shape}, "
                             f"expected ({cin}, {cout if cout is not None else 'any'})")
        return layer, (w, b)

    def frame_network(self, has_tnets: bool) -> None:
        """Input transform net, MLP1, feature transform net, MLP2, global FC (in that order)."""
        d = _DEPTHS
        if has_tnets:
            self.cfg_kw["input_transform_trained"] = self.tnet(
                "input_tnet", self.dim, len(d.input_tnet_mlp), len(d.input_tnet_fc))
        mlp1 = self.mlp("mlp1", len(d.mlp1), self.dim, "MLP1")
        if has_tnets:
            self.cfg_kw["feature_transform_trained"] = self.tnet(
                "feature_tnet", mlp1, len(d.feature_tnet_mlp), len(d.feature_tnet_fc))
        mlp2 = self.mlp("mlp2", len(d.mlp2), mlp1, "MLP2")
        ly, wb = self.take_dense(mlp2, "global feature FC")
        self.rows.append((ly, wb, True, True))
        self.global_features = wb[0].shape[1]

    def mlp(self, key: str, n: int, cin: int, what: str) -> int:
        """A shared MLP of ``n`` point layers; returns its output width."""
        layers = self.take_convs(n, cin, what)
        self.rows.extend((ly, wb, True, True) for ly, wb in layers)
        self.cfg_kw[key] = tuple(wb[0].shape[1] for _, wb in layers)
        return self.cfg_kw[key][-1]

    def tnet(self, prefix: str, k: int, nmlp: int, nfc: int) -> bool:
        """A transform net on ``k`` features: its MLP and FCs, and its output FC ``(fc, k*k)``
        if the file has one (trained); without it the branch is dead weight, dropped."""
        mlp = self.take_convs(nmlp, k, f"{prefix} MLP")
        c = mlp[-1][1][0].shape[1]
        fcs = []
        for i in range(nfc):
            fcs.append(self.take_dense(c, f"{prefix} FC {i}"))
            c = fcs[-1][1][0].shape[1]
        trained = bool(self.dense) and self.dense[0].shape("kernel") == (c, k * k)
        rows: list[_Row] = [(ly, wb, True, trained) for ly, wb in mlp + fcs]
        if trained:
            ly, wb = self.take_dense(c, f"{prefix} output", k * k)
            rows.append((ly, wb, False, True))
            self.cfg_kw[f"{prefix}_mlp"] = tuple(wb_[0].shape[1] for _, wb_ in mlp)
            self.cfg_kw[f"{prefix}_fc"] = tuple(wb_[0].shape[1] for _, wb_ in fcs)
        else:
            self.dropped += sum(w.size + b.size for _, (w, b), _, _ in rows)
        self.rows.extend(rows)
        return trained

    def fold_batchnorms(self, bns: list[_KLayer], eps: float, notes: list[str]) -> None:
        """Fold the BatchNorm layers, in order, into the layer whose width each has."""
        queue = list(bns)
        folded = []
        for i, (ly, (w, b), may_bn, kept) in enumerate(self.rows):
            if may_bn and queue and queue[0].shape("gamma") == (w.shape[1],):
                bn = queue.pop(0)
                self.rows[i] = (ly, _fold_bn(w, b, bn, eps, self.where), may_bn, kept)
                folded.append(bn.name)
        if queue:
            raise ValueError(f"{self.where}: BatchNormalization layer(s) "
                             f"{[x.name for x in queue]} do not follow any point-wise or FC "
                             "layer of matching width")
        notes.append(f"folded {len(folded)} BatchNorm layers (eps {eps})")


def _sequence_tensors(bilstms: list[_KLayer], lns: list[_KLayer], c: int,
                      where: str) -> tuple[list[tuple[np.ndarray, str]], list[int]]:
    """The BiLSTMs' tensors (kernel, recurrent kernel, bias per direction) each followed by its
    layer norm's gamma and beta, on ``c`` input features; and the units of each BiLSTM."""
    tensors: list[tuple[np.ndarray, str]] = []
    units = []
    for bl, ln in zip(bilstms, lns):
        u = None
        for dname in ("fwd", "bwd"):
            kern = bl.get(f"{dname}.kernel", where)
            rec = bl.get(f"{dname}.recurrent_kernel", where)
            u = rec.shape[0]
            what = f"{bl.name} ({dname})"
            check_shape(kern, (c, 4 * u), f"{where}: {what} kernel")
            tensors += [(kern, f"{what} kernel"), (rec, f"{what} recurrent_kernel"),
                        (bl.get(f"{dname}.bias", where), f"{what} bias")]
        units.append(u)
        c = 2 * u
        tensors += [(ln.get("gamma", where), f"{ln.name}/gamma"),
                    (ln.get("beta", where), f"{ln.name}/beta")]
    return tensors, units


def _report(model: TPNet, has_tnets: bool, dropped: int, notes: list[str]) -> str:
    cfg = model.config
    tr = {False: "identity (output FC not saved)", True: "trained"}
    return (f"m={cfg.m}, N={cfg.n_out}, params={model.num_params:,}; "
            + (f"input transform {tr[cfg.input_transform_trained]}, feature transform "
               f"{tr[cfg.feature_transform_trained]}" if has_tnets else "no transform nets")
            + (f"; dropped {dropped:,} dead transform-net parameters" if dropped else "")
            + (f"; {'; '.join(notes)}" if notes else ""))


__all__ = ["import_keras_h5"]
