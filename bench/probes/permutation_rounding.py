"""How much a per-frame permutation changes TP-Net's output with the canonical sort OFF.

    PYTHONPATH=bench python bench/probes/permutation_rounding.py [--examples 50]

At the released shape (``init_random(seed=21)``, m = 4), for the implementations the property
tests check at a quarter of every width (tests/test_invariance.py): ``reference.forward``, the
NumPy and the Numba engine with the sort off (``model.with_point_sort(False)``), the PyTorch model
(float32 and float64), and the ONNX export under onnxruntime (float32, 30 points per frame):
the largest change of the output (world units) a per-frame permutation causes over
``--examples`` windows of ``tpnet_ref.testing.windows`` (1..64 points, ragged or not, spreads
1e-3..1e3, ties and duplicate points), found with :func:`tpnet_ref.testing.permutation_invariant`;
beside it the largest distance to the float64 reference on such windows (the implementation's
rounding, :func:`~tpnet_ref.testing.agrees_with_reference`) and the tolerance the tests allow
(``tpnet_ref.testing.TOLERANCE``). Prints the machine line first.
"""
from __future__ import annotations

import argparse
import warnings

import numpy as np

import _common
from tpnet_ref.engines import reference
from tpnet_ref import testing
from tpnet_ref.model import init_random


def torch_predict(model):
    """``TorchTPNet`` of ``model`` as window -> points (frame by frame: ragged windows too)."""
    import torch
    from tpnet_ref.training.torch_model import TorchTPNet
    net = TorchTPNet.from_numpy(model).eval()

    def pytorch(window):
        x = [torch.from_numpy(model.normalize(np.asarray(f, dtype=model.dtype))) for f in window]
        with torch.no_grad():
            y = net.sequence_head(torch.cat([net.frame_features(f[None]) for f in x])[None])[0]
        return model.denormalize(y.numpy())
    return pytorch


def onnx_predict(model, n_points):
    from tpnet_ref.conformance.onnx_peer import onnx_session
    sess = onnx_session(model, n_points, threads=1)

    def onnx_export(window):
        x = model.normalize(np.stack(window).astype(np.float32))[None]
        return model.denormalize(sess.run(None, {"window": x})[0][0])
    return onnx_export


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--examples", type=int, default=50)
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")       # random windows lie outside the training range
    print(_common.machine())
    print(f"| implementation | dtype | max change under a permutation | max distance to the "
          f"float64 reference | test tolerance |\n|---|---|---|---|---|")
    for dtype in ("float64", "float32"):
        model = init_random(seed=21, dtype=dtype)
        unsorted = model.with_point_sort(False)
        cases = [("reference.forward", lambda w: reference.forward(model.config, model.params, w)),
                 ("NumPy engine, sort off", unsorted.predict),
                 ("Numba engine, sort off", unsorted.with_engine("numba").predict),
                 ("PyTorch TorchTPNet", torch_predict(model))]
        if dtype == "float32":
            cases.append(("ONNX export, onnxruntime (N = 30)", onnx_predict(model, 30)))
        for name, fn in cases:
            windows = (testing.windows(m=4, n=30, ragged=False) if name.startswith("ONNX")
                       else testing.windows(m=4))
            perm = testing.permutation_invariant(fn, windows, tol=float("inf"),
                                                 max_examples=args.examples, seed=0)
            ref = testing.agrees_with_reference(fn, model, tol=float("inf"), windows=windows,
                                                max_examples=args.examples, seed=0)
            print(f"| {name} | {dtype} | {perm:.3g} | {ref:.3g} | {testing.TOLERANCE[dtype]:g} |",
                  flush=True)


if __name__ == "__main__":
    main()
