"""B = 1 latency and 80-frame rollout of the shipped model against onnxruntime, alternating
call by call (each ratio from medians of the same minutes; useful on a VM whose speed drifts).

    python bench/bench_interleaved.py [--reps 400]

Inputs as in ``bench_inference.py``: test case 0's first window and 64 windows of 8 test cases
(normalised), and the rollout from the first. Needs onnxruntime and onnx (``crosscheck`` extra).
"""
from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import tpnet_ref  # noqa: E402
from bench_inference import scene_windows  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=400)
    args = ap.parse_args(argv)
    from tpnet_ref.onnx_peer import onnx_session
    warnings.simplefilter("ignore")
    m = tpnet_ref.load()
    x1, x256 = scene_windows(m)
    sess = onnx_session(m)

    def alternate(pairs, reps):
        t = {k: [] for k, _ in pairs}
        for _ in range(reps):
            for k, f in pairs:
                t0 = time.perf_counter()
                f()
                t[k].append(time.perf_counter() - t0)
        return {k: float(np.median(v)) for k, v in t.items()}

    r = alternate([("ours", lambda: m.predict(x1[0], normalized=True)),
                   ("ort", lambda: sess.run(None, {"window": x1}))], args.reps)
    print(f"B=1, one window:   tpnet_ref {r['ours'] * 1e3:.3f} ms  onnxruntime {r['ort'] * 1e3:.3f} ms"
          f"  ratio {r['ours'] / r['ort']:.3f}")
    ws = x256[::4]
    t = {"ours": [], "ort": []}
    for _ in range(max(1, args.reps // 64)):
        for w in ws:
            for k, f in (("ours", lambda: m.predict(w, normalized=True)),
                         ("ort", lambda: sess.run(None, {"window": w[None]}))):
                t0 = time.perf_counter()
                f()
                t[k].append(time.perf_counter() - t0)
    o, p = float(np.median(t["ours"])), float(np.median(t["ort"]))
    print(f"B=1, 64 windows:   tpnet_ref {o * 1e3:.3f} ms  onnxruntime {p * 1e3:.3f} ms  ratio {o / p:.3f}")

    def ort_loop() -> None:
        win = x1.copy()
        for _ in range(80):
            y = sess.run(None, {"window": win})[0]
            win = np.concatenate([win[:, 1:], y[:, None]], axis=1)

    r = alternate([("ours", lambda: m.rollout(x1[0], 80, normalized=True)), ("ort", ort_loop)],
                  max(3, args.reps // 80))
    print(f"rollout, per frame: tpnet_ref {r['ours'] / 80 * 1e3:.3f} ms  onnxruntime loop "
          f"{r['ort'] / 80 * 1e3:.3f} ms  ratio {r['ours'] / r['ort']:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
