"""Same bits on every call: a probe run in a fresh process per OpenBLAS kernel and thread count.

    python tests/determinism_probe.py            # this process's kernel and threads: JSON
    python tests/determinism_probe.py --sweep    # every kernel this CPU runs x 1 and 2 threads:
                                                 # a table, and how far the kernels' outputs differ
    python tests/determinism_probe.py --calls 10 # fewer repeated calls (the test suite's setting)

OpenBLAS picks its kernel (``OPENBLAS_CORETYPE``) and thread count (``OPENBLAS_NUM_THREADS``)
when NumPy is imported, and numba its thread count (``NUMBA_NUM_THREADS``) when it is, so each
setting needs a process of its own. In each, for both engines and both dtypes, with the thread
policy forced to switch plans on every call: 100 ``predict`` calls on one window give one output,
20 random per-frame permutations give that output too, and ``predict_batch`` (a small batch and a
split one, split on 1 thread and on every core), ``rollout`` and ``rollout_batch`` give one
output per call and the same under permutation. It prints each check and a digest of every
output; ``tests/test_determinism.py`` asserts the checks and that the digests do not depend on
the thread counts.
"""
from __future__ import annotations

import hashlib
import itertools
import json
import os
import subprocess
import sys
from pathlib import Path

#: OpenBLAS kernels (x86-64) and the CPU flags each needs (Linux /proc/cpuinfo names)
KERNELS = {
    "Nehalem": {"sse4_2"},
    "Sandybridge": {"avx"},
    "Haswell": {"avx2", "fma"},
    "SkylakeX": {"avx512f", "avx512bw", "avx512dq", "avx512vl", "avx512cd"},
}


def cpu_flags() -> set[str]:
    """The CPU's feature flags (empty where /proc/cpuinfo does not exist)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    for line in text.splitlines():
        if line.startswith("flags"):
            return set(line.split(":", 1)[1].split())
    return set()


def runnable_kernels() -> dict[str, str | None]:
    """Each kernel of :data:`KERNELS` -> None if this CPU runs it, else why not."""
    flags = cpu_flags()
    if not flags:
        return {k: "CPU flags unknown (no /proc/cpuinfo)" for k in KERNELS}
    return {k: (None if need <= flags else f"CPU lacks {', '.join(sorted(need - flags))}")
            for k, need in KERNELS.items()}


def run_child(kernel: str, threads: int, calls: int = 100, timeout: float = 300,
              save: str | os.PathLike | None = None) -> dict:
    """This script in a fresh process under ``kernel`` with ``threads`` BLAS and numba threads,
    ``calls`` repeated predict calls (and a fifth as many permutations); ``save``: a folder for
    the outputs (each ``predict``, and the shipped model's 80-step ``rollout``) as ``.npy``."""
    env = dict(os.environ, OPENBLAS_CORETYPE=kernel, OPENBLAS_NUM_THREADS=str(threads),
               NUMBA_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads))
    if save is not None:
        env["TPNET_PROBE_SAVE"] = str(save)
    env.pop("TPNET_THREADS", None)
    env.pop("TPNET_BLAS_THREADS", None)
    out = subprocess.run([sys.executable, __file__, "--calls", str(calls)], env=env, capture_output=True, text=True,
                         timeout=timeout)
    if out.returncode:
        raise RuntimeError(f"probe under {kernel}, {threads} threads failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.splitlines()[-1])


# ----------------------------------------------------------------------------- the probe

def _probe(calls: int) -> dict:
    import numpy as np
    from threadpoolctl import threadpool_info

    import tpnet_ref
    from tpnet_ref.engines import thread_policy
    from tpnet_ref.model import init_random

    # the thread policy switches plans on every call (one thread, two threads, ...)
    plans = itertools.cycle((0, 1))
    thread_policy.adaptive.choose = lambda kind: next(plans)

    rng = np.random.default_rng(1)
    t = np.linspace(0, 2 * np.pi, 30, endpoint=False)
    ring = np.stack([2 * np.sin(t), 2 * np.cos(t)], 1)
    scene = np.stack([ring * (1 + 0.02 * i) + [20 - 0.4 * i, 25 - 0.3 * i] for i in range(4)])
    noise = rng.uniform(5, 40, (4, 30, 2))                  # dense activations on a random net
    others = [scene + rng.normal(0, 0.5, scene.shape) for _ in range(4)]
    big = np.stack([scene + rng.normal(0, 0.5, scene.shape) for _ in range(70)])

    def shuffled(w: np.ndarray) -> np.ndarray:
        return np.stack([f[rng.permutation(len(f))] for f in w])

    def digest(a: np.ndarray) -> str:
        return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]

    def one(fn, n: int) -> tuple[bool, np.ndarray]:
        outs = [fn() for _ in range(n)]
        return all(np.array_equal(outs[0], o) for o in outs[1:]), outs[0]

    checks, digests = {}, {}
    engines = ["numpy"]
    try:
        import numba  # noqa: F401
        engines.append("numba")
    except ImportError:
        pass
    for engine, dtype in itertools.product(engines, ("float32", "float64")):
        for net, window in (("shipped", scene), ("random", noise)):
            model = (tpnet_ref.load(dtype=dtype, engine=engine) if net == "shipped" else
                     init_random(seed=0, dtype=dtype).with_engine(engine))
            key = f"{engine} {dtype} {net}"
            ok, y = one(lambda: model.predict(window), calls)
            checks[f"{key}: {calls} predict calls, one output"] = ok
            checks[f"{key}: {calls // 5} permutations, the same output"] = all(
                np.array_equal(model.predict(shuffled(window)), y) for _ in range(calls // 5))
            digests[f"{key} predict"] = digest(y)
            small = np.stack([window] + others)
            ok, yb = one(lambda: model.predict_batch(small), 10)
            checks[f"{key}: predict_batch of 5, one output"] = ok
            checks[f"{key}: predict_batch of 5, permuted"] = np.array_equal(
                model.predict_batch(np.stack([shuffled(w) for w in small])), yb)
            digests[f"{key} predict_batch 5"] = digest(yb)
            if net == "shipped":
                ok, ys = one(lambda: model.predict_batch(big), 3)
                model.threads = 1
                checks[f"{key}: predict_batch of 70, one output, split on 1 or every core"] = (
                    ok and np.array_equal(model.predict_batch(big), ys))
                model.threads = None
                digests[f"{key} predict_batch 70"] = digest(ys)
            ok, r = one(lambda: model.rollout(window, 10), 5)
            checks[f"{key}: rollout, one output"] = ok
            checks[f"{key}: rollout, permuted"] = np.array_equal(
                model.rollout(shuffled(window), 10), r)
            checks[f"{key}: rollout's first step is predict"] = np.array_equal(r[0], y)
            digests[f"{key} rollout 10"] = digest(r)
            ok, rb = one(lambda: model.rollout_batch(small[:3], 5), 3)
            checks[f"{key}: rollout_batch, one output"] = ok
            digests[f"{key} rollout_batch 3x5"] = digest(rb)
            if _SAVE:
                np.save(_SAVE / f"{key.replace(' ', '-')}.npy", y)
                if net == "shipped":         # docs/tolerances.md: kernels over a rollout
                    np.save(_SAVE / f"{key.replace(' ', '-')}-rollout80.npy",
                            model.rollout(window, 80))
    info = [d for d in threadpool_info() if d.get("user_api") == "blas"]
    return {"kernel": info[0].get("architecture") if info else None,
            "blas_threads": info[0].get("num_threads") if info else None,
            "numba_threads": int(os.environ.get("NUMBA_NUM_THREADS", "0")) or None,
            "checks": checks, "digests": digests}


_SAVE = Path(os.environ["TPNET_PROBE_SAVE"]) if os.environ.get("TPNET_PROBE_SAVE") else None


def _sweep() -> None:
    """Every kernel this CPU runs, 1 and 2 threads: checks, digests, kernels' differences."""
    import tempfile

    import numpy as np
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for kernel, why in runnable_kernels().items():
            if why:
                print(f"{kernel:12s} skipped: {why}")
                continue
            for threads in (1, 2):
                os.environ["TPNET_PROBE_SAVE"] = str(Path(tmp, f"{kernel}-{threads}"))
                Path(os.environ["TPNET_PROBE_SAVE"]).mkdir()
                r = run_child(kernel, threads)
                results[kernel, threads] = r
                failed = [k for k, v in r["checks"].items() if not v]
                same = r["digests"] == results[kernel, 1]["digests"]
                print(f"{kernel:12s} (OpenBLAS ran {r['kernel']}) threads {threads}: "
                      f"{len(r['checks']) - len(failed)}/{len(r['checks'])} checks hold"
                      + (f", FAILED: {failed}" if failed else "")
                      + ("" if threads == 1 else
                         f"; outputs {'identical to' if same else 'DIFFER from'} 1 thread"))
        print("\nlargest difference between kernels' predict outputs (world units), per case:")
        first = next(iter(results))
        base = Path(tmp, f"{first[0]}-1")
        for f in sorted(base.glob("*.npy")):            # (a rollout: its 80th prediction)
            a = np.load(f)[..., -1, :, :] if "rollout" in f.stem else np.load(f)
            diffs = {k: float(np.abs(np.load(Path(tmp, f"{k}-1", f.name))[..., -1, :, :] - a).max()
                              if "rollout" in f.stem else
                              np.abs(np.load(Path(tmp, f"{k}-1", f.name)) - a).max())
                     for k, t in results if t == 1}
            print(f"  {f.stem:28s} " + ", ".join(f"{k} {d:.1e}" for k, d in diffs.items())
                  + f"  (against {first[0]})")


if __name__ == "__main__":
    if "--sweep" in sys.argv:
        _sweep()
    else:
        n = int(sys.argv[sys.argv.index("--calls") + 1]) if "--calls" in sys.argv else 100
        print(json.dumps(_probe(n)))
