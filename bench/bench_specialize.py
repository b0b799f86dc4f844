"""The scene-specialised model against the full one: exactness, fallbacks, B = 1 speed.

    python bench/bench_specialize.py            # 36 training-grid trajectories to calibrate
    python bench/bench_specialize.py --quick    # 12

Calibrates the shipped m = 4 model on windows of simulated training-grid trajectories (every
window, plus the windows of the model's own 40-frame rollouts from them; never the test cases),
then checks on the 60 test cases (their simulated windows and the model's own rollout windows)
and on inputs built to trip every guard: max |specialised - full| in world units (target <=
1e-4), the fraction of windows that fall back to the full network, and B = 1 latency of both
on the test windows, interleaved (target: specialised >= 2x faster).
"""
from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import tpnet_ref  # noqa: E402
from tpnet_ref import specialize as S  # noqa: E402
from tpnet_ref.protocol import FRAME_EVERY  # noqa: E402
from tpnet_ref.sim.cases import TEST_CASES  # noqa: E402
from tpnet_ref.sim.scene import simulate  # noqa: E402


def windows(frames: np.ndarray, m: int) -> np.ndarray:
    return np.stack([frames[s:s + m] for s in range(len(frames) - m + 1)])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    n_cal = 12 if args.quick else 36
    full = tpnet_ref.load()
    m = full.config.m
    t0 = time.perf_counter()
    cal = S.calibration_windows(full, n_cal, seed=0, rollout=40)
    spec = full.specialize(cal)
    print(f"calibrated on {len(cal)} windows of {n_cal} training-grid trajectories "
          f"({time.perf_counter() - t0:.0f} s): units used "
          + ", ".join(f"{k} {a}/{b}" for k, (a, b) in S.fraction_used(spec.specialization.used).items())
          + f"; head parameters read {spec.specialization.num_params():,} of {full.num_params:,}")

    test = [simulate(*c)[::FRAME_EVERY] for c in TEST_CASES]
    sim_w = np.concatenate([windows(t, m) for t in test])
    roll_w = np.concatenate([windows(np.concatenate([t[:m], full.rollout(t[:m], 80)]), m)
                             for t in test])
    rng = np.random.default_rng(1)
    centre = sim_w[:200].mean(axis=2, keepdims=True)
    trips = {"random points": rng.uniform(0, 45, (200, m, 30, 2)),
             "ring far outside the box": sim_w[:200] + 300.0,
             "tiny ring (x0.01)": centre + (sim_w[:200] - centre) * 0.01,
             "huge ring (x10)": centre + (sim_w[:200] - centre) * 10}
    print(f"\n{'windows':36s} {'count':>6s} {'max |spec - full| (world)':>26s} {'fallback':>9s}")
    worst = 0.0
    fallback = {}
    for name, w in [("test cases, simulated", sim_w), ("test cases, model's own rollout", roll_w),
                    *trips.items()]:
        spec.counts.update(windows=0, fallbacks=0)
        d = float(np.abs(spec.predict_batch(w) - full.predict_batch(w)).max())
        worst = max(worst, d)
        fallback[name] = spec.counts["fallbacks"] / spec.counts["windows"]
        print(f"{name:36s} {len(w):6d} {d:26.2e} {fallback[name]:9.2%}")

    # B = 1 latency on the scene's windows, interleaved, medians
    sample = sim_w[np.random.default_rng(2).choice(len(sim_w), 64, replace=False)]
    tf, ts = [], []
    for rep in range(5):
        for w in sample:
            t = time.perf_counter()
            full.predict(w)
            tf.append(time.perf_counter() - t)
            t = time.perf_counter()
            spec.predict(w)
            ts.append(time.perf_counter() - t)
    f_ms, s_ms = 1e3 * float(np.median(tf)), 1e3 * float(np.median(ts))
    print(f"\nB = 1 latency on test-case windows: full {f_ms:.3f} ms, specialised {s_ms:.3f} ms")
    print("\ntargets:")
    for label, val, ok in [("max |specialised - full|, world units (target <= 1e-4)", worst,
                            worst <= 1e-4),
                           ("B = 1 speed-up over the full model (target >= 2)", f_ms / s_ms,
                            f_ms / s_ms >= 2.0),
                           ("fallback fraction, simulated test windows (reported)",
                            fallback["test cases, simulated"], None)]:
        print(f"  {label:58s} {val:10.3g}  {'' if ok is None else ('MET' if ok else 'NOT MET')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
