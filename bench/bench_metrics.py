"""Benchmark of tpnet_ref.metrics against scipy's cKDTree and pykdtree (not a test).

    PYTHONPATH=. python bench/bench_metrics.py [--quick]

Prints the machine, then ratios measured in this run (best of several repeats each):
1. a batch of 10,000 pairs of 30-point sets vs a Python loop of cKDTree queries;
2. one pair of N = 10^5 and 10^6 uniform points vs cKDTree(...).query(workers=-1) and pykdtree,
   both directions, same metric (released variant: sum of Euclidean nearest distances);
3. first-call time in a fresh process with an empty numba cache, and with the cache warm;
4. ns per point pair (time / (B·N·M)) in 2-D and in 3-D on one thread, side by side in this run, at
   N = 30 (a batch of 10,000 pairs), N = 1000 (a batch of 20 pairs, and one pair); the target is
   3-D at least as fast per point pair as 2-D (``--dims`` runs this part alone).
"""
from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile

import numpy as np

from _common import best_of, cpu_name

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def machine() -> str:
    cpu = cpu_name()
    import numba
    import scipy
    try:
        import pykdtree
        pk = getattr(pykdtree, "__version__", "installed")
    except ImportError:
        pk = "not installed"
    return (f"CPU: {cpu}; os.cpu_count()={os.cpu_count()}; usable cores="
            f"{len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else '?'}; "
            f"numba threads={numba.config.NUMBA_NUM_THREADS}; "
            f"load average before the run={os.getloadavg()[0]:.2f}\n"
            f"Python {platform.python_version()}, numpy {np.__version__}, numba {numba.__version__}, "
            f"scipy {scipy.__version__}, pykdtree {pk}, {platform.platform()}")


def bench_batch(repeats: int) -> None:
    from scipy.spatial import cKDTree

    from tpnet_ref.metrics import position_error
    rng = np.random.default_rng(1)
    P = rng.random((10_000, 30, 2))
    Q = rng.random((10_000, 30, 2))
    position_error(P[:2], Q[:2], "released")  # load compiled kernels

    def loop():
        out = np.empty(len(P))
        for b in range(len(P)):
            dp = cKDTree(Q[b]).query(P[b])[0]
            dq = cKDTree(P[b]).query(Q[b])[0]
            out[b] = dp.sum() + dq.sum()
        return out

    t_nb, r_nb = best_of(lambda: position_error(P, Q, "released"), repeats)
    t_kd, r_kd = best_of(loop, max(1, repeats // 2))
    assert np.allclose(r_nb, r_kd, rtol=1e-12, atol=0)
    print(f"[1] batch 10000 x (30 vs 30 points), released: tpnet_ref {t_nb * 1e3:.2f} ms, "
          f"Python loop of cKDTree {t_kd * 1e3:.1f} ms -> {t_kd / t_nb:.1f}x faster (target >= 20x)")


def bench_large(n: int, repeats: int) -> None:
    from scipy.spatial import cKDTree

    from tpnet_ref.metrics import position_error
    rng = np.random.default_rng(n)
    P = rng.random((n, 2))
    Q = rng.random((n, 2)) * 0.9 + 0.05
    position_error(P[:3000], Q[:3000], "released")  # load compiled kernels

    def scipy_kd():
        return (cKDTree(Q).query(P, workers=-1)[0].sum()
                + cKDTree(P).query(Q, workers=-1)[0].sum())

    t_nb, r_nb = best_of(lambda: position_error(P, Q, "released"), repeats)
    t_kd, r_kd = best_of(scipy_kd, repeats)
    assert np.isclose(r_nb, r_kd, rtol=1e-10)
    line = (f"[2] one pair N = M = {n:,}, released: tpnet_ref {t_nb * 1e3:.1f} ms, "
            f"cKDTree(workers=-1) {t_kd * 1e3:.1f} ms ({t_kd / t_nb:.2f}x)")
    try:
        from pykdtree.kdtree import KDTree

        def py_kd():
            return (KDTree(Q).query(P, k=1)[0].sum() + KDTree(P).query(Q, k=1)[0].sum())
        t_pk, r_pk = best_of(py_kd, repeats)
        assert np.isclose(r_nb, r_pk, rtol=1e-10)
        line += f", pykdtree {t_pk * 1e3:.1f} ms ({t_pk / t_nb:.2f}x)"
    except ImportError:
        line += ", pykdtree not installed"
    print(line + "   [ratio = other time / tpnet_ref time; > 1 means tpnet_ref is faster]")


_FIRST_CALL = """
import time, numpy as np
t0 = time.perf_counter()
from tpnet_ref.metrics import position_error, shape_error, chamfer_loss
rng = np.random.default_rng(0)
position_error(rng.random((4, 30, 2)), rng.random((4, 30, 2)))           # brute force
position_error(rng.random((2, 400, 2)), rng.random((2, 400, 2)))         # batched grid
position_error(rng.random((30000, 2)), rng.random((30000, 2)))           # parallel grid
position_error(rng.random((4, 30, 3)), rng.random((4, 30, 3)))           # the same in 3-D
position_error(rng.random((2, 800, 3)), rng.random((2, 800, 3)))
position_error(rng.random((30000, 3)), rng.random((30000, 3)))
print(f"{time.perf_counter() - t0:.3f}")
"""


def bench_compile() -> None:
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache,
                   PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
        times = []
        for _ in range(2):  # first with the empty cache, then warm
            out = subprocess.run([sys.executable, "-c", _FIRST_CALL], env=env, check=True,
                                 capture_output=True, text=True).stdout
            times.append(float(out.strip().splitlines()[-1]))
    print(f"[3] fresh process, import + first calls of the kernels (2-D and 3-D): "
          f"empty numba cache {times[0]:.2f} s, warm cache {times[1]:.2f} s")


def bench_dims(repeats: int) -> None:
    """[4]: 2-D and 3-D per point pair, each size's two timings interleaved (best of each):
    wall time, and CPU time of the process. On one numba thread: the work per point pair, which
    a second thread on a shared machine (waiting for its core) would blur."""
    import time

    import numba

    from tpnet_ref.metrics import position_error
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    rng = np.random.default_rng(2)
    for n, batch in ((30, 10_000), (1000, 20), (1000, 1)):
        sets = {d: (rng.random((batch, n, d)), rng.random((batch, n, d))) for d in (2, 3)}
        for P, Q in sets.values():
            position_error(P[:2], Q[:2], "released")   # load compiled kernels
        wall = {2: np.inf, 3: np.inf}
        cpu = {2: np.inf, 3: np.inf}
        for _ in range(repeats):
            for d, (P, Q) in sets.items():
                c0, t0 = time.process_time(), time.perf_counter()
                position_error(P, Q, "released")
                wall[d] = min(wall[d], time.perf_counter() - t0)
                cpu[d] = min(cpu[d], time.process_time() - c0)
        pairs = batch * n * n / 1e9
        w = {d: wall[d] / pairs for d in wall}
        c = {d: cpu[d] / pairs for d in cpu}
        print(f"[4] N = M = {n}, batch {batch}, released, method auto, one thread, ns per point "
              f"pair: wall 2-D {w[2]:.3f}, 3-D {w[3]:.3f} (3-D / 2-D = {w[3] / w[2]:.2f}); "
              f"CPU 2-D {c[2]:.3f}, 3-D {c[3]:.3f} ({c[3] / c[2]:.2f}); target 3-D / 2-D <= 1")
    numba.set_num_threads(threads)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats, skip N = 10^6")
    ap.add_argument("--dims", action="store_true", help="only [4], 2-D against 3-D")
    args = ap.parse_args()
    reps = 3 if args.quick else 7
    print(machine())
    if args.dims:
        bench_dims(2 * reps)
        return
    bench_batch(reps)
    for n in ((100_000,) if args.quick else (100_000, 1_000_000)):
        bench_large(n, reps if n < 10 ** 6 else 3)
    bench_compile()
    bench_dims(2 * reps)


if __name__ == "__main__":
    main()
