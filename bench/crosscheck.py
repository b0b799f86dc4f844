"""Cross-check the NumPy forward pass against the frameworks and print the max differences.

    PYTHONPATH=. python bench/crosscheck.py                       # torch (live) + Keras fixtures
    PYTHONPATH=. python bench/crosscheck.py --keras-full DIR       # + released-size Keras files
                                                                   #   (make_keras_fixtures.py tf --full DIR)

Torch: a released-size network (init_random, seed 0) is loaded into the PyTorch model, saved with
``torch.save(state_dict)``, imported with ``import_torch``; one step on a batch of windows and an
80-step rollout are compared in float32 and float64 (normalised coordinates). Keras: the frameworks'
own outputs stored next to the fixtures (one step and the recursive model's 8 outputs).
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from tpnet_ref.model import TPNetConfig, init_random
from tpnet_ref.weights.keras import import_keras_h5
from tpnet_ref.weights.torch import import_torch

#: the repository (the Keras fixtures are in tests/fixtures)
ROOT = Path(__file__).resolve().parent.parent


def ring_windows(b: int, m: int = 4, n: int = 30, seed: int = 0) -> np.ndarray:
    """Soft-body-like windows: a ring of n points moving and deforming a little per frame."""
    rng = np.random.default_rng(seed)
    a = np.arange(n) * 2 * np.pi / n
    out = np.empty((b, m, n, 2))
    for i in range(b):
        c = rng.uniform(0.2, 0.8, 2)
        v = rng.uniform(-0.01, 0.01, 2)
        for t in range(m):
            r = 0.047 * (1 + 0.05 * np.sin(3 * a + t * 0.3))
            out[i, t] = c + t * v + np.stack([r * np.sin(a), r * np.cos(a)], 1)
            out[i, t] = out[i, t][rng.permutation(n)]
    return out


def torch_check(steps: int = 80) -> None:
    import torch

    from tpnet_ref.training.torch_model import TorchTPNet

    torch.set_num_threads(2)
    for trained in (False, True):
        cfg = TPNetConfig(input_transform_trained=trained, feature_transform_trained=trained)
        ref64 = init_random(cfg, seed=0, dtype="float64")
        w = ring_windows(8)
        res = {}
        for dt, tdt in (("float32", torch.float32), ("float64", torch.float64)):
            net = TorchTPNet.from_numpy(ref64.astype(dt))
            with tempfile.TemporaryDirectory() as d:
                torch.save(net.state_dict(), f"{d}/m.pt")
                model = import_torch(f"{d}/m.pt", dtype=dt)
            x = torch.from_numpy(w.astype(dt))
            with torch.no_grad():
                yt = net(x).numpy()
                rt = net.rollout(x[:1], steps).numpy()[0]
            yn = model.predict_batch(w.astype(dt), normalized=True)
            rn = model.rollout(w[0].astype(dt), steps, normalized=True)
            res[dt] = (yn, rn)
            print(f"torch  transforms={'trained ' if trained else 'identity'} {dt}: "
                  f"|numpy-torch| one step {np.abs(yn - yt).max():.2e}, "
                  f"{steps}-step rollout {np.abs(rn - rt).max():.2e}")
        (y32, r32), (y64, r64) = res["float32"], res["float64"]
        print(f"       numpy float32 vs float64 drift: one step {np.abs(y32 - y64).max():.2e}, "
              f"{steps}-step rollout {np.abs(r32 - r64).max():.2e}")


def keras_check(files: list[tuple[Path, Path]]) -> None:
    for h5, npz in files:
        data = np.load(npz)
        model = import_keras_h5(h5)
        line = []
        for dt in ("float32", "float64"):
            m = model.astype(dt)
            y = m.predict_batch(data["windows"], normalized=True)
            r = np.stack([m.rollout(x, 8, normalized=True) for x in data["windows"]])
            line.append(f"{dt}: step {np.abs(y - data['step']).max():.2e}, "
                        f"8-step {np.abs(r - data['rollout']).max():.2e}")
        print(f"keras  {h5.name} ({model.num_params:,} params, "
              f"{'identity' if not model.config.input_transform_trained else 'trained'} "
              f"transforms): " + "; ".join(line))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keras-full", default=None, help="folder with tf2_full.h5 / .npz")
    ap.add_argument("--steps", type=int, default=80)
    ap.add_argument("--no-torch", action="store_true")
    args = ap.parse_args()
    if not args.no_torch:
        torch_check(args.steps)
    fix = ROOT / "tests" / "fixtures"
    files = [(fix / f, fix / f"{s}.npz") for f, s in (
        ("tf2_released.h5", "tf2_released"), ("tf2_released_weights.h5", "tf2_released"),
        ("tf2_trained_bn.h5", "tf2_trained_bn"), ("k3_trained.weights.h5", "k3_trained"),
        ("k3_trained.keras", "k3_trained"), ("k3_legacy.h5", "k3_trained"))]
    if args.keras_full:
        d = Path(args.keras_full)
        files += [(d / "tf2_full.h5", d / "tf2_full.npz"),
                  (d / "tf2_full_weights.h5", d / "tf2_full.npz")]
    keras_check(files)


if __name__ == "__main__":
    main()
