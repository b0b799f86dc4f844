"""Compare tpnet_ref.sim with the Box2D 2.3 scene (tpnet_ref.sim.box2d) over the 60 test cases.

    python bench/compare_box2d.py [--cases N] [--both] [--model sim|naive|box2d-perturbed]
                                  [key=value ...]
    python bench/compare_box2d.py --checks          # the point checks of docs/simulator.md
    python bench/compare_box2d.py --speed [--repeats 7]   # one 600-step trajectory, both engines

Both engines run the scene as the released code does by default (start impulse at the ring
centre, no sleeping); ``impulse_point=particle_centre`` runs both with the centre-of-mass
convention, ``--both`` runs the two conventions one after the other.

Prints, after 40/160/320/600 steps (rows 39/159/319/599), the mean and max
distance between the two bodies' centroids and the mean shape error (paper's Chamfer position
error, squared distances averaged over points, after centring each set on its centroid), in
world units, and both errors in the released-code metric on normalised coordinates. Extra
``key=value`` arguments are passed to ``tpnet_ref.sim.simulate``, and to the Box2D scene too
where it has a parameter of that name (e.g. ``wall_restitution=1``, ``frequency=2``).
``--model naive`` runs a plain pymunk port instead (:func:`simulate_naive`).

``--checks`` prints (both engines in the released convention, impulse at the ring centre): the
first step against Box2D's, when a body dropped from rest falls asleep (sleep=True), how far a
particle that starts inside the wall (start x = 41.9) is pushed out after one step.

``--speed``: one 600-step trajectory of test case (1.3, 195, 39.5, 29.5), each engine building
the scene from scratch and returning the (600, 30, 2) positions, interleaved so both see the same
machine load (one untimed run before each timed one: Numba's compilation is excluded); the best
and the median of the repeats, and the ratio Box2D / ours (> 1: ours is faster).
"""
from __future__ import annotations

import argparse
import math
import statistics
import sys
import time

import numpy as np

from tpnet_ref.sim import TEST_CASES, SceneParams, ring_positions, simulate, spring_pairs
from tpnet_ref.sim.box2d import simulate_box2d

STEPS = (40, 160, 320, 600)
#: issue targets (mean centroid distance, world units) and the steps they apply to
TARGETS = {160: 0.05, 600: 0.5}

#: the case of ``--checks``' first step and of ``--speed``
CASE = (1.3, 195.0, 39.5, 29.5)


def simulate_naive(force: float, angle_deg: float, x: float, y: float, steps: int = 600, *,
                   frequency: float = 1.0, dt: float = 1 / 45) -> np.ndarray:
    """A straightforward pymunk port of the scene (for comparison only): pymunk defaults
    everywhere, DampedSpring springs of stiffness mu (2 pi f)^2 (explicit), contact slop 0.1,
    default collision bias, friction and restitution multiplied, no continuous collision, no
    velocity clamps, no sleeping; walls are 1-thick boxes without skin."""
    import pymunk

    space = pymunk.Space()
    space.gravity = (0.0, -0.5)
    space.iterations = 10
    for x0, y0, x1, y1 in ((0, 0, 45, 1), (0, 44, 45, 45), (0, 0, 1, 45), (44, 0, 45, 45)):
        w = pymunk.Poly(space.static_body, [(x0, y0), (x1, y0), (x1, y1), (x0, y1)])
        w.friction, w.elasticity = 1.0, 0.0
        space.add(w)
    start = ring_positions(x, y)
    bodies = []
    for i in range(30):
        b = pymunk.Body()
        b.position = tuple(start[i])
        s = pymunk.Circle(b, 0.15)
        s.density, s.friction, s.elasticity = 1.0, 1.0, 0.0
        s.filter = pymunk.ShapeFilter(group=1)  # no particle-particle contacts at all
        space.add(b, s)
        bodies.append(b)
    m = bodies[0].mass
    k = 0.5 * m * (2 * math.pi * frequency) ** 2
    for i, j in spring_pairs():
        a, b = bodies[i], bodies[j]
        rest = float(np.linalg.norm(start[i] - start[j]))
        space.add(pymunk.DampedSpring(a, b, (0, 0), (0, 0), rest, k, 0.0))
    for b in bodies:
        b.apply_impulse_at_local_point((force * math.cos(math.radians(angle_deg)),
                                        force * math.sin(math.radians(angle_deg))))
    out = np.empty((steps, 30, 2))
    for t in range(steps):      # row t: after t + 1 steps, as tpnet_ref.sim
        space.step(dt)
        out[t] = [tuple(b.position) for b in bodies]
    return out


def chamfer_paper(p: np.ndarray, q: np.ndarray) -> float:
    """docs/spec.md §3 position error: (sum min d^2 both ways) / |P| (brute force)."""
    d2 = ((p[:, None, :] - q[None, :, :]) ** 2).sum(-1)
    return float((d2.min(1).sum() + d2.min(0).sum()) / len(p))


def shape_error(p: np.ndarray, q: np.ndarray) -> float:
    return chamfer_paper(p - p.mean(0), q - q.mean(0))


def chamfer_released(p: np.ndarray, q: np.ndarray) -> float:
    """docs/spec.md §3 released-code variant: unsquared distances, summed both ways, no 1/|P|."""
    d = np.sqrt(((p[:, None, :] - q[None, :, :]) ** 2).sum(-1))
    return float(d.min(1).sum() + d.min(0).sum())


def released_pair(p: np.ndarray, q: np.ndarray) -> tuple[float, float]:
    """(E_p, E_s) of the released variant on normalised coordinates."""
    from tpnet_ref.config import normalize
    p, q = normalize(p), normalize(q)
    return chamfer_released(p, q), chamfer_released(p - p.mean(0), q - q.mean(0))


def parse_kw(items: list[str]) -> dict:
    kw: dict = {}
    for it in items:
        k, v = it.split("=", 1)
        if v == "None":
            kw[k] = None
        elif v in ("True", "False"):
            kw[k] = v == "True"
        else:
            try:
                kw[k] = int(v) if k in ("iterations", "n_particles", "spring_reach") else float(v)
            except ValueError:
                kw[k] = v                       # e.g. impulse_point=particle_centre
    return kw


def compare(cases: list, model: str, kw: dict) -> dict:
    """Run both engines on ``cases``; print the table and return the figures."""
    import inspect
    shared = set(inspect.signature(simulate_box2d).parameters)
    b2kw = {k: v for k, v in kw.items() if k in shared}   # same setting in both engines
    b2kw.setdefault("impulse_point", SceneParams().impulse_point)
    b2kw.setdefault("sleep", SceneParams().sleep)
    rows = [s - 1 for s in STEPS]          # row k: after k + 1 steps
    cen = np.zeros((len(cases), 600))
    shp = np.zeros((len(cases), len(rows)))
    rel = np.zeros((len(cases), len(rows), 2))
    t_pm = t_b2 = 0.0
    simulate(*cases[0], 2, **kw)           # Numba's compilation / cache load is not timed
    for c, (f, a, x, y) in enumerate(cases):
        t0 = time.perf_counter()
        b = simulate_box2d(f, a, x, y, 600, **b2kw)
        t1 = time.perf_counter()
        if model == "sim":
            p = simulate(f, a, x, y, 600, **kw)
        elif model == "naive":
            p = simulate_naive(f, a, x, y, 600)
        else:
            p = simulate_box2d(f, a, x + 1e-4, y, 600, **b2kw)
        t2 = time.perf_counter()
        t_b2 += t1 - t0
        t_pm += t2 - t1
        cen[c] = np.linalg.norm(p.mean(1) - b.mean(1), axis=1)
        shp[c] = [shape_error(p[r], b[r]) for r in rows]
        rel[c] = [released_pair(p[r], b[r]) for r in rows]
    print(f"{len(cases)} cases, model {model}, impulse_point={b2kw['impulse_point']}, "
          f"sleep={b2kw['sleep']}, kwargs {kw or '(defaults)'}")
    print(f"{'step':>5} {'centroid mean':>14} {'median':>8} {'max':>8} {'shape err mean':>15}"
          f" {'rel. E_p':>9} {'rel. E_s':>9}")
    for j, (s, r) in enumerate(zip(STEPS, rows)):
        print(f"{s:5d} {cen[:, r].mean():14.4f} {np.median(cen[:, r]):8.4f} "
              f"{cen[:, r].max():8.4f} {shp[:, j].mean():15.5f} {rel[:, j, 0].mean():9.4f}"
              f" {rel[:, j, 1].mean():9.4f}")
    print("(centroid distance in world units; shape error in units^2, paper metric after "
          "centring; rel. = released-code metric on normalised coordinates, docs/spec.md §3)")
    ms_ours, ms_b2 = 1e3 * t_pm / len(cases), 1e3 * t_b2 / len(cases)
    print(f"time per trajectory: {model} {ms_ours:.1f} ms, box2d {ms_b2:.1f} ms "
          f"(box2d/ours {ms_b2 / ms_ours:.2f}x)")
    ok = [cen[:, s - 1].mean() <= t for s, t in TARGETS.items()] + [ms_ours < ms_b2]
    print("targets: " + ", ".join(f"mean centroid @{s} <= {t}: {cen[:, s - 1].mean():.4f}"
                                  for s, t in TARGETS.items())
          + f", faster than Box2D: {ms_ours < ms_b2} -> {'MET' if all(ok) else 'NOT MET'}")
    return {"centroid": cen, "shape": shp, "ms": (ms_ours, ms_b2), "met": all(ok)}


def last_moving_step(traj: np.ndarray) -> int:
    moved = np.nonzero(np.abs(np.diff(traj, axis=0)).max(axis=(1, 2)) > 0)[0]
    return int(moved.max()) + 1 if len(moved) else 0


def checks() -> None:
    """The point checks against Box2D quoted in docs/simulator.md."""
    d = np.abs(simulate(*CASE, 1) - simulate_box2d(*CASE, 1)).max()
    print(f"after the first step, largest difference to Box2D: {d:.2g}")
    drop = (0.0, 270.0, 22.0, 3.3)
    b = simulate_box2d(*drop, 1500, include_initial=True, sleep=True)
    s = simulate(*drop, 1500, include_initial=True, sleep=True)
    diff = np.abs(b[-1] - s[-1]).max()
    print(f"dropped from rest: asleep after {last_moving_step(s)} steps "
          f"(Box2D {last_moving_step(b)}); final positions differ by {diff:.2g}")
    b0 = b1 = s1 = 0.0
    for a in (180.0, 225.0, 270.0):
        for f in (1.0, 1.6):
            b = simulate_box2d(f, a, 41.9, 39.3, 2, include_initial=True)
            b0, b1 = max(b0, b[0].max()), max(b1, b[1].max())
            s1 = max(s1, simulate(f, a, 41.9, 39.3, 1).max())
    print(f"start (41.9, 39.3): largest centre initially {b0:.4f}, after one step "
          f"Box2D {b1:.4f}, tpnet_ref.sim {s1:.4f}")


def speed(repeats: int) -> None:
    """Seconds of one 600-step trajectory of :data:`CASE`, the engines interleaved."""
    def once(fn) -> float:
        fn(*CASE, 600)                  # untimed: compilation, caches
        t = time.perf_counter()
        fn(*CASE, 600)
        return time.perf_counter() - t
    ours, ref = [], []
    for _ in range(repeats):            # interleave so both see the same machine load
        ours.append(once(simulate))
        ref.append(once(simulate_box2d))
    for name, t in (("tpnet_ref.sim", ours), ("Box2D 2.3.10", ref)):
        print(f"{name:14s} best {1e3 * min(t):7.1f} ms  "
              f"median {1e3 * statistics.median(t):7.1f} ms")
    print(f"ratio Box2D/ours: best {min(ref) / min(ours):.2f}x, "
          f"median {statistics.median(ref) / statistics.median(ours):.2f}x")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=60, help="first N of the 60 test cases")
    ap.add_argument("--model", default="sim", choices=("sim", "naive", "box2d-perturbed"),
                    help="sim: tpnet_ref.sim; naive: a plain pymunk port (simulate_naive); "
                         "box2d-perturbed: Box2D started 1e-4 to the right (Box2D's own "
                         "sensitivity)")
    ap.add_argument("--both", action="store_true",
                    help="also run the centre-of-mass convention (impulse_point=particle_centre)")
    ap.add_argument("--checks", action="store_true", help="only the point checks")
    ap.add_argument("--speed", action="store_true", help="only the speed of one trajectory")
    ap.add_argument("--repeats", type=int, default=7, help="--speed: timed runs of each engine")
    ap.add_argument("kw", nargs="*", help="key=value SceneParams overrides")
    args = ap.parse_args()
    if args.checks:
        checks()
        return 0
    if args.speed:
        speed(args.repeats)
        return 0
    kw = parse_kw(args.kw)
    cases = list(TEST_CASES)[: args.cases]
    compare(cases, args.model, kw)
    if args.both:
        print()
        compare(cases, args.model, dict(kw, impulse_point="particle_centre"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
