"""Error against run time: every way of obtaining the next frames, timed and scored in one run.

Rows: the network in NumPy float64/float32, optionally float32 scene-specialised (calibrated on
training-grid trajectories, :mod:`tpnet_ref.engines.specialised`), with the ``crosscheck`` extra PyTorch and
onnxruntime, the two baselines, and the simulator itself at its reference step and coarser ones.
"""
from __future__ import annotations

import importlib.util
import math
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import normalize
from ..sim.protocol import FRAME_EVERY, REFERENCE_DT, constant_velocity, copy_last, split_protocol
from .run import ModelSpec, batched_rollout, errors, progress_bar

#: training-grid trajectories the scene-specialised row is calibrated on (shipped m = 4 model:
#: 6,768 windows, about 20 s on 2 cores)
CALIBRATION_TRAJECTORIES = 36
#: frames of the model's own rollout from each calibration trajectory's first m frames
CALIBRATION_ROLLOUT = 40


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


def sim_coarse(case: Sequence[float], dt_factor: int, frames: int, **scene: Any) -> np.ndarray:
    """Model frames ``0 .. frames-1`` ``(frames, N, 2)`` of the simulator run with
    ``dt = dt_factor / 45`` s over the same total time. Frames are 4/45 s apart: with
    ``dt_factor`` dividing 4 every frame is a simulated state (every ``4/dt_factor``-th row);
    otherwise (``dt_factor = 8``: a state every two frames) frames that fall between two
    states are linearly interpolated between them."""
    from ..sim import simulate
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
                 peers: bool = True, specialized: bool = False,
                 calibration_trajectories: int = CALIBRATION_TRAJECTORIES,
                 progress: bool = False) -> list[TimingRow]:
    """Error against run time, measured in one run: one row per way of obtaining the next
    ``horizon`` frames of every case (ordering ``given``).

    ``ms_batch``: best of ``repeats`` wall times for all cases together divided by
    ``cases × horizon``; ``ms_single``: the same for the first case alone divided by
    ``horizon``. The simulator rows start from the case's initial condition (the simulator
    needs the full state, which m point sets do not give) and are timed from t = 0 to the
    last predicted frame; their cost is divided by the ``horizon`` predicted frames.

    ``specialized``: also a row "<label> NumPy float32, scene-specialised" for each model: the
    float32 network specialised (:meth:`TPNet.specialize`) on the windows of
    ``calibration_trajectories`` simulated training-grid trajectories and the model's own
    rollouts from them (:func:`tpnet_ref.sim.dataset.calibration_windows`; never the test cases),
    calibrated before and outside the timed part, timed like the float32 row. Its note gives the
    calibration, the fraction of the timed windows that fell back to the full network and the
    largest difference from the float32 row's predictions.
    """
    frames_n = normalize(np.asarray(frames, dtype=np.float64))
    t = _Timer(*split_protocol(frames_n, m, horizon), horizon, repeats)
    preds: dict[str, np.ndarray | None] = {}
    todo = _network_rows(models, m, specialized, peers)
    for name, model, kind in progress_bar(todo, progress, len(todo), "timing"):
        if kind == "numpy":
            preds[name] = _time_numpy(t, name, model)
        elif kind == "specialised":
            _time_specialised(t, name, model, calibration_trajectories,
                              preds.get(name.replace(", scene-specialised", "")))
        elif kind == "torch":
            _time_torch(t, name, model)
        else:
            _time_onnx(t, name, model)
    _time_baselines(t)
    _time_simulator(t, cases, m, dt_factors)
    return t.rows


class _Timer:
    """Times the ways of predicting ``targets`` from ``inputs`` (all cases, then the first one
    alone) and keeps a :class:`TimingRow` for each."""

    def __init__(self, inputs: np.ndarray, targets: np.ndarray, horizon: int,
                 repeats: int) -> None:
        self.inputs, self.targets, self.horizon, self.repeats = inputs, targets, horizon, repeats
        self.rows: list[TimingRow] = []

    def add(self, name: str, fn_batch: Callable[[], np.ndarray] | None,
            fn_single: Callable[[], Any] | None, note: str = "", reps: int | None = None,
            kind: str = "model") -> np.ndarray | None:
        """Time ``fn_batch`` (all cases; its result is scored) and ``fn_single`` (the first
        case), best of ``reps`` (default ``repeats``) each; returns the batch predictions."""
        reps = self.repeats if reps is None else reps
        n_cases, horizon = self.inputs.shape[0], self.horizon
        tb, pred = _best_time(fn_batch, reps) if fn_batch else (None, None)
        ts = _best_time(fn_single, reps)[0] if fn_single else None
        self.rows.append(TimingRow(name,
                                   None if tb is None else 1e3 * tb / (n_cases * horizon),
                                   None if ts is None else 1e3 * ts / horizon,
                                   errors(self.targets, pred), note, kind))
        return pred

    def skip(self, name: str, why: str) -> None:
        self.rows.append(TimingRow(name, None, None, {}, why))


def _network_rows(models: Sequence[ModelSpec], m: int, specialized: bool,
                  peers: bool) -> list[tuple[str, Any, str]]:
    """``(row name, model, kind)`` for each network row, in table order (models of window
    length ``m`` only)."""
    todo = []
    for spec in models:
        if spec.model.config.m != m:
            continue
        for dt in ("float64", "float32"):
            todo.append((f"{spec.label} NumPy {dt}", spec.model.astype(dt), "numpy"))
        if specialized:
            todo.append((f"{spec.label} NumPy float32, scene-specialised",
                         spec.model.astype("float32"), "specialised"))
        if peers:
            todo.append((f"{spec.label} PyTorch", spec.model.astype("float32"), "torch"))
            todo.append((f"{spec.label} onnxruntime", spec.model.astype("float32"), "onnx"))
    return todo


def _time_numpy(t: _Timer, name: str, model: Any) -> np.ndarray | None:
    inputs, horizon = t.inputs, t.horizon
    model.rollout(inputs[0], 2, normalized=True)     # warm caches
    return t.add(name, lambda: batched_rollout(model, inputs, horizon),
                 lambda: model.rollout(inputs[0], horizon, normalized=True),
                 "tpnet_ref, windows stepped together (batch) / model.rollout (single)")


def _time_specialised(t: _Timer, name: str, model: Any, calibration_trajectories: int,
                      ref: np.ndarray | None) -> None:
    """The float32 network specialised on simulated training-grid windows (calibrated before
    and outside the timed part); ``ref``: the float32 row's predictions, for the note."""
    if model.config.lstm_activation != "relu":
        t.skip(name, "not a ReLU-LSTM network: no unit stays exactly zero")
        return
    from ..sim.dataset import calibration_windows
    inputs, horizon = t.inputs, t.horizon
    t0 = time.perf_counter()
    with warnings.catch_warnings():        # training-range warnings of the rollouts
        warnings.simplefilter("ignore")
        cal = calibration_windows(model, calibration_trajectories, rollout=CALIBRATION_ROLLOUT)
        model = model.specialize(cal)
    t_cal = time.perf_counter() - t0
    model.rollout(inputs[0], 2, normalized=True)     # warm caches
    model.counts.update(windows=0, fallbacks=0)
    pred = t.add(name, lambda: batched_rollout(model, inputs, horizon),
                 lambda: model.rollout(inputs[0], horizon, normalized=True))
    n_win, n_fb = model.counts["windows"], model.counts["fallbacks"]
    note = (f"`TPNet.specialize` calibrated ({t_cal:.0f} s, not timed) on {len(cal):,} "
            f"windows of {calibration_trajectories} simulated training-grid "
            f"trajectories and the model's own {CALIBRATION_ROLLOUT}-frame rollouts "
            f"from them; {n_fb / max(n_win, 1):.1%} of the {n_win:,} timed windows fell "
            "back to the full network")
    if ref is not None:
        scale = model.config.norm_hi - model.config.norm_lo
        d = float(np.abs(np.asarray(pred, np.float64) - ref).max()) * scale
        note += (f"; max abs difference from the float32 row's predictions over the "
                 f"{horizon}-frame rollouts {d:.1e} world units")
    t.rows[-1].note = note


#: the peers of the error-against-run-time table: (modules they need, rows, extra)
PEERS = ((("torch",), "PyTorch", "crosscheck"),
         (("onnx", "onnxruntime"), "onnxruntime", "crosscheck"))


def missing_peers() -> list[str]:
    """One line per peer whose rows this environment cannot time, naming the extra to install
    (``tpnet eval`` says so before it starts)."""
    out = []
    for modules, rows, extra in PEERS:
        lacking = [m for m in modules if importlib.util.find_spec(m) is None]
        if lacking:
            out.append(f"the {rows} rows of the error-against-run-time table need "
                       f"{' and '.join(lacking)} (pip install 'tpnet-ref[{extra}]'): without it "
                       "they are written as not installed and left out of the figure")
    return out


def _time_torch(t: _Timer, name: str, model: Any) -> None:
    if importlib.util.find_spec("torch") is None:
        t.skip(name, "PyTorch not installed")
        return
    import torch
    from ..training.torch_model import TorchTPNet
    net = TorchTPNet.from_numpy(model).eval()
    xb = torch.from_numpy(np.ascontiguousarray(t.inputs, dtype=np.float32))

    def run(x: Any) -> np.ndarray:
        with torch.inference_mode():
            return net.rollout(x, t.horizon).numpy()
    run(xb[:1, :, :, :])
    t.add(name, lambda: run(xb), lambda: run(xb[:1]),
          f"torch {torch.__version__}, {torch.get_num_threads()} threads, float32")


def _time_onnx(t: _Timer, name: str, model: Any) -> None:
    if importlib.util.find_spec("onnxruntime") is None \
            or importlib.util.find_spec("onnx") is None:
        t.skip(name, "onnx/onnxruntime not installed")
        return
    from ..conformance.onnx_peer import onnx_session     # the crosscheck extra
    sess = onnx_session(model, n_points=t.inputs.shape[2])

    def run(x: np.ndarray) -> np.ndarray:
        w = np.ascontiguousarray(x, dtype=np.float32)
        out = np.empty((w.shape[0], t.horizon) + w.shape[2:], np.float32)
        for s in range(t.horizon):
            y = sess.run(None, {"window": w})[0]
            out[:, s] = y
            w = np.concatenate([w[:, 1:], y[:, None]], axis=1)
        return out
    run(t.inputs[:1])
    t.add(name, lambda: run(t.inputs), lambda: run(t.inputs[:1]),
          "one-step ONNX graph in a loop: recomputes the m frames' features every step")


def _time_baselines(t: _Timer) -> None:
    inputs, horizon = t.inputs, t.horizon
    t.add("copy last input frame", lambda: copy_last(inputs, horizon),
          lambda: copy_last(inputs[:1], horizon), "baseline", kind="baseline")
    t.add("constant velocity", lambda: constant_velocity(inputs, horizon),
          lambda: constant_velocity(inputs[:1], horizon), "baseline, points matched by order",
          kind="baseline")


def _time_simulator(t: _Timer, cases: np.ndarray, m: int, dt_factors: Sequence[int]) -> None:
    """The simulator from each case's initial condition to the last predicted frame, at the
    reference step and ``dt_factors`` times it."""
    from ..sim import simulate
    horizon = t.horizon
    last_frame = m - 1 + horizon
    simulate(*cases[0], 9)                                   # compile / load the kernel
    for k in (1, *dt_factors):
        def run(cs: np.ndarray, k: int = k) -> np.ndarray:
            if k == 1:
                return np.stack([simulate(*c, last_frame * FRAME_EVERY + 1)[::FRAME_EVERY]
                                 for c in cs])
            return np.stack([sim_coarse(c, k, last_frame + 1) for c in cs])

        def pred(k: int = k) -> np.ndarray:
            return normalize(run(cases, k)[:, m:m + horizon])
        steps = last_frame * FRAME_EVERY / k
        note = (f"dt = {k}/45 s, {steps:g} steps to frame {last_frame}"
                + ("; frames between two steps linearly interpolated" if FRAME_EVERY % k else ""))
        if k == 1:
            note = f"reference dt = 1/45 s ({steps:g} steps): differs from the targets only " \
                   "if they come from another simulator (--data)"
        t.add(f"pymunk simulator dt x{k}", pred, lambda k=k: run(cases[:1], k), note,
              reps=max(1, min(t.repeats, 2)), kind="simulator")


__all__ = ["TimingRow", "sim_coarse", "timing_table", "CALIBRATION_TRAJECTORIES",
           "CALIBRATION_ROLLOUT", "PEERS", "missing_peers"]
