"""The testing kit's default tolerance against a fixed 1e-4: the honest PyTorch port and one whose
second LayerNorm has epsilon 1e-5 instead of 1e-3, on the shipped model (docs/testing.md,
"Choosing tol").

    PYTHONPATH=. python bench/probes/kit_tolerance.py [--size full] [--examples 20] [--seed 1]

Needs torch and hypothesis. Each port is checked by ``agrees_with_reference`` on windows in model
coordinates, with the measured default and with ``tol=1e-4``; each line is the check's report or
its failure.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import torch

import tpnet_ref
from tpnet_ref import testing
from tpnet_ref.training.torch_model import TorchTPNet


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="full", help="the shipped size (full, half, quarter)")
    ap.add_argument("--examples", type=int, default=20)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(1)
    model = tpnet_ref.load(size=args.size)
    honest = TorchTPNet.from_numpy(model).eval()
    planted = TorchTPNet.from_numpy(model).eval()
    planted.ln2.eps = 1e-5                              # the released network's is 1e-3

    def port(net, name):
        def fn(window):
            with torch.no_grad():
                return net(torch.as_tensor(np.stack(window), dtype=torch.float32)[None])[0]
        fn.__qualname__ = name
        return fn

    frames = testing.windows(m=model.config.m, ragged=False, normalized=True)
    for net, name in ((honest, "honest"), (planted, "ln2_eps_1e-5")):
        for tol in (None, 1e-4):
            t = time.perf_counter()
            try:
                text = testing.agrees_with_reference(
                    port(net, name), model, tol=tol, windows=frames, normalized=True,
                    max_examples=args.examples, seed=args.seed).report
            except testing.PropertyFailure as exc:
                text = f"FAILS: {exc}"
            print(f"[tol={tol}, {time.perf_counter() - t:.0f} s] {text}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
