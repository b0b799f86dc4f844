"""The layer-by-layer trace of every implementation the project runs, named as the reference's
(:func:`tpnet_ref.engines.reference.forward` with ``trace=``; docs/crosscheck.md lists the names):

- :func:`torch_trace` -- a :class:`~tpnet_ref.training.torch_model.TorchTPNet` (or a port built on it)
  observed through forward hooks and pre-hooks on its modules, so what is recorded is what the
  module computed, bugs included;
- :func:`onnx_trace` -- a graph written by :mod:`tpnet_ref.conformance.onnx_peer` run by onnxruntime with
  every traced intermediate marked as a graph output (as Polygraphy's ``--onnx-outputs mark
  all`` does), found by the initializers its layers read;
- :func:`keras_trace` -- a Keras 3 model built from the parameters (the ``keras`` extra; the
  torch backend unless ``KERAS_BACKEND`` says otherwise), every layer an output;
- :func:`engine_trace` -- the NumPy or Numba engine of a :class:`~tpnet_ref.model.TPNet`:
  what they expose cheaply (each frame's global feature, the head's output, the prediction).

Each takes one window (``m`` frames ``(N_t, dim)``, world units) and returns ``{layer: array}``
in the shapes of :func:`tpnet_ref.conformance.layer_names.layer_shapes`. A framework that takes frames of
one size gets a ragged window padded by repeating each short frame's first point: max-pooling
is unchanged, and the padded rows are dropped from the per-point layers.
"""
from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..config import TPNetConfig
from .vectors import Vectors, check_same_network
from .layer_names import layer_names, layer_shapes
from ..extras import require


def _padded(frames: list[np.ndarray]) -> tuple[np.ndarray, list[int]]:
    """``(m, N_max, dim)`` with each short frame padded by its first point, and the counts."""
    counts = [len(f) for f in frames]
    n = max(counts)
    return np.stack([np.concatenate([f, np.repeat(f[:1], n - len(f), axis=0)])
                     for f in frames]), counts


def _unpad(a: np.ndarray, counts: list[int]) -> np.ndarray:
    """``(m, N_max, C)`` -> ``(P, C)``: each frame's own points, frame after frame."""
    return np.concatenate([a[t, :n] for t, n in enumerate(counts)])


# --------------------------------------------------------------------------- PyTorch
def torch_trace(net: Any, window: Any) -> dict[str, np.ndarray]:
    """The trace of a :class:`~tpnet_ref.training.torch_model.TorchTPNet` (any subclass, any dtype).

    Observed with hooks: a per-point layer's output after its activation is the input of the
    module that reads it next (a forward pre-hook); ``pooled`` the input of the global FC;
    ``global`` the input of BiLSTM 1; each BiLSTM direction the return value of its
    ``_direction``; ``lstmI.concat`` / ``lnI`` / ``head.logits`` the modules' outputs;
    ``head.sigmoid`` the module's result and ``output`` it in world units. Only the last MLP
    layer's ReLU is applied here (no module reads its output before the max)."""
    torch = require("torch", "crosscheck")
    cfg: TPNetConfig = net.config
    frames = [np.asarray(f, np.float64) for f in window]
    x, counts = _padded(frames)
    m, n = x.shape[:2]
    dt = next(net.parameters()).dtype
    rec: dict[str, Any] = {}
    handles = []

    def pre(mod: Any, name: str) -> None:
        handles.append(mod.register_forward_pre_hook(
            lambda _m, args: rec.__setitem__(name, args[0].detach())))

    def post(mod: Any, name: str, fn: Any = None) -> None:
        handles.append(mod.register_forward_hook(
            lambda _m, _a, out: rec.__setitem__(name, (fn(out) if fn else out).detach())))

    # the module that reads each per-point layer, in forward order
    chain: list[tuple[str, Any]] = [("input.normalized", net.input_tnet or net.mlp1[0])]
    if net.input_tnet is not None:
        post(net.input_tnet, "input_tnet.transform")
        chain.append(("input.transformed", net.mlp1[0]))
    chain += [(f"mlp1.{i}", mod) for i, mod in enumerate(list(net.mlp1)[1:])]
    chain.append((f"mlp1.{len(net.mlp1) - 1}", net.feature_tnet or net.mlp2[0]))
    if net.feature_tnet is not None:
        post(net.feature_tnet, "feature_tnet.transform")
        chain.append(("mlp1.transformed", net.mlp2[0]))
    chain += [(f"mlp2.{i}", mod) for i, mod in enumerate(list(net.mlp2)[1:])]
    for name, mod in chain:
        pre(mod, name)
    post(net.mlp2[-1], f"mlp2.{len(net.mlp2) - 1}", torch.relu)
    pre(net.global_fc, "pooled")
    pre(net.lstm1, "global")
    n_lstm = len(cfg.lstm_units)
    originals = []
    for i in range(1, n_lstm + 1):
        lstm = getattr(net, f"lstm{i}")
        post(lstm, f"lstm{i}.concat")
        post(getattr(net, f"ln{i}"), f"ln{i}")

        def spy(x_: Any, sfx: str, reverse: bool, _i: int = i, _orig: Any = lstm._direction) -> Any:
            h = _orig(x_, sfx, reverse)
            rec[f"lstm{_i}.{'bwd' if reverse else 'fwd'}"] = h.detach()
            return h
        originals.append(lstm)
        lstm._direction = spy                          # this instance only, removed below
    post(net.head, "head.logits")
    lo, scale = cfg.norm_lo, cfg.norm_hi - cfg.norm_lo
    try:
        with torch.no_grad():
            xt = torch.from_numpy(x[None]).to(dt)
            y = net((xt - lo) / scale)
            out = y * scale + lo
    finally:
        for h in handles:
            h.remove()
        for lstm in originals:
            del lstm._direction
    t: dict[str, np.ndarray] = {"input": _unpad(x, counts)}
    shapes = layer_shapes(cfg)
    for name in layer_names(cfg):
        if name not in rec:
            continue
        a = rec[name].double().cpu().numpy()
        if name.endswith(".transform"):
            a = a.reshape(m, *a.shape[-2:])
        elif name.startswith(("input.", "mlp")):
            a = _unpad(a.reshape(m, n, -1), counts)
        else:
            a = a.reshape([m if d == "m" else d for d in shapes[name]])
        t[name] = a
    t["head.sigmoid"] = y[0].double().numpy()
    t["output"] = out[0].double().numpy()
    return {k: t[k] for k in layer_names(cfg) if k in t}


def torch_model(path: str | os.PathLike) -> Any:
    """A float32 :class:`~tpnet_ref.training.torch_model.TorchTPNet` from a state dict file (read with
    ``torch.load(weights_only=True)`` only)."""
    from ..training.torch_model import TorchTPNet
    from ..weights.torch import import_torch
    return TorchTPNet.from_numpy(import_torch(path, dtype="float32")).eval()


# --------------------------------------------------------------------------- ONNX
def onnx_outputs(proto: Any, config: TPNetConfig) -> tuple[dict[str, str], bool]:
    """The graph's tensor for each traced layer (``{layer: tensor name}``) and whether it takes
    world units. Layers are found by the initializers they read (``mlp1.0_w_*`` ...): the
    graphs :func:`tpnet_ref.conformance.onnx_peer.build_onnx` writes."""
    g = proto.graph
    inits = {i.name for i in g.initializer}
    consumers: dict[str, list[Any]] = {}
    for node in g.node:
        for i in node.input:
            consumers.setdefault(i, []).append(node)

    def after(tensor: str, kinds: tuple[str, ...]) -> Any:
        for node in consumers.get(tensor, []):
            if node.op_type in kinds:
                return node
        return None

    def dense(prefix: str) -> tuple[str, str, Any] | None:
        pat = re.compile(re.escape(prefix) + r"_w_\d+$")
        for node in g.node:
            if node.op_type == "MatMul" and len(node.input) == 2 and node.input[1] in inits \
                    and pat.match(node.input[1]):
                add = after(node.output[0], ("Add",))
                if add is None:
                    return None
                act = after(add.output[0], ("Relu", "Sigmoid"))
                return node.input[0], add.output[0], act
        return None

    names: dict[str, str] = {}
    world = False
    sub = after(g.input[0].name, ("Sub",))
    div = after(sub.output[0], ("Div",)) if sub is not None else None
    if div is not None:
        world = True
        names["input.normalized"] = div.output[0]
    for stack in ("mlp1", "mlp2"):
        for i in range(len(getattr(config, stack))):
            d = dense(f"{stack}.{i}")
            if d and d[2] is not None:
                names[f"{stack}.{i}"] = d[2].output[0]
    d = dense("global")
    if d and d[2] is not None:
        names["pooled"], names["global"] = d[0], d[2].output[0]
    lstms = [nd for nd in g.node if nd.op_type == "LSTM"]
    lns = [nd for nd in g.node if nd.op_type == "LayerNormalization"]
    for i, (ls, ln) in enumerate(zip(lstms, lns), start=1):
        names[f"lstm{i}.Y"] = ls.output[0]
        names[f"lstm{i}.concat"] = ln.input[0]
        names[f"ln{i}"] = ln.output[0]
    d = dense("head")
    if d:
        names["head.logits"] = d[1]
        if d[2] is not None:
            names["head.sigmoid"] = d[2].output[0]
    names["output"] = g.output[0].name
    return names, world


def onnx_trace(model: Any, window: Any, config: TPNetConfig,
               session: Any = None) -> dict[str, np.ndarray]:
    """The trace of an ONNX graph (a ``ModelProto`` or a path) run by onnxruntime (CPU, full
    graph optimisation) with every traced intermediate marked as an output. ``config``: the
    network's (the graph does not carry its widths). ``session``: reuse one from
    :func:`onnx_trace_session`."""
    if session is None:
        session = onnx_trace_session(model, config)
    sess, names, world = session
    frames = [np.asarray(f, np.float64) for f in window]
    x, counts = _padded(frames)
    m, n = x.shape[:2]
    lo, scale = config.norm_lo, config.norm_hi - config.norm_lo
    feed = x if world else (x - lo) / scale
    order = list(names)
    outs = dict(zip(order, sess.run([names[k] for k in order],
                                    {sess.get_inputs()[0].name: feed[None].astype(np.float32)})))
    t: dict[str, np.ndarray] = {"input": _unpad(x, counts)}
    if not world:
        t["input.normalized"] = _unpad((x - lo) / scale, counts)
    for name, a in outs.items():
        a = np.asarray(a, np.float64)
        if name.startswith(("input.", "mlp")):
            t[name] = _unpad(a.reshape(m, n, -1), counts)
        elif name in ("pooled", "global"):
            t[name] = a.reshape(m, -1)
        elif name.endswith(".Y"):                   # (T, 2, B, u)
            t[name[:-2] + ".fwd"] = a[:, 0, 0]
            t[name[:-2] + ".bwd"] = a[:, 1, 0]
        elif name.endswith(".concat") or name.startswith("ln"):
            t[name] = a[:, 0] if a.ndim == 3 else a[0]   # (m, B, 2u) or (B, 2u)
        elif name == "head.logits":
            t[name] = a.reshape(-1)
        elif name == "head.sigmoid":
            t[name] = a.reshape(config.n_out, config.dim)
    out = np.asarray(outs["output"], np.float64)[0]
    if world:
        t["output"] = out
        t.setdefault("head.sigmoid", (out - lo) / scale)
    else:
        t["head.sigmoid"] = out
        t["output"] = out * scale + lo
    return {k: t[k] for k in layer_names(config) if k in t}


def onnx_trace_session(model: Any, config: TPNetConfig) -> tuple[Any, dict[str, str], bool]:
    """``(session, {layer: tensor}, world_units)`` for :func:`onnx_trace`."""
    onnx = require("onnx", "crosscheck")
    ort = require("onnxruntime", "crosscheck")
    from onnx import TensorProto, helper

    if isinstance(model, (str, os.PathLike)):
        p = Path(model)
        if not p.is_file():
            raise FileNotFoundError(f"ONNX file not found: {p}")
        try:
            proto = onnx.load(str(p))
        except Exception as exc:      # DecodeError and kin: not a protobuf
            raise ValueError(f"{p}: not an ONNX model ({type(exc).__name__})") from None
    else:
        proto = model
    proto_copy = type(proto)()
    proto_copy.CopyFrom(proto)
    names, world = onnx_outputs(proto_copy, config)
    if "output" not in names or not proto_copy.graph.input:
        raise ValueError("ONNX model: no input or output to trace")
    have = {o.name for o in proto_copy.graph.output}
    for tensor in names.values():
        if tensor not in have:
            proto_copy.graph.output.append(helper.make_tensor_value_info(tensor,
                                                                         TensorProto.FLOAT, None))
            have.add(tensor)
    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    try:
        sess = ort.InferenceSession(proto_copy.SerializeToString(), opts,
                                    providers=["CPUExecutionProvider"])
    except Exception as exc:
        raise ValueError(f"ONNX model: onnxruntime refused it ({str(exc).splitlines()[0]})"
                         ) from None
    return sess, names, world


# --------------------------------------------------------------------------- Keras
def keras_model(config: TPNetConfig, params: dict[str, np.ndarray], n_points: int) -> Any:
    """A Keras 3 functional model of TP-Net (identity transform nets), its weights set from
    ``params``, input ``(1, m, n_points, dim)`` in world units, one output per traced layer
    (``{layer: tensor}``): Dense layers per point, ``ops.max`` over the points, Keras
    ``Bidirectional(LSTM(activation=...))`` with its ``forward_layer`` / ``backward_layer``
    also called alone for the per-direction outputs, ``LayerNormalization(epsilon=...)``."""
    os.environ.setdefault("KERAS_BACKEND", "torch")
    keras = require("keras", "keras")
    if config.input_transform_trained or config.feature_transform_trained:
        raise ValueError("the Keras trace builds identity transform nets only")
    L, ops = keras.layers, keras.ops
    c, p = config, {k: np.asarray(v, np.float32) for k, v in params.items()}
    lo, scale = c.norm_lo, c.norm_hi - c.norm_lo
    win = keras.Input((c.m, n_points, c.dim), batch_size=1, name="window")
    outs: dict[str, Any] = {}
    x = L.Lambda(lambda w: (w - lo) / scale, name="normalize")(win)
    outs["input.normalized"] = x
    setters = []
    for stack in ("mlp1", "mlp2"):
        for i in range(len(getattr(c, stack))):
            lay = L.Dense(p[f"{stack}.{i}.w"].shape[1], activation="relu",
                          name=f"{stack}_{i}")
            x = lay(x)
            outs[f"{stack}.{i}"] = x
            setters.append((lay, [p[f"{stack}.{i}.w"], p[f"{stack}.{i}.b"]]))
    g = L.Lambda(lambda h: ops.max(h, axis=2), name="max_over_points")(x)
    outs["pooled"] = g
    lay = L.Dense(c.global_features, activation="relu", name="global")
    seq = lay(g)
    outs["global"] = seq
    setters.append((lay, [p["global.w"], p["global.b"]]))
    n = len(c.lstm_units)
    for i, u in enumerate(c.lstm_units, start=1):
        bi = L.Bidirectional(L.LSTM(u, activation=c.lstm_activation,
                                    return_sequences=i < n), name=f"bidirectional_{i}")
        y = bi(seq)
        outs[f"lstm{i}.concat"] = y
        fl = bi.forward_layer
        bl = bi.backward_layer
        # the directions alone, with full sequences (the same weights, shared)
        fs = L.LSTM(u, activation=c.lstm_activation, return_sequences=True, name=f"fwd_{i}")
        bs = L.LSTM(u, activation=c.lstm_activation, return_sequences=True,
                    go_backwards=True, name=f"bwd_{i}")
        outs[f"lstm{i}.fwd"] = fs(seq)
        outs[f"lstm{i}.bwd"] = L.Lambda(lambda h: ops.flip(h, axis=1),
                                        name=f"bwd_{i}_in_time")(bs(seq))
        for d, layers in (("fwd", (fl, fs)), ("bwd", (bl, bs))):
            w = [p[f"lstm{i}.{d}.kernel"], p[f"lstm{i}.{d}.recurrent"], p[f"lstm{i}.{d}.bias"]]
            for lay in layers:
                setters.append((lay, w))
        ln = L.LayerNormalization(epsilon=c.layer_norm_eps, name=f"layer_normalization_{i}")
        seq = ln(y)
        outs[f"ln{i}"] = seq
        setters.append((ln, [p[f"ln{i}.gamma"], p[f"ln{i}.beta"]]))
    lay = L.Dense(c.n_out * c.dim, name="head")
    z = lay(seq)
    setters.append((lay, [p["head.w"], p["head.b"]]))
    outs["head.logits"] = z
    y = L.Reshape((c.n_out, c.dim))(L.Activation("sigmoid")(z))
    outs["head.sigmoid"] = y
    outs["output"] = L.Lambda(lambda v: v * scale + lo, name="denormalize")(y)
    model = keras.Model(win, outs)
    for lay, w in setters:
        lay.set_weights(w)
    return model


def keras_trace(config: TPNetConfig, params: dict[str, np.ndarray],
                window: Any) -> dict[str, np.ndarray]:
    """The trace of :func:`keras_model` on one window (float32, the ``keras`` extra)."""
    frames = [np.asarray(f, np.float64) for f in window]
    x, counts = _padded(frames)
    m, n = x.shape[:2]
    model = keras_model(config, params, n)
    outs = model(x[None].astype(np.float32))
    t: dict[str, np.ndarray] = {"input": _unpad(x, counts)}
    for name, v in outs.items():
        a = np.asarray(_to_numpy(v), np.float64)[0]
        if name.startswith(("input.", "mlp")):
            a = _unpad(a, counts)
        t[name] = a
    return {k: t[k] for k in layer_names(config) if k in t}


def _to_numpy(v: Any) -> np.ndarray:
    if hasattr(v, "detach"):
        return v.detach().cpu().numpy()
    return np.asarray(v)


# --------------------------------------------------------------------------- the engines
def engine_trace(model: Any, window: Any) -> dict[str, np.ndarray]:
    """What the NumPy or Numba engine of a :class:`~tpnet_ref.model.TPNet` exposes cheaply:
    ``input``, ``global`` (each frame's feature, the engine's extractor), ``head.sigmoid``
    (its head) and ``output`` (``predict``)."""
    frames = [np.asarray(f, model.dtype) for f in window]
    pts, counts = model.canonical_points(frames, False)
    feats = model.frame_features(pts, counts, 1)
    y = model.sequence_head(feats.reshape(1, model.config.m, -1))[0]
    return {"input": np.concatenate(frames).astype(np.float64),
            "global": feats.astype(np.float64),
            "head.sigmoid": y.astype(np.float64),
            "output": _quiet(model.predict, frames).astype(np.float64)}


def _quiet(fn: Any, *args: Any) -> Any:
    """``fn(*args)`` without the input warnings (a conformance case may be unusual on purpose)."""
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fn(*args)


# --------------------------------------------------------------------------- a model file
def model_tracer(path: str | os.PathLike, vectors: Vectors, engine: str = "numpy") -> Any:
    """``(what, fn)``: a description of the file and ``fn(window) -> trace`` for a model file
    told apart by content: an ONNX graph, a PyTorch state dict, a Keras ``.h5`` / ``.keras``
    file (the ``keras`` extra) or a native weights file (the ``engine``'s trace)."""
    import zipfile

    from ..weights import hdf5
    from ..model import load
    from ..weights.native import is_native

    config = vectors.config
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"model file not found: {p}")
    with open(p, "rb") as fh:
        head = fh.read(8)
    if head == hdf5.HDF5_MAGIC and is_native(p):
        model = load(p, engine=engine)
        check_same_network(vectors, model.config, f"model {p}")
        return f"native weights file, {engine} engine", lambda w: engine_trace(model, w)
    if head == hdf5.HDF5_MAGIC or (zipfile.is_zipfile(p) and _is_keras_zip(p)):
        from ..weights.keras import import_keras_h5
        tp = import_keras_h5(p, dtype="float32")
        check_same_network(vectors, tp.config, f"model {p}")
        os.environ.setdefault("KERAS_BACKEND", "torch")     # the keras extra's backend
        require("keras", "keras", "tracing a Keras checkpoint")
        return ("Keras checkpoint, traced by a Keras model built from it",
                lambda w: keras_trace(tp.config, tp.params, w))
    if zipfile.is_zipfile(p):
        net = torch_model(p)
        check_same_network(vectors, net.config, f"model {p}")
        return "PyTorch state dict, traced with hooks (float32)", lambda w: torch_trace(net, w)
    sess = onnx_trace_session(p, config)
    return ("ONNX graph, every layer marked as an output, onnxruntime (float32)",
            lambda w: onnx_trace(None, w, config, sess))


def _is_keras_zip(p: Path) -> bool:
    import zipfile
    try:
        with zipfile.ZipFile(p) as z:
            return "model.weights.h5" in z.namelist()
    except (zipfile.BadZipFile, OSError):
        return False


__all__ = ["torch_trace", "torch_model", "onnx_trace", "onnx_trace_session", "onnx_outputs",
           "keras_model", "keras_trace", "engine_trace", "model_tracer"]
