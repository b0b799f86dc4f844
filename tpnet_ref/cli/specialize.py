"""``tpnet specialize`` and ``tpnet sort-units``: a weights file made faster on a scene
(docs/performance.md)."""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ..weights.provenance import portable_path
from .files import load_npy, output_path


def _output_args(p: Any, what: str) -> None:
    """The arguments both commands share: -o, --weights, --max-windows."""
    p.add_argument("-o", "--output", required=True, help="native weights file to write")
    p.add_argument("--weights", default=None, help="native weights file (default: shipped m=4)")
    p.add_argument("--max-windows", type=int, default=20000,
                   help=f"use at most this many {what} (default 20000)")


def add_cli(sub: Any) -> None:
    p = sub.add_parser("specialize", help="write a model that computes only the units a scene "
                                          "uses (the same function on every input up to rounding: other windows run in full)")
    p.add_argument("source", help="calibration windows: a dataset file of `tpnet data` (its "
                                  "training windows, never the test cases) or a .npy (B, m, N, 2) "
                                  "array of windows in world units")
    _output_args(p, "calibration windows")
    p.set_defaults(func=_cli_specialize)

    q = sub.add_parser("sort-units", help="write the same network with each layer's units laid "
                                          "out most used first on a scene (the same function "
                                          "up to rounding, faster on the scene)")
    q.add_argument("source", nargs="?", default=None,
                   help="windows to measure use on: a dataset file of `tpnet data` (its training "
                        "windows) or a .npy (B, m, N, 2) array in world units; default: windows "
                        "of --trajectories simulated training-grid trajectories and the model's "
                        "own rollouts from them (never the test cases)")
    _output_args(q, "windows")
    q.add_argument("--trajectories", type=int, default=36,
                   help="training-grid trajectories when no source is given (default 36)")
    q.set_defaults(func=_cli_sort_units)


def _prepare(args: Any) -> tuple[Path | None, Path, Any]:
    """The checked source (None: simulate), the output path and the model to start from; a
    missing source is reported before anything is loaded."""
    from ..model import load
    src = None if args.source is None else Path(args.source)
    if src is not None and not src.is_file():
        raise FileNotFoundError(f"source not found: {src}")
    # batches of many windows: the NumPy head runs them either way (no numba to load)
    return src, output_path(args.output, "-o"), load(args.weights, engine="numpy")


def _windows(args: Any, src: Path | None, model: Any) -> tuple[np.ndarray, bool, str]:
    """At most ``--max-windows`` windows from ``src`` (or simulated training-grid ones), whether
    they are normalised, and a description for the provenance."""
    if src is None:
        from ..sim.dataset import calibration_windows
        n = args.trajectories
        windows, normalized = calibration_windows(model, n), False
        what = f"{n} training-grid trajectories + rollouts"
    elif src.suffix == ".npy":
        windows, normalized, what = load_npy(str(src), "source"), False, portable_path(src)
    else:
        from ..sim.dataset import load_windows
        windows, _ = load_windows(str(src), "train", normalized=True)
        normalized, what = True, f"{portable_path(src)} (training windows)"
    return np.asarray(windows)[:args.max_windows], normalized, what


def _cli_sort_units(args: Any) -> int:
    from ..engines import unit_order as U

    src, out, model = _prepare(args)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        windows, normalized, what = _windows(args, src, model)
        use = U.measure(model, windows, normalized)
    srt = model.with_unit_order(U.from_use(use))
    srt.save(out, units_sorted_on=f"{len(windows)} windows: {what}")
    print(f"wrote {out}: units sorted by use on {len(windows)} windows ({what}); never used: "
          + ", ".join(f"{k} {int((v == 0).sum())}/{v.size}" for k, v in use.items()))
    return 0


def _cli_specialize(args: Any) -> int:
    from ..engines import specialised as S

    src, out, model = _prepare(args)
    windows, normalized, _ = _windows(args, src, model)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        spec = model.specialize(windows, normalized=normalized)
    spec.save(out, specialized_from=portable_path(args.weights) if args.weights else "shipped m=4",
           calibration_windows=len(windows))
    used = S.fraction_used(spec.specialization.used)
    print(f"wrote {out}: calibrated on {len(windows)} windows; units used: "
          + ", ".join(f"{k} {a}/{b}" for k, (a, b) in used.items())
          + f"; the specialised head reads {spec.specialization.num_params():,} of "
          f"{model.num_params:,} parameters")
    return 0
