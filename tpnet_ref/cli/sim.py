"""``tpnet sim run``, ``tpnet sim show`` and ``tpnet sim render``: one trajectory of the scene to a
.npy file, a PNG, or a video / PNG frames from a synthetic camera (:mod:`tpnet_ref.observe.render`)."""
from __future__ import annotations

from typing import Any

from .files import output_path, save_npy


def add_cli(sub: Any) -> None:
    p = sub.add_parser("sim", help="simulate the paper's soft-body scene")
    ssub = p.add_subparsers(dest="sim_command", metavar="SIM_COMMAND")
    ssub.required = True
    for name, helptext in (("show", "write a PNG of one trajectory"),
                           ("run", "write one trajectory, (steps, 30, 2) world units, to .npy"),
                           ("render", "film one trajectory with a synthetic camera: a video "
                                      "(.mp4/.avi) or PNG frames, with its calibration (JSON)")):
        q = ssub.add_parser(name, help=helptext)
        q.add_argument("--force", type=float, default=1.3, help="impulse per particle")
        q.add_argument("--angle", type=float, default=225.0, help="impulse direction, degrees")
        q.add_argument("--x", type=float, default=30.0, help="start centre x, world units")
        q.add_argument("--y", type=float, default=35.0, help="start centre y, world units")
        q.add_argument("--steps", type=int, default=600, help="simulation steps (45 a second)")
        q.add_argument("--frequency", type=float, default=1.0, help="spring frequency, Hz")
        q.add_argument("--damping-ratio", type=float, default=0.0, help="spring damping ratio")
        q.add_argument("--wall-restitution", type=float, default=0.0, help="wall restitution")
        add_scene_flags(q)
        if name == "show":
            q.add_argument("-o", "--output", required=True, help=".png file to write")
            q.add_argument("--every", type=int, default=4,
                           help="draw every k-th row (4 = one model frame)")
            q.set_defaults(func=_cli_show)
        elif name == "render":
            q.add_argument("-o", "--output", required=True,
                           help="a .mp4 or .avi video, or a directory for PNG frames; the "
                                "calibration <stem>.json, the background <stem>.background.png "
                                "and the true centres <stem>.truth.npy go next to a video "
                                "(calibration.json, background.png, truth.npy in a directory)")
            q.add_argument("--size", type=int, default=640,
                           help="image width = height in px, the whole 45 x 45 box")
            q.add_argument("--fps", type=float, default=45.0,
                           help="frames per second (45: one frame per simulation step)")
            q.add_argument("--noise", type=float, default=3.0,
                           help="sensor noise, standard deviation in grey levels")
            q.add_argument("--texture", type=float, default=60.0,
                           help="background texture, grey levels peak to peak (0: plain)")
            q.add_argument("--distractors", type=int, default=0,
                           help="stray blobs per frame, clear of the body")
            q.add_argument("--seed", type=int, default=0, help="random seed of the texture, noise and distractors")
            q.set_defaults(func=_cli_render)
        else:
            q.add_argument("-o", "--output", required=True,
                           help=".npy file to write (exactly this path); row k is the state "
                                "after k + 1 steps, a model frame is every 4th row")
            q.set_defaults(func=_cli_run)


def add_scene_flags(q: Any) -> None:
    """``--impulse-point`` and ``--sleep``: the scene convention (default: the released code's),
    for ``tpnet sim`` and ``tpnet data generate``."""
    q.add_argument("--impulse-point", default="ring_centre",
                   choices=("ring_centre", "particle_centre"),
                   help="where the start impulse acts: ring_centre (released code: particles "
                        "spin) or particle_centre (centre of mass)")
    q.add_argument("--sleep", action="store_true",
                   help="freeze the body once it has rested 0.5 s (every particle slower than "
                        "0.01 units/s and 2 deg/s), as Box2D's island sleeping does; the "
                        "released world, and the default, never freezes it")


def _trajectory(args: Any, include_initial: bool = False) -> Any:
    from ..sim.scene import simulate
    return simulate(args.force, args.angle, args.x, args.y, args.steps,
                    include_initial=include_initial, frequency=args.frequency,
                    damping_ratio=args.damping_ratio, wall_restitution=args.wall_restitution,
                    impulse_point=args.impulse_point, sleep=args.sleep)


def _cli_run(args: Any) -> int:
    output_path(args.output, "--output", ".npy")      # before the work, not after
    traj = _trajectory(args)
    path = save_npy(args.output, traj, "--output")
    print(f"wrote {traj.shape} to {path}")
    return 0


def _cli_show(args: Any) -> int:
    if args.every < 1:
        raise ValueError(f"--every: must be >= 1, got {args.every}")
    path = output_path(args.output, "--output", ".png")
    from ..sim.plot import show
    traj = _trajectory(args, include_initial=True)
    show(traj, path, every=args.every,
         title=f"F={args.force:g} angle={args.angle:g} start=({args.x:g}, {args.y:g})")
    print(f"wrote {path}")
    return 0


def _cli_render(args: Any) -> int:
    from ..observe.render import RenderSettings, output_paths, write_render
    settings = RenderSettings(size=args.size, fps=args.fps, noise=args.noise,
                              texture=args.texture, distractors=args.distractors, seed=args.seed)
    if args.steps < 2:
        raise ValueError(f"--steps: a video needs at least 2 steps, got {args.steps}")
    paths = output_paths(args.output)                  # a bad name fails before the work
    traj = _trajectory(args)
    scene = {"force": args.force, "angle_deg": args.angle, "x": args.x, "y": args.y,
             "steps": args.steps, "frequency": args.frequency,
             "damping_ratio": args.damping_ratio, "wall_restitution": args.wall_restitution,
             "impulse_point": args.impulse_point, "sleep": args.sleep,
             "rows": "row k is the state after k + 1 steps; video frame j shows t = j / fps "
                     "with row 0 at t = 0"}
    calib = write_render(args.output, traj, settings, scene)
    print(f"wrote {calib['frames']} frames of {args.size} x {args.size} px at {args.fps:g} fps to "
          f"{args.output}; camera {calib['camera']['left_wall_px']:.4g},"
          f"{calib['camera']['right_wall_px']:.4g},{calib['camera']['floor_px']:.4g} px "
          f"(walls, floor) in {paths['calibration']}")
    return 0
