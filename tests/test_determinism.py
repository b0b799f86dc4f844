"""Same bits on every call, under every OpenBLAS kernel this CPU runs and any thread count.

Each kernel runs ``tests/determinism_probe.py`` in two fresh processes, one with one BLAS and
numba thread and one with two, both with the thread policy switching plans on every call. The
probe checks, for both engines and dtypes, that repeated calls give one output and that
per-frame permutations give that output (predict, predict_batch small and split, rollout,
rollout_batch); here the two processes' outputs must also be identical. The kernels' outputs may
differ from each other by rounding (``python tests/determinism_probe.py --sweep`` prints by how
much); a kernel this CPU cannot run is skipped with the flag it lacks.
"""
from __future__ import annotations

import pytest

import determinism_probe as probe

_RUNNABLE = probe.runnable_kernels()


@pytest.mark.slow
@pytest.mark.parametrize("kernel", list(probe.KERNELS))
def test_same_bits_on_cpu_kernel_with_one_or_two_threads(kernel):
    if _RUNNABLE[kernel]:
        pytest.skip(f"OpenBLAS kernel {kernel}: {_RUNNABLE[kernel]}")
    runs = {t: probe.run_child(kernel, t, calls=10) for t in (1, 2)}
    for t, r in runs.items():
        assert r["kernel"] is not None, "no OpenBLAS under NumPy: nothing to probe"
        if r["kernel"] != kernel:
            pytest.skip(f"OpenBLAS ran {r['kernel']} when asked for {kernel}")
        failed = [k for k, ok in r["checks"].items() if not ok]
        assert not failed, f"{kernel}, {t} thread(s): {failed}"
    assert runs[2]["blas_threads"] == 2
    assert runs[1]["digests"] == runs[2]["digests"]
