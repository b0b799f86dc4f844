"""Where one B = 1 prediction of the shipped model spends its time, stage by stage.

    PYTHONPATH=bench python bench/probes/profile_stages.py [--reps 300] [--engine numpy|numba]
        [--size full|half|quarter] [--separate]

Inputs: 64 windows of simulated test cases (``_common.scene_windows``), normalised, one
after another, a one-thread BLAS. Each stage's time is the median over predictions of the time
spent inside it (the stages nest: ``sequence head`` holds the products and recurrences; the
layer functions are timed separately). The Numba engine runs the network as one compiled call
(``engines/numba_predict.py``), timed as one stage; ``--separate`` runs it as separate calls
(extractor, projection, head), each timed.

With the NumPy engine it also counts the weight bytes the prediction network's products read
per prediction (the rows each product reads: recurrent prefixes and projection spans) and
times how fast this core streams an array of the model's size from beyond its own caches: their
quotient is the network's floor on this machine with one thread.
"""
from __future__ import annotations

import argparse
import collections
import sys
import time
import warnings

import numpy as np


import tpnet_ref
from tpnet_ref.engines import layers as L
from tpnet_ref import model as M
from tpnet_ref.engines.blas import one_thread
from _common import scene_windows

STAGES = {  # label: (owner, attribute)
    "predict (whole call)": (M.TPNet, "predict"),
    "input checks and warnings": (M, "check_window"),
    "  warnings (range, one body)": (M, "warn_about_input"),
    "canonical order + normalise": (M.TPNet, "canonical_points"),
    "feature extractor": (M.TPNet, "frame_features"),
    "sequence head": (M.TPNet, "sequence_head"),
    "  BiLSTM 1 input projection": (M.TPNet, "project_frames"),
    "  recurrences (bilstm_steps)": (L, "bilstm_steps"),
    "  LayerNorm-folded projections": (L, "project_layer_norm"),
}


def read_bytes(model, wins: list) -> None:
    """Print the weight bytes the NumPy prediction network reads per prediction (mean over
    ``wins``) and the core's streaming read rate over an array the size of the model."""
    got = {"recurrent products": 0.0, "input projections": 0.0}
    nonzero = [0.0]                      # of the recurrent rows read, those of non-zero states
    up, ps = L.used_prefixes, L.project_spans

    def prefixes(x):                     # each direction's rows of its (u, 4u) recurrent matrix
        ks = up(x)
        row = 4 * x.shape[2] * x.itemsize
        got["recurrent products"] += sum(ks) * row
        nonzero[0] += sum(int((x[d] != 0).any(axis=0).sum()) for d in range(len(ks))) * row
        return ks

    def spans(x, kernel, blocks, sp, *a, **k):
        got["input projections"] += sum(b - a0 for a0, b in sp if b > a0) * kernel.shape[1] * kernel.itemsize
        return ps(x, kernel, blocks, sp, *a, **k)
    L.used_prefixes, L.project_spans = prefixes, spans
    try:
        with one_thread():
            for w in wins:
                model.predict(w, normalized=True)
    finally:
        L.used_prefixes, L.project_spans = up, ps
    mb = {k: v / len(wins) / 1e6 for k, v in got.items()}
    # the products' own kind (a row vector times a (rows, 2048) matrix) over the model's bytes
    big = np.ones((model.num_params // 2048, 2048), dtype=np.float32)      # 28 MB
    v = np.ones(big.shape[0], dtype=np.float32)
    ts = []
    with one_thread():
        for _ in range(30):
            t = time.perf_counter()
            np.dot(v, big)
            ts.append(time.perf_counter() - t)
    rate = big.nbytes / float(np.median(ts)) / 1e9
    total = sum(mb.values())
    print(f"weights read by the prediction network per prediction: {total:.1f} MB ("
          + ", ".join(f"{k} {v:.1f} MB" for k, v in mb.items())
          + f"; of the recurrent rows read, {nonzero[0] / got['recurrent products']:.0%} multiply "
          f"non-zero states); one core reads a {big.nbytes / 1e6:.0f} MB matrix in a vector-matrix product "
          f"at {rate:.1f} GB/s (median of 30): {total / rate * 1e3:.0f} us at that rate\n")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=300)
    ap.add_argument("--engine", default="numpy", choices=("numpy", "numba"))
    ap.add_argument("--size", default="full", choices=("full", "half", "quarter"),
                    help="which shipped size (default: the full one)")
    ap.add_argument("--separate", action="store_true",
                    help="the Numba engine's network as separate calls, not one compiled call")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    model = tpnet_ref.load(engine=args.engine, size=args.size)
    if model.screen is not None:          # the Numba engine's first pass, where it decides
        STAGES["input checks: the compiled first pass"] = (type(model.screen), "__call__")
    if args.separate:
        model.fused = None
    elif model.fused is not None:
        STAGES["the network in one compiled call"] = (model.fused, "run")
    _, x256 = scene_windows(model)
    wins = list(x256[::4])
    spent: dict[str, float] = collections.defaultdict(float)
    per_call: dict[str, list[float]] = collections.defaultdict(list)
    originals = {}
    for label, (owner, name) in STAGES.items():
        fn = getattr(owner, name)
        originals[label] = fn

        def timed(*a, _fn=fn, _label=label, **k):
            t = time.perf_counter()
            try:
                return _fn(*a, **k)
            finally:
                spent[_label] += time.perf_counter() - t
        setattr(owner, name, timed)
    try:
        with one_thread():
            for w in wins:
                model.predict(w, normalized=True)               # warm
            for i in range(args.reps):
                spent.clear()
                model.predict(wins[i % len(wins)], normalized=True)
                for label in STAGES:
                    per_call[label].append(spent.get(label, 0.0))
    finally:
        for label, (owner, name) in STAGES.items():
            setattr(owner, name, originals[label])
    if args.engine == "numpy":
        read_bytes(model, wins)
    print(f"{model}\nB = 1, one-thread BLAS, {args.reps} predictions of 64 scene windows; "
          "median time inside each stage:")
    total = float(np.median(per_call["predict (whole call)"]))
    for label in STAGES:
        if not any(per_call[label]):       # a NumPy layer function the numba engine never calls
            continue
        t = float(np.median(per_call[label]))
        print(f"  {label:34s} {t * 1e6:8.1f} us  {100 * t / total:5.1f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
