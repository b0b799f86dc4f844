"""B = 1 latency and 80-frame rollout of the shipped model: NumPy engine, Numba engine and
onnxruntime, alternating call by call (ratios from medians of the same minutes).

    python bench/bench_engine_numba.py [--reps 6] [--one-thread] [--no-ort] [--batches 2,4,8]
                                       [--ort-threads 1]

Inputs: ``_common.scene_windows`` (normalised windows of simulated test cases): B = 1 on the
64 windows ``x256[::4]``, each window once per repeat and engine; the prediction network alone
(``sequence_head`` on precomputed global features) on the same windows; the rollout of 80
frames from test case 0's first window (onnxruntime: a loop of 80 calls); with ``--batches``,
``predict_batch`` of consecutive windows of ``x256`` in batches of those sizes (the Numba
engine runs batches up to ``ENGINE_MAX_BATCH``). ``--one-thread``: everything inside
:func:`tpnet_ref.engines.blas.one_thread` (one-thread BLAS; the Numba engine then runs its serial
kernels, else the two directions of each layer on two threads). Prints the load average first:
on a shared machine the figures are only comparable within one run.
"""
from __future__ import annotations

import argparse
import contextlib
import sys
import warnings

import numpy as np

import tpnet_ref
from _common import alternate, load_average, scene_windows
from tpnet_ref.engines.blas import one_thread
from tpnet_ref.engines.interface import ENGINE_MAX_BATCH


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=6, help="passes over the 64 windows")
    ap.add_argument("--rollouts", type=int, default=8, help="80-frame rollouts per engine")
    ap.add_argument("--one-thread", action="store_true", help="inside blas.one_thread()")
    ap.add_argument("--no-ort", action="store_true", help="leave out onnxruntime")
    ap.add_argument("--batches", default="", help="comma-separated batch sizes to time too")
    ap.add_argument("--ort-threads", type=int, default=None,
                    help="onnxruntime's intra-op threads (default: its own, every core)")
    ap.add_argument("--engine-parallel", action="store_true",
                    help="ask the engine for its two-thread kernels on every call (they run "
                         "inside blas.one_thread only); model.py asks only outside it")
    args = ap.parse_args(argv)
    print(load_average())
    warnings.simplefilter("ignore")
    npy = tpnet_ref.load(engine="numpy")
    nb = npy.with_engine("numba")
    from tpnet_ref.engines.numba_engine import NumbaHead
    class AskTwo(NumbaHead):                    # always asks for the two-thread kernels
        def project_rows(self, x, parallel=False, batch=1):
            return super().project_rows(x, True, batch)

        def run(self, xp1, steps, batch, parallel=False):
            return super().run(xp1, steps, batch, True)

    head = AskTwo if args.engine_parallel else NumbaHead
    if args.engine_parallel:      # the engine laid out as the model does, asking for two threads
        nb.heads[0] = head(nb.config, nb.params, nb.dtype, nb.unit_order, ENGINE_MAX_BATCH)
        print("(two threads asked for on every call)")
    x1, x256 = scene_windows(npy)
    ws = list(x256[::4])
    calls = {"numpy": lambda w: npy.predict(w, normalized=True),
             "numba": lambda w: nb.predict(w, normalized=True)}
    if not args.no_ort:
        from tpnet_ref.conformance.onnx_peer import onnx_session
        sess = onnx_session(npy, threads=args.ort_threads)
        calls["onnxruntime"] = lambda w: sess.run(None, {"window": w[None]})
    feats = [npy.window_features(w[None], normalized=True) for w in ws]
    heads = {"numpy": lambda g: npy.sequence_head(g), "numba": lambda g: nb.sequence_head(g)}
    ctx = one_thread() if args.one_thread else contextlib.nullcontext()
    with ctx:
        for f in list(calls.values()):          # warm-up (compilation, caches)
            f(ws[0])
        for f in heads.values():
            f(feats[0])
        r = alternate(calls, ws, args.reps)
        h = alternate(heads, feats, args.reps)
        rolls = {k: (lambda x, mm=mm: mm.rollout(x, 80, normalized=True))
                 for k, mm in (("numpy", npy), ("numba", nb))}
        if not args.no_ort:
            def ort_loop(x: np.ndarray) -> None:
                win = x[None]
                for _ in range(80):
                    y = sess.run(None, {"window": win})[0]
                    win = np.concatenate([win[:, 1:], y[:, None]], axis=1)
            rolls["onnxruntime"] = ort_loop
        roll = alternate(rolls, [x1[0]], args.rollouts)
        batches = {}
        for b in (int(v) for v in args.batches.split(",") if v):
            chunks = [x256[i:i + b] for i in range(0, len(x256) - b + 1, max(b, 32))]
            bc = {"numpy": lambda w: npy.predict_batch(w, normalized=True),
                  "numba": lambda w: nb.predict_batch(w, normalized=True)}
            if not args.no_ort:
                bc["onnxruntime"] = lambda w: sess.run(None, {"window": w})
            batches[b] = alternate(bc, chunks, args.reps)
    print(f"{'one-thread BLAS' if args.one_thread else 'default threads'}; onnxruntime "
          f"threads: {args.ort_threads or 'default'}; {len(ws)} windows x {args.reps} reps")
    base = r.get("onnxruntime")
    for k, v in r.items():
        extra = f"  {v / base:.3f}x onnxruntime" if base else ""
        print(f"B=1 predict   {k:12s} {v * 1e3:7.3f} ms{extra}  {v / r['numpy']:.3f}x numpy")
    for k, v in h.items():
        print(f"B=1 head      {k:12s} {v * 1e3:7.3f} ms  {v / h['numpy']:.3f}x numpy")
    for k, v in roll.items():
        print(f"rollout/frame {k:12s} {v / 80 * 1e3:7.3f} ms  {v / roll['numpy']:.3f}x numpy")
    for b, rb in batches.items():
        for k, v in rb.items():
            print(f"B={b:<3d} batch   {k:12s} {v * 1e3:7.3f} ms  {v / rb['numpy']:.3f}x numpy")
    return 0


if __name__ == "__main__":
    sys.exit(main())
