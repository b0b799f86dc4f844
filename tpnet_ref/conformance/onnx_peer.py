"""The same TP-Net as an ONNX graph: ``tpnet export onnx`` (for runtimes this package does not
replace: a GPU, a phone, a C++ service) and onnxruntime as a peer in benchmarks and cross-checks.

Built directly from a :class:`tpnet_ref.model.TPNet` (float32) with ``onnx.helper``: point-wise
layers are MatMul/Add/Relu on ``(B*m*N, C)``, max-pooling is ReduceMax over the points, the
LSTMs are ONNX's fused ``LSTM`` op (bidirectional, activations Sigmoid/Relu/Relu as Keras'
``activation='relu'``, gate order converted from Keras i,f,c,o to ONNX i,o,f,c),
LayerNormalization (opset 17). Input ``window`` ``(B, m, N, dim)``, output ``prediction``
``(B, n_out, dim)`` (``dim`` the model's: 2, or 3 for a 3-D model), both normalised or, with
``world_units``, both in world units (the normalisation and its inverse are in the graph). The
batch is dynamic, and N too unless fixed.

The graph computes what :meth:`TPNet.predict_batch` computes, without its input checks and
without the canonical point order (max-pooling is invariant: the results differ by rounding
only, ``tests/test_conformance_onnx_peer.py``).
"""
from __future__ import annotations

import os

import numpy as np

from ..extras import require


def _ifco_to_iofc(a: np.ndarray) -> np.ndarray:
    """Reorder the gate blocks on axis 0 from Keras (i, f, c, o) to ONNX (i, o, f, c)."""
    i, f, c, o = np.split(a, 4, axis=0)
    return np.concatenate([i, o, f, c], axis=0)


class _Graph:
    """An ONNX graph being built from a model's float32 parameters: its nodes and initialisers,
    named in the order they are made."""

    def __init__(self, params: dict, helper, numpy_helper, n_points: int | None) -> None:
        self.f32 = {k: np.asarray(v, dtype=np.float32) for k, v in params.items()}
        self.helper, self.numpy_helper = helper, numpy_helper
        self.nodes: list = []
        self.inits: list = []
        self.count = 0
        self.n_points = n_points
        self.n_dyn = None
        if n_points is None:     # N from the input's shape: (F, N, C) reshapes take it at run time
            self.n_dyn = self.op("Slice", [self.op("Shape", ["window"]),
                                           self.const(np.array([2], np.int64), "start"),
                                           self.const(np.array([3], np.int64), "end")])

    def name(self, base: str) -> str:
        self.count += 1
        return f"{base}_{self.count}"

    def const(self, arr: np.ndarray, base: str) -> str:
        n = self.name(base)
        self.inits.append(self.numpy_helper.from_array(np.asarray(arr), n))
        return n

    def op(self, kind: str, inputs: list[str], **attrs) -> str:
        out = self.name(kind.lower())
        self.nodes.append(self.helper.make_node(kind, inputs, [out], **attrs))
        return out

    def dense(self, x: str, prefix: str, act: str | None = "Relu") -> str:
        y = self.op("Add", [self.op("MatMul", [x, self.const(self.f32[f"{prefix}.w"],
                                                               prefix + "_w")]),
                            self.const(self.f32[f"{prefix}.b"], prefix + "_b")])
        return self.op(act, [y]) if act else y

    def reshape(self, x: str, shape: list[int] | str) -> str:   # a list, or a shape tensor's name
        return self.op("Reshape", [x, shape if isinstance(shape, str) else
                                   self.const(np.array(shape, dtype=np.int64), "shape")])

    def frames(self, channels: int) -> list[int] | str:   # the shape (F, N, channels)
        if self.n_dyn is None:
            return [-1, int(self.n_points), channels]
        return self.op("Concat", [self.const(np.array([-1], np.int64), "minus_one"), self.n_dyn,
                                  self.const(np.array([channels], np.int64), "channels")], axis=0)

    def maxpool(self, x: str, channels: int) -> str:  # (F*N, C) -> (F, C)
        return self.op("ReduceMax", [self.reshape(x, self.frames(channels))], axes=[1],
                       keepdims=0)

    def tnet(self, x: str, prefix: str, k: int, mlp, fc) -> str:  # (F*N, k) -> (F*N, k)
        h = x
        for i in range(len(mlp)):
            h = self.dense(h, f"{prefix}.mlp.{i}")
        g = self.maxpool(h, mlp[-1])
        for i in range(len(fc)):
            g = self.dense(g, f"{prefix}.fc.{i}")
        t = self.reshape(self.dense(g, f"{prefix}.out", act=None), [-1, k, k])
        return self.reshape(self.op("MatMul", [self.reshape(x, self.frames(k)), t]), [-1, k])

    def bilstm(self, seq: str, li: int, u: int, act: str, last: bool, cfg) -> str:
        """BiLSTM ``li`` (``u`` units per direction) and its LayerNorm on ``seq``; the sequence
        ``(m, B, 2u)``, or after the ``last`` layer ``(B, 2u)``."""
        f32 = self.f32
        w = np.stack([_ifco_to_iofc(f32[f"lstm{li}.{d}.kernel"].T) for d in ("fwd", "bwd")])
        r = np.stack([_ifco_to_iofc(f32[f"lstm{li}.{d}.recurrent"].T) for d in ("fwd", "bwd")])
        b = np.stack([np.concatenate([_ifco_to_iofc(f32[f"lstm{li}.{d}.bias"]),
                                      np.zeros(4 * u, np.float32)]) for d in ("fwd", "bwd")])
        y, y_h = self.name("lstm_y"), self.name("lstm_yh")
        self.nodes.append(self.helper.make_node(
            "LSTM", [seq, self.const(w, "W"), self.const(r, "R"), self.const(b, "B")], [y, y_h],
            hidden_size=u, direction="bidirectional",
            activations=["Sigmoid", act, act, "Sigmoid", act, act]))
        if not last:  # (m, 2, B, u) -> (m, B, 2u)
            h = self.reshape(self.op("Transpose", [y], perm=[0, 2, 1, 3]), [cfg.m, -1, 2 * u])
        else:  # Y_h (2, B, u): forward after the last step, backward after the whole sequence
            h = self.reshape(self.op("Transpose", [y_h], perm=[1, 0, 2]), [-1, 2 * u])
        return self.op("LayerNormalization", [h, self.const(f32[f"ln{li}.gamma"], "gamma"),
                                              self.const(f32[f"ln{li}.beta"], "beta")],
                       axis=-1, epsilon=float(cfg.layer_norm_eps))


def build_onnx(model, n_points: int | None = 30, opset: int = 17, world_units: bool = False):
    """ONNX ``ModelProto`` computing ``model``'s forward pass in float32. The batch is dynamic;
    ``n_points`` fixes N in the declared input shape (None: dynamic, named "N");
    ``world_units``: input and output in world units (else model coordinates)."""
    onnx = require("onnx", "onnx")
    from onnx import TensorProto, helper, numpy_helper

    cfg = model.config
    g = _Graph(model.params, helper, numpy_helper, n_points)
    x = "window"
    lo, scale = np.float32(cfg.norm_lo), np.float32(cfg.norm_hi - cfg.norm_lo)
    if world_units:      # (x - lo) / scale, as TPNet.normalize computes it
        x = g.op("Div", [g.op("Sub", [x, g.const(lo, "norm_lo")]), g.const(scale, "norm_scale")])
    x = g.reshape(x, [-1, cfg.dim])
    if cfg.input_transform_trained:
        x = g.tnet(x, "input_tnet", cfg.dim, cfg.input_tnet_mlp, cfg.input_tnet_fc)
    for i in range(len(cfg.mlp1)):
        x = g.dense(x, f"mlp1.{i}")
    if cfg.feature_transform_trained:
        x = g.tnet(x, "feature_tnet", cfg.mlp1[-1], cfg.feature_tnet_mlp, cfg.feature_tnet_fc)
    for i in range(len(cfg.mlp2)):
        x = g.dense(x, f"mlp2.{i}")
    glob = g.dense(g.maxpool(x, cfg.mlp2[-1]), "global")
    seq = g.op("Transpose", [g.reshape(glob, [-1, cfg.m, cfg.global_features])], perm=[1, 0, 2])
    act = "Relu" if cfg.lstm_activation == "relu" else "Tanh"
    n_layers = len(cfg.lstm_units)
    for li, u in enumerate(cfg.lstm_units, start=1):
        seq = g.bilstm(seq, li, u, act, li == n_layers, cfg)
    out = g.reshape(g.dense(seq, "head", act="Sigmoid"), [-1, cfg.n_out, cfg.dim])
    if world_units:      # y * scale + lo, as TPNet.denormalize
        out = g.op("Add", [g.op("Mul", [out, g.const(scale, "norm_scale")]),
                           g.const(lo, "norm_lo")])
    g.nodes.append(helper.make_node("Identity", [out], ["prediction"]))
    n_in = "N" if n_points is None else int(n_points)
    graph = helper.make_graph(
        g.nodes, "tpnet",
        [helper.make_tensor_value_info("window", TensorProto.FLOAT, ["batch", cfg.m, n_in, cfg.dim])],
        [helper.make_tensor_value_info("prediction", TensorProto.FLOAT,
                                       ["batch", cfg.n_out, cfg.dim])],
        g.inits)
    proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)])
    proto.ir_version = min(proto.ir_version, 9)
    onnx.checker.check_model(proto)
    return proto


def export_onnx(model, path: str | os.PathLike, opset: int = 17) -> dict[str, str]:
    """Write ``model`` as an ONNX file for other runtimes (``tpnet export onnx``): input
    ``window`` float32 ``(batch, m, N, dim)`` in world units, output ``prediction``
    ``(batch, n_out, dim)`` in world units (``dim`` the model's, 2 or 3), batch and N dynamic,
    LSTMs as ONNX ``LSTM`` ops.
    Returns the metadata written with it (also readable as the file's ``metadata_props``)."""
    from onnx import helper

    proto = build_onnx(model, n_points=None, opset=opset, world_units=True)
    c = model.config
    meta = {"producer": "tpnet_ref.onnx_peer.export_onnx", "m": str(c.m), "n_out": str(c.n_out),
            "dim": str(c.dim), "units": "world", "norm_lo": repr(c.norm_lo), "norm_hi": repr(c.norm_hi),
            **{f"weights_{k}": str(model.meta[k]) for k in ("source", "created")
               if k in model.meta}}
    helper.set_model_props(proto, meta)
    proto.doc_string = (f"TP-Net (m={c.m}, lstm={c.lstm_units}): window (batch, {c.m}, N, "
                        f"{c.dim}) -> prediction (batch, {c.n_out}, {c.dim}), world units")
    with open(path, "wb") as f:
        f.write(proto.SerializeToString())
    return meta


def onnx_session(model, n_points: int | None = 30, threads: int | None = None,
                 world_units: bool = False):
    """An onnxruntime ``InferenceSession`` (CPU) for ``model``; ``run(window)`` -> prediction."""
    ort = require("onnxruntime", "crosscheck")
    opts = ort.SessionOptions()
    if threads:
        opts.intra_op_num_threads = threads
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    sess = ort.InferenceSession(
        build_onnx(model, n_points, world_units=world_units).SerializeToString(), opts,
        providers=["CPUExecutionProvider"])
    return sess


__all__ = ["build_onnx", "export_onnx", "onnx_session"]
