"""``tpnet info`` and ``tpnet predict``: describe a weights file, predict from a window file."""
from __future__ import annotations

from typing import Any

import numpy as np


def add_cli(sub: Any) -> None:
    p = sub.add_parser("info", help="describe a weights file (config, parameters, provenance)")
    p.add_argument("weights", nargs="?", default=None,
                   help="native weights file (default: the shipped m=4 model)")
    p.set_defaults(func=_cli_info)

    p = sub.add_parser("predict", help="predict the next point set(s) from a window in a .npy file")
    p.add_argument("window", help=".npy file holding an (m, N, 2) window in world units")
    p.add_argument("--weights", default=None, help="native weights file (default: shipped m=4)")
    p.add_argument("--steps", type=int, default=1, help="frames to roll out (default 1)")
    p.add_argument("--normalized", action="store_true", help="window is in model coordinates")
    p.add_argument("--dtype", default="float32", choices=("float32", "float64"))
    p.add_argument("-o", "--output", default=None, help=".npy file for the (steps, n_out, 2) result")
    p.set_defaults(func=_cli_predict)


def _cli_info(args: Any) -> int:
    from ..weights import load
    model = load(args.weights, dtype="float64")
    print(model)
    for k, v in model.config.to_dict().items():
        print(f"  {k:26s} {v}")
    for k, v in sorted(model.meta.items()):
        print(f"  meta.{k:21s} {v}")
    return 0


def _cli_predict(args: Any) -> int:
    from ..weights import load
    model = load(args.weights, dtype=args.dtype)
    try:
        window = np.load(args.window, allow_pickle=False)
    except (ValueError, EOFError, OSError) as exc:
        if isinstance(exc, FileNotFoundError):
            raise FileNotFoundError(f"window file not found: {args.window}") from None
        raise ValueError(f"window file {args.window}: not a numeric .npy array ({exc})") from None
    if not isinstance(window, np.ndarray):
        raise ValueError(f"window file {args.window}: holds an archive, not one .npy array")
    out = model.rollout(window, args.steps, normalized=args.normalized)
    if args.output:
        np.save(args.output, out)
        print(f"wrote {out.shape} to {args.output}")
    else:
        np.set_printoptions(precision=4, suppress=True)
        print(out)
    return 0
