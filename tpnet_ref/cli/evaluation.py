"""``tpnet eval``, ``tpnet demo`` and ``tpnet animate`` (argparse only; the work is in tpnet_ref.evaluation)."""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from ..extras import EVAL_MODULES, require_all

# the defaults shown in --help, spelled here so that the parser imports no library module
_DEMO_HORIZONS = (1, 10, 20, 40, 80, 140)
_ORDERINGS = ("given", "ascending_x", "descending_y", "shuffle")
_CALIBRATION_TRAJECTORIES = 36      # tpnet_ref.evaluation.timing.CALIBRATION_TRAJECTORIES


def add_cli(sub: Any) -> None:
    p = sub.add_parser("demo", help="simulate a held-out scene, predict it from shuffled frames, "
                                    "print errors beside copy-last and constant velocity, "
                                    "write a PNG")
    p.add_argument("--weights", default=None, help="native weights file (default: shipped m=4)")
    p.add_argument("--case", type=float, nargs=4, default=None,
                   metavar=("FORCE", "ANGLE", "X", "Y"), help="scene: impulse per particle, direction in degrees, start centre x, y "
                        "(default: test case 1)")
    p.add_argument("--steps", type=int, default=None,
                   help="predictions (default: to the end of the 600-step trajectory)")
    p.add_argument("--horizons", type=int, nargs="+", default=list(_DEMO_HORIZONS),
                   help="prediction steps at which errors are printed")
    p.add_argument("-o", "--output", default="tpnet_demo.png", help="PNG to write")
    p.add_argument("--no-png", action="store_true", help="do not write a PNG")
    p.add_argument("--seed", type=int, default=0, help="point shuffling seed")
    p.add_argument("--dtype", default="float32", choices=("float32", "float64"),
                   help="precision of the rollout")
    p.set_defaults(func=_cli_demo)

    p = sub.add_parser("animate", help="a GIF of a held-out case: the simulator's ring and "
                                       "TP-Net's rollout from shuffled frames, side by side")
    p.add_argument("-o", "--output", default="rollout.gif", help="GIF to write")
    p.add_argument("--weights", default=None, help="native weights file (default: shipped m=4)")
    p.add_argument("--case", type=float, nargs="+", default=None, metavar="V",
                   help="scene: FORCE ANGLE X Y, or for a 3-D model FORCE AZIMUTH ELEVATION X Y "
                        "Z (default: test case 1 of the model's dimension)")
    p.add_argument("--last-frame", type=int, default=None,
                   help="last model frame shown (default: the last simulated, 149)")
    p.add_argument("--every", type=int, default=2, help="show every k-th model frame")
    p.add_argument("--fps", type=int, default=12, help="GIF frames per second")
    p.add_argument("--dpi", type=int, default=64, help="size: 64 gives 416 x 250 pixels")
    p.add_argument("--seed", type=int, default=0, help="point shuffling seed")
    p.set_defaults(func=_cli_animate)

    p = sub.add_parser("eval", help="evaluation on the 60 held-out cases: the paper's table in "
                                    "the squared reading, the other readings, orderings, "
                                    "timings, plots -> results.md")
    p.add_argument("--weights", action="append", default=[],
                   help="native weights file; repeat for several models (m = 3/4/5); one at "
                        "least, unless --baselines-only")
    p.add_argument("--baselines-only", action="store_true",
                   help="no model: baselines and simulator rows only")
    p.add_argument("--dim", type=int, choices=(2, 3), default=None,
                   help="the scene: 3 evaluates 3-D models on the 60 held-out 3-D throws "
                        "(default: the weights' dimension, else 2)")
    p.add_argument("--m", type=int, nargs="+", default=None,
                   help="window lengths for the baselines (default: the models' m, else 4)")
    p.add_argument("--data", default=None,
                   help="HDF5 dataset (tpnet data generate): use its /test trajectories "
                        "instead of simulating")
    p.add_argument("--allow-other-scene", action="store_true",
                   help="accept a --data file made with another scene convention")
    p.add_argument("--cases", type=int, default=None, help="only the first N cases")
    p.add_argument("--horizon", type=int, default=None,
                   help="predictions per case (default: to the end of the trajectories)")
    p.add_argument("--orderings", nargs="+", default=list(_ORDERINGS), choices=_ORDERINGS,
                   help="orders the input points are given in, one table row each: as "
                        "simulated, sorted by x, sorted by y descending, shuffled")
    p.add_argument("--no-timing", action="store_true", help="skip the error-vs-time table")
    p.add_argument("--no-peers", action="store_true", help="timing without PyTorch/onnxruntime")
    p.add_argument("--repeats", type=int, default=3, help="timing repeats (best is kept)")
    p.add_argument("--no-specialized", action="store_true",
                   help="timing without the scene-specialised float32 row (its calibration "
                        "simulates training-grid trajectories: about 20 s)")
    p.add_argument("--calibration-trajectories", type=int, default=None, metavar="N",
                   help="training-grid trajectories the scene-specialised row is calibrated on "
                        "(default: %d)" % _CALIBRATION_TRAJECTORIES)
    p.add_argument("--generalisation", action="store_true",
                   help="also scenes outside the training ranges")
    p.add_argument("--gen-cases", type=int, default=20, help="generalisation cases per group")
    p.add_argument("--workers", type=int, default=0, help="simulation processes (0: auto)")
    p.add_argument("--seed", type=int, default=0, help="shuffle seed")
    p.add_argument("--out", default=None,
                   help="directory for results.md, eval_curves.csv and the PNGs (default: a new "
                        "./tpnet-eval-<timestamp>/; give --out docs to update the repository's)")
    p.add_argument("--no-plots", action="store_true",
                   help="write results.md and the CSVs only, no PNG figures")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_cli_eval)


def _cli_demo(args: Any) -> int:
    require_all(EVAL_MODULES, "eval", "tpnet demo")
    from ..evaluation import DEMO_CASE, demo
    demo(args.weights, case=args.case or DEMO_CASE, steps=args.steps, horizons=args.horizons,
         png=None if args.no_png else args.output, seed=args.seed, dtype=args.dtype)
    return 0


def _cli_animate(args: Any) -> int:
    require_all(EVAL_MODULES, "eval", "tpnet animate")
    from . import watched
    return watched("tpnet animate", "simulating a held-out scene, rolling the model out on it "
                   "and drawing the GIF", _animate, args)


def _animate(args: Any) -> int:
    from ..evaluation import DEMO_CASE
    from ..evaluation.animate import animate
    from ..evaluation.animate3d import DEMO_CASE3D, animate3d
    from ..model import load
    model = load(args.weights, dtype="float32")
    dim = model.config.dim
    want = 6 if dim == 3 else 4
    if args.case is not None and len(args.case) != want:
        raise ValueError(f"--case: a {dim}-D model's scene has {want} numbers, got "
                         f"{len(args.case)}")
    kw = dict(last_frame=args.last_frame, every=args.every, fps=args.fps, dpi=args.dpi,
              seed=args.seed)
    if dim == 3:
        r = animate3d(args.output, case=args.case or DEMO_CASE3D, model=model, **kw)
    else:
        r = animate(args.output, case=args.case or DEMO_CASE, model=model, **kw)
    size = Path(r["path"]).stat().st_size
    errs = ", ".join(f"@{h} {e:.3g}" for h, e in r["Ep_squared"].items())
    print(f"wrote {r['path']} ({r['gif_frames']} frames, {size / 1e6:.2f} MB); "
          f"TP-Net m = {r['m']} position error E_p (squared) on this case {errs}")
    return 0


def _cli_eval(args: Any) -> int:
    require_all(EVAL_MODULES, "eval", "tpnet eval")
    from . import watched
    return watched("tpnet eval", "evaluating on the held-out cases", _eval, args,
                   stream=sys.stderr)


def _eval(args: Any) -> int:
    from ..evaluation import run_eval
    if _eval_dim(args) == 3:
        return _eval3d(args)
    path = run_eval(args)
    text = Path(path).read_text()
    start = text.index("## The paper's table")
    end = text.index("## Protocol")
    print(text[start:end].rstrip())
    print(f"\nwrote {path} (and eval_curves.csv, figures) in {Path(path).parent}/")
    return 0


def _eval_dim(args: Any) -> int:
    """The scene ``tpnet eval`` runs: ``--dim``, else the weights' dimension (all the same)."""
    from ..weights.native import read_config
    dims = {read_config(w).dim for w in args.weights if Path(w).is_file()}  # a missing one: named below
    if len(dims) > 1:
        raise ValueError("--weights: 2-D and 3-D models together; evaluate each dimension on "
                         "its own")
    if args.dim is not None and dims and dims != {args.dim}:
        raise ValueError(f"--dim {args.dim}: the weights are {dims.pop()}-D")
    return args.dim or (dims.pop() if dims else 2)


def _eval3d(args: Any) -> int:
    from ..evaluation.suite import default_out_dir
    from ..evaluation.suite3d import run_eval3d
    if args.baselines_only and args.weights:
        raise ValueError("--baselines-only and --weights exclude each other")
    if not args.baselines_only and not args.weights:
        raise ValueError("give --weights PATH (repeatable) or --baselines-only")
    path = run_eval3d(args.weights, data=args.data, cases=args.cases, horizon=args.horizon,
                      seed=args.seed, out=args.out or default_out_dir(), repeats=args.repeats,
                      plots=not args.no_plots, progress=not args.quiet,
                      command=" ".join(["tpnet"] + sys.argv[1:]))
    text = Path(path).read_text()
    print(text[text.index("| m |"):].split("\n\n")[0])
    print(f"\nwrote {path} (and eval3d_curves.csv, eval3d_cases.csv) in {Path(path).parent}/")
    return 0
