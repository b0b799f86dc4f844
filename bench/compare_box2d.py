"""Compare tpnet_ref.sim with the Box2D 2.3 scene (bench/box2d_scene.py) over the 60 test cases.

    python bench/compare_box2d.py [--cases N] [--both] [key=value ...]

Both engines run the scene as the released code does by default (start impulse at the ring
centre, no sleeping); ``impulse_point=particle_centre`` runs both with the centre-of-mass
convention, ``--both`` runs the two conventions one after the other.

Prints, after 40/160/320/600 steps (rows 39/159/319/599), the mean and max
distance between the two bodies' centroids and the mean shape error (paper's Chamfer position
error, squared distances averaged over points, after centring each set on its centroid), in
world units, and both errors in the released-code metric on normalised coordinates. Extra
``key=value`` arguments are passed to ``tpnet_ref.sim.simulate``, and to the Box2D scene too
where it has a parameter of that name (e.g. ``wall_restitution=1``, ``frequency=2``).
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from box2d_scene import simulate_box2d  # noqa: E402
from naive_pymunk import simulate_naive  # noqa: E402

from tpnet_ref.sim import TEST_CASES, SceneParams, simulate  # noqa: E402

STEPS = (40, 160, 320, 600)
#: issue targets (mean centroid distance, world units) and the steps they apply to
TARGETS = {160: 0.05, 600: 0.5}


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


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", type=int, default=60, help="first N of the 60 test cases")
    ap.add_argument("--model", default="sim", choices=("sim", "naive", "box2d-perturbed"),
                    help="sim: tpnet_ref.sim; naive: bench/naive_pymunk.py; box2d-perturbed: "
                         "Box2D started 1e-4 to the right (Box2D's own sensitivity)")
    ap.add_argument("--both", action="store_true",
                    help="also run the centre-of-mass convention (impulse_point=particle_centre)")
    ap.add_argument("kw", nargs="*", help="key=value SceneParams overrides")
    args = ap.parse_args()
    kw = parse_kw(args.kw)
    cases = list(TEST_CASES)[: args.cases]
    compare(cases, args.model, kw)
    if args.both:
        print()
        compare(cases, args.model, dict(kw, impulse_point="particle_centre"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
