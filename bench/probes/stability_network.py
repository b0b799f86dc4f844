"""Numerical stability of the network (docs/spec.md §6): float32 overflow and float32/float64 divergence.

    nice -n 19 python bench/probes/stability_network.py [--frames 10000] [--seed 0]

1. Input scale: a window of the scene (world units) is scaled about the box centre by ``s``;
   for each ``s`` the float32 and float64 predictions, the largest ReLU-LSTM output reaching
   the first LayerNorm, and whether the product raised. Then the smallest scale at which
   float32 refuses (bisection), i.e. where LayerNorm's variance would overflow float32.
2. Long rollouts: the same weights in float32 and float64, rolled out ``--frames`` frames from
   the same window; the largest float32 - float64 difference (world units) at 10, 100, 1000,
   10000 frames, and the time per frame.

Weights: random released-shape weights (``init_random``, m = 4, 8.1M parameters) unless
``--weights`` names a native file.
"""
from __future__ import annotations

import argparse
import warnings
import time

import numpy as np

from tpnet_ref.engines import layers as L
from tpnet_ref.model import init_random
from tpnet_ref.checks import NonFiniteResultError, OutsideTrainingRangeWarning
from tpnet_ref.engines.numpy_engine import file_order_lstms


def window(m: int) -> np.ndarray:
    from tpnet_ref.sim import simulate
    traj = simulate(1.3, 225.0, 30.0, 35.0, 4 * (m - 1) + 1)
    return traj[::4]


def lstm1_peak(model, w: np.ndarray) -> float:
    """Largest first-BiLSTM output for window ``w`` (world units) in the model's dtype."""
    g = model.window_features(np.asarray(w)[None])
    fused = file_order_lstms(model.config, model.params)[0][0]
    with np.errstate(over="ignore", invalid="ignore"):
        h = L.bilstm_fused(g.transpose(1, 0, 2), *fused, activation=model.config.lstm_activation)
    return float(np.max(h))


def outcome(model, w):
    try:
        return model.predict(w), None
    except (NonFiniteResultError, ValueError) as exc:
        return None, type(exc).__name__


def main() -> None:
    warnings.simplefilter("ignore", OutsideTrainingRangeWarning)     # far-out input on purpose
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--weights", default=None)
    ap.add_argument("--skip-rollout", action="store_true")
    ap.add_argument("--trained-transforms", action="store_true",
                    help="random weights with trained (non-identity) transform nets")
    args = ap.parse_args()
    if args.weights:
        from tpnet_ref import load
        m64 = load(args.weights, "float64")
    else:
        from tpnet_ref.model import TPNetConfig
        cfg = TPNetConfig(input_transform_trained=args.trained_transforms,
                          feature_transform_trained=args.trained_transforms)
        m64 = init_random(cfg, seed=args.seed, dtype="float64")
    m32 = m64.astype("float32")
    w0 = window(m64.config.m)
    c = 22.5
    print(f"model: {m64}")
    print("\n1. input scale s (window scaled about the box centre; coordinates up to ~20 s)")
    print("| s | max coord | peak LSTM-1 output f32 | f32 result | f64 result | max diff f32-f64 |")
    print("|---|---|---|---|---|---|")
    for s in (1, 10, 1e2, 1e3, 1e4, 1e5, 1e6, 1e8, 1e10, 1e12, 1e14, 1e15, 1e16, 1e17, 1e18,
              1e20, 1e30, 1e100, 1e150, 1e160):
        w = c + (w0 - c) * s
        y32, e32 = outcome(m32, w)
        y64, e64 = outcome(m64, w)
        try:
            peak = f"{lstm1_peak(m32, w):.3g}"
        except ValueError:
            peak = "-"
        d = (f"{np.abs(y32.astype(np.float64) - y64).max():.3g}"
             if y32 is not None and y64 is not None else "-")
        print(f"| {s:g} | {np.abs(w).max():.3g} | {peak} | {e32 or 'finite'} | "
              f"{e64 or 'finite'} | {d} |")
    def refusal_scale(model, hi: float, iters: int) -> float:
        """Smallest scale s (bisected in log space) at which ``model`` refuses the window."""
        lo = 1.0
        for _ in range(iters):
            mid = float(np.exp((np.log(lo) + np.log(hi)) / 2))
            if outcome(model, c + (w0 - c) * mid)[1]:
                hi = mid
            else:
                lo = mid
        return hi

    hi = refusal_scale(m32, 1e30, 60)
    print(f"\nfloat32 refuses from s = {hi:.3g} (max |coordinate| {np.abs(c + (w0 - c) * hi).max():.3g}"
          f" world units); sqrt(float32 max)/4 = {np.sqrt(np.finfo(np.float32).max) / 4:.3g}")
    print(f"float64 refuses from s = {refusal_scale(m64, 1e300, 80):.3g}")
    y_inf = m64.predict(c + (w0 - c) * 1e12)
    print("LayerNorm scale invariance: max |f64(s) - f64(1e12)| for s = 1e4, 1e6, 1e8: "
          + ", ".join(f"{np.abs(m64.predict(c + (w0 - c) * s) - y_inf).max():.3g}"
                      for s in (1e4, 1e6, 1e8)))

    if args.skip_rollout:
        return
    n = args.frames
    print(f"\n2. rollout of {n} frames, float32 vs float64 (same weights, same window)")
    print("| frame | max abs diff (world units) | max abs diff up to here | "
          "f64 displacement from previous frame | ms/frame f32, f64 |")
    print("|---|---|---|---|---|", flush=True)
    # chunked rollout in model coordinates: the same computation as one rollout call (each
    # chunk restarts from the last m predicted frames, whose features are recomputed exactly)
    m = m64.config.m
    w32 = m32.normalize(w0.astype(np.float32))
    w64 = m64.normalize(w0)
    done, worst, prev, t32, t64 = 0, 0.0, None, 0.0, 0.0
    for k in (10, 100, 1000, 10000, 100000):
        if k > n:
            break
        t0 = time.perf_counter()
        r32 = m32.rollout(w32, k - done, normalized=True)
        t1 = time.perf_counter()
        r64 = m64.rollout(w64, k - done, normalized=True)
        t32 += t1 - t0
        t64 += time.perf_counter() - t1
        assert np.isfinite(r32).all() and np.isfinite(r64).all()
        d = np.abs(m64.denormalize(r32.astype(np.float64)) - m64.denormalize(r64)).max(axis=(1, 2))
        worst = max(worst, float(d.max()))
        last64 = m64.denormalize(r64)
        step = np.abs(last64[-1] - (last64[-2] if len(last64) > 1 else prev)).max()
        print(f"| {k} | {d[-1]:.3g} | {worst:.3g} | {step:.3g} | "
              f"{t32 / k * 1e3:.2f}, {t64 / k * 1e3:.2f} |", flush=True)
        prev = last64[-1]
        w32 = np.concatenate([w32, r32])[-m:]
        w64 = np.concatenate([w64, r64])[-m:]
        done = k

if __name__ == "__main__":
    main()
