"""TP-Net in NumPy: the model a user holds -- config, parameters, input checks, the forward pass.

:meth:`TPNet.predict` is ``check -> canonical points -> frame_features -> sequence_head ->
denormalise`` (data flow with shapes: docs/architecture.md; the same network written to be read:
:mod:`tpnet_ref.reference`). The feature extractor is the NumPy fast path
(:mod:`tpnet_ref.engines.numpy_engine`) or the Numba one; the prediction network runs on one of the
model's heads (:mod:`tpnet_ref.engines.interface`: NumPy, Numba, scene-specialised), every one tested
against the reference; a rollout's loop is :mod:`tpnet_ref.engines.rollout`. Permutation invariance
is exact: each frame's points are put in canonical order first (:mod:`tpnet_ref.point_order`;
``sort_points=False`` runs them as given, to check the network's own invariance). The bits do
not depend on threads (docs/architecture.md, "Determinism"): every product runs on a one-thread
BLAS, and a large batch is cut into chunks by its size alone.
"""
from __future__ import annotations

import os
from typing import Any

import numpy as np

from .engines import interface as H, rollout as R, specialised as S, unit_order as U
from .engines.batch_split import SPLIT_CHUNK, SPLIT_MIN_BATCH, split_batch  # noqa: F401
from .engines.thread_policy import adaptive, two_threads
from .engines.blas import one_thread
from .checks import (NonFiniteResultError, check_params, check_window, check_windows,
                     warn_about_input)
from .config import NORM_HI, NORM_LO, TPNetConfig, param_shapes, random_params
from .engines.numpy_engine import BLOCK_POINTS, NumpyFeatures
from .engines.interface import ENGINE_MAX_BATCH, ENGINES  # noqa: F401  (re-exported)
from .weights.shipped import default_weights_path
from .weights.native import read_native, write_native
from .point_order import SMALL_SORT, canonical_order  # noqa: F401  (re-exported)

class TPNet:
    """A TP-Net with its parameters in one dtype. Build it with :func:`init_random`,
    :func:`tpnet_ref.load` or an importer in :mod:`tpnet_ref.weights`. ``engine``: "numpy",
    "numba" (the compiled head, extra ``metrics``) or "auto" (numba when installed);
    ``unit_order``: the layout of the fast paths (:mod:`tpnet_ref.unit_order`); ``used``: the
    masks of a scene specialisation (:mod:`tpnet_ref.engines.specialised`); ``sort_points``: put each
    frame in canonical order before the network (the default; False runs the points in the order
    given, for checking the network's own invariance: :meth:`with_point_sort`). Every choice
    gives the same results up to rounding."""

    def __init__(self, config: TPNetConfig, params: dict[str, np.ndarray],
                 dtype: Any = "float32", meta: dict[str, Any] | None = None,
                 engine: str = "numpy", unit_order: dict[str, Any] | None = None,
                 used: dict[str, np.ndarray] | None = None, sort_points: bool = True) -> None:
        self.config = config
        if not isinstance(sort_points, (bool, np.bool_)):
            raise TypeError(f"sort_points must be True or False, got {sort_points!r}")
        #: whether each frame is put in canonical order first (bit-exact permutation invariance);
        #: a plain attribute, like ``threads``: setting it changes nothing else
        self.sort_points = bool(sort_points)
        self.dtype = np.dtype(dtype)
        if self.dtype not in (np.dtype(np.float32), np.dtype(np.float64)):
            raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
        self.engine = H.resolve_engine(engine)
        self.meta: dict[str, Any] = dict(meta or {})
        #: threads a large batch is split across (None: every core; 1: never split)
        self.threads: int | None = None
        #: windows through the specialised head, and those it sent to the full network
        self.counts = {"windows": 0, "fallbacks": 0}
        #: the parameters in the file's order, named and shaped as :func:`param_shapes` says
        self.params = check_params(params, param_shapes(config), self.dtype)
        #: each layer's units in the fast paths' layout (None: the file's order)
        self.unit_order = U.check(unit_order, config)
        self.features = NumpyFeatures(config, self.params, self.unit_order)
        #: the prediction network's heads, fastest first (:mod:`tpnet_ref.engines.interface`)
        self.heads = H.build(self, self.engine, used)
        #: the compiled feature extractor of the batches the numba head runs (None: NumPy's)
        self.engine_features = H.build_features(self, self.engine)
        #: the scene-specialised network, if any (:meth:`specialize`)
        self.specialization: S.SceneHead | None = next(
            (h.scene for h in self.heads if h.name == "specialised"), None)
        self._lo = self.dtype.type(config.norm_lo)
        self._scale = self.dtype.type(config.norm_hi - config.norm_lo)
        #: the compiled first pass over an array of windows (None: the checks serve every call)
        self.screen = H.build_screen(self.engine, config)
        #: the network as one compiled call for the one-thread plan (None: separate calls)
        self.fused = H.build_fused(self.engine)

    # ------------------------------------------------------- the same network, changed
    def _replace(self, **changes: Any) -> "TPNet":
        used = None if self.specialization is None else self.specialization.used
        kw = {"dtype": self.dtype, "meta": self.meta, "engine": self.engine,
              "unit_order": self.unit_order, "used": used, "sort_points": self.sort_points,
              **changes}
        out = TPNet(self.config, self.params, **kw)
        out.threads = self.threads
        return out

    def astype(self, dtype: Any) -> "TPNet":
        """The same network with its parameters in ``dtype`` (float32 or float64)."""
        return self._replace(dtype=dtype)

    def with_engine(self, engine: str) -> "TPNet":
        """The same network (and specialisation) run by ``engine`` ("numpy", "numba", "auto")."""
        return self._replace(engine=engine)

    def with_unit_order(self, order: dict[str, np.ndarray] | None) -> "TPNet":
        """The same network with its units laid out in ``order`` (:mod:`tpnet_ref.unit_order`;
        None: the file's order). Exact either way; only speed and rounding depend on it."""
        return self._replace(unit_order=order)

    def with_point_sort(self, enabled: bool) -> "TPNet":
        """The same network with the canonical point sort on (the default) or off. Off, each
        frame's points reach the network in the order given: the output is then invariant to
        per-frame permutations only up to rounding -- by the network's own structure (a shared
        per-point MLP and a max), which is what :mod:`tpnet_ref.testing` checks; on, bit for
        bit."""
        return self._replace(sort_points=enabled)

    def with_specialization(self, used: dict[str, np.ndarray] | None) -> "TPNet":
        """A copy of this network specialised to the units ``used`` marks (None: not at all)."""
        return self._replace(used=used)

    def sort_units(self, windows: Any, normalized: bool = False) -> "TPNet":
        """The same network with each layer's units laid out most used first on ``windows``
        ``(B, m, N, dim)`` (the scene's windows): the same function on every input up to
        rounding (docs/tolerances.md), faster on windows like these (:mod:`tpnet_ref.unit_order`). The order is saved with the model."""
        return self.with_unit_order(U.from_use(U.measure(self, windows, normalized)))

    def specialize(self, windows: Any, normalized: bool = False) -> "TPNet":
        """The same network computing only the units that ``windows`` ``(B, m, N, dim)`` (the
        scene's calibration windows) use, the same function on every input up to rounding
        (docs/tolerances.md): a window that would wake a
        dropped unit is computed in full (:mod:`tpnet_ref.engines.specialised`). Same ``predict`` /
        ``predict_batch`` / ``rollout`` API; ``counts`` says how many windows fell back."""
        return self.with_specialization(S.calibrate(self, windows, normalized))

    @property
    def num_params(self) -> int:
        """Number of stored parameters (identity transform nets count zero)."""
        return int(sum(p.size for p in self.params.values()))

    def __repr__(self) -> str:
        c = self.config
        spec = "" if self.specialization is None else ", specialised"
        spec += "" if self.sort_points else ", unsorted points"
        return (f"TPNet(m={c.m}, n_out={c.n_out}, lstm={c.lstm_units}, act={c.lstm_activation}, "
                f"transforms={'trained' if c.input_transform_trained else 'identity'}/"
                f"{'trained' if c.feature_transform_trained else 'identity'}, "
                f"params={self.num_params:,}, dtype={self.dtype.name}, engine={self.engine}{spec})")

    def save(self, path: str | os.PathLike, **provenance: Any) -> None:
        """Write the native HDF5 weights file (:mod:`tpnet_ref.weights.native`) in the model's dtype
        (bit-exact), with its ``meta`` and ``provenance`` as root attributes, its unit order,
        its specialisation's masks and the digest of all of it (:mod:`tpnet_ref.weights.native`)."""
        groups = {}
        if self.specialization is not None:
            groups[S.GROUP] = S.group(self.specialization.used)
        if self.unit_order is not None:
            groups[U.GROUP] = U.group(self.unit_order)
        write_native(path, self.config, self.params, self.dtype, {**self.meta, **provenance},
                     groups=groups)

    # ---------------------------------------------------------------- forward
    def normalize(self, x: np.ndarray) -> np.ndarray:
        """World units -> model coordinates (docs/spec.md §5)."""
        return (x - self._lo) / self._scale

    def denormalize(self, x: np.ndarray) -> np.ndarray:
        """Model coordinates -> world units."""
        return x * self._scale + self._lo

    def canonical_points(self, frames: list[np.ndarray],
                         normalized: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Checked frames (each ``(N_i, dim)``) -> their points in model coordinates, each frame
        in canonical order (in the given order when ``sort_points`` is off), ``(P, dim)``, and
        the points per frame ``(F,)``."""
        counts = np.fromiter((f.shape[0] for f in frames), dtype=np.intp, count=len(frames))
        pts = np.concatenate(frames, axis=0).astype(self.dtype, copy=False)
        if not normalized:
            pts = self.normalize(pts)
        else:
            pts = pts + self.dtype.type(0.0)  # a copy, and -0.0 -> +0.0 for a canonical order
        return self.sorted_points(pts, counts), counts

    def sorted_points(self, points: np.ndarray, counts: np.ndarray) -> np.ndarray:
        """``points (P, dim)`` of frames of ``counts`` points, each frame in canonical order
        (:func:`tpnet_ref.point_order.canonical_order`; as given when ``sort_points`` is off)."""
        if not self.sort_points:
            return points
        fast = None if self.screen is None else self.screen.sorted(points, counts)
        return points[canonical_order(points, counts)] if fast is None else fast

    def frame_features(self, points: np.ndarray, counts: np.ndarray,
                       batch: int | None = None) -> np.ndarray:
        """Global feature of every frame: ``points (P, dim)`` frame after frame, each in
        canonical order, ``counts (F,)`` -> ``(F, global_features)``. ``batch``: the windows
        they belong to; with a compiled extractor (the Numba engine's) every batch takes it
        (its frames on two threads when the call's thread plan offers a second one; the same
        bits either way), anything else the NumPy one."""
        if self.engine_features is not None and batch is not None:
            return self.engine_features(points, counts, two_threads())
        return self.features(points, counts)

    def window_features(self, windows: Any, normalized: bool = False) -> np.ndarray:
        """The global features of a batch's frames: ``(B, m, N, dim)`` -> ``(B, m, k)``."""
        frames, batch = check_windows(windows, self.config.m, self.config.dim, self.dtype)
        return self.frame_features(*self.canonical_points(frames, normalized),
                                   batch).reshape(batch, self.config.m, -1)

    def head_for(self, batch: int) -> H.Head:
        """The head that runs batches of ``batch`` windows (:mod:`tpnet_ref.engines.interface`)."""
        return H.for_batch(self.heads, batch)

    def project_frames(self, features: np.ndarray, batch: int = 1) -> np.ndarray | None:
        """BiLSTM 1's input projection of each frame's feature ``(F, k)`` in the layout of the
        head that runs ``batch`` windows (None: that head projects its inputs itself)."""
        return self.head_for(batch).project(features, batch)

    def sequence_head(self, features: np.ndarray, proj1: np.ndarray | None = None) -> np.ndarray:
        """Prediction network: ``(B, m, global_features)`` -> ``(B, n_out, dim)`` in [0, 1];
        ``proj1 (m, B, ...)``: :meth:`project_frames` of the frames, if already known."""
        return self.head_for(len(features))(features, proj1)

    def _threads(self, what: str, batch: int, points: int, held: bool = False) -> Any:
        """The block a call's work runs in: a one-thread BLAS, and :data:`~tpnet_ref.engines.thread_policy.adaptive`,
        which lets the parts that may take a second thread (the NumPy extractor's blocks of points,
        the Numba kernels) take it while that measures faster (the same bits either way), and
        says which plan runs. A call with nothing to share runs on one thread."""
        head = self.head_for(batch)
        if not head.threaded and points <= BLOCK_POINTS:
            return one_thread()
        # the Numba engine's own kernels alone (its feature extractor, its head): no BLAS product
        blas_free = head.name == "numba" and self.engine_features is not None
        return adaptive((id(self), what, batch, points), held, blas_free)

    def preferred_threads(self, what: str = "predict", batch: int = 1, points: int = 0) -> int | None:
        """The plan :data:`tpnet_ref.engines.thread_policy.adaptive` measured faster for this model's calls of
        ``what`` ("predict", "features", "rollout step") on ``batch`` windows of ``points``
        points in all: 1 (one thread), 0 (two threads) or None (not measured yet, or nothing
        to share: one feature block on the NumPy head)."""
        return adaptive.preferred((id(self), what, batch, points))

    def _run(self, fn: Any, windows: Any, one: bool, normalized: bool, *args: Any) -> np.ndarray:
        """``fn(points, counts, batch, normalized, *args)`` on :meth:`canonical_points`' points of
        one window (``one``) or a batch. An array the Numba engine's compiled first pass decides
        (:class:`tpnet_ref.engines.numba_checks.Screen`: the checks' warnings and the points at once)
        goes straight in; other input is checked, warned about (input outside the training range
        or not one body), and run in chunks set by the batch size (:func:`blas.split_batch`)."""
        c = self.config
        got = None if self.screen is None else self.screen(self, windows, one, normalized)
        try:    # the user's error: its traceback ends here, not deep in the checks or heads
            if got is None and one:
                frames, batch = check_window(windows, c.m, c.dim, self.dtype), 1
            elif got is None:
                frames, batch = check_windows(windows, c.m, c.dim, self.dtype)
        except (ValueError, TypeError) as exc:
            raise exc.with_traceback(None) from None
        try:
            if got is not None:
                return fn(*got, normalized, *args)
            warn_about_input(frames, c.norm_lo, c.norm_hi, normalized,
                             "window" if one else "windows", one)
            return split_batch(lambda f, b, *a: fn(*self.canonical_points(f, normalized), b, *a),
                               frames, batch, c.m, self.threads, normalized, *args)
        except NonFiniteResultError as exc:
            raise exc.with_traceback(None) from None

    # ------------------------------------------------------------ public API
    def predict(self, window: Any, normalized: bool = False) -> np.ndarray:
        """Next point set. ``window``: ``(m, N, dim)`` or m arrays ``(N_i, dim)`` -> ``(n_out, dim)``."""
        return self._run(self._network, window, True, normalized)[0]

    def predict_batch(self, windows: Any, normalized: bool = False) -> np.ndarray:
        """Next point set of each window: ``(B, m, N, dim)`` or B windows -> ``(B, n_out, dim)``."""
        return self._run(self._network, windows, False, normalized)

    def _network(self, points: np.ndarray, counts: np.ndarray, batch: int,
                 normalized: bool) -> np.ndarray:
        """:meth:`canonical_points`' output for ``batch`` windows -> ``(batch, n_out, dim)``."""
        with self._threads("predict", batch, len(points)) as plan:   # mostly one call
            y = None if not self.fused else self.fused.run(self, points, counts, batch,
                                                            normalized, plan == 0)
            if y is not None:
                return y
            g = self.frame_features(points, counts, batch)
            y = self.sequence_head(g.reshape(batch, self.config.m, -1))
        return y if normalized else self.denormalize(y)

    def rollout(self, window: Any, steps: int, normalized: bool = False) -> np.ndarray:
        """Recursive prediction: ``steps`` future point sets ``(steps, n_out, dim)``.

        After each step the window slides by one frame and the prediction becomes its newest
        frame. Each frame's global feature is computed once and kept
        (:func:`tpnet_ref.engines.rollout.rollout`).
        """
        return self._run(self._rollout, window, True, normalized, steps)[0]

    def rollout_batch(self, windows: Any, steps: int, normalized: bool = False) -> np.ndarray:
        """:meth:`rollout` of every window, the windows stepped together:
        ``(B, m, N, dim)`` or B windows -> ``(B, steps, n_out, dim)``."""
        return self._run(self._rollout, windows, False, normalized, steps)

    def _rollout(self, points: np.ndarray, counts: np.ndarray, batch: int, normalized: bool,
                 steps: Any) -> np.ndarray:
        return R.rollout(self, points, counts, batch, normalized, steps)


def load(path: str | os.PathLike | None = None, dtype: Any = "float32",
         engine: str = "auto") -> TPNet:
    """A :class:`TPNet` from a native weights file; ``path=None`` loads the shipped m = 4 model
    (:func:`tpnet_ref.weights.shipped.default_weights_path`; a one-line ``FileNotFoundError``
    when there is none). A file written by a specialised model loads specialised. ``engine``:
    see :class:`TPNet`; "auto" (the default) is the Numba head where numba is installed."""
    if np.dtype(dtype) not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
    H.resolve_engine(engine)          # the arguments' errors first, the file's below name it
    path = default_weights_path() if path is None else path
    config, params, meta = read_native(path)             # the digest checked: the file is whole
    unit_order, used = U.read(path), S.read(path)
    try:
        return TPNet(config, params, dtype, meta, engine, unit_order=unit_order, used=used)
    except ValueError as exc:         # what the file holds does not fit together
        raise ValueError(f"{path}: {exc}") from None


def init_random(config: TPNetConfig | None = None, seed: int = 0, dtype: Any = "float32",
                transform_scale: float = 0.1) -> TPNet:
    """A randomly initialised TP-Net (:func:`tpnet_ref.config.random_params`), for tests and
    benchmarks. Deterministic in ``seed``."""
    cfg = config or TPNetConfig()
    return TPNet(cfg, random_params(cfg, seed, transform_scale), dtype,
                 meta={"producer": "tpnet_ref.model.init_random", "seed": int(seed)})


__all__ = ["TPNetConfig", "TPNet", "load", "param_shapes", "init_random", "canonical_order",
           "NORM_LO", "NORM_HI"]
