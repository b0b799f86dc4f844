"""Error against run time: every way of obtaining the next frames, timed and scored in one run.

Rows: the network in NumPy float64/float32, optionally float32 scene-specialised (calibrated on
training-grid trajectories, :mod:`tpnet_ref.specialize`), with the ``crosscheck`` extra PyTorch and
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
from ..protocol import FRAME_EVERY, REFERENCE_DT, constant_velocity, copy_last, split_protocol
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
    rollouts from them (:func:`tpnet_ref.data.calibration_windows`; never the test cases),
    calibrated before and outside the timed part, timed like the float32 row. Its note gives the
    calibration, the fraction of the timed windows that fell back to the full network and the
    largest difference from the float32 row's predictions.
    """
    frames_n = normalize(np.asarray(frames, dtype=np.float64))
    inputs, targets = split_protocol(frames_n, m, horizon)
    C = inputs.shape[0]
    rows: list[TimingRow] = []

    def add(name: str, fn_batch: Callable[[], np.ndarray] | None,
            fn_single: Callable[[], Any] | None, note: str = "", reps: int = repeats,
            kind: str = "model") -> np.ndarray | None:
        tb, pred = _best_time(fn_batch, reps) if fn_batch else (None, None)
        ts = _best_time(fn_single, reps)[0] if fn_single else None
        rows.append(TimingRow(name,
                              None if tb is None else 1e3 * tb / (C * horizon),
                              None if ts is None else 1e3 * ts / horizon,
                              errors(targets, pred), note, kind))
        return pred

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
    preds: dict[str, np.ndarray] = {}
    for name, model, kind in progress_bar(todo, progress, len(todo), "timing"):
        if kind == "numpy":
            model.rollout(inputs[0], 2, normalized=True)     # warm caches
            preds[name] = add(name, lambda mo=model: batched_rollout(mo, inputs, horizon),
                              lambda mo=model: mo.rollout(inputs[0], horizon, normalized=True),
                              "tpnet_ref, windows stepped together (batch) / model.rollout "
                              "(single)")
        elif kind == "specialised":
            if model.config.lstm_activation != "relu":
                rows.append(TimingRow(name, None, None, {}, "not a ReLU-LSTM network: no unit "
                                                            "stays exactly zero"))
                continue
            from ..data import calibration_windows
            t0 = time.perf_counter()
            with warnings.catch_warnings():        # training-range warnings of the rollouts
                warnings.simplefilter("ignore")
                cal = calibration_windows(model, calibration_trajectories,
                                          rollout=CALIBRATION_ROLLOUT)
                model = model.specialize(cal)
            t_cal = time.perf_counter() - t0
            model.rollout(inputs[0], 2, normalized=True)     # warm caches
            model.counts.update(windows=0, fallbacks=0)
            pred = add(name, lambda mo=model: batched_rollout(mo, inputs, horizon),
                       lambda mo=model: mo.rollout(inputs[0], horizon, normalized=True))
            n_win, n_fb = model.counts["windows"], model.counts["fallbacks"]
            note = (f"`TPNet.specialize` calibrated ({t_cal:.0f} s, not timed) on {len(cal):,} "
                    f"windows of {calibration_trajectories} simulated training-grid "
                    f"trajectories and the model's own {CALIBRATION_ROLLOUT}-frame rollouts "
                    f"from them; {n_fb / max(n_win, 1):.1%} of the {n_win:,} timed windows fell "
                    "back to the full network")
            ref = preds.get(name.replace(", scene-specialised", ""))
            if ref is not None:
                scale = model.config.norm_hi - model.config.norm_lo
                d = float(np.abs(np.asarray(pred, np.float64) - ref).max()) * scale
                note += (f"; max abs difference from the float32 row's predictions over the "
                         f"{horizon}-frame rollouts {d:.1e} world units")
            rows[-1].note = note
        elif kind == "torch":
            if importlib.util.find_spec("torch") is None:
                rows.append(TimingRow(name, None, None, {}, "PyTorch not installed"))
                continue
            import torch
            from ..torch_model import TorchTPNet
            net = TorchTPNet.from_numpy(model).eval()
            xb = torch.from_numpy(np.ascontiguousarray(inputs, dtype=np.float32))

            def run_t(x: Any, net: Any = net) -> np.ndarray:
                with torch.inference_mode():
                    return net.rollout(x, horizon).numpy()
            run_t(xb[:1, :, :, :])
            add(name, lambda: run_t(xb), lambda: run_t(xb[:1]),
                f"torch {torch.__version__}, {torch.get_num_threads()} threads, float32")
        else:
            if importlib.util.find_spec("onnxruntime") is None \
                    or importlib.util.find_spec("onnx") is None:
                rows.append(TimingRow(name, None, None, {}, "onnx/onnxruntime not installed"))
                continue
            from ..onnx_peer import onnx_session     # the crosscheck extra
            sess = onnx_session(model, n_points=inputs.shape[2])

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
    from ..sim import simulate
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


__all__ = ["TimingRow", "sim_coarse", "timing_table", "CALIBRATION_TRAJECTORIES",
           "CALIBRATION_ROLLOUT"]
