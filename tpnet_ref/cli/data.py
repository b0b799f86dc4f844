"""``tpnet data generate``: simulate the training grid and the 60 test cases into one HDF5 file
(``--dim 3``: the 3-D scene's grid and its 60 test cases)."""
from __future__ import annotations

from typing import Any

from ..sim.cases import TRAIN_ANGLES_DEG, TRAIN_FORCES
from .sim import add_scene_flags

#: flags of one dimension only, and the dimension each belongs to
_ONLY = {"angles": 2, "impulse_point": 2, "sleep": 2, "azimuths": 3, "elevations": 3,
         "per_direction": 3}


def add_cli(sub: Any) -> None:
    p = sub.add_parser("data", help="generate the synthetic dataset (HDF5)")
    dsub = p.add_subparsers(dest="data_command", metavar="DATA_COMMAND")
    dsub.required = True
    q = dsub.add_parser("generate", help="simulate the training grid and the 60 test cases")
    q.add_argument("-o", "--output", required=True, help="HDF5 file (resumed if it exists)")
    q.add_argument("--dim", type=int, choices=(2, 3), default=2,
                   help="2: the paper's scene (a ring of 30 particles); 3: the 3-D scene (a "
                        "ball of 42 particles in a 45^3 box, MuJoCo: the sim3d extra), its grid "
                        "and its 60 test cases, released windows (default: %(default)s)")
    q.add_argument("--forces", type=float, nargs="+", default=list(TRAIN_FORCES),
                   help="impulses per particle of the training grid")
    q.add_argument("--angles", type=float, nargs="+", default=None,
                   help="impulse directions of the training grid, degrees (2-D; default: "
                        "180, 185, ..., 270)")
    q.add_argument("--azimuths", type=float, nargs="+", default=None,
                   help="3-D: horizontal impulse directions, degrees (default: 180, 185, ..., "
                        "270)")
    q.add_argument("--elevations", type=float, nargs="+", default=None,
                   help="3-D: impulse elevations above the horizontal, degrees (default: 0, -5, "
                        "..., -85)")
    q.add_argument("--per-direction", type=int, default=None,
                   help="3-D: throws per direction, forces taking turns (default 1: 342 "
                        "throws; 5: every force in every direction)")
    q.add_argument("--positions", type=int, default=None,
                   help="use the first N of the 75 start positions (default: all 75)")
    q.add_argument("--limit", type=int, default=None,
                   help="only the first N trajectories (default: all)")
    q.add_argument("--m", type=int, default=4, help="input frames per window (3, 4, 5)")
    q.add_argument("--steps", type=int, default=600, help="simulation steps per trajectory")
    q.add_argument("--seed", type=int, default=0, help="window sampling seed")
    q.add_argument("--whole", type=int, default=None,
                   help="trajectories that give every window (paper: 240; 3-D default: 3.5 %% "
                        "of the grid, the released share)")
    q.add_argument("--windows", choices=("model", "released"), default=None,
                   help="model: windows start at model frames; released: also keep every "
                        "simulator row (~1 GB for the 2-D grid) and the authors' "
                        "preprocessing's windows, for `tpnet train run --windows released` "
                        "(default: model in 2-D, released in 3-D)")
    q.add_argument("--workers", type=int, default=1, help="processes simulating in parallel")
    q.add_argument("--no-test", action="store_true", help="skip the 60 test cases")
    q.add_argument("--quiet", action="store_true", help="no progress bar")
    add_scene_flags(q)
    q.set_defaults(func=_cli_generate, impulse_point=None)


def _cli_generate(args: Any) -> int:
    import numpy as np

    from ..sim.dataset import generate, released_whole, train_grid, train_grid3d
    from ..sim.cases import TEST_CASES
    from ..sim.cases3d import TEST_CASES3D
    from ..sim.scene import SceneParams
    from ..sim.scene3d import SceneParams3D

    for name, dim in _ONLY.items():
        given = getattr(args, name)
        if given is not None and given is not False and dim != args.dim:
            raise ValueError(f"--{name.replace('_', '-')}: a {dim}-D flag; this is --dim "
                             f"{args.dim}")
    if args.dim == 2:
        grid = train_grid(args.forces, args.angles or list(TRAIN_ANGLES_DEG), args.positions)
        params: Any = SceneParams(impulse_point=args.impulse_point or "ring_centre",
                                  sleep=args.sleep)
        test = np.asarray(TEST_CASES)
    else:
        kw = {k: getattr(args, k) for k in ("azimuths", "elevations") if getattr(args, k)}
        grid = train_grid3d(args.forces, **kw, positions=args.positions,
                            per_direction=1 if args.per_direction is None else args.per_direction)
        params = SceneParams3D()
        test = np.asarray(TEST_CASES3D)
    if args.limit is not None:
        if args.limit < 1:
            raise ValueError(f"--limit: must be >= 1, got {args.limit}")
        grid = grid[: args.limit]
    whole = args.whole
    if whole is None:
        whole = 240 if args.dim == 2 else released_whole(len(grid))
    windows = args.windows or ("model" if args.dim == 2 else "released")
    extra = {} if args.dim == 2 else {"dim": 3}
    counts = generate(args.output, grid, None if args.no_test else test,
                      m=args.m, steps=args.steps, seed=args.seed, workers=args.workers,
                      whole=whole, progress=not args.quiet, windows=windows,
                      params=params, **extra)
    print(f"wrote {args.output}: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    return 0
