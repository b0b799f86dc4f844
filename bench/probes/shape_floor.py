"""What the shape error E_s can reach without the particles' rotation phase (model card, issue 6).

    PYTHONPATH=. python bench/probes/shape_floor.py [--weights weights/tpnet-m5.h5] [--variant squared]
        [--impulse-point particle_centre]

On the 60 held-out test cases (docs/spec.md §5 protocol, simulated in the default scene
convention unless ``--impulse-point`` says otherwise; metric reading ``--variant``, default
"released"; normalised), E_s at horizons 1, 10, 40, 80 of predictors that know more or less
than a model can:

* copy last / constant velocity: the baselines of the issue;
* rest ring at a random phase: the body's undeformed ring, turned by a uniform fraction of one
  particle spacing (averaged over 16 phases);
* true shape, evenly spaced, random phase: the exact outline of the true frame with its points
  evenly spaced along it from a random start (8 draws): what a perfect model that does not
  know the rotation phase would score;
* each true frame as the evenly spaced circle of its mean radius at a random phase: the
  best guess at a ring whose vibration is unknown;
* the model, its own outline evenly spaced (how much of its E_s is clumping), and the circle
  of its own mean radius (how much is its outline's raggedness and wrong deformation).

Then how far the body has turned (``ring_rotation``): the share of cases whose rotation,
modulo one particle spacing (12°), is more than 1° from the start phase, and the mean distance
from it (a uniform phase gives 3°). Last, the mean radius and the raggedness (mean distance of
the points from the set's smooth outline, Fourier modes ≤ 4; ``radial_fit``) of the true
frames and of the model's, in world units.
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import tpnet_ref
from tpnet_ref import evaluation as ev
from tpnet_ref.sim.cases import TEST_CASES
from tpnet_ref.sim.scene import IMPULSE_POINTS, SceneParams
from tpnet_ref.metrics import shape_error

HS = (1, 10, 40, 80)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--weights", default=None, help="native weights file (default: shipped m=4)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--variant", default="released", choices=("released", "squared", "paper"),
                    help="metric reading of E_s (docs/spec.md §3)")
    ap.add_argument("--impulse-point", default=SceneParams().impulse_point,
                    choices=IMPULSE_POINTS, help="scene convention of the ground truth")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    model = tpnet_ref.load(args.weights)
    m, hmax = model.config.m, max(HS)
    frames = ev.normalize(ev.simulate_cases(np.asarray(TEST_CASES), workers=args.workers,
                                              impulse_point=args.impulse_point))
    inputs, targets = ev.split_protocol(frames, m, hmax)
    at = [h - 1 for h in HS]
    truth = targets[:, at]                                             # (C, H, N, 2)
    c, nh, n = truth.shape[:3]
    rng = np.random.default_rng(0)

    def es(pred: np.ndarray) -> np.ndarray:                           # (C, H, N, 2) -> (H,)
        return shape_error(truth, np.broadcast_to(pred, truth.shape), variant=args.variant).mean(0)

    rows: list[tuple[str, np.ndarray]] = []
    rows.append(("copy last input frame", es(ev.copy_last(inputs, hmax)[:, at])))
    rows.append(("constant velocity", es(ev.constant_velocity(inputs, hmax)[:, at])))
    rings = ev.rest_ring((np.arange(16) + 0.5) / 16 * 2 * np.pi / n, n)
    rows.append(("rest ring, random phase", np.mean([es(x) for x in rings], axis=0)))
    flat = truth.reshape(c * nh, n, 2)
    even = [resampled.reshape(truth.shape) for resampled in
            (ev.resample_outline(flat, rng.uniform(0, 1, c * nh)) for _ in range(8))]
    rows.append(("true shape, evenly spaced, random phase", np.mean([es(x) for x in even], 0)))
    phases = [rng.uniform(0, 2 * np.pi / n, c * nh) for _ in range(8)]

    def circle(sets: np.ndarray) -> np.ndarray:                        # mean over 8 phases
        flat_sets = sets.reshape(c * nh, n, 2)
        return np.mean([es(ev.radial_outline(flat_sets, 0, p).reshape(truth.shape))
                        for p in phases], axis=0)

    rows.append(("true shape as a circle of its mean radius, random phase", circle(truth)))
    pred = ev.batched_rollout(model, inputs, hmax)[:, at]
    rows.append(("this model", es(pred)))
    rows.append(("this model's outline, evenly spaced",
                 es(ev.resample_outline(pred.reshape(c * nh, n, 2)).reshape(truth.shape))))
    rows.append(("this model as a circle of its mean radius, random phase", circle(pred)))

    print(f"E_s ({args.variant} reading, normalised) on the {c} test cases simulated with "
          f"impulse_point={args.impulse_point!r}, m = {m}, weights "
          f"{args.weights or 'shipped'}; rest ring at a uniform phase: "
          f"{ev.ring_phase_floor(variant=args.variant):.4g}")
    print()
    print("| predictor | " + " | ".join(f"E_s @{h}" for h in HS) + " |")
    print("|---|" + "---|" * nh)
    for name, v in rows:
        print(f"| {name} | " + " | ".join(f"{x:.3g}" for x in v) + " |")
    print()
    spacing = 360.0 / n
    rot = ev.ring_rotation(ev.denormalize(truth))                      # (C, H) degrees
    off = np.abs((rot + spacing / 2) % spacing - spacing / 2)
    print("| horizon | " + " | ".join(f"@{h}" for h in HS) + " |")
    print("|---|" + "---|" * nh)
    print("| median \\|rotation\\| since the start (°) | "
          + " | ".join(f"{x:.1f}" for x in np.median(np.abs(rot), 0)) + " |")
    print("| cases off the start phase by > 1° (mod 12°) | "
          + " | ".join(f"{x:.0f} %" for x in 100 * (off > 1.0).mean(0)) + " |")
    print(f"| mean distance from the start phase (°; uniform {spacing / 4:.1f}) | "
          + " | ".join(f"{x:.2f}" for x in off.mean(0)) + " |")
    print()
    scale = ev.NORM_HI - ev.NORM_LO
    print("| horizon (world units) | " + " | ".join(f"@{h}" for h in HS) + " |")
    print("|---|" + "---|" * nh)
    for name, sets in (("truth", truth), ("this model", pred)):
        coef, res = ev.radial_fit(sets.reshape(c * nh, n, 2), modes=4)
        r0 = coef[:, 0].reshape(c, nh).mean(0) * scale
        rag = np.abs(res).reshape(c, nh, n).mean((0, 2)) * scale
        print(f"| {name}: mean radius | " + " | ".join(f"{x:.4f}" for x in r0) + " |")
        print(f"| {name}: raggedness (mean \\|radius − modes ≤ 4 fit\\|) | "
              + " | ".join(f"{x:.4f}" for x in rag) + " |")
    print(f"\n{time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
