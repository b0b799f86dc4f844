"""``tpnet specialize``: a scene-specialised copy of a weights file (docs/performance.md)."""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

from .files import load_npy, output_path


def add_cli(sub: Any) -> None:
    p = sub.add_parser("specialize", help="write a model that computes only the units a scene "
                                          "uses (exact on every input: other windows run in full)")
    p.add_argument("source", help="calibration windows: a dataset file of `tpnet data` (its "
                                  "training windows, never the test cases) or a .npy (B, m, N, 2) "
                                  "array of windows in world units")
    p.add_argument("-o", "--output", required=True, help="native weights file to write")
    p.add_argument("--weights", default=None, help="native weights file (default: shipped m=4)")
    p.add_argument("--max-windows", type=int, default=20000,
                   help="use at most this many calibration windows (default 20000)")
    p.set_defaults(func=_cli_specialize)


def _cli_specialize(args: Any) -> int:
    from .. import specialize as S
    from ..model import load

    src = Path(args.source)
    if not src.is_file():
        raise FileNotFoundError(f"source not found: {src}")
    out = output_path(args.output, "-o")
    model = load(args.weights)
    if src.suffix == ".npy":
        windows = load_npy(str(src), "source")
        normalized = False
    else:
        from ..data import load_windows
        windows, _ = load_windows(str(src), "train", normalized=True)
        normalized = True
    windows = np.asarray(windows)[:args.max_windows]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        spec = model.specialize(windows, normalized=normalized)
    S.save(spec, out, specialized_from=str(args.weights or "shipped m=4"),
           calibration_windows=len(windows))
    used = S.fraction_used(spec.specialization.used)
    print(f"wrote {out}: calibrated on {len(windows)} windows; units used: "
          + ", ".join(f"{k} {a}/{b}" for k, (a, b) in used.items())
          + f"; the specialised head reads {spec.specialization.num_params():,} of "
          f"{model.num_params:,} parameters")
    return 0
