"""Evaluation of TP-Net (SPEC §5 protocol), baselines, timings, and the ``demo``/``eval`` commands.

Protocol (SPEC §5; the paper's "prediction steps" = recursive predictions):

* a trajectory is the simulator's ``(600, 30, 2)`` rows; model frame ``j`` is row ``4 j``
  (:data:`FRAME_EVERY`), so a trajectory has 150 frames;
* a model with ``m`` input frames gets frames ``0 .. m-1`` (rows 0, 4, ..., 4(m-1));
* its ``h``-th recursive prediction (``h = 1, 2, ...``, the *horizon*) is compared with frame
  ``m - 1 + h``; "E_p @40" is the error of the 40th prediction (frame ``m + 39``);
* errors are Chamfer position error ``E_p`` and shape error ``E_s`` (:mod:`tpnet_ref.metrics`,
  ground truth first), in normalised coordinates, averaged over the cases; the paper's table
  uses the ``"released"`` variant, the ``"paper"`` variant is reported next to it.

Baselines computed the same way: *copy last* (every prediction is the last input frame) and
*constant velocity* (each point keeps the displacement between the last two input frames;
points are matched by their order in the input, so the baseline is only meaningful when the
input is ordered the same way in both frames).

Input orderings (the paper's real-world study): ``given`` (the simulator's particle order, what
the paper's table uses), ``ascending_x``, ``descending_y``, ``shuffle`` (an independent random
permutation of every input frame).

Everything here imports matplotlib, tqdm, torch and onnxruntime only when asked to.
"""
from __future__ import annotations

import dataclasses
import datetime as _dt
import importlib.util
import math
import os
import platform
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .sim.cases import TEST_CASES, TRAIN_POSITIONS
from .config import NORM_HI, NORM_LO
from .model import TPNet

FRAME_EVERY = 4                      # simulation rows per model frame
SIM_ROWS = 600                       # rows per trajectory (SPEC §5)
REFERENCE_DT = 1.0 / 45.0
HORIZONS = (40, 80)                  # the paper's table
ORDERINGS = ("given", "ascending_x", "descending_y", "shuffle")
VARIANTS = ("released", "paper")
#: SPEC §4: TP-Net on the 60 held-out cases, ordered input, released metric, normalised:
#: m -> (E_p @40, E_s @40, E_p @80, E_s @80)
PAPER_TABLE: dict[int, tuple[float, float, float, float]] = {
    3: (0.094, 0.007, 0.246, 0.007),
    4: (0.071, 0.007, 0.164, 0.007),
    5: (0.101, 0.008, 0.225, 0.007),
}
#: the demo's built-in scene: the first held-out test case (force, angle, x, y)
DEMO_CASE: tuple[float, float, float, float] = TEST_CASES[0]
DEMO_HORIZONS = (1, 10, 20, 40, 80, 140)


# ============================================================================ data
def normalize(x: np.ndarray) -> np.ndarray:
    return (np.asarray(x, dtype=np.float64) - NORM_LO) / (NORM_HI - NORM_LO)


def denormalize(x: np.ndarray) -> np.ndarray:
    return np.asarray(x, dtype=np.float64) * (NORM_HI - NORM_LO) + NORM_LO


def _sim_frames(job: tuple[tuple[float, float, float, float], int, dict]) -> np.ndarray:
    case, rows, kw = job
    from .sim import simulate
    return simulate(*case, rows, **kw)[::FRAME_EVERY]


def simulate_cases(cases: Any, rows: int = SIM_ROWS, *, workers: int = 0, progress: bool = False,
                   desc: str = "simulate", **scene: Any) -> np.ndarray:
    """Model frames ``(C, ceil(rows/4), N, 2)`` (world units, float64) of each case
    ``(force, angle_deg, x, y)``, simulated with :func:`tpnet_ref.sim.simulate` (rows 0, 4, ...).

    ``workers``: processes (0: automatic, one per core up to 4 when there are at least 16
    cases, else in this process). ``scene``: :class:`~tpnet_ref.sim.SceneParams` overrides.
    """
    cases = [tuple(float(v) for v in c) for c in np.asarray(cases, dtype=float).reshape(-1, 4)]
    if workers == 0:
        workers = min(4, os.cpu_count() or 1) if len(cases) >= 16 else 1
    jobs = [(c, rows, scene) for c in cases]
    if workers > 1:
        with ProcessPoolExecutor(max_workers=workers) as ex:
            it = ex.map(_sim_frames, jobs, chunksize=max(1, len(jobs) // (4 * workers)))
            out = list(_progress(it, progress, len(jobs), desc))
    else:
        out = [_sim_frames(j) for j in _progress(jobs, progress, len(jobs), desc)]
    return np.stack(out)


def _progress(it: Any, enabled: bool, total: int, desc: str) -> Any:
    if not enabled:
        return it
    try:
        from tqdm import tqdm
    except ImportError:
        return it
    return tqdm(it, total=total, desc=desc, leave=False, file=sys.stderr)


def split_protocol(frames: np.ndarray, m: int, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """Inputs ``frames[:, 0:m]`` and targets ``frames[:, m:m+horizon]`` (horizon h ↔ frame m-1+h).

    ``frames (C, F, N, 2)``; raises ``ValueError`` when the trajectories are too short."""
    frames = np.asarray(frames)
    if frames.ndim != 4:
        raise ValueError(f"frames: expected (cases, frames, N, 2), got shape {frames.shape}")
    if m < 1 or horizon < 1:
        raise ValueError(f"need m >= 1 and horizon >= 1, got m={m}, horizon={horizon}")
    if frames.shape[1] < m + horizon:
        raise ValueError(f"trajectories have {frames.shape[1]} frames: too short for m={m} "
                         f"inputs and {horizon} predictions (need {m + horizon})")
    return frames[:, :m], frames[:, m:m + horizon]


def order_points(windows: np.ndarray, ordering: str, seed: int = 0) -> np.ndarray:
    """Reorder the points of every frame of ``windows (..., N, 2)`` (a copy).

    ``given``: unchanged; ``ascending_x``: by x ascending; ``descending_y``: by y descending;
    ``shuffle``: an independent random permutation per frame (deterministic in ``seed``)."""
    w = np.array(windows, copy=True)
    if ordering == "given":
        return w
    if ordering == "ascending_x":
        idx = np.argsort(w[..., 0], axis=-1, kind="stable")
    elif ordering == "descending_y":
        idx = np.argsort(-w[..., 1], axis=-1, kind="stable")
    elif ordering == "shuffle":
        rng = np.random.default_rng(seed)
        idx = np.argsort(rng.random(w.shape[:-1]), axis=-1)
    else:
        raise ValueError(f"ordering: expected one of {', '.join(ORDERINGS)}, got {ordering!r}")
    return np.take_along_axis(w, idx[..., None], axis=-2)


# ============================================================================ predictors
def copy_last(windows: np.ndarray, steps: int) -> np.ndarray:
    """Baseline: every prediction is the last input frame. ``(B, m, N, 2)`` -> ``(B, steps, N, 2)``."""
    w = np.asarray(windows)
    return np.repeat(w[:, -1:], int(steps), axis=1)


def constant_velocity(windows: np.ndarray, steps: int) -> np.ndarray:
    """Baseline: point ``i`` moves on by ``w[-1, i] - w[-2, i]`` per frame (points matched by
    their index). ``(B, m >= 2, N, 2)`` -> ``(B, steps, N, 2)``."""
    w = np.asarray(windows, dtype=np.float64)
    if w.shape[1] < 2:
        raise ValueError("constant_velocity: needs at least 2 input frames")
    v = w[:, -1] - w[:, -2]
    k = np.arange(1, int(steps) + 1, dtype=np.float64)[None, :, None, None]
    return w[:, -1][:, None] + k * v[:, None]


def batched_rollout(model: TPNet, windows: np.ndarray, steps: int, *, normalized: bool = True,
                    batch: int = 256, progress: bool = False) -> np.ndarray:
    """``steps`` recursive predictions of every window, ``batch`` windows stepped together
    (:meth:`TPNet.rollout_batch` on each chunk, with a progress bar over the chunks).

    ``windows (B, m, N, 2)`` -> ``(B, steps, n_out, 2)`` in ``model.dtype``. Equal to
    ``model.rollout`` on each window (up to BLAS rounding).
    """
    w = np.asarray(windows)
    if w.ndim != 4 or w.shape[1] != model.config.m or w.shape[-1] != model.config.dim:
        raise ValueError(f"windows: expected (B, m={model.config.m}, N, {model.config.dim}), "
                         f"got {w.shape}")
    chunks = range(0, w.shape[0], batch)
    parts = [model.rollout_batch(w[b0:b0 + batch], steps, normalized=normalized)
             for b0 in _progress(chunks, progress, len(chunks), "rollout")]
    return np.concatenate(parts, axis=0)


def errors(truth: np.ndarray, pred: np.ndarray) -> dict[str, np.ndarray]:
    """Per case and horizon errors ``(C, H)``: keys ``Ep_released``, ``Es_released``,
    ``Ep_paper``, ``Es_paper``. ``truth``/``pred`` ``(C, H, N, 2)`` in normalised coordinates."""
    from .metrics import position_error, shape_error
    t = np.ascontiguousarray(truth, dtype=np.float64)
    p = np.ascontiguousarray(pred, dtype=np.float64)
    out = {}
    for v in VARIANTS:
        out[f"Ep_{v}"] = np.asarray(position_error(t, p, variant=v))
        out[f"Es_{v}"] = np.asarray(shape_error(t, p, variant=v))
    return out


@dataclass
class Curve:
    """Errors of one way of predicting, per case and horizon (``(C, H)`` arrays)."""

    name: str
    m: int
    ordering: str
    err: dict[str, np.ndarray]
    group: str = "test"

    def mean(self, key: str = "Ep_released") -> np.ndarray:
        return self.err[key].mean(axis=0)

    def at(self, h: int, key: str = "Ep_released") -> float:
        """Mean over cases of the error of the ``h``-th prediction (1-based)."""
        return float(self.err[key][:, h - 1].mean())


# ============================================================================ protocol
@dataclass
class ModelSpec:
    """A model under evaluation: its label (the weights file) and the network."""

    label: str
    model: TPNet


def evaluate(frames: np.ndarray, models: Sequence[ModelSpec] = (), *, ms: Sequence[int] = (4,),
             horizon: int | None = None, orderings: Sequence[str] = ORDERINGS, seed: int = 0,
             group: str = "test", progress: bool = False,
             keep: dict[str, np.ndarray] | None = None) -> list[Curve]:
    """Errors of every model and both baselines on ``frames (C, F, N, 2)`` (world units).

    ``ms``: the window lengths the baselines are computed for (each model uses its own m).
    ``horizon``: predictions per case (default: as many as the shortest window allows).
    ``keep``: if a dict, receives the predictions of ordering ``given`` (for the gallery).
    """
    frames_n = normalize(frames)
    all_m = sorted({int(x) for x in ms} | {s.model.config.m for s in models})
    if horizon is None:
        horizon = frames_n.shape[1] - max(all_m)
    curves: list[Curve] = []
    for m in all_m:
        inputs, targets = split_protocol(frames_n, m, horizon)
        for o_i, ordering in enumerate(orderings):
            win = order_points(inputs, ordering, seed + o_i)
            for name, fn in (("copy last", copy_last), ("constant velocity", constant_velocity)):
                pred = fn(win, horizon)
                curves.append(Curve(name, m, ordering, errors(targets, pred), group))
                if keep is not None and ordering == "given":
                    keep[f"{name} m={m}"] = pred
            for spec in models:
                if spec.model.config.m != m:
                    continue
                pred = batched_rollout(spec.model, win, horizon, normalized=True,
                                       progress=progress)
                curves.append(Curve(spec.label, m, ordering, errors(targets, pred), group))
                if keep is not None and ordering == "given":
                    keep[spec.label] = pred
    return curves


def generalisation_cases(per_group: int = 20, seed: int = 0) -> dict[str, np.ndarray]:
    """Scenes outside the training ranges, ``(per_group, 4)`` cases (force, angle, x, y) per group:

    * ``force > 1.6``: force in [1.8, 2.6], angle and start from the training ranges;
    * ``angle outside 180-270``: angle in [275°, 535°) mod 360 (i.e. away from the training
      sector by at least 5°), force and start from the training ranges;
    * ``start near other walls``: the centre within 2.9–8 of the left or the bottom wall
      (training starts are all in the upper-right quadrant), force and angle in range.
    Deterministic in ``seed``.
    """
    rng = np.random.default_rng(seed)
    pos = np.asarray(TRAIN_POSITIONS)

    def train_pos(n: int) -> np.ndarray:
        return pos[rng.integers(0, len(pos), n)]

    n = per_group
    f_in = np.round(rng.uniform(1.0, 1.6, (3, n)), 2)
    a_in = np.round(rng.uniform(180.0, 270.0, (3, n)), 1)
    g1 = np.column_stack([np.round(rng.uniform(1.8, 2.6, n), 2), a_in[0], train_pos(n)])
    g2 = np.column_stack([f_in[1], np.round(rng.uniform(275.0, 535.0, n), 1) % 360.0, train_pos(n)])
    near = np.round(rng.uniform(2.9, 8.0, n), 1)
    along = np.round(rng.uniform(10.0, 40.0, n), 1)
    left = rng.random(n) < 0.5
    xy = np.where(left[:, None], np.column_stack([near, along]), np.column_stack([along, near]))
    g3 = np.column_stack([f_in[2], a_in[2], xy])
    return {"force > 1.6": g1, "angle outside 180-270": g2, "start near other walls": g3}


# ============================================================================ timing
@dataclass
class TimingRow:
    name: str
    ms_batch: float | None       # ms per predicted frame, all cases stepped together
    ms_single: float | None      # ms per predicted frame, one rollout alone
    err: dict[str, np.ndarray]   # (C, H) errors against the reference trajectories
    note: str = ""
    kind: str = "model"          # "model", "baseline" or "simulator"


def _best_time(fn: Callable[[], Any], repeats: int) -> tuple[float, Any]:
    best, result = math.inf, None
    for _ in range(max(1, repeats)):
        t = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t)
    return best, result


def _onnx_peer() -> Any:
    """``bench/onnx_peer.py`` of the source tree (not part of the installed package)."""
    path = Path(__file__).resolve().parents[1] / "bench" / "onnx_peer.py"
    if not path.is_file():
        return None
    spec = importlib.util.spec_from_file_location("tpnet_onnx_peer", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    return mod


def sim_coarse(case: Sequence[float], dt_factor: int, frames: int, **scene: Any) -> np.ndarray:
    """Model frames ``0 .. frames-1`` ``(frames, N, 2)`` of the simulator run with
    ``dt = dt_factor / 45`` s over the same total time. Frames are 4/45 s apart: with
    ``dt_factor`` dividing 4 every frame is a simulated state (every ``4/dt_factor``-th row);
    otherwise (``dt_factor = 8``: a state every two frames) frames that fall between two
    states are linearly interpolated between them."""
    from .sim import simulate
    k = int(dt_factor)
    t_rows = np.arange(frames) * FRAME_EVERY / k            # fractional row of each frame
    rows = int(math.ceil(t_rows[-1])) + 1
    traj = simulate(*case, rows, dt=k * REFERENCE_DT, **scene)
    lo = np.floor(t_rows).astype(int)
    hi = np.minimum(lo + 1, rows - 1)
    a = (t_rows - lo)[:, None, None]
    return (1.0 - a) * traj[lo] + a * traj[hi]


def timing_table(frames: np.ndarray, cases: np.ndarray, models: Sequence[ModelSpec] = (), *,
                 m: int = 4, horizon: int = 80, repeats: int = 3, dt_factors=(2, 4, 8),
                 peers: bool = True, progress: bool = False) -> list[TimingRow]:
    """Error against run time, measured in one run: one row per way of obtaining the next
    ``horizon`` frames of every case (ordering ``given``).

    ``ms_batch``: best of ``repeats`` wall times for all cases together divided by
    ``cases × horizon``; ``ms_single``: the same for the first case alone divided by
    ``horizon``. The simulator rows start from the case's initial condition (the simulator
    needs the full state, which m point sets do not give) and are timed from t = 0 to the
    last predicted frame; their cost is divided by the ``horizon`` predicted frames.
    """
    frames_n = normalize(frames)
    inputs, targets = split_protocol(frames_n, m, horizon)
    C = inputs.shape[0]
    rows: list[TimingRow] = []

    def add(name: str, fn_batch: Callable[[], np.ndarray] | None,
            fn_single: Callable[[], Any] | None, note: str = "", reps: int = repeats,
            kind: str = "model") -> None:
        tb, pred = _best_time(fn_batch, reps) if fn_batch else (None, None)
        ts = _best_time(fn_single, reps)[0] if fn_single else None
        rows.append(TimingRow(name,
                              None if tb is None else 1e3 * tb / (C * horizon),
                              None if ts is None else 1e3 * ts / horizon,
                              errors(targets, pred), note, kind))

    todo = []
    for spec in models:
        if spec.model.config.m != m:
            continue
        for dt in ("float64", "float32"):
            todo.append((f"{spec.label} NumPy {dt}", spec.model.astype(dt), "numpy"))
        if peers:
            todo.append((f"{spec.label} PyTorch", spec.model.astype("float32"), "torch"))
            todo.append((f"{spec.label} onnxruntime", spec.model.astype("float32"), "onnx"))
    for name, model, kind in _progress(todo, progress, len(todo), "timing"):
        if kind == "numpy":
            model.rollout(inputs[0], 2, normalized=True)     # warm caches
            add(name, lambda mo=model: batched_rollout(mo, inputs, horizon),
                lambda mo=model: mo.rollout(inputs[0], horizon, normalized=True),
                "tpnet_ref, windows stepped together (batch) / model.rollout (single)")
        elif kind == "torch":
            if importlib.util.find_spec("torch") is None:
                rows.append(TimingRow(name, None, None, {}, "PyTorch not installed"))
                continue
            import torch
            from .torch_model import TorchTPNet
            net = TorchTPNet.from_numpy(model).eval()
            xb = torch.from_numpy(np.ascontiguousarray(inputs, dtype=np.float32))

            def run_t(x: Any, net: Any = net) -> np.ndarray:
                with torch.inference_mode():
                    return net.rollout(x, horizon).numpy()
            run_t(xb[:1, :, :, :])
            add(name, lambda: run_t(xb), lambda: run_t(xb[:1]),
                f"torch {torch.__version__}, {torch.get_num_threads()} threads, float32")
        else:
            peer = _onnx_peer()
            if peer is None or importlib.util.find_spec("onnxruntime") is None:
                rows.append(TimingRow(name, None, None, {},
                                      "onnxruntime or bench/onnx_peer.py not available"))
                continue
            sess = peer.onnx_session(model, n_points=inputs.shape[2])

            def run_o(x: np.ndarray, sess: Any = sess) -> np.ndarray:
                w = np.ascontiguousarray(x, dtype=np.float32)
                out = np.empty((w.shape[0], horizon) + w.shape[2:], np.float32)
                for s in range(horizon):
                    y = sess.run(None, {"window": w})[0]
                    out[:, s] = y
                    w = np.concatenate([w[:, 1:], y[:, None]], axis=1)
                return out
            run_o(inputs[:1])
            add(name, lambda: run_o(inputs), lambda: run_o(inputs[:1]),
                "one-step ONNX graph in a loop: recomputes the m frames' features every step")
    add("copy last input frame", lambda: copy_last(inputs, horizon),
        lambda: copy_last(inputs[:1], horizon), "baseline", kind="baseline")
    add("constant velocity", lambda: constant_velocity(inputs, horizon),
        lambda: constant_velocity(inputs[:1], horizon), "baseline, points matched by order",
        kind="baseline")
    last_frame = m - 1 + horizon
    from .sim import simulate
    simulate(*cases[0], 9)                                   # compile / load the kernel
    for k in (1, *dt_factors):
        def run_s(cs: np.ndarray, k: int = k) -> np.ndarray:
            if k == 1:
                return np.stack([simulate(*c, last_frame * FRAME_EVERY + 1)[::FRAME_EVERY]
                                 for c in cs])
            return np.stack([sim_coarse(c, k, last_frame + 1) for c in cs])

        def pred_s(k: int = k) -> np.ndarray:
            return normalize(run_s(cases, k)[:, m:m + horizon])
        steps = last_frame * FRAME_EVERY / k
        note = (f"dt = {k}/45 s, {steps:g} steps to frame {last_frame}"
                + ("; frames between two steps linearly interpolated" if FRAME_EVERY % k else ""))
        if k == 1:
            note = f"reference dt = 1/45 s ({steps:g} steps): differs from the targets only " \
                   "if they come from another simulator (--data)"
        add(f"pymunk simulator dt x{k}", pred_s, lambda k=k: run_s(cases[:1], k), note,
            reps=max(1, min(repeats, 2)), kind="simulator")
    return rows


# ============================================================================ reports
def _fmt(x: float | None, digits: int = 3) -> str:
    if x is None or not np.isfinite(x):
        return "–"
    if x != 0 and abs(x) < 10 ** -digits:
        return f"{x:.1e}"
    return f"{x:.{digits}f}"


def md_table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A GitHub markdown table (cells converted with ``str``)."""
    lines = ["| " + " | ".join(header) + " |",
             "|" + "|".join("---" for _ in header) + "|"]
    for r in rows:
        lines.append("| " + " | ".join(str(c) for c in r) + " |")
    return "\n".join(lines)


def table_horizons(n: int) -> tuple[int, ...]:
    """The paper's horizons (40, 80) that a rollout of ``n`` predictions reaches, else ``(n,)``."""
    return tuple(h for h in HORIZONS if h <= n) or (int(n),)


def _curves_h(curves: Sequence[Curve]) -> tuple[int, ...]:
    return table_horizons(min(c.err["Ep_released"].shape[1] for c in curves))


def _err_cells(c: Curve, variant: str, hs: Sequence[int]) -> list[str]:
    return [_fmt(c.at(h, f"{k}_{variant}")) for h in hs for k in ("Ep", "Es")]


def results_tables(curves: Sequence[Curve], variant: str = "released",
                   ordering: str = "given", with_paper: bool = True) -> str:
    """The paper-style table (one block per m): E_p and E_s at 40 and 80 predictions."""
    hs = _curves_h(curves)
    header = ["m", "method"] + [f"{k} @{h}" for h in hs for k in ("E_p", "E_s")]
    rows = []
    for m in sorted({c.m for c in curves}):
        if with_paper and variant == "released" and m in PAPER_TABLE and set(hs) & set(HORIZONS):
            paper = dict(zip(HORIZONS, np.reshape(PAPER_TABLE[m], (2, 2))))
            rows.append([m, "TP-Net, paper (SPEC §4)"]
                        + [_fmt(paper[h][i]) if h in paper else "–" for h in hs for i in (0, 1)])
        for c in curves:
            if c.m == m and c.ordering == ordering:
                rows.append([m, c.name] + _err_cells(c, variant, hs))
    return md_table(header, rows)


def ordering_table(curves: Sequence[Curve], variant: str = "released") -> str:
    hs = _curves_h(curves)
    header = ["m", "method", "ordering"] + [f"{k} @{h}" for h in hs for k in ("E_p", "E_s")]
    rows = [[c.m, c.name, c.ordering] + _err_cells(c, variant, hs)
            for c in sorted(curves, key=lambda c: (c.m, c.name))]
    return md_table(header, rows)


def timing_md(rows: Sequence[TimingRow], n_cases: int) -> str:
    hs = table_horizons(min((r.err["Ep_released"].shape[1] for r in rows if r.err), default=80))
    header = ["way of obtaining the next frames", "ms/frame (batch of %d)" % n_cases,
              "ms/frame (one rollout)"] + [f"{k} @{h}" for h in hs for k in ("E_p", "E_s")] \
        + ["note"]
    out = []
    for r in rows:
        cells = []
        for h in hs:
            for k in ("Ep", "Es"):
                e = r.err.get(f"{k}_released")
                cells.append(_fmt(float(e[:, h - 1].mean())) if e is not None else "–")
        out.append([r.name, _fmt(r.ms_batch, 3), _fmt(r.ms_single, 3)] + cells + [r.note])
    return md_table(header, out)


@dataclass
class Report:
    """Everything ``tpnet eval`` measured, for :func:`write_results`."""

    command: str
    n_cases: int
    horizon: int
    source: str
    curves: list[Curve]
    timing: list[TimingRow] | None = None
    timing_m: int = 4
    generalisation: dict[str, list[Curve]] = field(default_factory=dict)
    models: list[str] = field(default_factory=list)
    elapsed_s: float = 0.0
    figures: list[str] = field(default_factory=list)


def render_markdown(rep: Report) -> str:
    """The text of ``results.md``."""
    now = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    L: list[str] = ["# Evaluation results", "",
                    f"Made by `{rep.command}` ({now}, {rep.elapsed_s:.0f} s; python "
                    f"{platform.python_version()}, numpy {np.__version__}, "
                    f"{os.cpu_count()} CPU cores, {platform.machine()}{_load()}).", ""]
    if not rep.models:
        L += ["**No trained weights yet: the TP-Net rows come when the shipped weights exist** "
              "(run the same command with `--weights` for each m). The numbers below are the "
              "baselines and the simulator itself, computed with the protocol the model rows "
              "will use; they are real and reproducible.", ""]
    else:
        L += ["Weights: " + ", ".join(f"`{w}`" for w in rep.models), ""]
    L += ["## Protocol", "",
          f"{rep.n_cases} cases ({rep.source}); 600 simulator rows, model frame j = row 4j. "
          "A model with m input frames gets frames 0..m-1 and predicts recursively; its h-th "
          "prediction is compared with frame m-1+h (\"@40\" = the 40th prediction, as the "
          f"paper's \"prediction steps\"). Rollouts of {rep.horizon} predictions. Errors: "
          "Chamfer position error E_p and shape error E_s on normalised coordinates, ground "
          "truth first, averaged over the cases (SPEC §3). *Copy last*: every prediction is the "
          "last input frame. *Constant velocity*: each point moves on by its displacement "
          "between the last two input frames (points matched by index, so it needs ordered "
          "input).", ""]
    L += ["## Rollout error, ordered input (released-code metric, as the paper's table)", "",
          results_tables(rep.curves, "released"), "",
          *_scale_note(rep.curves),
          "Same, paper metric (squared distances / |P|):", "",
          results_tables(rep.curves, "paper", with_paper=False), ""]
    L += ["## Input orderings", "",
          "The paper's real-world study orders the points of each input frame in three ways; "
          "`given` is the simulator's particle order. TP-Net sorts every frame canonically, so "
          "its four rows must be identical; the constant-velocity baseline matches points by "
          "index and breaks when the order changes between frames.", "",
          ordering_table(rep.curves), ""]
    if rep.timing is not None:
        L += ["## Error against run time", "",
              f"One run, {rep.n_cases} cases, m = {rep.timing_m}, ordering `given`; ms per "
              "predicted frame (wall time, best of the repeats; batch: all cases together). "
              "Errors: released metric.", "",
              timing_md(rep.timing, rep.n_cases), "", *_timing_paragraph(rep), ""]
    if rep.generalisation:
        L += ["## Generalisation (outside the training ranges)", "",
              "Cases generated on the fly by `generalisation_cases()` (seed 0): forces above "
              "1.6, angles outside 180–270°, starts near the left/bottom walls (training starts "
              "are all in the upper-right quadrant).", ""]
        for g, cs in rep.generalisation.items():
            L += [f"### {g}", "", results_tables(cs, "released", with_paper=False), ""]
    if rep.figures:
        L += ["## Figures", ""] + [f"![{Path(f).stem}]({Path(f).name})" for f in rep.figures] + [""]
    return "\n".join(L)


def _load() -> str:
    """The machine's load average when the report is written (timings depend on it)."""
    try:
        return f", load average {os.getloadavg()[0]:.1f}"
    except (AttributeError, OSError):
        return ""


def rest_ring(phases: float | np.ndarray = 0.0, n: int = 30, radius: float = 2.0) -> np.ndarray:
    """The body's undeformed ring (SPEC §5: particle ``i`` at angle ``i·2π/n`` from +y towards
    +x, ``radius`` world units) in normalised units about the origin, each particle's angle
    advanced by ``phases`` (radians, scalar or ``(P,)``): ``(n, 2)`` or ``(P, n, 2)``."""
    r = radius / (NORM_HI - NORM_LO)
    a = 2 * np.pi * np.arange(n) / n + np.asarray(phases, dtype=np.float64)[..., None]
    return np.stack([r * np.sin(a), r * np.cos(a)], axis=-1)


def ring_phase_floor(n: int = 30, radius: float = 2.0, samples: int = 720) -> float:
    """Released shape error E_s between the body's rest ring (``n`` particles, ``radius`` world
    units, normalised like the data) and the same ring rotated by a phase drawn uniformly from
    one particle spacing (``samples`` evenly spaced phases, averaged). A prediction that has the
    exact shape but not the particles' rotation phase scores this on average: copying the last
    frame scores about this once the body has turned, so beating it on E_s needs the phase or
    a nearly exact outline (``bench/shape_floor.py``)."""
    from .metrics import shape_error
    turned = rest_ring((np.arange(samples) + 0.5) / samples * (2 * np.pi / n), n, radius)
    return float(np.mean(shape_error(np.broadcast_to(rest_ring(0.0, n, radius), turned.shape),
                                     turned, variant="released")))


def spacing_stats(sets: np.ndarray) -> dict[str, float]:
    """How evenly a set's points cover the body, in world units, averaged over ``sets (K, N, 2)``
    (normalised coordinates): ``nn_mean`` the mean distance from a point to its nearest other
    point, ``nn_min`` the smallest such distance in a set, ``radius_std`` the spread of the
    points' distances from the set's centroid. The body's rest ring has 0.418 / 0.418 / 0.
    Points clumped in pairs (two outputs on one particle, a gap next to it) show as a small
    ``nn_min``: the Chamfer distance barely penalises it, the shape error E_s does."""
    x = np.asarray(sets, dtype=np.float64)
    if x.ndim != 3 or x.shape[1] < 2:
        raise ValueError(f"sets: expected (K, N >= 2, dim), got shape {x.shape}")
    scale = NORM_HI - NORM_LO
    d = np.linalg.norm(x[:, :, None] - x[:, None, :], axis=-1)
    d[:, np.arange(x.shape[1]), np.arange(x.shape[1])] = np.inf
    nn = d.min(axis=2)
    r = np.linalg.norm(x - x.mean(axis=1, keepdims=True), axis=-1)
    return {"nn_mean": float(nn.mean() * scale), "nn_min": float(nn.min(axis=1).mean() * scale),
            "radius_std": float(r.std(axis=1).mean() * scale)}


def resample_outline(sets: np.ndarray, offset: float | np.ndarray = 0.0) -> np.ndarray:
    """Each set's outline, resampled with its points evenly spaced along it.

    The outline is the closed polygon through the points taken in angular order about the
    centroid; point ``j`` of the result sits at arc length ``(j + offset) / N`` of its perimeter,
    starting from the point of smallest angle. ``sets (K, N, 2)``; ``offset`` a scalar or
    ``(K,)`` array, in spacings. Returns ``(K, N, 2)`` float64 (same units as ``sets``). Used to
    tell an outline's error from its spacing's: clumped points and the same outline evenly
    spaced have the same polygon."""
    x = np.asarray(sets, dtype=np.float64)
    if x.ndim != 3 or x.shape[-1] != 2 or x.shape[1] < 3:
        raise ValueError(f"sets: expected (K, N >= 3, 2), got shape {x.shape}")
    k, n = x.shape[:2]
    off = np.broadcast_to(np.asarray(offset, dtype=np.float64), (k,))
    d = x - x.mean(axis=1, keepdims=True)
    order = np.argsort(np.arctan2(d[..., 1], d[..., 0]), axis=1, kind="stable")
    q = np.take_along_axis(x, order[..., None], axis=1)
    q = np.concatenate([q, q[:, :1]], axis=1)                      # close the polygon
    s = np.concatenate([np.zeros((k, 1)),
                        np.cumsum(np.linalg.norm(np.diff(q, axis=1), axis=-1), axis=1)], axis=1)
    out = np.empty_like(x)
    for i in range(k):
        t = (np.arange(n) + off[i]) % n / n * s[i, -1]
        out[i, :, 0] = np.interp(t, s[i], q[i, :, 0])
        out[i, :, 1] = np.interp(t, s[i], q[i, :, 1])
    return out


def radial_fit(sets: np.ndarray, modes: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Each set's distance from its centroid as a Fourier series in the angle about it.

    Least-squares fit of ``r(θ) = a_0 + Σ_{k=1..modes} (a_k cos kθ + b_k sin kθ)`` to the points
    of each set. ``sets (K, N, 2)`` -> ``(coef (K, 1 + 2·modes), residual (K, N))``, coefficients
    ordered ``a_0, a_1, b_1, a_2, ...`` and the residual in the units of ``sets``. ``modes = 0``
    fits a circle (``a_0`` the mean radius); mode 2 is the ring's squash. The residual's spread
    tells a ragged outline (point to point) from a smooth deformation."""
    x = np.asarray(sets, dtype=np.float64)
    if x.ndim != 3 or x.shape[-1] != 2 or x.shape[1] < 1 + 2 * modes or modes < 0:
        raise ValueError(f"sets: expected (K, N >= {1 + 2 * max(modes, 0)}, 2) and modes >= 0, "
                         f"got shape {x.shape}, modes {modes}")
    d = x - x.mean(axis=1, keepdims=True)
    th = np.arctan2(d[..., 1], d[..., 0])
    r = np.linalg.norm(d, axis=-1)
    a = _radial_basis(th, modes)                                    # (K, N, 1 + 2·modes)
    coef = np.stack([np.linalg.lstsq(a[i], r[i], rcond=None)[0] for i in range(len(x))])
    return coef, r - np.einsum("knj,kj->kn", a, coef)


def _radial_basis(th: np.ndarray, modes: int) -> np.ndarray:
    cols = [np.ones_like(th)]
    for k in range(1, modes + 1):
        cols += [np.cos(k * th), np.sin(k * th)]
    return np.stack(cols, axis=-1)


def radial_outline(sets: np.ndarray, modes: int = 0, phase: float | np.ndarray = 0.0) -> np.ndarray:
    """Each set replaced by its smooth outline (:func:`radial_fit` with ``modes``) sampled at
    ``N`` evenly spaced angles ``phase + 2πj/N`` (radians, scalar or ``(K,)``) about the same
    centroid: ``(K, N, 2)`` float64. ``modes = 0`` gives the circle of the set's mean radius,
    the best phase-blind guess at a ring whose vibration is unknown (``bench/shape_floor.py``)."""
    x = np.asarray(sets, dtype=np.float64)
    coef, _ = radial_fit(x, modes)
    k, n = x.shape[:2]
    th = np.broadcast_to(np.asarray(phase, dtype=np.float64), (k,))[:, None] \
        + 2 * np.pi * np.arange(n) / n
    r = np.einsum("knj,kj->kn", _radial_basis(th, modes), coef)
    return x.mean(axis=1, keepdims=True) + np.stack([r * np.cos(th), r * np.sin(th)], axis=-1)


def ring_rotation(frames: np.ndarray, n: int = 30) -> np.ndarray:
    """How far the body has turned since its start, in degrees (counter-clockwise positive):
    the circular mean, over the particles, of each particle's angle about the centroid minus its
    start angle (SPEC §5: particle ``i`` starts at ``i·360°/n`` from +y towards +x).
    ``frames (..., n, 2)`` in the simulator's particle order -> ``(...)``."""
    x = np.asarray(frames, dtype=np.float64)
    if x.shape[-2:] != (n, 2):
        raise ValueError(f"frames: expected (..., {n}, 2) in particle order, got {x.shape}")
    d = x - x.mean(axis=-2, keepdims=True)
    ang = np.arctan2(d[..., 0], d[..., 1])            # from +y towards +x, like the start ring
    start = 2 * np.pi * np.arange(n) / n
    return -np.degrees(np.angle(np.exp(1j * (ang - start)).mean(axis=-1)))


def _scale_note(curves: Sequence[Curve]) -> list[str]:
    """What the released-metric numbers mean in distances (from the copy-last row)."""
    cands = [c for c in curves if c.name == "copy last" and c.ordering == "given"
             and c.err["Ep_released"].shape[1] >= HORIZONS[0]]
    c = next((c for c in cands if c.m == 4), cands[0] if cands else None)
    if c is None:
        return []
    n = 30
    scale = NORM_HI - NORM_LO
    h = HORIZONS[0]
    e = c.at(h)
    lines = [f"Scale: the released metric sums the nearest-point distances of both sets "
             f"(2 × {n} terms, no division), so E_p / {2 * n} is the mean nearest-point distance "
             f"in normalised units (× {scale:.2f} for world units). Copy last (m={c.m}) @{h}: "
             f"E_p {e:.3f}, i.e. {e / (2 * n):.3f} = {e / (2 * n) * scale:.1f} world units."]
    if c.m in PAPER_TABLE:
        p = PAPER_TABLE[c.m][0]
        lines[0] += (f" The paper's TP-Net E_p {p} @{h} would be {p / (2 * n):.4f} "
                     f"= {p / (2 * n) * scale:.3f} world units after {h} recursive predictions, "
                     f"{e / p:.0f}× below copying the last frame; compare the model rows with "
                     "care (a per-point mean instead of a sum would divide by "
                     f"{n} or {2 * n}).")
    lines += ["", f"Shape error floor: the body's rest ring (30 particles, radius 2) against the "
              f"same ring turned by a random fraction of one particle spacing scores E_s "
              f"{ring_phase_floor():.3f} (`evaluation.ring_phase_floor()`). Copy last sits near "
              f"it once the body has rolled ({_fmt(c.at(h, 'Es_released'))} @{h}). Beating it "
              f"needs either where each particle has turned to (positions to a fraction of the "
              f"0.42 world-unit particle spacing) or evenly spaced points on a nearly exact "
              f"outline (`bench/shape_floor.py` scores such references)."]
    return lines + [""]


def _timing_paragraph(rep: Report) -> list[str]:
    t = {r.name: r for r in rep.timing or []}
    sim = t.get("pymunk simulator dt x1")
    cv = t.get("constant velocity")
    lines = ["What it means for a user choosing between them: the simulator is the ground truth "
             "when the full state (initial velocity, spring constants) is known"]
    if sim and sim.ms_single is not None:
        lines[0] += f" and costs about {sim.ms_single:.2f} ms per frame on this machine"
    lines[0] += (". Coarser time steps are cheaper (not proportionally: each step has a fixed "
                 "cost) but their error grows quickly with dt, because the discretisation of "
                 "the springs and of the wall contacts changes when and how the body bounces, "
                 "and Box2D's per-step translation clamp (2 units per step) caps the speed at "
                 "2/dt (22.5 units/s at dt x4, where the fastest test bodies start at 22.6; "
                 "11.25 at dt x8). The baselines cost nothing but are only useful for a few "
                 "frames")
    if cv:
        lines[0] += (f" (constant velocity reaches E_p {_fmt(cv.err['Ep_released'][:, 39].mean())}"
                     f" at 40 predictions)" if cv.err['Ep_released'].shape[1] >= 40 else "")
    lines[0] += (". TP-Net needs only m unordered point sets (no velocities, no correspondence, "
                 "no physical parameters), which is what a camera gives; its rows show what that "
                 "costs per frame and in accuracy.")
    net = [r for r in rep.timing or [] if r.err and r.kind == "model" and r.ms_single is not None]
    if net:
        fs = min(net, key=lambda r: r.ms_single)
        fb = min(net, key=lambda r: r.ms_batch if r.ms_batch is not None else math.inf)
        lines[0] += (f" Fastest here for one rollout: {fs.name} ({fs.ms_single:.2f} ms/frame); "
                     f"for many rollouts stepped together: {fb.name} ({fb.ms_batch:.2f} ms/frame "
                     "per rollout). NumPy float64 is for checking; its errors and float32's "
                     "should agree to the digits shown.")
    if not net:
        lines.append("")
        lines.append("(TP-Net rows: pending the shipped weights.)")
    return lines


def write_results(rep: Report, out_dir: str | os.PathLike, *, plots: bool = True,
                  gallery: dict[str, Any] | None = None) -> Path:
    """Write ``results.md`` (and the PNG figures when ``plots`` and matplotlib is installed)
    into ``out_dir``; returns the markdown's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rep.figures = []
    if plots and importlib.util.find_spec("matplotlib") is not None:
        rep.figures.append(str(plot_orderings(rep.curves, out / "eval_error_vs_frame.png")))
        if gallery:
            rep.figures.append(str(plot_gallery(out / "eval_gallery.png", **gallery)))
        if rep.timing:
            rep.figures.append(str(plot_timing(rep.timing, out / "eval_error_vs_time.png")))
        if rep.generalisation:
            rep.figures.append(str(plot_groups(rep.generalisation,
                                               out / "eval_generalisation.png")))
    csv = write_curves_csv([*rep.curves, *(c for cs in rep.generalisation.values() for c in cs)],
                           out / "eval_curves.csv")
    path = out / "results.md"
    path.write_text(render_markdown(rep) + f"\nPer-step means of every curve: [{csv.name}]"
                    f"({csv.name}).\n")
    return path


def write_curves_csv(curves: Sequence[Curve], path: str | os.PathLike) -> Path:
    """Mean over cases of every error at every prediction step, one row per (curve, step)."""
    keys = [f"{k}_{v}" for v in VARIANTS for k in ("Ep", "Es")]
    lines = ["group,method,m,ordering,step,frame," + ",".join(keys)]
    for c in curves:
        means = [c.mean(k) for k in keys]
        for i in range(len(means[0])):
            lines.append(f"{c.group},{c.name},{c.m},{c.ordering},{i + 1},{c.m + i},"
                         + ",".join(f"{mu[i]:.4g}" for mu in means))
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)


# ============================================================================ plots
def _plt() -> Any:
    try:
        import matplotlib
    except ImportError as exc:
        raise ImportError("plots need matplotlib: pip install 'tpnet-ref[plot]'") from exc
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_orderings(curves: Sequence[Curve], path: str | os.PathLike) -> Path:
    """Error vs prediction step, one column per input ordering (E_p top, E_s bottom)."""
    plt = _plt()
    orderings = [o for o in ORDERINGS if any(c.ordering == o for c in curves)]
    fig, axes = plt.subplots(2, len(orderings), figsize=(4 * len(orderings), 6.5),
                             sharex=True, sharey="row", squeeze=False)
    names = sorted({(c.m, c.name) for c in curves})
    colors = {n: plt.cm.tab10(i % 10) for i, n in enumerate(names)}
    for j, o in enumerate(orderings):
        for c in curves:
            if c.ordering != o:
                continue
            h = np.arange(1, c.err["Ep_released"].shape[1] + 1)
            for i, k in enumerate(("Ep_released", "Es_released")):
                axes[i, j].plot(h, c.mean(k), color=colors[(c.m, c.name)], lw=1.2,
                                label=f"{c.name} (m={c.m})")
        axes[0, j].set_title(o)
        axes[1, j].set_xlabel("prediction step h")
        for i in range(2):
            axes[i, j].set_yscale("log")
            axes[i, j].grid(True, which="both", alpha=0.3)
    axes[0, 0].set_ylabel("E_p (released)")
    axes[1, 0].set_ylabel("E_s (released)")
    axes[0, -1].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)


def plot_groups(groups: dict[str, Sequence[Curve]], path: str | os.PathLike) -> Path:
    """Generalisation: E_p vs prediction step, one panel per group of scenes (ordering given)."""
    plt = _plt()
    fig, axes = plt.subplots(1, len(groups), figsize=(4 * len(groups), 3.5), squeeze=False)
    for j, (g, cs) in enumerate(groups.items()):
        ax = axes[0, j]
        for c in cs:
            if c.ordering == "given":
                ax.plot(np.arange(1, c.err["Ep_released"].shape[1] + 1), c.mean(), lw=1.2,
                        label=f"{c.name} (m={c.m})")
        ax.set_title(g)
        ax.set_yscale("log")
        ax.set_xlabel("prediction step h")
        ax.grid(True, which="both", alpha=0.3)
    axes[0, 0].set_ylabel("E_p (released)")
    axes[0, -1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)


def plot_timing(rows: Sequence[TimingRow], path: str | os.PathLike) -> Path:
    """E_p at 40 (hollow) and 80 (filled) predictions against ms per predicted frame."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 5))
    for i, r in enumerate(rows):
        ms = r.ms_single if r.ms_single is not None else r.ms_batch
        e = r.err.get("Ep_released")
        if ms is None or e is None:
            continue
        c = plt.cm.tab10(i % 10)
        if not e.any():        # the reference itself: no error to draw on a log axis
            ax.axvline(ms, color=c, ls="--", lw=1, label=f"{r.name} (reference, error 0)")
            continue
        hs = table_horizons(e.shape[1])
        pts = [(h, float(e[:, h - 1].mean())) for h in hs]
        for h, v in pts:
            ax.scatter(ms, max(v, 1e-6), color=c, s=40,
                       facecolors="none" if h == hs[0] and len(hs) > 1 else c,
                       label=r.name if h == pts[-1][0] else None)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("ms per predicted frame (one rollout)")
    ax.set_ylabel("E_p (released), hollow @%d, filled @%d" % HORIZONS)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)


def plot_gallery(path: str | os.PathLike, truth: np.ndarray, preds: dict[str, np.ndarray],
                 horizons: Sequence[int], case_labels: Sequence[str] | None = None,
                 m: int | None = None) -> Path:
    """Predicted vs true shapes: one row per case, one column per prediction step.

    ``truth (C, H, N, 2)`` and each ``preds[name] (C, H, N, 2)`` in world units."""
    plt = _plt()
    C = truth.shape[0]
    hs = [h for h in horizons if h <= truth.shape[1]]
    fig, axes = plt.subplots(C, len(hs), figsize=(2.6 * len(hs), 2.6 * C), squeeze=False)
    for i in range(C):
        for j, h in enumerate(hs):
            ax = axes[i, j]
            t = truth[i, h - 1]
            sets = [t] + [p[i, h - 1] for p in preds.values()]
            allp = np.clip(np.concatenate(sets), -1.0, 46.0)   # far-off predictions: at the edge
            c = 0.5 * (allp.min(0) + allp.max(0))
            r = max(3.0, 0.55 * float((allp.max(0) - allp.min(0)).max()))
            ax.scatter(t[:, 0], t[:, 1], s=8, color="k", label="simulator")
            for k, (name, p) in enumerate(preds.items()):
                q = p[i, h - 1]
                col = plt.cm.tab10((k + 1) % 10)
                ax.scatter(q[:, 0], q[:, 1], s=8, marker="x", color=col, label=name)
                cq = q.mean(0)
                if (cq < -1.0).any() or (cq > 46.0).any():      # left the box: say where
                    ax.text(0.03, 0.97 - 0.08 * k, f"{name}: off panel at ({cq[0]:.0f}, "
                            f"{cq[1]:.0f})", transform=ax.transAxes, fontsize=6, color=col,
                            va="top")
            for w in (1.0, 44.0):   # walls (inner faces)
                ax.axvline(w, color="0.4", lw=2)
                ax.axhline(w, color="0.4", lw=2)
            ax.set_xlim(c[0] - r, c[0] + r)
            ax.set_ylim(c[1] - r, c[1] + r)
            ax.set_aspect("equal")
            ax.tick_params(labelsize=6)
            if i == 0:
                ax.set_title(f"prediction {h}" + (f" (frame {m - 1 + h})" if m else ""),
                             fontsize=8)
            if j == 0 and case_labels is not None:
                ax.set_ylabel(case_labels[i], fontsize=7)
    axes[0, -1].legend(fontsize=6, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)


# ============================================================================ demo
def demo(weights: str | None = None, *, case: Sequence[float] = DEMO_CASE, steps: int | None = None,
         horizons: Sequence[int] = DEMO_HORIZONS, png: str | None = "tpnet_demo.png",
         seed: int = 0, dtype: str = "float32", out: Any = None) -> dict[str, Any]:
    """Simulate ``case``, give the model its first m frames with the points of each frame
    shuffled, roll out, print errors against the simulator at ``horizons`` and write a PNG.

    Raises ``FileNotFoundError`` (from :func:`tpnet_ref.load`) when there are no weights.
    Returns the numbers printed (errors per horizon, timings)."""
    from .weights import load
    from .sim import simulate
    stream = out or sys.stdout

    def say(s: str = "") -> None:
        print(s, file=stream)

    t0 = time.perf_counter()
    model = load(weights, dtype=dtype)
    m = model.config.m
    t_load = time.perf_counter() - t0
    t = time.perf_counter()
    frames = simulate(*case, SIM_ROWS)[::FRAME_EVERY]
    t_sim = time.perf_counter() - t
    H = int(steps) if steps is not None else frames.shape[0] - m
    inputs, targets = split_protocol(frames[None], m, H)
    window = order_points(inputs, "shuffle", seed)[0]
    t = time.perf_counter()
    pred = model.rollout(window, H)                         # world units
    t_roll = time.perf_counter() - t
    err = errors(normalize(targets), normalize(pred[None]))
    f, a, x, y = case
    say(f"tpnet demo: {model!r}")
    say(f"scene: force {f:g}, angle {a:g} deg, start ({x:g}, {y:g}) (held-out test case); "
        f"simulated {SIM_ROWS} steps in {t_sim * 1e3:.0f} ms")
    say(f"input: frames 0..{m - 1}, the 30 points of each frame shuffled independently; "
        f"{H} recursive predictions in {t_roll * 1e3:.0f} ms ({t_roll * 1e3 / H:.2f} ms/frame, "
        f"{model.dtype.name})")
    say("errors against the simulator (normalised coordinates; released-code metric as in the "
        "paper's table, paper metric in brackets):")
    say(f"  {'step':>5} {'frame':>6} {'E_p':>8} {'E_s':>8}   {'[E_p':>9} {'E_s]':>9}")
    shown = [h for h in horizons if 1 <= h <= H]
    rows = {}
    for h in shown:
        r = {k: float(v[0, h - 1]) for k, v in err.items()}
        rows[h] = r
        say(f"  {h:>5} {m - 1 + h:>6} {r['Ep_released']:8.4f} {r['Es_released']:8.4f}   "
            f"{r['Ep_paper']:9.2e} {r['Es_paper']:9.2e}")
    wrote = None
    if png:
        if importlib.util.find_spec("matplotlib") is None:
            print("tpnet demo: matplotlib is not installed (pip install 'tpnet-ref[plot]'); "
                  "no PNG written", file=sys.stderr)
        else:
            gh = [h for h in (1, 20, 40, 80, H) if h <= H]
            gh = sorted(set(gh))
            plot_gallery(png, targets, {f"TP-Net (m={m})": pred[None]}, gh,
                         [f"F={f:g}, {a:g} deg"], m=m)
            wrote = png
            say(f"wrote {png} (simulator vs prediction at steps {', '.join(map(str, gh))})")
    total = time.perf_counter() - t0
    say(f"total {total:.1f} s (load {t_load:.2f} s)")
    return {"errors": rows, "t_sim": t_sim, "t_rollout": t_roll, "png": wrote, "m": m,
            "steps": H, "total": total}


# ============================================================================ CLI
def add_cli(sub: Any) -> None:
    p = sub.add_parser("demo", help="simulate a scene, predict it from shuffled frames, "
                                    "print errors and write a PNG")
    p.add_argument("--weights", default=None, help="native weights file (default: shipped m=4)")
    p.add_argument("--case", type=float, nargs=4, default=list(DEMO_CASE),
                   metavar=("FORCE", "ANGLE", "X", "Y"), help="scene (default: test case 1)")
    p.add_argument("--steps", type=int, default=None,
                   help="predictions (default: to the end of the 600-step trajectory)")
    p.add_argument("--horizons", type=int, nargs="+", default=list(DEMO_HORIZONS),
                   help="prediction steps at which errors are printed")
    p.add_argument("-o", "--output", default="tpnet_demo.png", help="PNG to write")
    p.add_argument("--no-png", action="store_true", help="do not write a PNG")
    p.add_argument("--seed", type=int, default=0, help="point shuffling seed")
    p.add_argument("--dtype", default="float32", choices=("float32", "float64"))
    p.set_defaults(func=_cli_demo)

    p = sub.add_parser("eval", help="SPEC §5 evaluation on the 60 held-out cases: tables, "
                                    "orderings, timings, plots -> results.md")
    p.add_argument("--weights", action="append", default=[],
                   help="native weights file; repeat for several models (m = 3/4/5)")
    p.add_argument("--baselines-only", action="store_true",
                   help="no model: baselines and simulator rows only")
    p.add_argument("--m", type=int, nargs="+", default=None,
                   help="window lengths for the baselines (default: the models' m, else 4)")
    p.add_argument("--data", default=None,
                   help="HDF5 dataset (tpnet data generate): use its /test trajectories "
                        "instead of simulating")
    p.add_argument("--cases", type=int, default=None, help="only the first N cases")
    p.add_argument("--horizon", type=int, default=None,
                   help="predictions per case (default: to the end of the trajectories)")
    p.add_argument("--orderings", nargs="+", default=list(ORDERINGS), choices=ORDERINGS)
    p.add_argument("--no-timing", action="store_true", help="skip the error-vs-time table")
    p.add_argument("--no-peers", action="store_true", help="timing without PyTorch/onnxruntime")
    p.add_argument("--repeats", type=int, default=3, help="timing repeats (best is kept)")
    p.add_argument("--generalisation", action="store_true",
                   help="also scenes outside the training ranges")
    p.add_argument("--gen-cases", type=int, default=20, help="generalisation cases per group")
    p.add_argument("--workers", type=int, default=0, help="simulation processes (0: auto)")
    p.add_argument("--seed", type=int, default=0, help="shuffle seed")
    p.add_argument("--out", default="docs", help="directory for results.md and the PNGs")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_cli_eval)


def _cli_demo(args: Any) -> int:
    demo(args.weights, case=args.case, steps=args.steps, horizons=args.horizons,
         png=None if args.no_png else args.output, seed=args.seed, dtype=args.dtype)
    return 0


def _command_line(args: Any = None) -> str:
    """The command that made the report: this process's ``tpnet eval ...`` command line, or
    (when ``main`` was called from Python) the same rebuilt from the parsed arguments."""
    if sys.argv[1:2] == ["eval"] or args is None:
        return " ".join(["tpnet"] + sys.argv[1:])
    parts = ["tpnet eval"] + [f"--weights {w}" for w in args.weights]
    for flag, value in (("--baselines-only", args.baselines_only), ("--data", args.data),
                        ("--cases", args.cases), ("--horizon", args.horizon),
                        ("--generalisation", args.generalisation), ("--out", args.out)):
        if value is True:
            parts.append(flag)
        elif value not in (None, False):
            parts.append(f"{flag} {value}")
    if args.m:
        parts.append("--m " + " ".join(map(str, args.m)))
    return " ".join(parts)


def run_eval(args: Any, command: str | None = None, log: Any = None) -> Path:
    """``tpnet eval`` with parsed ``args``; returns the path of ``results.md``."""
    from .weights import load
    log = log or sys.stderr
    t_start = time.perf_counter()
    progress = not args.quiet
    if args.baselines_only and args.weights:
        raise ValueError("--baselines-only and --weights exclude each other")
    if not args.baselines_only and not args.weights:
        raise ValueError("give --weights PATH (repeatable) or --baselines-only")
    if args.cases is not None and args.cases < 1:
        raise ValueError(f"--cases: must be >= 1, got {args.cases}")
    names = [Path(w).name for w in args.weights]
    models = [ModelSpec(f"TP-Net {n if names.count(n) == 1 else w}", load(w, dtype="float32"))
              for n, w in zip(names, args.weights)]
    ms = args.m or ([s.model.config.m for s in models] or [4])
    if args.data:
        from .data import load_trajectories
        frames, params = load_trajectories(args.data, "test")
        frames = frames.astype(np.float64)
        cases = np.asarray(params, dtype=float)
        source = f"test split of {args.data}"
    else:
        cases = np.asarray(TEST_CASES, dtype=float)
        frames = None
        source = "held-out test cases simulated on the fly with tpnet_ref.sim"
    if args.cases is not None:
        cases = cases[: args.cases]
        frames = None if frames is None else frames[: args.cases]
    if args.horizon is not None and args.horizon < 1:
        raise ValueError(f"--horizon: must be >= 1, got {args.horizon}")
    # rows so that the longest window plus the horizon fits (model frame j = row 4 j)
    need = max(list(ms) + [s.model.config.m for s in models]) + (args.horizon or 0)
    rows = SIM_ROWS if args.horizon is None else FRAME_EVERY * (need - 1) + 1
    if frames is None:
        print(f"simulating {len(cases)} cases ...", file=log)
        frames = simulate_cases(cases, rows, workers=args.workers, progress=progress)
    keep: dict[str, np.ndarray] = {}
    print("rollouts and errors ...", file=log)
    curves = evaluate(frames, models, ms=ms, horizon=args.horizon, orderings=args.orderings,
                      seed=args.seed, progress=progress, keep=keep)
    horizon = curves[0].err["Ep_released"].shape[1]
    timing = None
    t_m = models[0].model.config.m if models else (4 if 4 in ms else ms[0])
    if not args.no_timing:
        print("timing ...", file=log)
        timing = timing_table(frames, cases, models, m=t_m, horizon=min(80, horizon),
                              repeats=args.repeats, peers=not args.no_peers, progress=progress)
    gen: dict[str, list[Curve]] = {}
    if args.generalisation:
        for g, gc in generalisation_cases(args.gen_cases).items():
            print(f"generalisation: {g} ...", file=log)
            gf = simulate_cases(gc, rows, workers=args.workers, progress=progress, desc=g)
            gen[g] = evaluate(gf, models, ms=ms, horizon=args.horizon, orderings=("given",),
                              seed=args.seed, group=g, progress=progress)
    # gallery: the first model (else the constant-velocity baseline) on 4 cases
    m0 = t_m
    sel = np.linspace(0, len(cases) - 1, min(4, len(cases))).astype(int)
    _, targets = split_protocol(frames, m0, horizon)
    gal_names = [s.label for s in models if s.model.config.m == m0][:1] or \
        [f"constant velocity m={m0}"]
    gallery = {"truth": targets[sel],
               "preds": {n: denormalize(keep[n][sel]) for n in gal_names},
               "horizons": sorted({h for h in (1, 20, 40, 80, horizon) if h <= horizon}),
               "case_labels": [f"F={c[0]:g} {c[1]:g}° ({c[2]:g},{c[3]:g})" for c in cases[sel]],
               "m": m0}
    rep = Report(command=command or _command_line(args), n_cases=len(cases), horizon=horizon,
                 source=source, curves=curves, timing=timing, timing_m=t_m, generalisation=gen,
                 models=list(args.weights), elapsed_s=time.perf_counter() - t_start)
    path = write_results(rep, args.out, plots=not args.no_plots, gallery=gallery)
    return path


def _cli_eval(args: Any) -> int:
    path = run_eval(args)
    print(f"wrote {path}")
    print(Path(path).read_text().split("## Input orderings")[0].split("## Rollout error")[-1])
    return 0


__all__ = ["simulate_cases", "split_protocol", "order_points", "copy_last", "constant_velocity",
           "batched_rollout", "errors", "evaluate", "generalisation_cases", "timing_table",
           "sim_coarse", "results_tables", "ordering_table", "md_table", "render_markdown",
           "write_results", "demo", "Curve", "Report", "TimingRow", "ModelSpec", "PAPER_TABLE",
           "HORIZONS", "ORDERINGS", "FRAME_EVERY", "ring_phase_floor", "spacing_stats",
           "rest_ring", "resample_outline", "ring_rotation", "radial_fit", "radial_outline"]
