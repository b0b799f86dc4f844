"""What do predict's input checks cost on a ring of the scene and on random points?

    python bench/probes/input_checks_cost.py [--rounds 5]

Times ``check_window`` + ``warn_about_input`` (what ``tpnet_ref.predict`` runs before the network)
on a window of the held-out scene and on four frames of 30 uniformly random points in the box,
with the one-body test's shortcut for scattered frames (``checks._cannot_hold_a_body``) and
without it (the pairwise grouping for every such frame), interleaved round by round; the
Numba engine's compiled first pass (``model.screen``: what ``predict`` runs instead of both
when it decides the window); and ``predict`` itself on both windows, for the share
(docs/performance.md, "Every size at one window").
"""
from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np

import tpnet_ref
from tpnet_ref import checks as C


def _median_us(fn, n: int) -> float:
    for _ in range(20):
        fn()
    ts = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts)) * 1e6


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds")
    ap.add_argument("--calls", type=int, default=300, help="calls per timing")
    args = ap.parse_args()
    warnings.simplefilter("ignore", C.OutsideTrainingRangeWarning)
    model = tpnet_ref.load()
    c = model.config
    ring = tpnet_ref.example_window()
    rand = model.denormalize(np.random.default_rng(0).uniform(0.1, 0.9, (4, 30, 2))
                             ).astype(np.float32)
    shortcut = C._cannot_hold_a_body

    def checks(w):
        frames = C.check_window(w, c.m, c.dim, model.dtype)
        C.warn_about_input(frames, c.norm_lo, c.norm_hi, False, "window", True)

    rows: dict = {}
    for _ in range(args.rounds):
        for name, w in (("ring", ring), ("random points", rand)):
            for mode in ("shortcut", "pairwise"):
                C._cannot_hold_a_body = shortcut if mode == "shortcut" else (
                    lambda f: np.zeros(len(f), dtype=bool))
                rows.setdefault((name, f"checks, {mode}"), []).append(
                    _median_us(lambda: checks(w), args.calls))
            C._cannot_hold_a_body = shortcut
            if model.screen is not None:       # the Numba engine's compiled first pass
                rows.setdefault((name, "first pass (compiled)"), []).append(
                    _median_us(lambda: model.screen(model, w, True, False), args.calls))
            rows.setdefault((name, f"predict ({model.engine})"), []).append(
                _median_us(lambda: model.predict(w), args.calls))
    print(f"load average {' '.join(f'{v:.2f}' for v in os.getloadavg())}; medians of "
          f"{args.rounds} rounds of {args.calls} calls, us")
    for (name, what), v in rows.items():
        print(f"  {name:14s} {what:22s} {np.median(v):8.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
