"""Where the time of one B = 1 prediction goes (float32, released shape, m = 4, N = 30).

    python bench/profile_predict.py      (OPENBLAS_NUM_THREADS=1 for one core)

Times each stage on its own (median of many calls) and prints its share of the sum, next to the
bytes of weights it streams, so the memory-bound and compute-bound parts can be told apart.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from tpnet_ref import layers as L  # noqa: E402
from tpnet_ref.model import canonical_order, init_random  # noqa: E402


def med(fn, reps: int = 400) -> float:
    fn()
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def in_sequence(model, window, calls: int = 300) -> None:
    """The same stages timed inside whole predictions (each call wrapped, medians): the weights
    then come from memory as in real use, not from cache as when a stage is repeated alone."""
    import tpnet_ref.model as M
    times: dict[str, list[float]] = {}
    layer = [0]
    saved = []

    def wrap(owner, name: str, per_layer: bool = False) -> None:
        f = getattr(owner, name)
        saved.append((owner, name, f))

        def timed(*a, **k):
            t = time.perf_counter()
            r = f(*a, **k)
            dt = time.perf_counter() - t
            key = f"{name} {layer[0] % 3 + 1}" if per_layer else name
            if name == "bilstm_fused":
                layer[0] += 1
            times.setdefault(key, []).append(dt)
            return r
        setattr(owner, name, timed)

    wrap(M.TPNet, "_check_window")
    wrap(M, "canonical_order")
    wrap(M.TPNet, "frame_features")
    wrap(L, "project", True)
    wrap(L, "bilstm_fused", True)
    wrap(L, "layer_norm")
    wrap(M.TPNet, "predict")
    try:
        for _ in range(30):
            model.predict(window)
        times.clear()
        layer[0] = 0
        for _ in range(calls):
            model.predict(window)
    finally:
        for owner, name, f in saved:
            setattr(owner, name, f)
    print(f"\nin sequence, inside {calls} whole predictions (median per prediction; "
          "bilstm_fused includes its input projection 'project'):")
    for key, ts in times.items():
        n = len(ts) // calls
        print(f"  {key:22s} x{n}  {np.median(ts) * n * 1e6:8.1f} us")


def cold_blocks(model, reps: int = 11) -> None:
    """Each LSTM input projection of one window (4 rows) with its weights not in cache (256 MB
    read before every call), as one product and in column blocks of several widths, one thread."""
    from tpnet_ref.blas import SMALL_PRODUCT, one_thread
    evict = np.ones(64 * 2**20, np.float32)
    rng = np.random.default_rng(1)

    def cold(fn) -> float:
        ts = []
        for _ in range(reps):
            evict.sum()
            t = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t)
        return float(np.median(ts))

    print("\ninput projections of one window, weights not in cache, one thread (us):")
    with one_thread():
        for fused, _, _ in model._lstms:
            k = fused.kernel
            c, n = k.shape
            x = rng.standard_normal((4, c)).astype(k.dtype)
            row = [f"plain {cold(lambda: x @ k) * 1e6:7.0f}"]
            for nb in (16, 32, 64, 128, 256, 1024):
                if n % nb == 0 and 4 * c * nb <= SMALL_PRODUCT:
                    b = np.ascontiguousarray(k.reshape(c, n // nb, nb).transpose(1, 0, 2))
                    row.append(f"blocks of {nb} {cold(lambda: np.matmul(x, b)) * 1e6:6.0f}")
            print(f"  {c}x{n}: " + ", ".join(row))


def engine_numba(model, window, calls: int = 200) -> None:
    """The numba engine's prediction network against the NumPy one, inside whole predictions
    (weights from memory), serial and with the two directions in parallel (medians)."""
    try:
        nb = model.with_engine("numba")
    except ImportError as exc:
        print(f"\nengine=numba skipped ({exc})")
        return
    from tpnet_ref.blas import one_thread
    counts = np.full(4, 30)
    pts = model.normalize(window.reshape(-1, 2).astype(np.float32))
    pts = pts[canonical_order(pts, counts)]
    g = model.frame_features(pts, counts).reshape(1, 4, -1)

    def serial(fn):
        def run():
            with one_thread():
                fn()
        return run

    fns = {"NumPy head, BLAS threads": lambda: model._full_head(g),
           "NumPy head, one thread": serial(lambda: model._full_head(g)),
           "numba head, directions in parallel": lambda: nb._full_head(g),
           "numba head, serial": serial(lambda: nb._full_head(g)),
           "predict, engine=numpy": lambda: model.predict(window),
           "predict, engine=numba": lambda: nb.predict(window)}
    ts: dict[str, list[float]] = {k: [] for k in fns}
    for f in fns.values():
        f()
    for _ in range(calls):                  # interleaved
        for k, f in fns.items():
            t = time.perf_counter()
            f()
            ts[k].append(time.perf_counter() - t)
    print(f"\nprediction network (BiLSTMs, LayerNorms, head) of one window, {calls} interleaved calls:")
    for k, v in ts.items():
        print(f"  {k:40s} {np.median(v) * 1e6:8.1f} us")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.parse_args(argv)
    model = init_random(seed=0, dtype="float32")
    rng = np.random.default_rng(0)
    window = rng.uniform(5, 40, (4, 30, 2))
    counts = np.full(4, 30)
    pts = model.normalize(window.reshape(-1, 2).astype(np.float32))
    pts = pts[canonical_order(pts, counts)]
    g = model.frame_features(pts, counts).reshape(4, 1, -1)   # time-major (m, B, k)

    stages: list[tuple[str, float, float]] = []
    stages.append(("validate + normalise + canonical sort",
                   med(lambda: (model._check_window(window, "window"),
                                canonical_order(model.normalize(window.reshape(-1, 2).astype(np.float32)),
                                                counts))), 0.0))
    fb = sum(p.nbytes for k, p in model.params.items() if k.startswith(("mlp", "global")))
    stages.append(("feature extractor, 4 frames x 30 points", med(lambda: model.frame_features(pts, counts)), fb))
    h = g
    last = len(model._lstms) - 1
    for i, (fused, gamma, beta) in enumerate(model._lstms):
        k, r = fused.kernel, fused.recurrent
        rows = h.reshape(4, -1)
        stages.append((f"BiLSTM {i + 1}: input projection {k.shape[0]}->{k.shape[1]} (4 steps)",
                       med(lambda: L.project(rows, k, fused.blocks)), k.nbytes))
        full = med(lambda: L.bilstm_fused(h, *fused, return_sequences=i < last))
        proj = stages[-1][1]
        stages.append((f"BiLSTM {i + 1}: recurrence, gates (3 products of {r.shape[1]}x{r.shape[2]} x2)",
                       max(full - proj, 0.0), 3 * r.nbytes))
        out = L.bilstm_fused(h, *fused, return_sequences=i < last)
        stages.append((f"LayerNorm {i + 1}", med(lambda: L.layer_norm(out, gamma, beta, 1e-3)), 0.0))
        h = L.layer_norm(out, gamma, beta, 1e-3)
    stages.append(("head FC 512->60 + sigmoid",
                   med(lambda: L.dense(h, model.params["head.w"], model.params["head.b"], "sigmoid")),
                   model.params["head.w"].nbytes))
    total = med(lambda: model.predict(window), 400)
    s = sum(t for _, t, _ in stages)
    print(f"{'stage':66s} {'us':>8s} {'share':>6s} {'weights MB':>10s} {'GB/s':>6s}")
    for name, t, nbytes in stages:
        gbs = f"{nbytes / t / 1e9:6.1f}" if nbytes and t > 0 else ""
        print(f"{name:66s} {t * 1e6:8.1f} {t / s:6.1%} {nbytes / 1e6:10.2f} {gbs}")
    print(f"{'sum of stages':66s} {s * 1e6:8.1f}")
    print(f"{'predict(window), measured whole':66s} {total * 1e6:8.1f}")
    in_sequence(model, window)
    cold_blocks(model)
    engine_numba(model, window)

    # B = 256: the split between the two halves, and the share of matrix products in the head
    big = rng.uniform(5, 40, (256, 4, 30, 2))
    bp = model.normalize(big.reshape(-1, 2).astype(np.float32))
    bc = np.full(1024, 30)
    bp = bp[canonical_order(bp, bc)]
    gb = model.frame_features(bp, bc).reshape(256, 4, -1)
    gb_tm = gb.transpose(1, 0, 2)
    t_sort = med(lambda: canonical_order(bp, bc), 10)
    t_feat = med(lambda: model.frame_features(bp, bc), 10)
    t_head = med(lambda: model.sequence_head(gb), 10)
    flops = 0.0
    t_mm = 0.0
    h = gb_tm
    for i, (fused, gamma, beta) in enumerate(model._lstms):
        k, r = fused.kernel, fused.recurrent
        rows = h.reshape(-1, k.shape[0])
        hb = np.random.default_rng(i).standard_normal((2, 256, r.shape[1])).astype(np.float32)
        t_mm += med(lambda: rows @ k, 10) + 3 * med(lambda: np.matmul(hb, r), 10)
        flops += 2 * rows.shape[0] * k.shape[0] * k.shape[1] + 3 * 2 * 2 * 256 * r.shape[1] * r.shape[2]
        h = L.layer_norm(L.bilstm_fused(h, *fused, return_sequences=i < last), gamma, beta, 1e-3)
    print(f"\nB = 256 (1024 frames): canonical sort {t_sort * 1e3:.1f} ms, feature extractor "
          f"{t_feat * 1e3:.1f} ms, prediction network {t_head * 1e3:.1f} ms, of which matrix "
          f"products {t_mm * 1e3:.1f} ms ({flops / 1e9:.1f} GFLOP at {flops / t_mm / 1e9:.0f} GFLOP/s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
