"""``tpnet info`` and ``tpnet predict``: describe a weights file, predict from a window file."""
from __future__ import annotations

import sys
import warnings
from typing import Any

import numpy as np

from ..checks import OutsideTrainingRangeWarning
from ..engines.interface import resolve_engine

#: ``tpnet predict`` runs the Numba engine (where installed) from this many steps on: below, a
#: fresh process's cost of loading numba and its cached code (docs/deployment.md) is more than
#: what it saves on the steps
NUMBA_MIN_STEPS = 1000


def add_cli(sub: Any) -> None:
    p = sub.add_parser("info", help="describe a weights file: network, parameters, stored dtype, "
                                    "provenance")
    p.add_argument("weights", nargs="?", default=None,
                   help="native weights file (default: the shipped m=4 model)")
    p.add_argument("--json", action="store_true",
                   help="every config field and root attribute of the file as JSON")
    p.set_defaults(func=_cli_info)

    p = sub.add_parser("predict", help="predict the next point set(s) from a window in a .npy file")
    p.add_argument("window", help=".npy file holding an (m, N, 2) window in world units ((m, N, "
                                  "3) for a 3-D model): m frames 4 simulation steps apart "
                                  "(every 4th row of `tpnet sim run`)")
    p.add_argument("--weights", default=None, help="native weights file (default: shipped m=4)")
    p.add_argument("--steps", type=int, default=1, help="frames to roll out")
    p.add_argument("--normalized", action="store_true", help="window is in model coordinates")
    p.add_argument("--dtype", default="float32", choices=("float32", "float64"),
                   help="precision of the computation; float64 where float32 overflows")
    p.add_argument("--engine", default=None, choices=("numpy", "numba", "auto"),
                   help="inference engine (default: the faster for this call from a fresh "
                        f"process: numba, where installed, from {NUMBA_MIN_STEPS} steps on; "
                        "numpy below, where loading numba costs more than it saves)")
    p.add_argument("-o", "--output", default=None, help="file for the (steps, n_out, 2) result, .npy format, written to exactly this path")
    p.set_defaults(func=_cli_predict)


def _cli_info(args: Any) -> int:
    import json

    from ..weights.native import UnverifiedFileWarning, describe, read_native
    from ..weights.shipped import default_weights_path
    path = args.weights or default_weights_path()
    with warnings.catch_warnings(record=True) as caught:   # damage is an error (exit 2)
        warnings.simplefilter("always", UnverifiedFileWarning)
        if args.json:
            cfg, _, meta = read_native(path)
            text = json.dumps({"config": cfg.to_dict(), "meta": meta}, indent=1, sort_keys=True,
                              default=str)
        else:
            text = describe(path)
    for w in caught:
        print(f"tpnet info: warning: {w.message}", file=sys.stderr)
    print(text)
    return 0


def _predict(args: Any, engine: str) -> tuple[np.ndarray, list[Any]]:
    """The rollout ``tpnet predict`` asks for, and the input warnings it gave."""
    import tpnet_ref

    from .files import load_npy
    model = tpnet_ref.load(args.weights, dtype=args.dtype, engine=engine)
    window = load_npy(args.window)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", OutsideTrainingRangeWarning)
        out = tpnet_ref.rollout(window, args.steps, model=model, normalized=args.normalized)
    return out, caught


def _cli_predict(args: Any) -> int:
    from .files import output_path, save_npy
    if args.output:
        output_path(args.output)                # a bad directory fails before any work
    engine = args.engine or ("auto" if args.steps >= NUMBA_MIN_STEPS else "numpy")
    if resolve_engine(engine) == "numpy":
        out, caught = _predict(args, engine)
    else:                       # the Numba engine: what it does and its compilation said
        from . import watched
        steps = f"{args.steps} step" + ("" if args.steps == 1 else "s")
        out, caught = watched("tpnet predict", f"{steps} on the Numba engine", _predict, args,
                              engine)
    for w in caught:
        print(f"tpnet predict: warning: {w.message}", file=sys.stderr)
    if args.output:
        p = save_npy(args.output, out)
        print(f"wrote {out.shape} to {p}")
    else:
        np.set_printoptions(precision=4, suppress=True)
        print(out)
    return 0
