"""Speed of one 600-step trajectory: tpnet_ref.sim (pymunk + Numba springs) vs Box2D 2.3.

    PYTHONPATH=. python bench/bench_sim.py [--repeats 7]

Both run the released convention (impulse at the ring centre, no sleeping), build the scene
from scratch and return the (600, 30, 2) positions; the best and the median of the repeats are
printed, and the ratio Box2D / ours (> 1: ours is faster). Numba's
compilation is excluded (one warm-up run each).
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.dirname(__file__))
from box2d_scene import simulate_box2d  # noqa: E402

from tpnet_ref.sim import simulate  # noqa: E402

CASE = (1.3, 195.0, 39.5, 29.5)


def timeit(fn, repeats: int) -> list[float]:
    fn(*CASE, 600)
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn(*CASE, 600)
        out.append(time.perf_counter() - t)
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    ours, ref = [], []
    for _ in range(args.repeats):       # interleave so both see the same machine load
        ours += timeit(simulate, 1)
        ref += timeit(simulate_box2d, 1)
    for name, t in (("tpnet_ref.sim", ours), ("Box2D 2.3.10", ref)):
        print(f"{name:14s} best {1e3 * min(t):7.1f} ms  "
              f"median {1e3 * statistics.median(t):7.1f} ms")
    print(f"ratio Box2D/ours: best {min(ref) / min(ours):.2f}x, "
          f"median {statistics.median(ref) / statistics.median(ours):.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
