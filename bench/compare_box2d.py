"""Compare tpnet_ref.sim (pymunk) with the Box2D 2.3 scene over the 60 test cases.

    PYTHONPATH=. /work/venv-sim/bin/python bench/compare_box2d.py [--cases N] [key=value ...]

Prints, after 40/160/320/600 steps (rows 39/159/319/599), the mean and max
distance between the two bodies' centroids and the mean shape error (paper's Chamfer position
error, squared distances averaged over points, after centring each set on its centroid), in
world units, and both errors in the released-code metric on normalised coordinates. Extra
``key=value`` arguments are passed to ``tpnet_ref.sim.simulate``, and to the Box2D scene too
where it has a parameter of that name (e.g. ``wall_restitution=1``, ``frequency=2``).
"""
from __future__ import annotations

import argparse
import csv
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from box2d_scene import simulate_box2d  # noqa: E402
from naive_pymunk import simulate_naive  # noqa: E402

from tpnet_ref.sim import simulate  # noqa: E402

CASES = os.environ.get("TPNET_TEST_CASES", "/work/shared/data/test_cases.csv")
STEPS = (40, 160, 320, 600)


def chamfer_paper(p: np.ndarray, q: np.ndarray) -> float:
    """SPEC section 3 position error: (sum min d^2 both ways) / |P| (brute force)."""
    d2 = ((p[:, None, :] - q[None, :, :]) ** 2).sum(-1)
    return float((d2.min(1).sum() + d2.min(0).sum()) / len(p))


def shape_error(p: np.ndarray, q: np.ndarray) -> float:
    return chamfer_paper(p - p.mean(0), q - q.mean(0))


def chamfer_released(p: np.ndarray, q: np.ndarray) -> float:
    """SPEC section 3 released-code variant: unsquared distances, summed both ways, no 1/|P|."""
    d = np.sqrt(((p[:, None, :] - q[None, :, :]) ** 2).sum(-1))
    return float(d.min(1).sum() + d.min(0).sum())


def released_pair(p: np.ndarray, q: np.ndarray) -> tuple[float, float]:
    """(E_p, E_s) of the released variant on normalised coordinates."""
    from tpnet_ref.config import normalize
    p, q = normalize(p), normalize(q)
    return chamfer_released(p, q), chamfer_released(p - p.mean(0), q - q.mean(0))


def load_cases(path: str = CASES) -> list[tuple[float, float, float, float]]:
    with open(path) as f:
        return [(float(r["force"]), float(r["angle_deg"]), float(r["x"]), float(r["y"]))
                for r in csv.DictReader(f)]


def parse_kw(items: list[str]) -> dict:
    kw = {}
    for it in items:
        k, v = it.split("=", 1)
        kw[k] = None if v == "None" else (v == "True" if v in ("True", "False") else float(v))
        if k in ("iterations", "n_particles", "spring_reach"):
            kw[k] = int(kw[k])
    return kw


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", type=int, default=60)
    ap.add_argument("--model", default="sim", choices=("sim", "naive", "box2d-perturbed"),
                    help="sim: tpnet_ref.sim; naive: bench/naive_pymunk.py; box2d-perturbed: "
                         "Box2D started 1e-4 to the right (Box2D's own sensitivity)")
    ap.add_argument("kw", nargs="*")
    args = ap.parse_args()
    kw = parse_kw(args.kw)
    cases = load_cases()[: args.cases]
    import inspect
    shared = set(inspect.signature(simulate_box2d).parameters)
    b2kw = {k: v for k, v in kw.items() if k in shared}   # same setting in both engines
    rows = [s - 1 for s in STEPS]          # row k: after k + 1 steps
    cen = np.zeros((len(cases), 600))
    shp = np.zeros((len(cases), len(rows)))
    rel = np.zeros((len(cases), len(rows), 2))
    t_pm = t_b2 = 0.0
    for c, (f, a, x, y) in enumerate(cases):
        t0 = time.perf_counter()
        b = simulate_box2d(f, a, x, y, 600, **b2kw)
        t1 = time.perf_counter()
        if args.model == "sim":
            p = simulate(f, a, x, y, 600, **kw)
        elif args.model == "naive":
            p = simulate_naive(f, a, x, y, 600)
        else:
            p = simulate_box2d(f, a, x + 1e-4, y, 600)
        t2 = time.perf_counter()
        t_b2 += t1 - t0
        t_pm += t2 - t1
        cen[c] = np.linalg.norm(p.mean(1) - b.mean(1), axis=1)
        shp[c] = [shape_error(p[r], b[r]) for r in rows]
        rel[c] = [released_pair(p[r], b[r]) for r in rows]
    print(f"{len(cases)} cases, model {args.model}, kwargs {kw or '(defaults)'}")
    print(f"{'step':>5} {'centroid mean':>14} {'median':>8} {'max':>8} {'shape err mean':>15}"
          f" {'rel. E_p':>9} {'rel. E_s':>9}")
    for j, (s, r) in enumerate(zip(STEPS, rows)):
        print(f"{s:5d} {cen[:, r].mean():14.4f} {np.median(cen[:, r]):8.4f} "
              f"{cen[:, r].max():8.4f} {shp[:, j].mean():15.5f} {rel[:, j, 0].mean():9.4f}"
              f" {rel[:, j, 1].mean():9.4f}")
    print("(centroid and shape error in world units / units^2, paper metric; rel. = released-code"
          " metric on normalised coordinates, as SPEC section 4's table)")
    print(f"time per trajectory: pymunk {1e3 * t_pm / len(cases):.1f} ms, "
          f"box2d {1e3 * t_b2 / len(cases):.1f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
