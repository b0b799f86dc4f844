"""The Numba engine (``load()``'s default where numba is installed): TP-Net's prediction
network (BiLSTMs, LayerNorms, head) as one compiled function, :class:`NumbaHead`, for every
batch, and its feature extractor as another, :class:`NumbaFeatures`, for every batch too.
``TPNet(..., engine="numba")`` or
``model.with_engine("numba")``; needs numba (the ``metrics`` extra). The NumPy path
(:func:`tpnet_ref.engines.layers.bilstm_steps`, :func:`tpnet_ref.engines.layers.project_layer_norm`,
:class:`tpnet_ref.engines.numpy_engine.NumpyFeatures`, specified by :mod:`tpnet_ref.engines.reference`) is the
reference; ``tests/test_engines_numba.py`` checks they agree.

What it does that NumPy cannot:

- one call per prediction instead of ~100 NumPy calls (plus one for BiLSTM 1's input
  projection, which a rollout computes once per frame): the gates, cell and output of each unit
  are computed right after their pre-activations, LayerNorm and head included;
- every product reads only the weight rows that a non-zero input multiplies, each one, not all
  rows up to the last used one (a ReLU network's activations are mostly zeros): BiLSTM 1's
  input projection (the global features, ~80 % zeros on the scene), every recurrent product
  (the state ``h``), and BiLSTM 2's and 3's input projections, whose input is a LayerNorm output
  (no zeros): LayerNorm is affine per row, so with ``r = 1 / sqrt(var + eps)`` and the row mean
  ``mu``, ``LN(h) @ K = r * ((h * gamma) @ K) - r * mu * (gamma @ K) + beta @ K``, and
  ``h * gamma`` has ``h``'s zeros (``gamma @ K`` and ``beta @ K + bias`` computed at load in
  float64). With tanh (no zeros) LayerNorm is applied first, then the plain product;
- the products stream whole weight rows: a kernel written in LLVM IR (:func:`tpnet_ref.engines.numba_products._row_kernel`)
  reads :data:`CHAIN` of the needed rows side by side, each sequentially (what the hardware
  prefetcher streams best: a window's products mostly read weights from memory), and adds
  them into up to :data:`GROUP_ROWS` accumulator rows (a window's m steps share their
  non-zero inputs, so at B = 1 each needed weight row is read once per layer and direction);
- the feature extractor's per-point layers and its global layer run in tiles of points whose
  sums stay in registers over the whole chain (:func:`tpnet_ref.engines.numba_tiles.tiled_product`:
  each weight vector and input read once per tile, not once per chain of rows; 1.5-2.5x on the
  extractor), the same chain of multiply-adds, so the same bits; the tiles' shape follows the
  CPU's vector registers (:data:`tpnet_ref.engines.numba_codegen.TILE_PLAN`: AVX-512's 32 or
  AVX2's 16), the sums the same;
- the weights are laid out at load, each matrix row-major with its gate columns padded to
  whole 64-byte vectors, in the model's unit order when given one (:mod:`tpnet_ref.engines.unit_order`:
  the rows a window needs lie closer together; a few percent here, as the rows are streamed
  one by one anyway);
- the gates are vectorised (a branch-free ``exp``, :func:`tpnet_ref.engines.numba_lstm._exp_neg`, within 1.5 ulp);
- with ``parallel``, the two directions of a layer on two threads (``prange``), only beside a
  one-thread BLAS (:func:`~tpnet_ref.engines.two_thread_gate.take`), and only for batches whose weight reads are large
  enough to pay for it (:data:`NETWORK_APART_BYTES`).

Determinism: each output number is one chain of fused multiply-adds (``llvm.fma``, explicit,
not left to the compiler) over its group's non-zero inputs in increasing order, starting from
+0. An input that is zero in this row but not in another row of its group adds
``fma(0, w, s) = s`` exactly (the weights are finite, and a sum that starts at +0 is never -0),
so a row's result is the same bits whatever the other rows of its group and however rows are
grouped: the result does not depend on the other windows of a batch, nor on the thread count
(each number is computed by one thread, by the same code); the canonical point order before the
extractor keeps permutation invariance exact. Element-wise work uses no fast-math flags.
Weights of fewer bits (``weights="bf16"`` / ``"int8"``, :mod:`tpnet_ref.weights.quantize`) keep
all of this: each weight is widened to float32 exactly in registers, the chain is the same, and
int8's scale multiplies the finished sum (one rounding, the same for every row).
Products accumulate in the model's dtype (as the BLAS does); LayerNorm statistics in float64.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from .two_thread_gate import LOCK, available, take, two_thread_kernels_skipped
from .thread_policy import two_threads
from ..checks import overflow_error
from ..weights.quantize import SCHEMES, codes_of, wide_names
from .numba_features import FEATURE_CHUNK, features_parallel, frame_range
from .numba_lstm import head_parallel, head_serial, project_parallel, project_serial
from .numba_products import CHAIN, GROUP_ROWS, pad_columns, padded_columns


class NumbaFeatures:
    """The feature extractor as one compiled function (frames of any size, ragged included):
    ``(points (P, dim), counts (F,))`` -> global features ``(F, k)`` in the file's order of
    units, each frame computed on its own by the same code (the same bits alone, in a batch,
    on one thread or two). Only for networks whose transform nets are the identity (the
    released ones; :meth:`supports`). A call where the model's thread policy offers a second
    thread runs on two: two frames or more in two halves, one frame (a rollout's new one) its
    points in two halves (:func:`features_parallel`); the same bits either way."""

    def __init__(self, config: Any, params: dict[str, np.ndarray], dtype: Any) -> None:
        if not self.supports(config):
            raise ValueError("NumbaFeatures: trained transform nets are not supported")
        dt = self.dtype = np.dtype(dtype)
        names = ([f"mlp1.{i}" for i in range(len(config.mlp1))]
                 + [f"mlp2.{i}" for i in range(len(config.mlp2))])
        # the products stream whole vectors: every layer's columns padded with zeros to whole
        # vectors, and its rows (inputs) to the previous layer's padded width
        w = [np.asarray(params[f"{n}.w"], dtype=dt) for n in names + ["global"]]
        b = [np.asarray(params[f"{n}.b"], dtype=dt) for n in names + ["global"]]
        rows = [w[0].shape[0]] + [padded_columns(x.shape[1], dt) for x in w[:-1]]
        ws = [np.pad(pad_columns(x, dt), ((0, r - x.shape[0]), (0, 0))) for x, r in zip(w, rows)]
        bs = [pad_columns(x, dt) for x in b]
        self.w0, self.b0 = ws[0], bs[0]
        self.ws, self.bs = tuple(ws[1:-1]), tuple(bs[1:-1])
        self.gw, self.gb = ws[-1], bs[-1]
        self.k = int(config.global_features)
        self._loaded: dict[Any, bool] = {}        # available's answers for this layout

    @staticmethod
    def supports(config: Any) -> bool:
        return not (config.input_transform_trained or config.feature_transform_trained)

    def __call__(self, points: np.ndarray, counts: np.ndarray, parallel: bool = False) -> np.ndarray:
        """Global feature of every frame (see the class); ``parallel``: on two threads if
        :func:`~tpnet_ref.engines.two_thread_gate.take` allows."""
        pts = np.ascontiguousarray(points, dtype=self.dtype)
        counts = np.ascontiguousarray(counts, dtype=np.intp)
        starts = np.zeros(counts.shape[0], dtype=np.intp)
        np.cumsum(counts[:-1], out=starts[1:])
        out = np.empty((counts.shape[0], self.gw.shape[1]), dtype=self.dtype)
        weights = (self.w0, self.b0, self.ws, self.bs, self.gw, self.gb, self.dtype.type(0))
        if (counts.shape[0] > 1 or counts[0] >= 2 * GROUP_ROWS) and take(
                parallel and available(features_parallel, self._loaded,
                                        (pts, starts, counts, *weights, out))):
            try:
                features_parallel(pts, starts, counts, *weights, out)
            finally:
                LOCK.release()
        else:       # called directly: a wrapper would be one more level to compile
            frame_range(pts, starts, counts, 0, counts.shape[0], *weights, out)
        return out if out.shape[1] == self.k else np.ascontiguousarray(out[:, :self.k])


#: the prediction network's two directions go to two threads (when the call's plan offers a
#: second one) only for batches whose weight reads per direction come to this many bytes: a
#: product at a small batch reads each weight once, and on a VM whose cores share the bandwidth
#: that bounds it, a second thread costs its region launches (four per call) and gains little.
#: AMD EPYC VM, two-thread plan, float32, median us of a call with the directions apart /
#: together: quarter (0.9 MB a direction) B = 1 95 / 76, B = 8 255 / 229; half (3.5 MB) B = 1
#: 163 / 135, B = 2 190 / 192, B = 8 495 / 540; full (14 MB) B = 1 320 / 375.
#: Codes of fewer bits count at the model's float size (:attr:`NumbaHead.direction_bytes`):
#: widening each one costs what reading a float does, so int8's products are bound by
#: arithmetic, and a second thread pays (the full size's int8 at B = 1: 243 / 301 us)
NETWORK_APART_BYTES = 10_000_000


class NumbaHead:
    """A model's prediction network laid out for the kernels above (built once per model), the
    :class:`tpnet_ref.engines.interface.Head` "numba": ``params`` in the file's order (``model.params``),
    ``unit_order`` the model's (:mod:`tpnet_ref.engines.unit_order`; None: the file's order) -- only the
    layout, and so the order of the sums, depends on it. Its calls take the second thread that
    :data:`tpnet_ref.engines.thread_policy.adaptive` offers (``threaded``); the bits do not depend on it.
    ``weights`` "bf16" or "int8" (a float32 model whose BiLSTM matrices lie on that grid:
    :mod:`tpnet_ref.weights.quantize`): the kernels read those matrices' codes, widened to
    float32 in registers, and apply int8's scales to each sum; ``wide``: the matrices held in two
    planes (:func:`tpnet_ref.weights.quantize.wide_of`; None: the scheme's default)."""

    name = "numba"
    threaded = True

    def __init__(self, config: Any, params: dict[str, np.ndarray], dtype: np.dtype,
                 unit_order: dict[str, np.ndarray] | None = None,
                 max_batch: int | None = None, weights: str | None = None,
                 wide: Any = None) -> None:
        #: the largest batch it runs (None: any; :data:`tpnet_ref.engines.interface.ENGINE_MAX_BATCH`)
        self.max_batch = max_batch
        self.dtype = dt = np.dtype(dtype)
        self.relu = config.lstm_activation == "relu"
        if not self.relu and config.lstm_activation != "tanh":
            raise ValueError(f"unknown LSTM activation {config.lstm_activation!r}: "
                             "expected 'relu' or 'tanh'")
        order = unit_order or {}
        # the global features' order (BiLSTM 1's kernel rows; project() takes the file's order)
        self.feature_order = order.get("global")
        prev = self.feature_order
        kernels, recs, gks, csts, gammas, betas = [], [], [], [], [], []
        for i, u in enumerate(config.lstm_units, start=1):
            po = order.get(f"lstm{i}")
            per_dir = ((np.arange(u), np.arange(u)) if po is None else
                       (po[po < u], po[po >= u] - u))
            n = padded_columns(4 * u, dt)
            c_in = params[f"lstm{i}.fwd.kernel"].shape[0]
            kern = np.zeros((2, c_in, n), dtype=dt)
            rec = np.zeros((2, u, n), dtype=dt)
            gk = np.zeros((2, n), dtype=dt)
            cst = np.zeros((2, n), dtype=dt)
            for d, name in enumerate(("fwd", "bwd")):
                cols = np.concatenate([g * u + per_dir[d] for g in range(4)])
                k = np.take(params[f"lstm{i}.{name}.kernel"], cols, axis=1)
                if prev is not None:
                    k = np.take(k, prev, axis=0)
                kern[d, :, :4 * u] = k
                rec[d, :, :4 * u] = np.take(np.take(params[f"lstm{i}.{name}.recurrent"],
                                                    per_dir[d], axis=0), cols, axis=1)
                b = np.asarray(params[f"lstm{i}.{name}.bias"], dtype=np.float64)[cols]
                if i > 1 and self.relu:     # LayerNorm i-1 folded into this projection
                    k64 = k.astype(np.float64)
                    gk[d, :4 * u] = gammas[-1] @ k64
                    cst[d, :4 * u] = betas[-1] @ k64 + b
                else:
                    cst[d, :4 * u] = b
            prev = np.concatenate([per_dir[0], u + per_dir[1]])   # this layer's outputs
            gammas.append(np.asarray(params[f"ln{i}.gamma"], dtype=np.float64)[prev])
            betas.append(np.asarray(params[f"ln{i}.beta"], dtype=np.float64)[prev])
            kernels.append(kern)
            recs.append(rec)
            gks.append(gk)
            csts.append(cst)
        #: the weights' scheme the kernels read (:mod:`tpnet_ref.weights.quantize`; float32
        #: models only), None: the model's dtype
        self.weights = weights if weights in SCHEMES and dt == np.float32 else None
        wide = (set() if not self.weights else
                set(wide_names(config, self.weights) if wide is None else wide))
        (self.kernels, self.kscs), (self.recs, self.rscs) = (
            _codes(ws, self.weights, dt, [f"lstm{i}.fwd.{t}" in wide for i in
                                          range(1, len(ws) + 1)])
            for ws, t in ((kernels, "kernel"), (recs, "recurrent")))
        self.gks, self.csts = tuple(gks), tuple(csts)
        self.units = tuple(int(u) for u in config.lstm_units)
        self.gammas = tuple(np.ascontiguousarray(g, dtype=dt) for g in gammas)
        self.betas = tuple(np.ascontiguousarray(b, dtype=dt) for b in betas)
        self.head_w = np.ascontiguousarray(np.asarray(params["head.w"])[prev], dtype=dt)
        self.head_b = np.ascontiguousarray(params["head.b"], dtype=dt)
        t = dt.type
        self.out_shape = (config.n_out, config.dim)
        self.one, self.eps = t(1.0), t(config.layer_norm_eps)
        self.limit = t(np.sqrt(np.finfo(dt).max) / 4)
        self._loaded: dict[Any, bool] = {}        # available's answers for this layout
        #: the bytes of the float weights one direction's products read at one window (codes
        #: of fewer bits counted at the model's float size: see :data:`NETWORK_APART_BYTES`)
        self.direction_bytes = sum(int(a[0].size) for a in (*self.kernels, *self.recs)) * dt.itemsize

    def apart(self, batch: int) -> bool:
        """Whether a call on ``batch`` windows runs the two directions on two threads: when its
        plan offers a second thread (:func:`two_threads`) and the directions' weight reads come
        to :data:`NETWORK_APART_BYTES` (the same bits either way)."""
        return two_threads() and self.direction_bytes * batch >= NETWORK_APART_BYTES

    def project(self, features: np.ndarray, batch: int = 1) -> np.ndarray:
        """BiLSTM 1's input projection of each frame's feature ``(F, k)`` -> ``(F, 2N)``, in this
        head's layout (:meth:`project_rows`, bias included)."""
        return self.project_rows(features, self.apart(batch), batch).reshape(len(features), -1)

    def __call__(self, features: np.ndarray, proj1: np.ndarray | None = None) -> np.ndarray:
        """``features (B, m, k)`` -> ``(B, n_out, dim)`` in [0, 1]; ``proj1`` ``(m, B, 2N)``:
        :meth:`project` of the frames, time-major, if already known."""
        batch, m = features.shape[:2]
        parallel = self.apart(batch)
        if proj1 is None:
            proj1 = self.project_rows(features.transpose(1, 0, 2).reshape(m * batch, -1),
                                      parallel, batch)
        y, bad = self.run(proj1.reshape(m * batch, 2, -1, 4), m, batch, parallel)
        if bad:
            raise overflow_error(self.dtype, f"BiLSTM {bad}")
        if not np.isfinite(y).all():
            raise overflow_error(self.dtype, "the output layer")
        return y.reshape(-1, *self.out_shape)

    def project_rows(self, x: np.ndarray, parallel: bool = False, batch: int = 1) -> np.ndarray:
        """BiLSTM 1's input projection (with bias) of feature rows ``(R, k)`` -> ``(R, 2, N)``
        (each direction's gates i, f, c, o, then zero padding up to ``N``, whole vectors).
        ``parallel``: the two directions on two threads if :func:`~tpnet_ref.engines.two_thread_gate.take` allows.
        ``batch``: the rows are ``R / batch`` steps of ``batch`` windows, time-major (only
        groups the rows that share weight reads; the result is the same whatever it is)."""
        k = self.kernels[0]
        rows = x.shape[0]
        out = np.empty((rows, 2, k.shape[2]), dtype=self.dtype)
        if self.feature_order is not None:
            x = x[:, self.feature_order]
        x = np.ascontiguousarray(x, dtype=self.dtype)
        steps, bsz = (rows // batch, batch) if batch > 0 and rows % batch == 0 else (rows, 1)
        if take(parallel and available(project_parallel, self._loaded,
                                                (x, k, self.kscs[0], self.csts[0], out, steps,
                                                 bsz))):
            try:
                project_parallel(x, k, self.kscs[0], self.csts[0], out, steps, bsz)
            finally:
                LOCK.release()
        else:
            project_serial(x, k, self.kscs[0], self.csts[0], out, steps, bsz)
        return out

    def run(self, xp1: np.ndarray, steps: int, batch: int,
            parallel: bool = False) -> tuple[np.ndarray, int]:
        """The network from BiLSTM 1's projection ``xp1`` (:meth:`project_rows`' rows, time-major,
        ``T*B`` of them, any shape with ``2N`` numbers per row) -> ``(y (B, n_out*dim) in
        [0, 1], bad)``, ``bad`` = 1-based layer that overflowed, or 0. ``parallel``: each
        layer's two directions on two threads if :func:`~tpnet_ref.engines.two_thread_gate.take` allows."""
        xp1 = np.ascontiguousarray(xp1, dtype=self.dtype).reshape(steps * batch, 2, -1)
        args = (xp1, self.kernels, self.recs, self.kscs, self.rscs, self.gks, self.csts, self.units, self.gammas,
                self.betas, self.head_w, self.head_b, steps, batch, self.relu, self.one,
                self.eps, self.limit)
        if take(parallel and available(head_parallel, self._loaded, args)):
            try:
                return head_parallel(*args)
            finally:
                LOCK.release()
        return head_serial(*args)


def _codes(mats: list[np.ndarray], scheme: str | None, dt: np.dtype,
           wide: list[bool]) -> tuple[tuple, tuple]:
    """The matrices ``(2, C, N)`` as the kernels read them: as they are (no scheme), or their
    ``scheme`` codes (:func:`tpnet_ref.weights.quantize.codes_of`, exact; layer ``li`` in two
    planes, ``(2, 2C, N)``, where ``wide[li]``: :func:`tpnet_ref.weights.quantize.wide_names`;
    int8's high plane's rows then the low one's, bf16's weight pairs (hi, lo) interleaved, row
    ``k``'s in rows ``2k`` and ``2k + 1``), with each one's int8 scales ``(2, N)`` (``(2, 0)``:
    none)."""
    if scheme is None:
        return tuple(mats), tuple(np.zeros((2, 0), dtype=dt) for _ in mats)
    codes, scales = [], []
    for li, w in enumerate(mats):
        got = [codes_of(w[d], scheme, "NumbaHead", wide[li]) for d in range(2)]
        c = np.ascontiguousarray(np.stack([c for c, _ in got]))
        if wide[li] and scheme == "bf16":    # row k's pairs (hi, lo) interleaved, 2N a row
            half = c.shape[1] // 2
            c = np.stack([c[:, :half], c[:, half:]], axis=-1).reshape(c.shape)
        codes.append(c)
        scales.append(np.stack([s for _, s in got]) if scheme == "int8"
                      else np.zeros((2, 0), dtype=dt))
    return tuple(codes), tuple(scales)


__all__ = ["NumbaHead", "NumbaFeatures", "two_thread_kernels_skipped", "FEATURE_CHUNK", "CHAIN", "GROUP_ROWS", "padded_columns", "pad_columns"]
