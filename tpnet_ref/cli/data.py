"""``tpnet data generate``: simulate the training grid and the 60 test cases into one HDF5 file."""
from __future__ import annotations

from typing import Any

from ..sim.cases import TRAIN_ANGLES_DEG, TRAIN_FORCES
from .sim import add_scene_flags


def add_cli(sub: Any) -> None:
    p = sub.add_parser("data", help="generate the synthetic dataset (HDF5)")
    dsub = p.add_subparsers(dest="data_command", metavar="DATA_COMMAND")
    dsub.required = True
    q = dsub.add_parser("generate", help="simulate the training grid and the 60 test cases")
    q.add_argument("-o", "--output", required=True, help="HDF5 file (resumed if it exists)")
    q.add_argument("--forces", type=float, nargs="+", default=list(TRAIN_FORCES),
                   help="impulses per particle of the training grid")
    q.add_argument("--angles", type=float, nargs="+", default=list(TRAIN_ANGLES_DEG),
                   help="impulse directions of the training grid, degrees")
    q.add_argument("--positions", type=int, default=None,
                   help="use the first N of the 75 start positions (default: all 75)")
    q.add_argument("--limit", type=int, default=None,
                   help="only the first N trajectories (default: all)")
    q.add_argument("--m", type=int, default=4, help="input frames per window (3, 4, 5)")
    q.add_argument("--steps", type=int, default=600, help="simulation steps per trajectory")
    q.add_argument("--seed", type=int, default=0, help="window sampling seed")
    q.add_argument("--whole", type=int, default=240,
                   help="trajectories that give every window (paper: 240)")
    q.add_argument("--windows", choices=("model", "released"), default="model",
                   help="model: windows start at model frames; released: also keep every "
                        "simulator row (~1 GB for the grid) and the authors' preprocessing's "
                        "windows, for `tpnet train run --windows released` (default: %(default)s)")
    q.add_argument("--workers", type=int, default=1, help="processes simulating in parallel")
    q.add_argument("--no-test", action="store_true", help="skip the 60 test cases")
    q.add_argument("--quiet", action="store_true", help="no progress bar")
    add_scene_flags(q)
    q.set_defaults(func=_cli_generate)


def _cli_generate(args: Any) -> int:
    import numpy as np

    from ..sim.dataset import generate, train_grid
    from ..sim.cases import TEST_CASES
    from ..sim.scene import SceneParams
    grid = train_grid(args.forces, args.angles, args.positions)
    if args.limit is not None:
        if args.limit < 1:
            raise ValueError(f"--limit: must be >= 1, got {args.limit}")
        grid = grid[: args.limit]
    counts = generate(args.output, grid, None if args.no_test else np.asarray(TEST_CASES),
                      m=args.m, steps=args.steps, seed=args.seed, workers=args.workers,
                      whole=args.whole, progress=not args.quiet, windows=args.windows,
                      params=SceneParams(impulse_point=args.impulse_point, sleep=args.sleep))
    print(f"wrote {args.output}: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    return 0
