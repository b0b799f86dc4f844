"""What a small network's B = 1 call costs besides its arithmetic, and what each thread plan gives.

    PYTHONPATH=bench python bench/probes/call_overhead.py [--size half|quarter|full] [--seconds 1]

Prints, for one shipped size on the default (Numba) engine, a scene ring in world units:

1. the network kernel called through numba's dispatcher against its compiled code's own entry
   (``compile_watch.entry_point``), and a kernel of the same 32 arguments that does nothing
   (what typing and unboxing the arguments cost);
2. the input checks' compiled first pass (``numba_checks.screen``) with and without its one-body
   test and its sort;
3. ``predict`` with ``TPNET_THREADS=1`` and ``=2`` and the policy's own choice, with the latency
   the policy records per plan (its block: what it compares);
4. a rollout's time per frame: the compiled call of every step (``TPNET_THREADS=1``), the steps
   one by one on one thread and on two;
5. ``predict`` with two threads on the prediction network's directions too
   (``NETWORK_APART_BYTES = 0``) against the default.

Each figure is the median over ``--seconds`` of calls; nothing here changes a result.
"""
from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np

import tpnet_ref
from _common import machine
from tpnet_ref.engines import compile_watch as CW
from tpnet_ref.engines import numba_checks as NC
from tpnet_ref.engines import numba_engine as NE
from tpnet_ref.engines import numba_predict as NP
from tpnet_ref.engines import numba_rollout as NR
from tpnet_ref.engines.thread_policy import ThreadPolicy


def median_us(fn, seconds: float, per: int = 1) -> float:
    fn()
    ts: list[float] = []
    start = time.perf_counter()
    while time.perf_counter() - start < seconds or len(ts) < 5:
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts)) * 1e6 / per


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="half", choices=["full", "half", "quarter"])
    ap.add_argument("--seconds", type=float, default=1.0)
    a = ap.parse_args()
    warnings.simplefilter("ignore")
    sec = a.seconds
    model = tpnet_ref.load(size=a.size)
    ring = np.asarray(tpnet_ref.example_window(), dtype=np.float32)
    c = model.config
    print(f"{machine()}\n{model}; medians over {sec} s of calls")

    points, counts, _ = model.screen(model, ring, True, False)
    head, fx = model.head_for(1), model.engine_features
    const = NP._constants(head, fx, model.dtype)[1]
    out = np.empty((1, c.n_out * c.dim), dtype=model.dtype)
    args = (points, counts, c.m, 1, *const, False, model._lo, model._scale,
            np.empty((0, 0), dtype=model.dtype), out)
    NP.network_steps(*args)
    entry = CW.entry_point(NP.network_steps, args)
    names = ", ".join(f"a{i}" for i in range(len(args)))
    scope: dict = {}
    exec(f"def nothing({names}):\n    return 0", scope)
    from numba import njit
    nothing = njit(scope["nothing"])
    nothing(*args)
    empty = CW.entry_point(nothing, args)
    print(f"1. network kernel: dispatcher {median_us(lambda: NP.network_steps(*args), sec):.1f} us, "
          f"entry {median_us(lambda: entry(*args), sec):.1f} us; an empty kernel of the same "
          f"{len(args)} arguments: dispatcher {median_us(lambda: nothing(*args), sec):.2f} us, "
          f"entry {median_us(lambda: empty(*args), sec):.2f} us")

    pts = np.empty((c.m * ring.shape[1], c.dim), dtype=model.dtype)
    full = (ring, c.m, False, c.norm_lo, c.norm_hi - c.norm_lo, model._lo, model._scale, np.inf,
            True, model.sort_points, pts)
    nobody = full[:8] + (False,) + full[9:]
    nosort = nobody[:9] + (False,) + nobody[10:]
    print(f"2. first pass: {median_us(lambda: NC.screen(*full), sec):.2f} us; without the "
          f"one-body test {median_us(lambda: NC.screen(*nobody), sec):.2f}; without it and the "
          f"sort {median_us(lambda: NC.screen(*nosort), sec):.2f}")

    seen: list = []
    record = ThreadPolicy.record

    def spy(self, kind, choice, seconds):
        if kind[1] == "predict":
            seen.append((choice, seconds))
        return record(self, kind, choice, seconds)
    ThreadPolicy.record = spy
    for fixed in ("1", "2", ""):
        os.environ["TPNET_THREADS"] = fixed
        seen.clear()
        call = median_us(lambda: model.predict(ring), 2 * sec)
        blocks = {p: [s for ch, s in seen if ch == p] for p in (1, 0)}
        rec = ", ".join(f"{'one' if p else 'two'} thread(s) {len(v)} calls, block "
                        f"{np.median(v) * 1e6:.0f} us" for p, v in blocks.items() if v)
        print(f"3. predict, TPNET_THREADS={fixed or 'unset'}: {call:.0f} us"
              + (f" (the policy recorded {rec})" if rec else ""))
    ThreadPolicy.record = record

    fusable = NR.fusable
    for label, fixed, fuse in (("compiled call of every step", "1", True),
                               ("steps one by one, one thread", "1", False),
                               ("steps one by one, two threads", "2", False)):
        os.environ["TPNET_THREADS"] = fixed
        NR.fusable = fusable if fuse else (lambda *x: False)
        print(f"4. rollout of 80, {label}: "
              f"{median_us(lambda: model.rollout(ring, 80), 2 * sec, 80):.0f} us a frame")
    NR.fusable = fusable

    os.environ["TPNET_THREADS"] = "2"
    together = median_us(lambda: model.predict(ring), 2 * sec)
    kept, NE.NETWORK_APART_BYTES = NE.NETWORK_APART_BYTES, 0
    apart = median_us(lambda: model.predict(ring), 2 * sec)
    NE.NETWORK_APART_BYTES = kept
    print(f"5. predict, TPNET_THREADS=2: the directions together {together:.0f} us, apart "
          f"{apart:.0f} us")
    del os.environ["TPNET_THREADS"]


if __name__ == "__main__":
    main()
