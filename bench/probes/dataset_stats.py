"""Figures of a generated dataset quoted in docs/dataset.md.

    python bench/probes/dataset_stats.py data/tpnet.h5
"""
from __future__ import annotations

import sys
import time

import h5py
import numpy as np

from tpnet_ref.sim.dataset import load_windows, scene_convention


def main(path: str) -> int:
    with h5py.File(path, "r") as h:
        print(f"scene convention: {scene_convention(h)}")
        for split in ("train", "test"):
            if split not in h:
                continue
            pos = h[f"{split}/positions"][...]
            nrm = h[f"{split}/normalized"][...]
            print(f"{split}: {pos.shape[0]} trajectories, {pos.shape[1]} frames; centres "
                  f"{pos.min():.4f}..{pos.max():.4f} (normalised {nrm.min():.4f}..{nrm.max():.4f})")
        kinds = np.bincount(h["train/windows"][:, 2], minlength=3)
        print(f"windows: {kinds.sum()} = normal {kinds[0]}, collision {kinds[1]}, "
              f"whole {kinds[2]}")
    t = time.perf_counter()
    x, y = load_windows(path, allow_other_scene=True)   # figures of any file
    print(f"load_windows: {x.shape} + {y.shape} in {time.perf_counter() - t:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
