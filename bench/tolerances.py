"""How far apart the ways of computing the same prediction are: per prediction and over an
80-step rollout (docs/tolerances.md).

    python bench/tolerances.py [--windows K] [--kernels]

On the shipped m = 4 model and ``K`` windows (default 12) of simulated training-grid
trajectories (never the held-out test cases), for float32 and float64, the largest absolute
difference in world units between:

- ``batch vs single``: ``predict_batch`` / ``rollout_batch`` of all windows against
  ``predict`` / ``rollout`` of each alone (NumPy and Numba engines);
- ``specialised vs plain``: ``model.specialize(scene)`` against ``model``;
- ``file order vs unit-sorted``: ``model.with_unit_order(None)`` against ``model`` (the shipped
  file carries an order);
- ``numba vs numpy``: the two engines;
- ``float32 vs float64``: the float32 model against the float64 one;
- ``BLAS kernel`` (``--kernels``): each OpenBLAS kernel this CPU runs against the default,
  each in a fresh process (``OPENBLAS_CORETYPE``).

For each: the largest difference of one prediction (``predict``), and of the rollout's
predictions 1, 10, 40 and 80; the growth is how many times the 80th exceeds the first.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

import _common

STEPS = 80
AT = (1, 10, 40, 80)


def scene_windows(k: int) -> np.ndarray:
    """``k`` windows ``(k, 4, 30, 2)`` of training-grid trajectories: one trajectory per 3
    windows (every 7th grid position, forces and angles in turn), starting at rows 0, 60, 120."""
    from tpnet_ref.sim import simulate
    from tpnet_ref.sim.cases import TRAIN_ANGLES_DEG, TRAIN_FORCES, TRAIN_POSITIONS
    out = []
    for i in range(-(-k // 3)):
        traj = simulate(TRAIN_FORCES[i % 5], TRAIN_ANGLES_DEG[(3 * i) % 19],
                        *TRAIN_POSITIONS[(7 * i) % 75])
        out += [traj[s:s + 16:4] for s in (0, 60, 120)]
    return np.stack(out[:k])


def outputs(model, w: np.ndarray, batch: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``(predictions (K, 30, 2), rollouts (K, 80, 30, 2))``, batched or one window at a time."""
    if batch:
        return model.predict_batch(w), model.rollout_batch(w, STEPS)
    return (np.stack([model.predict(x) for x in w]),
            np.stack([model.rollout(x, STEPS) for x in w]))


def gap(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> dict:
    d = np.abs(a[1].astype(np.float64) - b[1]).max(axis=(0, 2, 3))
    return {"predict": float(np.abs(a[0].astype(np.float64) - b[0]).max()),
            **{f"rollout@{s}": float(d[s - 1]) for s in AT}}


def comparisons(w: np.ndarray, engines: tuple[str, ...]) -> dict:
    import tpnet_ref
    out = {}
    base32 = tpnet_ref.load()
    scene = base32.specialize(w)
    for dtype in ("float32", "float64"):
        model = base32.astype(dtype)
        single = outputs(model, w)
        for engine in engines:
            m = model.with_engine(engine)
            s = single if engine == "numpy" else outputs(m, w)
            out[f"batch vs single ({engine})", dtype] = gap(outputs(m, w, batch=True), s)
            if engine == "numba":
                out["numba vs numpy", dtype] = gap(s, single)
        out["specialised vs plain", dtype] = gap(outputs(scene.astype(dtype), w), single)
        out["file order vs unit-sorted", dtype] = gap(outputs(model.with_unit_order(None), w),
                                                      single)
        if dtype == "float64":
            out["float32 vs float64", "float32"] = gap(outputs(base32, w), single)
    return out


def _determinism_probe():
    """``tests/determinism_probe.py`` loaded from its path (it lists the kernels this CPU runs),
    without putting ``tests/`` on ``sys.path``."""
    import importlib.util
    path = Path(__file__).resolve().parents[1] / "tests" / "determinism_probe.py"
    spec = importlib.util.spec_from_file_location("determinism_probe", path)
    probe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(probe)
    return probe


def kernels(w: np.ndarray) -> dict:
    """Each OpenBLAS kernel this CPU runs (a fresh process each) against the default."""
    probe = _determinism_probe()
    runnable = [k for k, why in probe.runnable_kernels().items() if not why]
    res, out = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        np.save(Path(tmp, "w.npy"), w)
        for kernel in [None] + runnable:
            env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
            if kernel:
                env["OPENBLAS_CORETYPE"] = kernel
            dst = Path(tmp, f"{kernel or 'default'}.npz")
            subprocess.run([sys.executable, __file__, "--child", tmp, str(dst)], env=env,
                           check=True)
            res[kernel] = np.load(dst)
        for kernel in runnable:
            for dtype in ("float32", "float64"):
                a, b = res[kernel], res[None]
                out[f"BLAS kernel {kernel} vs default", dtype] = gap(
                    (a[f"p{dtype}"], a[f"r{dtype}"]), (b[f"p{dtype}"], b[f"r{dtype}"]))
    return out


def child(tmp: str, dst: str) -> None:
    import tpnet_ref
    w = np.load(Path(tmp, "w.npy"))
    arrays = {}
    for dtype in ("float32", "float64"):
        p, r = outputs(tpnet_ref.load(dtype=dtype), w)
        arrays[f"p{dtype}"], arrays[f"r{dtype}"] = p, r
    np.savez(dst, **arrays)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--windows", type=int, default=12)
    ap.add_argument("--kernels", action="store_true", help="also each OpenBLAS kernel")
    ap.add_argument("--json", default=None, help="also write the figures to this file")
    ap.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    if args.child:
        child(*args.child)
        return 0
    print(_common.machine())
    print(_common.load_average())
    w = scene_windows(args.windows)
    try:
        import numba  # noqa: F401
        engines: tuple[str, ...] = ("numpy", "numba")
    except ImportError:
        engines = ("numpy",)
    res = comparisons(w, engines)
    if args.kernels:
        res.update(kernels(w))
    print(f"\n{len(w)} windows; largest |difference| in world units\n")
    print(f"| comparison | dtype | per prediction | " + " | ".join(f"rollout @{s}" for s in AT)
          + " | growth @80 / @1 |")
    print("|---|---|---|" + "---|" * len(AT) + "---|")
    for (name, dtype), g in res.items():
        growth = g["rollout@80"] / g["rollout@1"] if g["rollout@1"] else float("nan")
        cells = " | ".join(f"{g[f'rollout@{s}']:.2g}" for s in AT)
        print(f"| {name} | {dtype} | {g['predict']:.2g} | {cells} | "
              + ("exact" if not g["rollout@80"] else f"{growth:.3g}") + " |")
    if args.json:
        Path(args.json).write_text(json.dumps({f"{n} | {d}": g for (n, d), g in res.items()},
                                              indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
