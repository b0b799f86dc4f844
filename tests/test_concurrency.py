"""One model serves many threads: ``predict``, ``predict_batch`` (small, and large enough to be
split across threads itself) and ``rollout`` called concurrently from 8 threads on one model
give the same bits as the same calls made one after another, on both engines (README, "Same
bits on every call"; docs/tolerances.md); and a split batch gives, window by window and in its
order, what each window gives alone (within the stated per-prediction bound)."""
from __future__ import annotations

import threading
import warnings

import numpy as np
import pytest

import tpnet_ref
from tolerance_bounds import BOUNDS

THREADS = 8
CALLS = 6            # per thread
BIG = 2              # of the calls, batches of 70 windows (split into chunks run on the cores)


def _work(model, rng):
    """The calls: ``(kind, argument)``, mixed, on ring windows drifting through the box."""
    a = np.arange(30) * 2 * np.pi / 30
    ring = 2 * np.stack([np.sin(a), np.cos(a)], 1)
    def window():
        start, vel = rng.uniform(8, 37, 2), rng.uniform(-0.6, 0.6, 2)
        w = start + vel * np.arange(4)[:, None, None] + ring
        return np.stack([f[rng.permutation(30)] for f in w])
    calls = []
    for i in range(THREADS * CALLS):
        kind = "big" if i < BIG else ("predict", "batch", "rollout")[i % 3]
        if kind == "predict":
            calls.append((kind, window()))
        elif kind == "batch":
            calls.append((kind, np.stack([window() for _ in range(5)])))
        elif kind == "rollout":
            calls.append((kind, window()))
        else:
            calls.append(("batch", np.stack([window() for _ in range(70)])))   # split inside
    return calls


def _run(model, call):
    kind, x = call
    if kind == "predict":
        return model.predict(x)
    if kind == "batch":
        return model.predict_batch(x)
    return model.rollout(x, 12)


@pytest.mark.parametrize("engine", ["numpy", "numba"])
def test_concurrent_calls_give_the_serial_bits(engine):
    if engine == "numba":
        pytest.importorskip("numba")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = tpnet_ref.load(engine=engine)
    calls = _work(model, np.random.default_rng(0))
    serial = [_run(model, c) for c in calls]
    for (kind, x), y in zip(calls[:BIG], serial[:BIG]):          # the split batches
        alone = np.stack([model.predict(w) for w in x])
        gap = np.abs(y - alone).max()
        assert gap <= BOUNDS["float32"]["predict"], f"split batch vs its windows alone: {gap}"
    got: list = [None] * len(calls)
    errors: list = []
    start = threading.Barrier(THREADS)

    def worker(t: int) -> None:
        try:
            start.wait()
            for i in range(t, len(calls), THREADS):      # each thread its share, interleaved
                got[i] = _run(model, calls[i])
        except BaseException as exc:                      # reported below, not lost in a thread
            errors.append(exc)

    threads = [threading.Thread(target=worker, args=(t,)) for t in range(THREADS)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert not errors, errors
    bad = [i for i, (a, b) in enumerate(zip(serial, got)) if not np.array_equal(a, b)]
    assert not bad, f"{len(bad)} of {len(calls)} concurrent calls differ from serial: {bad[:10]}"
