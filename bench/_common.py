"""What several bench scripts share: the machine line, the scene's windows, medians of timings.

A script run as ``python bench/NAME.py`` has ``bench/`` on its path, so ``import _common`` works
(the package itself comes from the installed ``tpnet_ref``, editable in a checkout).
"""
from __future__ import annotations

import os
import platform
import time
from pathlib import Path
from typing import Callable

import numpy as np

#: the test case whose first window is the B = 1 input (and the rollouts' start)
TEST_CASE_B1 = 0


def cpu_name() -> str:
    """The CPU's model name (``/proc/cpuinfo``), else what :mod:`platform` says."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "?"


def load_average() -> str:
    """``"load average 1.02 0.98 0.95, 2 CPUs"``: on a shared machine, figures of different runs
    are comparable only when this was alike."""
    return "load average " + " ".join(f"{v:.2f}" for v in os.getloadavg()) + \
        f", {os.cpu_count()} CPUs"


def machine() -> str:
    """CPU, cores, Python, NumPy and the BLAS as loaded (library, version, kernel, threads)."""
    from tpnet_ref.engines.blas import describe
    return (f"{cpu_name()}, {os.cpu_count()} cores; Python {platform.python_version()}, "
            f"NumPy {np.__version__} ({describe()}; OPENBLAS_CORETYPE="
            f"{os.environ.get('OPENBLAS_CORETYPE', 'unset')})")


def scene_windows(model) -> tuple[np.ndarray, np.ndarray]:
    """``(1, m, 30, 2)`` and ``(256, m, 30, 2)`` normalised float32 windows of simulated test
    cases (the scene's inputs; only timed, never used to choose anything): test case
    :data:`TEST_CASE_B1`'s first window, and 32 windows spread over each of the first 8 test
    cases. The B = 1 benches time ``x256[::4]`` (64 windows)."""
    from tpnet_ref.sim.protocol import FRAME_EVERY
    from tpnet_ref.sim.cases import TEST_CASES
    from tpnet_ref.sim.scene import simulate
    m = model.config.m
    wins = []
    for case in TEST_CASES[:8]:
        traj = simulate(*case)[::FRAME_EVERY]
        starts = np.linspace(0, len(traj) - m, 32).astype(int)
        wins.append(np.stack([traj[s:s + m] for s in starts]))
    x256 = model.normalize(np.concatenate(wins).astype(np.float32))
    x1 = model.normalize(simulate(*TEST_CASES[TEST_CASE_B1])[::FRAME_EVERY][:m].astype(np.float32))
    return x1[None], x256


def alternate(calls: dict, inputs: list, reps: int) -> dict:
    """Median seconds of each of ``calls`` (key -> fn(input)), alternating call by call: every
    callable sees the same minutes of a machine whose speed drifts. No warm-up."""
    t: dict = {k: [] for k in calls}
    for _ in range(reps):
        for x in inputs:
            for k, f in calls.items():
                t0 = time.perf_counter()
                f(x)
                t[k].append(time.perf_counter() - t0)
    return {k: float(np.median(v)) for k, v in t.items()}


def best_of(fn: Callable, repeats: int) -> tuple[float, object]:
    """Shortest of ``repeats`` timings of ``fn()`` in seconds, and its last result."""
    best, out = np.inf, None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out
