"""How much a per-frame permutation changes TP-Net's output with the canonical sort OFF.

    PYTHONPATH=. python bench/permutation_rounding.py [--examples 200]

For each implementation the property tests check at a quarter of every width, here at the
released shape (tests/property_helpers.py: the reference,
the NumPy and the Numba engine with the sort off, the PyTorch model; float32 and float64) and for
the ONNX export (float32, m = 4, 30 points), the largest change of the output (world units) that
a per-frame permutation causes over ``--examples`` windows of ``tpnet_ref.testing.windows``
(m = 1, 2, 4; 1..64 points, ragged or not, spreads 1e-3..1e3, ties and duplicate points), found
with :func:`tpnet_ref.testing.permutation_invariant`; beside it the same implementation's largest
distance to the float64 reference on those windows (its rounding; :func:`agrees_with_reference`)
and the tolerance the tests allow (``tpnet_ref.testing.TOLERANCE``). Prints the machine line.
"""
from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

import _common  # noqa: E402
from property_helpers import MS, Implementations  # noqa: E402

from tpnet_ref import testing  # noqa: E402
from tpnet_ref.model import TPNetConfig  # noqa: E402


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--examples", type=int, default=200)
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")       # random windows lie outside the training range
    impl = Implementations(TPNetConfig())     # the released shape
    print(_common.machine())
    print(f"{'implementation':<32} {'dtype':<8} {'max change, permuted':>21} "
          f"{'max |x - reference64|':>22} {'test tolerance':>15}")
    cases = []
    for dtype in ("float64", "float32"):
        cases += [("reference.forward", dtype, impl.reference(dtype), None),
                  ("NumPy engine, sort off", dtype, impl.engine("numpy", dtype), None),
                  ("Numba engine, sort off", dtype, impl.engine("numba", dtype), None),
                  ("PyTorch TorchTPNet", dtype, impl.torch(dtype), None)]
    cases.append(("ONNX export (onnxruntime)", "float32", impl.onnx(30),
                  testing.windows(m=4, n=30, ragged=False)))
    for name, dtype, fn, strategy in cases:
        perm = testing.permutation_invariant(fn, strategy or testing.windows(m=MS),
                                             tol=float("inf"), max_examples=args.examples, seed=0)
        # the reference in float64 with this dtype's parameters (m = 4: the base model's)
        ref = testing.agrees_with_reference(fn, impl.base[dtype], tol=float("inf"),
                                            windows=strategy or testing.windows(m=4),
                                            max_examples=args.examples, seed=0)
        print(f"{name:<32} {dtype:<8} {perm:>21.3g} {ref:>22.3g} "
              f"{testing.TOLERANCE[dtype]:>15.3g}")


if __name__ == "__main__":
    main()
