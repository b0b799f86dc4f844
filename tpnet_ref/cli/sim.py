"""``tpnet sim run`` and ``tpnet sim show``: one trajectory of the scene to a .npy file or a PNG."""
from __future__ import annotations

from typing import Any

from .files import output_path, save_npy


def add_cli(sub: Any) -> None:
    p = sub.add_parser("sim", help="simulate the paper's soft-body scene")
    ssub = p.add_subparsers(dest="sim_command", metavar="SIM_COMMAND")
    ssub.required = True
    for name, helptext in (("show", "write a PNG of one trajectory"),
                           ("run", "write one trajectory, (steps, 30, 2) world units, to .npy")):
        q = ssub.add_parser(name, help=helptext)
        q.add_argument("--force", type=float, default=1.3, help="impulse per particle (1.3)")
        q.add_argument("--angle", type=float, default=225.0, help="impulse direction, degrees (225)")
        q.add_argument("--x", type=float, default=30.0, help="start centre x (30)")
        q.add_argument("--y", type=float, default=35.0, help="start centre y (35)")
        q.add_argument("--steps", type=int, default=600, help="simulation steps (600)")
        q.add_argument("--frequency", type=float, default=1.0, help="spring frequency, Hz (1)")
        q.add_argument("--damping-ratio", type=float, default=0.0, help="spring damping ratio (0)")
        q.add_argument("--wall-restitution", type=float, default=0.0, help="wall restitution (0)")
        _scene_flags(q)
        if name == "show":
            q.add_argument("-o", "--output", required=True, help=".png file to write")
            q.add_argument("--every", type=int, default=4,
                           help="draw every k-th row (4 = one model frame)")
            q.set_defaults(func=_cli_show)
        else:
            q.add_argument("-o", "--output", required=True,
                           help=".npy file to write (exactly this path); row k is the state "
                                "after k + 1 steps, a model frame is every 4th row")
            q.set_defaults(func=_cli_run)


def _scene_flags(q: Any) -> None:
    """``--impulse-point`` and ``--sleep``: the scene convention (default: the released code's)."""
    q.add_argument("--impulse-point", default="ring_centre",
                   choices=("ring_centre", "particle_centre"),
                   help="where the start impulse acts: ring_centre (released code: particles "
                        "spin) or particle_centre (centre of mass)")
    q.add_argument("--sleep", action="store_true",
                   help="allow Box2D island sleeping (the released world: off)")


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
