"""Same bits on every call, under every OpenBLAS kernel this CPU runs and any thread count.

Each kernel runs ``tests/determinism_probe.py`` in two fresh processes side by side, one with
one BLAS and numba thread and one with two, both with the thread policy switching plans on every
call. The probe checks, for both engines and dtypes, that repeated calls give one output and that
per-frame permutations give that output (predict, predict_batch small and split, rollout,
rollout_batch); here the two processes' outputs must also be identical. The kernels' outputs may
differ from each other by rounding (``python tests/determinism_probe.py --sweep`` prints by how
much); a kernel this CPU cannot run is skipped with the flag it lacks.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import determinism_probe as probe
from tolerance_bounds import BOUNDS, gaps

#: last in the session: the probes load the kernels the suite compiled from numba's cache
pytestmark = pytest.mark.late
_RUNNABLE = probe.runnable_kernels()
#: kernel -> the folder its one-thread probe saved its outputs in (for the last test)
_SAVED: dict = {}


@pytest.mark.slow
@pytest.mark.parametrize("kernel", list(probe.KERNELS))
def test_same_bits_on_cpu_kernel_with_one_or_two_threads(kernel, tmp_path_factory):
    if _RUNNABLE[kernel]:
        pytest.skip(f"OpenBLAS kernel {kernel}: {_RUNNABLE[kernel]}")
    save = tmp_path_factory.mktemp(f"probe-{kernel}")
    # the two processes side by side (each its own thread counts; a busy core changes the plans
    # the policy takes, never the bits: the probe checks them)
    with ThreadPoolExecutor(2) as pool:
        futures = {t: pool.submit(probe.run_child, kernel, t, calls=10,
                                  save=save if t == 1 else None) for t in (1, 2)}
        runs = {t: f.result() for t, f in futures.items()}
    for t, r in runs.items():
        assert r["kernel"] is not None, "no OpenBLAS under NumPy: nothing to probe"
        if r["kernel"] != kernel:
            pytest.skip(f"OpenBLAS ran {r['kernel']} when asked for {kernel}")
        failed = [k for k, ok in r["checks"].items() if not ok]
        assert not failed, f"{kernel}, {t} thread(s): {failed}"
    assert runs[2]["blas_threads"] == 2
    assert runs[1]["digests"] == runs[2]["digests"]
    _SAVED[kernel] = save


@pytest.mark.slow
def test_the_kernels_differ_within_the_stated_bounds():
    """docs/tolerances.md, "another BLAS kernel": every pair of the kernels probed above, per
    prediction (shipped and random networks) and over the shipped model's 80-step rollout."""
    if len(_SAVED) < 2:
        pytest.skip(f"fewer than two OpenBLAS kernels ran here: {sorted(_SAVED)}")
    kernels = sorted(_SAVED)
    names = sorted(p.name for p in _SAVED[kernels[0]].glob("*.npy"))
    assert any("rollout80" in n for n in names)
    for other in kernels[1:]:
        for name in names:
            a, b = np.load(_SAVED[kernels[0]] / name), np.load(_SAVED[other] / name)
            dtype = "float64" if "float64" in name else "float32"
            bound = BOUNDS[dtype]
            if "rollout80" in name:
                over = {k: v for k, v in gaps(a, b).items() if k in bound and v > bound[k]}
            else:
                d = float(np.abs(a - b).max())
                over = {"predict": d} if d > bound["predict"] else {}
            assert not over, f"{name}: {kernels[0]} vs {other}: {over} exceed {bound}"
