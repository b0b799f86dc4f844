"""Where one B = 1 prediction of the shipped model spends its time, stage by stage.

    python bench/profile_stages.py [--reps 300] [--engine numpy|numba]

Inputs: 64 windows of simulated test cases (``bench_inference.scene_windows``), normalised, one
after another, a one-thread BLAS. Each stage's time is the median over predictions of the time
spent inside it (the stages nest: ``sequence head`` holds the products and recurrences; the
layer functions are timed separately).
"""
from __future__ import annotations

import argparse
import collections
import sys
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import tpnet_ref  # noqa: E402
from tpnet_ref import layers as L  # noqa: E402
from tpnet_ref import model as M  # noqa: E402
from tpnet_ref.blas import one_thread  # noqa: E402
from bench_inference import scene_windows  # noqa: E402

STAGES = {  # label: (owner, attribute)
    "predict (whole call)": (M.TPNet, "predict"),
    "input checks": (M.TPNet, "_check_window"),
    "canonical order + normalise": (M.TPNet, "_canonical_points"),
    "feature extractor": (M.TPNet, "frame_features"),
    "sequence head": (M.TPNet, "sequence_head"),
    "  BiLSTM 1 input projection": (M.TPNet, "project_frames"),
    "  recurrences (bilstm_steps)": (L, "bilstm_steps"),
    "  LayerNorm-folded projections": (L, "project_layer_norm"),
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=300)
    ap.add_argument("--engine", default="numpy", choices=("numpy", "numba"))
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    model = tpnet_ref.load(engine=args.engine)
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
    print(f"{model}\nB = 1, one-thread BLAS, {args.reps} predictions of 64 scene windows; "
          "median time inside each stage:")
    total = float(np.median(per_call["predict (whole call)"]))
    for label in STAGES:
        t = float(np.median(per_call[label]))
        print(f"  {label:34s} {t * 1e6:8.1f} us  {100 * t / total:5.1f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
