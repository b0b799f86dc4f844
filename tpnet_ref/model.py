"""TP-Net in NumPy: the config, the parameters and the forward pass (docs/spec.md §2).

Data flow for one window of ``m`` frames (``N`` points each, normalised coordinates):

    frame (N, 2) --sort--> [input T-Net] -> MLP 2-64-64 -> [feature T-Net]
        -> MLP 64-128-256-512 -> max over points (512) -> FC 512-128 ReLU  = G_t (128)
    (G_{t-m+1} .. G_t) (m, 128) -> BiLSTM 512 -> LN -> BiLSTM 256 -> LN
        -> BiLSTM 256 (last output) -> LN -> FC 512 -> N_out*2 sigmoid -> (N_out, 2)

Every frame's global feature depends on that frame alone, so a batch computes all frames'
features in one pass and a rollout computes each frame's features exactly once.

Permutation invariance is exact, not approximate: each frame's points are put in a canonical
order (lexicographic by x, then y) before the feature extractor, so every permutation of a
frame produces the very same matrix and hence bit-identical output, whatever the BLAS does
with row blocking. (Max-pooling alone is invariant in exact arithmetic only.)
"""
from __future__ import annotations

import importlib.util
import math
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any, NamedTuple

import numpy as np

from . import layers as L
from . import specialize as S
from . import unit_order as U
from .config import NORM_HI, NORM_LO, TPNetConfig, param_shapes
from .blas import adaptive, cpu_count, one_thread, two_threads
from .checks import NonFiniteResultError, as_point_set, as_real_array
from .extras import require
from .native import default_weights_path, read_native, write_native

#: points per block of the feature extractor (activations of a block stay in cache)
BLOCK_POINTS = 2048
#: batches of this many windows or more are cut into chunks of ``SPLIT_CHUNK`` windows (the last
#: one shorter) that run on threads; the cut depends on the batch size alone, never on the
#: thread count, so neither changes a bit (docs/architecture.md, "Determinism")
SPLIT_MIN_BATCH = 64
SPLIT_CHUNK = 64
#: up to this many points the canonical order is one lexsort (measured 120 points: 19 -> 5 us);
#: above it, row-wise stable argsorts (1,024 frames of 30 points: 1.5 ms instead of 7 ms)
SMALL_SORT = 512
#: the prediction engines: "numpy" (layers.py, the reference), "numba" (engine_numba.py, the
#: optional compiled prediction network; extra ``metrics``), "auto" (numba when installed)
ENGINES = ("numpy", "numba", "auto")
#: the numba engine runs batches of up to this many windows; larger ones take the NumPy path
#: (BLAS products of many rows, split across threads: faster, measured in docs/performance.md)
ENGINE_MAX_BATCH = 8
_POOLS: dict[int, ThreadPoolExecutor] = {}


class _Layer(NamedTuple):
    """One BiLSTM of the NumPy engine's layout (units in the model's unit order)."""

    fused: L.FusedBiLSTM
    gamma: np.ndarray          # (2u,) this layer's LayerNorm
    beta: np.ndarray
    gk: np.ndarray | None      # (8u,) previous LayerNorm's gamma @ kernel (None for BiLSTM 1)
    bk: np.ndarray | None      # (8u,) previous LayerNorm's beta @ kernel
    merge: np.ndarray | None   # (2u,) output columns [forward | backward] -> the layer's order


def _pool(n: int) -> ThreadPoolExecutor:
    """A process-wide pool of ``n`` threads for split batches, made on first use."""
    if n not in _POOLS:
        _POOLS[n] = ThreadPoolExecutor(max_workers=n, thread_name_prefix="tpnet")
    return _POOLS[n]


def _as_engine(engine: Any) -> str:
    """The engine a model runs: ``engine`` checked, "auto" resolved (numba if installed)."""
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {', '.join(map(repr, ENGINES))}, got {engine!r}")
    if engine == "auto":
        return "numba" if importlib.util.find_spec("numba") is not None else "numpy"
    return engine


def _as_dtype(dtype: Any) -> np.dtype:
    dt = np.dtype(dtype)
    if dt not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
    return dt


class TPNet:
    """A TP-Net with its parameters in one dtype. Build it with :func:`init_random`,
    :func:`tpnet_ref.load` or an importer in :mod:`tpnet_ref.weights`. ``engine``: "numpy" (the
    reference), "numba" (the compiled prediction network of :mod:`tpnet_ref.engine_numba`, needs
    the ``metrics`` extra) or "auto" (numba when installed); every engine gives the same results
    up to rounding."""

    def __init__(self, config: TPNetConfig, params: dict[str, np.ndarray],
                 dtype: Any = "float32", meta: dict[str, Any] | None = None,
                 engine: str = "numpy", unit_order: dict[str, Any] | None = None) -> None:
        self.config = config
        self.dtype = _as_dtype(dtype)
        #: "numpy" or "numba" (see :data:`ENGINES`)
        self.engine = _as_engine(engine)
        if self.engine == "numba":
            require("numba", "metrics", "engine='numba' (the Numba inference engine)")
        self.meta: dict[str, Any] = dict(meta or {})
        #: threads a large batch is split across (None: every core; 1: never split)
        self.threads: int | None = None
        #: the scene-specialised prediction network, if any (:meth:`specialize`)
        self.specialization: S.SceneHead | None = None
        #: windows through the prediction network, and those a specialisation sent to the full one
        self.counts = {"windows": 0, "fallbacks": 0}
        expected = param_shapes(config)
        missing = [k for k in expected if k not in params]
        extra = [k for k in params if k not in expected]
        if missing or extra:
            raise ValueError(f"parameters do not fit the config: missing {missing}, unexpected {extra}")
        self.params: dict[str, np.ndarray] = {}
        for name, shape in expected.items():
            p = as_real_array(params[name], f"parameter {name!r}")
            if p.shape != shape:
                raise ValueError(f"parameter {name!r}: expected shape {shape}, got {p.shape}")
            if not np.isfinite(p).all():
                raise ValueError(f"parameter {name!r}: contains NaN or infinite values")
            self.params[name] = np.ascontiguousarray(p, dtype=self.dtype)
        #: the order of each layer's units in the NumPy engine's layout (None: the file's order;
        #: :mod:`tpnet_ref.unit_order`, :meth:`sort_units`)
        self.unit_order = U.check(unit_order, config)
        self._prepare()

    # ----------------------------------------------------------------- set-up
    def _prepare(self) -> None:
        """Group the parameters the way the forward pass consumes them."""
        cfg, p = self.config, self.params

        def stack(prefix: str, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
            return [(p[f"{prefix}.{i}.w"], p[f"{prefix}.{i}.b"]) for i in range(n)]

        def tnet(prefix: str, mlp: Sequence[int], fc: Sequence[int]):
            return (stack(f"{prefix}.mlp", len(mlp)), stack(f"{prefix}.fc", len(fc)),
                    (p[f"{prefix}.out.w"], p[f"{prefix}.out.b"]))

        order = self.unit_order or {}

        def ordered(prefix: str, n: int, prev: np.ndarray | None):
            """A per-point MLP's layers, each layer's units (columns, bias, the next layer's
            rows) in the unit order; also the last layer's order."""
            out = []
            for i in range(n):
                w, b = p[f"{prefix}.{i}.w"], p[f"{prefix}.{i}.b"]
                po = order.get(f"{prefix}.{i}")
                if prev is not None:
                    w = w[prev]
                if po is not None:
                    w, b = w[:, po], b[po]
                out.append((np.ascontiguousarray(w), np.ascontiguousarray(b)))
                prev = po
            return out, prev

        self._input_tnet = (tnet("input_tnet", cfg.input_tnet_mlp, cfg.input_tnet_fc)
                            if cfg.input_transform_trained else None)
        self._mlp1, prev = ordered("mlp1", len(cfg.mlp1), None)
        self._feature_tnet = (tnet("feature_tnet", cfg.feature_tnet_mlp, cfg.feature_tnet_fc)
                              if cfg.feature_transform_trained else None)
        self._mlp2, prev = ordered("mlp2", len(cfg.mlp2), prev)
        self._global_w = p["global.w"] if prev is None else np.ascontiguousarray(p["global.w"][prev])
        # the prediction network, units in the unit order (see tpnet_ref.unit_order): each
        # direction's gate columns, recurrent rows and bias, the next layer's kernel rows, the
        # LayerNorm's gamma and beta, and the head's rows follow the order of their layer
        self._global_order = order.get("global")
        prev = self._global_order
        self._layers: list[_Layer] = []
        for i, u in enumerate(cfg.lstm_units, start=1):
            po = order.get(f"lstm{i}")         # the outputs' order, both directions together
            merge = None
            if po is not None:                 # each direction's units in the same order
                per_dir = (po[po < u], po[po >= u] - u)
                pos = np.empty(2 * u, dtype=np.intp)
                pos[per_dir[0]] = np.arange(u)
                pos[u + per_dir[1]] = u + np.arange(u)
                merge = pos[po]                # where each output sits after the recurrence
                if np.array_equal(merge, np.arange(2 * u)):
                    merge = None
            dirs = []
            for d, name in enumerate(("fwd", "bwd")):
                k, r, b = (p[f"lstm{i}.{name}.{x}"] for x in ("kernel", "recurrent", "bias"))
                if po is not None:
                    pd = per_dir[d]
                    cols = np.concatenate([g * u + pd for g in range(4)])
                    k, r, b = k[:, cols], r[pd][:, cols], b[cols]
                if prev is not None:
                    k = k[prev]
                dirs.append((k, r, b))
            fused = L.fuse_bilstm(*dirs, block_rows=cfg.m)
            gamma, beta = p[f"ln{i}.gamma"], p[f"ln{i}.beta"]
            if po is not None:
                gamma, beta = gamma[po], beta[po]
            gk = bk = None
            if self._layers:      # LayerNorm i-1 folded into this layer's input projection
                g0, b0 = self._layers[-1].gamma, self._layers[-1].beta
                wide = fused.kernel.astype(np.float64)
                gk = (g0.astype(np.float64) @ wide).astype(self.dtype)
                bk = (b0.astype(np.float64) @ wide).astype(self.dtype)
            self._layers.append(_Layer(fused, np.ascontiguousarray(gamma),
                                       np.ascontiguousarray(beta), gk, bk, merge))
            prev = po
        self._head_w = p["head.w"] if prev is None else np.ascontiguousarray(p["head.w"][prev])
        self._lstms_file: list | None = None
        self._nb = None                     # the numba engine's prediction network
        if self.engine == "numba":
            from . import engine_numba     # optional: imports numba
            self._nb = engine_numba.NumbaHead(cfg, p, self.dtype, self.unit_order)
        self._lo = self.dtype.type(cfg.norm_lo)
        self._scale = self.dtype.type(cfg.norm_hi - cfg.norm_lo)

    @property
    def _lstms(self) -> list[tuple[L.FusedBiLSTM, np.ndarray, np.ndarray]]:
        """Each BiLSTM's fused weights and LayerNorm, units in the file's order (for
        calibration and profiling; predictions use the unit-ordered layout)."""
        if self.unit_order is None:
            return [(lay.fused, lay.gamma, lay.beta) for lay in self._layers]
        if self._lstms_file is None:
            p = self.params
            self._lstms_file = [
                (L.fuse_bilstm(*(tuple(p[f"lstm{i}.{d}.{k}"] for k in ("kernel", "recurrent", "bias"))
                                 for d in ("fwd", "bwd")), block_rows=self.config.m),
                 p[f"ln{i}.gamma"], p[f"ln{i}.beta"])
                for i in range(1, len(self.config.lstm_units) + 1)]
        return self._lstms_file

    def _copy(self, dtype: Any = None, engine: str | None = None, unit_order: Any = "same",
              used: Any = "same") -> "TPNet":
        """This network with the given changes ("same": this one's unit order / specialisation
        masks; None: none)."""
        out = TPNet(self.config, self.params, self.dtype if dtype is None else dtype, self.meta,
                    self.engine if engine is None else engine,
                    self.unit_order if isinstance(unit_order, str) else unit_order)
        out.threads = self.threads
        if isinstance(used, str):
            used = None if self.specialization is None else self.specialization.used
        if used is not None:
            out.specialization = S.SceneHead(out, used)
        return out

    def sort_units(self, windows: Any, normalized: bool = False) -> "TPNet":
        """The same network with each layer's units laid out most used first on ``windows``
        ``(B, m, N, dim)`` (the scene's windows): exact on every input, faster on windows like
        these (:mod:`tpnet_ref.unit_order`). The order is saved with the model."""
        return self.with_unit_order(U.from_use(U.measure(self, windows, normalized)))

    def astype(self, dtype: Any) -> "TPNet":
        """The same network with its parameters in ``dtype`` (float32 or float64)."""
        return self._copy(dtype=dtype)

    def specialize(self, windows: Any, normalized: bool = False) -> "TPNet":
        """The same network computing only the units that ``windows`` ``(B, m, N, dim)`` (the
        scene's calibration windows) use, exact on every input: a window that would wake a
        dropped unit is computed in full (:mod:`tpnet_ref.specialize`). Same ``predict`` /
        ``predict_batch`` / ``rollout`` API; ``counts`` says how many windows fell back."""
        return self.with_specialization(S.calibrate(self, windows, normalized))

    def with_specialization(self, used: dict[str, np.ndarray] | None) -> "TPNet":
        """A copy of this network specialised to the units ``used`` marks (None: not at all)."""
        return self._copy(used=used)

    def with_unit_order(self, order: dict[str, np.ndarray] | None) -> "TPNet":
        """The same network with its units laid out in ``order`` (:mod:`tpnet_ref.unit_order`;
        None: the file's order). Exact either way; only speed and rounding depend on it."""
        return self._copy(unit_order=order)

    def with_engine(self, engine: str) -> "TPNet":
        """The same network (and specialisation) run by ``engine`` ("numpy", "numba", "auto")."""
        return self._copy(engine=engine)

    @property
    def num_params(self) -> int:
        """Number of stored parameters (identity transform nets count zero)."""
        return int(sum(p.size for p in self.params.values()))

    def __repr__(self) -> str:
        c = self.config
        spec = "" if self.specialization is None else ", specialised"
        return (f"TPNet(m={c.m}, n_out={c.n_out}, lstm={c.lstm_units}, act={c.lstm_activation}, "
                f"transforms={'trained' if c.input_transform_trained else 'identity'}/"
                f"{'trained' if c.feature_transform_trained else 'identity'}, "
                f"params={self.num_params:,}, dtype={self.dtype.name}, engine={self.engine}{spec})")

    def save(self, path: str | os.PathLike, **provenance: Any) -> None:
        """Write the native HDF5 weights file (:mod:`tpnet_ref.native`) in the model's
        dtype (bit-exact), with its ``meta`` and ``provenance`` as root attributes."""
        write_native(path, self.config, self.params, self.dtype, {**self.meta, **provenance})
        if self.specialization is not None:        # the masks, beside config and params
            S.write(path, self.specialization.used)
        if self.unit_order is not None:
            U.write(path, self.unit_order)

    # ------------------------------------------------------------ coordinates
    def normalize(self, x: np.ndarray) -> np.ndarray:
        """World units -> model coordinates (docs/spec.md §5)."""
        return (x - self._lo) / self._scale

    def denormalize(self, x: np.ndarray) -> np.ndarray:
        """Model coordinates -> world units."""
        return x * self._scale + self._lo

    # ---------------------------------------------------------------- forward
    def frame_features(self, points: np.ndarray, counts: np.ndarray) -> np.ndarray:
        """Global feature ``G`` of every frame.

        ``points (P, dim)``: the frames' points one frame after another, each frame already in
        canonical order (see :func:`canonical_order`); ``counts (F,)`` points per frame
        -> ``(F, global_features)``. Large inputs go through the extractor in blocks of whole
        frames (about ``BLOCK_POINTS`` points each) so that the per-point activations stay in
        cache; each frame's feature depends on its own points only.
        """
        counts = np.asarray(counts)
        if points.shape[0] <= BLOCK_POINTS:
            return self._features_block(points, counts)
        ends = np.cumsum(counts)
        out = np.empty((len(counts), self.config.global_features), dtype=self.dtype)
        f0, p0 = 0, 0
        while f0 < len(counts):
            f1 = max(f0 + 1, int(np.searchsorted(ends, p0 + BLOCK_POINTS, side="right")))
            out[f0:f1] = self._features_block(points[p0:ends[f1 - 1]], counts[f0:f1])
            f0, p0 = f1, int(ends[f1 - 1])
        return out

    def _features_block(self, points: np.ndarray, counts: np.ndarray) -> np.ndarray:
        x = points
        if self._input_tnet is not None:
            x = L.apply_transform(x, L.transform_net(x, counts, *self._input_tnet), counts)
        # every product after the first reads only the weight rows up to the last unit that
        # is non-zero at some point of the block (L.used_columns; exact)
        h = L.pointwise_mlp(x, self._mlp1, used=True)
        if self._feature_tnet is not None:
            h = L.apply_transform(h, L.transform_net(h, counts, *self._feature_tnet), counts)
        g = L.mlp_max(h, self._mlp2, counts, used=True)
        return L.dense(g, self._global_w, self.params["global.b"], "relu", used=True)

    def sequence_head(self, features: np.ndarray, proj1: np.ndarray | None = None) -> np.ndarray:
        """Prediction network: ``(B, m, global_features)`` -> ``(B, n_out, dim)`` in [0, 1].
        With a specialisation, the specialised one, and the full one for the windows it flags
        (except where the numba engine runs the batch: its full network is faster).
        ``proj1`` ``(m, B, 8u)``: BiLSTM 1's input projections of the frames, if already known
        (:meth:`project_frames`; used by the full network only)."""
        spec = self._specialised(len(features))
        if spec is None:
            return self._full_head(features, proj1)
        y, ok = spec(features)
        y = y.reshape(-1, self.config.n_out, self.config.dim)
        bad = np.flatnonzero(~ok)
        if bad.size:
            y[bad] = self._full_head(features[bad])
        self.counts["windows"] += len(ok)
        self.counts["fallbacks"] += int(bad.size)
        return y

    def _specialised(self, batch: int) -> Any:
        """The specialised network that runs batches of ``batch`` windows, or None: none when
        the numba engine runs them (its full network skips every zero weight row by itself and
        is faster than the specialised NumPy one; bench/bench_specialize.py prints both)."""
        return None if self._engine_for(batch) is not None else self.specialization

    def _engine_for(self, batch: int) -> Any:
        """The numba engine's network if it runs batches of ``batch`` windows, else None."""
        return self._nb if self._nb is not None and batch <= ENGINE_MAX_BATCH else None

    def project_frames(self, features: np.ndarray, batch: int = 1) -> np.ndarray:
        """BiLSTM 1's input projection (without bias) of each frame's feature: ``(F, k)`` ->
        ``(F, 8u)``. A function of the frame alone, so a rollout computes it once per frame.
        For the numba engine (batches of ``batch`` windows it runs), its own layout
        (:meth:`tpnet_ref.engine_numba.NumbaHead.project`, the bias included, columns padded)."""
        nb = self._engine_for(batch)
        if nb is not None:
            return nb.project(features, parallel=two_threads(),
                              batch=batch).reshape(len(features), -1)
        if self._global_order is not None:
            features = features[:, self._global_order]
        fused = self._layers[0].fused        # kernel rows past the last non-zero feature unread
        return L.project_spans(features, fused.kernel, fused.blocks,
                               [(0, L.used_columns(features))])

    def _full_head(self, features: np.ndarray, proj1: np.ndarray | None = None) -> np.ndarray:
        batch, m = features.shape[:2]
        nb = self._engine_for(batch)
        if nb is not None:
            parallel = two_threads()
            if proj1 is None:
                proj1 = nb.project(features.transpose(1, 0, 2).reshape(m * batch, -1), parallel,
                                   batch)
            y, bad = nb(proj1.reshape(m * batch, 2, -1, 4), m, batch, parallel)
            if bad:
                self._overflow(f"BiLSTM {bad}")
            if not np.isfinite(y).all():
                self._overflow("the output layer")
            return y.reshape(-1, self.config.n_out, self.config.dim)
        act = self.config.lstm_activation
        eps = self.config.layer_norm_eps
        if proj1 is None:                 # time-major rows (t, b)
            proj1 = self.project_frames(features.transpose(1, 0, 2).reshape(m * batch, -1), batch)
        last = len(self._layers) - 1
        # LayerNorm squares its centred input: a ReLU LSTM output above sqrt(max)/2 would
        # overflow the variance to inf and silently turn the layer's output into beta
        # (finite but wrong), so every LSTM output is checked against that bound.
        limit = np.sqrt(np.finfo(self.dtype).max) / 4
        xp = proj1
        with np.errstate(over="ignore", invalid="ignore"):
            for i, lay in enumerate(self._layers):
                h = L.bilstm_steps(xp, lay.fused.recurrent, lay.fused.bias, m, batch, act,
                                   return_sequences=i < last)
                if act == "relu" and not h.max() < limit:   # also catches NaN
                    self._overflow(f"BiLSTM {i + 1}")
                n = h.shape[-1]
                if lay.merge is not None:     # both directions' outputs in one order
                    h = np.take(h, lay.merge, axis=-1)
                if i < last:              # LayerNorm folded into the next input projection
                    nxt = self._layers[i + 1]
                    spans = ((0, n),) if lay.merge is not None else ((0, n // 2), (n // 2, n))
                    xp = L.project_layer_norm(h.reshape(m * batch, -1), lay.gamma, lay.beta, eps,
                                              nxt.fused.kernel, nxt.fused.blocks, nxt.gk, nxt.bk,
                                              spans)
                else:
                    h = L.layer_norm(h, lay.gamma, lay.beta, eps)
            y = L.dense(h, self._head_w, self.params["head.b"], "sigmoid")
        if not np.isfinite(y).all():
            self._overflow("the output layer")
        return y.reshape(-1, self.config.n_out, self.config.dim)

    def _overflow(self, where: str) -> None:
        remedy = ("try dtype='float64'" if self.dtype == np.float32
                  else "rescale the input towards the training range")
        raise NonFiniteResultError(
            f"the prediction network overflowed in {self.dtype.name} at {where} (the ReLU "
            "LSTM's state is unbounded); the input is far outside the training range — "
            + remedy)

    # ------------------------------------------------------------ public API
    def _canonical_points(self, frames: list[np.ndarray],
                          normalized: bool) -> tuple[np.ndarray, np.ndarray]:
        """Validated frames (each ``(N_i, dim)``) -> their points in model coordinates, each
        frame in canonical order, ``(P, dim)``, and the points per frame ``(F,)``."""
        counts = np.fromiter((f.shape[0] for f in frames), dtype=np.intp, count=len(frames))
        pts = np.concatenate(frames, axis=0).astype(self.dtype, copy=False)
        if not normalized:
            pts = self.normalize(pts)
        else:
            pts = pts + self.dtype.type(0.0)  # a copy, and -0.0 -> +0.0 for a canonical order
        return pts[canonical_order(pts, counts)], counts

    def _frames_to_features(self, frames: list[np.ndarray], normalized: bool) -> np.ndarray:
        """Validated frames (each ``(N_i, dim)``) -> their global features ``(F, k)``."""
        return self.frame_features(*self._canonical_points(frames, normalized))

    def _check_window(self, window: Any, name: str) -> list[np.ndarray]:
        m, dim = self.config.m, self.config.dim
        if isinstance(window, (str, bytes, os.PathLike)):
            raise TypeError(f"{name}: expected points, got the path or string {window!r}; "
                            "load the file first, e.g. np.load(path), or run `tpnet predict PATH`")
        if isinstance(window, np.ndarray) or not isinstance(window, Sequence):
            arr = as_real_array(window, name)
            if arr.ndim != 3 or arr.shape[-1] != dim:
                raise ValueError(f"{name}: expected shape (m={m}, N, {dim}) or a sequence of m "
                                 f"arrays (N_i, {dim}), got an array of shape {arr.shape}")
            frames = [arr[i] for i in range(arr.shape[0])]
        else:
            frames = list(window)
        if len(frames) != m:
            raise ValueError(f"{name}: the model takes m={m} frames, got {len(frames)}")
        out = [as_point_set(f, f"{name}[{i}]", dim) for i, f in enumerate(frames)]
        big = np.finfo(self.dtype).max
        for i, f in enumerate(out):
            if f.dtype.itemsize > self.dtype.itemsize and np.abs(f).max() > big:
                raise ValueError(f"{name}[{i}]: values beyond the {self.dtype.name} range "
                                 f"(|x| > {big:.3g}); use a float64 model")
        return out

    def predict(self, window: Any, normalized: bool = False) -> np.ndarray:
        """Next point set. ``window``: ``(m, N, dim)`` or m arrays ``(N_i, dim)`` -> ``(n_out, dim)``."""
        return self._split(self._predict_frames, self._check_window(window, "window"), 1,
                           normalized)[0]

    def predict_batch(self, windows: Any, normalized: bool = False) -> np.ndarray:
        """Next point set of each window: ``(B, m, N, dim)`` or B windows -> ``(B, n_out, dim)``."""
        frames, batch = self._check_windows(windows)
        return self._split(self._predict_frames, frames, batch, normalized)

    def _check_windows(self, windows: Any) -> tuple[list[np.ndarray], int]:
        """A batch of windows -> its validated frames, window after window, and the batch size."""
        if isinstance(windows, np.ndarray):
            arr = as_real_array(windows, "windows")
            if arr.ndim != 4:
                raise ValueError(f"windows: expected shape (B, m, N, {self.config.dim}) or a "
                                 f"sequence of windows, got an array of shape {arr.shape}")
            windows = list(arr)
        elif isinstance(windows, (str, bytes, os.PathLike)):
            self._check_window(windows, "windows")          # the one-line path error
        elif not isinstance(windows, Sequence):
            raise TypeError(f"windows: expected an array or a sequence of windows, "
                            f"got {type(windows).__name__}")
        if len(windows) == 0:
            raise ValueError("windows: empty batch")
        frames: list[np.ndarray] = []
        for b, w in enumerate(windows):
            frames.extend(self._check_window(w, f"windows[{b}]"))
        return frames, len(windows)

    def _split(self, fn: Any, frames: list[np.ndarray], batch: int, *args: Any) -> np.ndarray:
        """``fn(frames, batch, *args)`` with a one-thread BLAS: a batch of fewer than
        ``SPLIT_MIN_BATCH`` windows as it is (``fn`` runs it under :meth:`_threads`), a larger
        one in chunks of ``SPLIT_CHUNK`` consecutive windows, joined along the batch axis; the
        chunks run on ``self.threads`` threads (None: every core), one after another with 1.
        The chunks depend on ``batch`` alone, so the thread count changes no bit."""
        if batch < SPLIT_MIN_BATCH:
            return fn(frames, batch, *args)
        m = self.config.m
        parts = [(frames[b0 * m:(b0 + SPLIT_CHUNK) * m], min(SPLIT_CHUNK, batch - b0))
                 for b0 in range(0, batch, SPLIT_CHUNK)]
        n = min(self.threads or cpu_count(), len(parts))
        with one_thread():
            run = map if n < 2 else _pool(n).map
            return np.concatenate(list(run(lambda p: fn(p[0], p[1], *args), parts)))

    def _threads(self, what: str, batch: int, points: int) -> Any:
        """The block a call's work runs in: always a one-thread BLAS; for the batches the Numba
        engine runs, also :data:`tpnet_ref.blas.adaptive`, which lets its two LSTM directions
        take a second thread while that measures faster (the same bits either way)."""
        if self._engine_for(batch) is None:
            return one_thread()
        return adaptive((id(self), what, batch, points))

    def preferred_threads(self, what: str = "predict", batch: int = 1, points: int = 0) -> int | None:
        """The plan :data:`tpnet_ref.blas.adaptive` measured faster for this model's calls of
        ``what`` ("predict", "features", "rollout step") on ``batch`` windows of ``points``
        points in all: 1 (one thread), 0 (two threads) or None (not measured: the NumPy engine
        runs on one thread)."""
        return adaptive.preferred((id(self), what, batch, points))

    def _predict_frames(self, frames: list[np.ndarray], batch: int, normalized: bool) -> np.ndarray:
        """``batch * m`` validated frames, window after window -> ``(batch, n_out, dim)``."""
        with self._threads("predict", batch, sum(f.shape[0] for f in frames)):
            g = self._frames_to_features(frames, normalized)
            y = self.sequence_head(g.reshape(batch, self.config.m, -1))
        return y if normalized else self.denormalize(y)

    def rollout(self, window: Any, steps: int, normalized: bool = False) -> np.ndarray:
        """Recursive prediction: ``steps`` future point sets ``(steps, n_out, dim)``.

        After each step the window slides by one frame and the prediction becomes its newest
        frame. Each frame's global feature is computed once and kept.
        """
        frames = self._check_window(window, "window")
        return self._split(self._rollout_frames, frames, 1, steps, normalized)[0]

    def rollout_batch(self, windows: Any, steps: int, normalized: bool = False) -> np.ndarray:
        """:meth:`rollout` of every window, the windows stepped together:
        ``(B, m, N, dim)`` or B windows -> ``(B, steps, n_out, dim)``."""
        frames, batch = self._check_windows(windows)
        return self._split(self._rollout_frames, frames, batch, steps, normalized)

    def _rollout_frames(self, frames: list[np.ndarray], batch: int, steps: Any,
                        normalized: bool) -> np.ndarray:
        """``batch * m`` validated frames -> ``(batch, steps, n_out, dim)``."""
        if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
            raise ValueError(f"steps: expected a positive integer, got {steps!r}")
        m, steps = self.config.m, int(steps)
        try:
            feats = np.empty((batch, m + steps, self.config.global_features), dtype=self.dtype)
            out = np.empty((batch, steps, self.config.n_out, self.config.dim), dtype=self.dtype)
        except MemoryError:
            raise ValueError(f"steps: {steps} steps do not fit in memory") from None
        # BiLSTM 1's input projection of each frame, also computed once per frame (the full
        # network only: a specialised one projects its kept units itself); the last m kept
        cache = self._specialised(batch) is None
        with self._threads("features", batch, sum(f.shape[0] for f in frames)):
            feats[:, :m] = self._frames_to_features(frames, normalized).reshape(batch, m, -1)
            proj = (list(self.project_frames(feats[:, :m].transpose(1, 0, 2).reshape(m * batch, -1),
                                             batch).reshape(m, batch, -1)) if cache else None)
        counts = np.full(batch, self.config.n_out)
        for s in range(steps):
            with self._threads("rollout step", batch, self.config.n_out):   # follows the load
                y = self.sequence_head(feats[:, s:s + m],             # (batch, n_out, dim)
                                       np.stack(proj[-m:]) if cache else None)
                out[:, s] = y
                flat = y.reshape(-1, self.config.dim)
                feats[:, m + s] = self.frame_features(flat[canonical_order(flat, counts)], counts)
                if cache and s + 1 < steps:
                    proj = proj[len(proj) - m + 1:] + [self.project_frames(feats[:, m + s], batch)]
        return out if normalized else self.denormalize(out)


def load(path: str | os.PathLike | None = None, dtype: Any = "float32",
         engine: str = "numpy") -> TPNet:
    """A :class:`TPNet` from a native weights file; ``path=None`` loads the shipped m = 4 model
    (:func:`tpnet_ref.native.default_weights_path`; a one-line ``FileNotFoundError``
    when there is none). A file written by a specialised model loads specialised. ``engine``:
    see :class:`TPNet`."""
    path = default_weights_path() if path is None else path
    config, params, meta = read_native(path)
    order = U.read(path)
    return S.attach(TPNet(config, params, dtype, meta, engine, unit_order=order), path)   # specialised if the file says so


def canonical_order(points: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Indices that sort each frame's points by x, then y (then the remaining coordinates).

    ``points (P, dim)``, ``counts (F,)`` -> ``(P,)`` indices into ``points``. Points that tie
    on every coordinate are identical rows, so the sorted matrix does not depend on the input
    order at all.
    """
    counts = np.asarray(counts)
    dim = points.shape[1]
    if points.shape[0] <= SMALL_SORT:
        # few points (a window, a rollout's new frame): one lexsort is cheapest (same indices)
        frame_id = np.repeat(np.arange(len(counts)), counts)
        return np.lexsort([points[:, d] for d in range(dim - 1, -1, -1)] + [frame_id])
    if counts.size and np.all(counts == counts[0]):
        # equal frames: stable sorts within each row, least significant coordinate first
        a = points.reshape(counts.size, int(counts[0]), dim)
        idx = np.argsort(a[..., dim - 1], axis=1, kind="stable")
        for d in range(dim - 2, -1, -1):
            key = np.take_along_axis(a[..., d], idx, axis=1)
            idx = np.take_along_axis(idx, np.argsort(key, axis=1, kind="stable"), axis=1)
        idx += (np.arange(counts.size) * int(counts[0]))[:, None]
        return idx.ravel()
    frame_id = np.repeat(np.arange(len(counts)), counts)
    keys = [points[:, d] for d in range(dim - 1, -1, -1)] + [frame_id]
    return np.lexsort(keys)


def init_random(config: TPNetConfig | None = None, seed: int = 0, dtype: Any = "float32",
                transform_scale: float = 0.1) -> TPNet:
    """A randomly initialised TP-Net (Glorot-uniform kernels, small random biases, LSTM forget
    bias 1, non-trivial transform nets when the config asks for trained ones), for tests and
    benchmarks. Deterministic in ``seed``.
    """
    cfg = config or TPNetConfig()
    rng = np.random.default_rng(seed)
    params: dict[str, np.ndarray] = {}
    for name, shape in param_shapes(cfg).items():
        if len(shape) == 2:
            limit = math.sqrt(6.0 / (shape[0] + shape[1]))
            if name.endswith(".out.w"):
                limit = transform_scale / math.sqrt(shape[0])
            params[name] = rng.uniform(-limit, limit, size=shape)
        elif name.endswith(".out.b"):
            k = int(round(math.sqrt(shape[0])))
            params[name] = np.eye(k).ravel() + rng.uniform(-transform_scale, transform_scale, shape)
        elif name.endswith("gamma"):
            params[name] = 1.0 + rng.uniform(-0.2, 0.2, size=shape)
        elif name.endswith(".bias") and name.startswith("lstm"):
            u = shape[0] // 4
            b = rng.uniform(-0.1, 0.1, size=shape)
            b[u:2 * u] += 1.0  # Keras unit_forget_bias
            params[name] = b
        else:
            params[name] = rng.uniform(-0.1, 0.1, size=shape)
    return TPNet(cfg, params, dtype, meta={"producer": "tpnet_ref.model.init_random",
                                           "seed": int(seed)})


__all__ = ["TPNetConfig", "TPNet", "load", "param_shapes", "init_random", "canonical_order",
           "NORM_LO", "NORM_HI"]
