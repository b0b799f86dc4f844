"""Which register tiles suit this CPU: the wide plan (64-byte vectors, 4 x 4 and 8 x 2 tiles,
made for AVX-512's 32 registers) against the narrow one (32-byte vectors, 4 x 2 tiles, for
AVX2's 16), on the per-point layers' shapes, the same bits checked.

    python bench/probes/tile_plans.py [--zeros 0.5] [--reps 2000]

For each layer shape ``C -> N`` it times ``numba_tiles.tiled_plan`` on 32 rows of ReLU-like
inputs (a share ``--zeros`` of them zero) in both plans, one thread, the best of 5 rounds, and
prints the multiply-adds per second the narrow plan reaches (counting the zeros it skips as
done). The engine takes the plan :data:`tpnet_ref.engines.numba_codegen.TILE_PLAN` names.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from tpnet_ref.engines import numba_codegen as CG
from tpnet_ref.engines import numba_tiles as NT

SHAPES = ((16, 16), (16, 32), (32, 64), (64, 64), (64, 128), (128, 256), (256, 512))


def best_time(fn, reps: int) -> float:
    fn()
    times = []
    for _ in range(5):
        t = time.perf_counter()
        for _ in range(reps):
            fn()
        times.append((time.perf_counter() - t) / reps)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--zeros", type=float, default=0.5, help="share of zero inputs (ReLU)")
    ap.add_argument("--reps", type=int, default=2000, help="calls per round")
    args = ap.parse_args()
    info = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    name = next((ln.split(":", 1)[1].strip() for ln in info.splitlines()
                 if ln.startswith("model name")), "unknown CPU")
    print(f"{name}, AVX-512: {'avx512f' in info}; the engine's plan here: {CG.TILE_PLAN}")
    rng = np.random.default_rng(0)
    rows = 32
    for cin, cout in SHAPES:
        x = rng.standard_normal((64, cin)).astype(np.float32)
        x[rng.random(x.shape) < args.zeros] = 0
        w = rng.standard_normal((cin, cout)).astype(np.float32)
        act = np.empty(cin, dtype=np.intp)
        outs = {p: np.empty((64, cout), dtype=np.float32) for p in (False, True)}
        for narrow, out in outs.items():
            NT.tiled_plan(x, w, rows, act, out, narrow)
        same = np.array_equal(outs[False][:rows].view(np.uint32), outs[True][:rows].view(np.uint32))
        reps = max(20, args.reps * 4096 // (cin * cout))
        t = {p: best_time(lambda p=p: NT.tiled_plan(x, w, rows, act, outs[p], p), reps)
             for p in (False, True)}
        print(f"  {cin:4d} -> {cout:4d}: wide {t[False] * 1e6:8.2f} us  narrow {t[True] * 1e6:8.2f}"
              f" us  wide/narrow {t[False] / t[True]:4.2f}  narrow "
              f"{rows * cin * cout / t[True] / 1e9:5.1f} GMAC/s  same bits: {same}")


if __name__ == "__main__":
    main()
