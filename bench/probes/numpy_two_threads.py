"""Can the NumPy engine's one window use the second core the way onnxruntime does?

    PYTHONPATH=bench python bench/probes/numpy_two_threads.py [--rounds 5]

Three measurements of the shipped m = 4 model on scene windows, in one run, rounds interleaved:

1. onnxruntime at B = 1 with one intra-op thread and with its default (every core), beside the
   NumPy engine's B = 1 (one core by design): how much of the peer's lead is its second core.
2. BiLSTM 1's recurrence of one window (the largest part of the prediction network): the
   engine's (one direction after the other, ``layers.DIRECTION_MAJOR_BYTES``), both directions
   stepped together, and the engine's step loop (``layers.advance_directions``) with the
   backward direction handed to a second Python thread (a dedicated worker woken by a lock: the
   cheapest hand-off Python offers) -- the same bits, checked.
3. The cost of that hand-off alone (an empty job), and of a ``ThreadPoolExecutor`` round trip.

Each figure is the median of the rounds' medians. What it answered is in docs/performance.md,
"Why the NumPy engine stops short of onnxruntime at B = 1".
"""
from __future__ import annotations

import argparse
import threading
import time
import warnings
from concurrent.futures import ThreadPoolExecutor

import numpy as np

import tpnet_ref
import tpnet_ref.engines.layers as L
from _common import machine, scene_windows
from tpnet_ref.engines.blas import one_thread


class Worker:
    """One thread that runs a job when a lock is released and releases another when done."""

    def __init__(self) -> None:
        self.go, self.done = threading.Lock(), threading.Lock()
        self.go.acquire()
        self.done.acquire()
        self.job: tuple = ()
        self.result = None
        threading.Thread(target=self._run, daemon=True).start()

    def _run(self) -> None:
        while True:
            self.go.acquire()
            fn, args = self.job
            self.result = fn(*args)
            self.done.release()

    def submit(self, fn, *args) -> None:
        self.job = (fn, args)
        self.go.release()

    def wait(self):
        self.done.acquire()
        return self.result


def median_us(fn, calls: int) -> float:
    fn()
    t = []
    for _ in range(calls):
        a = time.perf_counter()
        fn()
        t.append(time.perf_counter() - a)
    return float(np.median(t)) * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    from tpnet_ref.conformance.onnx_peer import onnx_session
    print(f"machine: {machine()}")
    model = tpnet_ref.load(engine="numpy")
    _, x256 = scene_windows(model)
    xs = x256[::4]
    ort1, ort_all = onnx_session(model, threads=1), onnx_session(model, threads=None)

    # BiLSTM 1 of one window: its input projection, then the recurrence one way and the other
    head = model.head_for(1)
    frames = list(xs[3])
    g = model.frame_features(*model.canonical_points(frames, True), 1)
    xp = head.project(g)
    lay = head.layers[0]
    rec, bias, u = lay.fused.recurrent, lay.fused.bias, lay.fused.recurrent.shape[1]
    steps = model.config.m
    both = lambda: L.bilstm_steps(xp, rec, bias, steps, 1, "relu", True)  # noqa: E731
    x4 = xp.reshape(steps, 2, 1, 4 * u)

    def split() -> np.ndarray:
        """bilstm_steps's layout, its step loop per direction, the backward one on the worker."""
        xs = np.empty_like(x4)
        np.add(x4[:, 0], bias[:4 * u], out=xs[:, 0])
        np.add(x4[::-1, 1], bias[4 * u:], out=xs[:, 1])
        hs, c = np.empty((steps, 2, 1, u), np.float32), np.empty((2, 1, u), np.float32)
        worker.submit(L.advance_directions, xs[:, 1:], hs[:, 1:], c[1:], rec[1:])
        L.advance_directions(xs[:, :1], hs[:, :1], c[:1], rec[:1])
        worker.wait()
        return np.concatenate([hs[:, 0], hs[::-1, 1]], axis=-1)

    def together() -> np.ndarray:     # bilstm_steps with its direction-major path turned off
        saved, L.DIRECTION_MAJOR_BYTES = L.DIRECTION_MAJOR_BYTES, 1 << 62
        try:
            return both()
        finally:
            L.DIRECTION_MAJOR_BYTES = saved

    worker, pool = Worker(), ThreadPoolExecutor(max_workers=1)
    same = all(np.array_equal(f(), both()) for f in (split, together))
    rows: dict[str, list[float]] = {}
    with one_thread():
        for _ in range(args.rounds):
            for label, fn, calls in (
                    ("onnxruntime B = 1, one thread", lambda: [ort1.run(None, {"window": xs[i][None]}) for i in range(64)], 10),
                    ("onnxruntime B = 1, default threads", lambda: [ort_all.run(None, {"window": xs[i][None]}) for i in range(64)], 10),
                    ("NumPy engine B = 1", lambda: [model.predict(xs[i], normalized=True) for i in range(64)], 10)):
                rows.setdefault(label, []).append(median_us(fn, calls) / 64)
            for label, fn in (("BiLSTM 1 recurrence, the engine's (bilstm_steps)", both),
                              ("BiLSTM 1 recurrence, both directions stepped together", together),
                              ("BiLSTM 1 recurrence, backward on a second thread", split),
                              ("hand-off to a waiting thread, empty job", lambda: (worker.submit(int), worker.wait())),
                              ("ThreadPoolExecutor round trip, empty job", lambda: pool.submit(int).result())):
                rows.setdefault(label, []).append(median_us(fn, 300))
    print(f"{args.rounds} rounds; medians of the rounds' medians:")
    for label, v in rows.items():
        print(f"  {label:52s} {np.median(v):8.1f} us")
    print(f"  the two-thread recurrence gives the same bits: {same}")


if __name__ == "__main__":
    main()
