"""Which register tiles suit this CPU: the wide plan (64-byte vectors, 4 x 4 and 8 x 2 tiles,
made for AVX-512's 32 registers) against the narrow one (32-byte vectors, 4 x 2 tiles, for
AVX2's 16), on the per-point layers' shapes, the same bits checked.

    PYTHONPATH=bench python bench/probes/tile_plans.py [--zeros 0.5] [--reps 2000]

For each layer shape ``C -> N`` it times ``numba_tiles.tiled_plan`` on 32 rows of ReLU-like
inputs (a share ``--zeros`` of them zero) in both plans, one thread, the best of 5 rounds, and
prints the multiply-adds per second the narrow plan reaches (counting the zeros it skips as
done). The engine takes the plan :data:`tpnet_ref.engines.numba_codegen.TILE_PLAN` names.
"""
from __future__ import annotations

import argparse

import numpy as np

from _common import best_of, cpu_name
from tpnet_ref.engines import numba_codegen as CG
from tpnet_ref.engines import numba_tiles as NT

SHAPES = ((16, 16), (16, 32), (32, 64), (64, 64), (64, 128), (128, 256), (256, 512))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--zeros", type=float, default=0.5, help="share of zero inputs (ReLU)")
    ap.add_argument("--reps", type=int, default=2000, help="calls per round")
    args = ap.parse_args()
    print(f"{cpu_name()}; AVX-512: {CG.wide_registers()}, so the engine's plan: {CG.TILE_PLAN}")
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

        def rounds(p: bool) -> None:
            for _ in range(reps):
                NT.tiled_plan(x, w, rows, act, outs[p], p)

        t = {p: best_of(lambda p=p: rounds(p), 5)[0] / reps for p in (False, True)}
        print(f"  {cin:4d} -> {cout:4d}: wide {t[False] * 1e6:8.2f} us  narrow {t[True] * 1e6:8.2f}"
              f" us  wide/narrow {t[False] / t[True]:4.2f}  narrow "
              f"{rows * cin * cout / t[True] / 1e9:5.1f} GMAC/s  same bits: {same}")


if __name__ == "__main__":
    main()
