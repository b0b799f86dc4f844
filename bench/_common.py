"""What several bench scripts share: the machine line, the scene's windows, medians of timings.

A script run as ``python bench/NAME.py`` has ``bench/`` on its path, so ``import _common`` works
(the package itself comes from the installed ``tpnet_ref``, editable in a checkout).
"""
from __future__ import annotations

import os
import pickle
import platform
import subprocess
import sys
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
    """Median seconds of each of ``calls`` (key -> fn(input), or a :class:`RemoteCall`),
    alternating call by call: every callable sees the same minutes of a machine whose speed
    drifts. No warm-up."""
    t: dict = {k: [] for k in calls}
    for _ in range(reps):
        for x in inputs:
            for k, f in calls.items():
                if isinstance(f, RemoteCall):        # timed in its own process
                    t[k].append(f.timed(x))
                    continue
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


def median_seconds(fn: Callable, min_time: float, min_reps: int = 3,
                   settle: float = 0.0) -> float:
    """Median seconds per call of ``fn`` over at least ``min_time`` seconds and ``min_reps``
    calls, after calls not timed for ``settle`` seconds (at least one)."""
    start = time.perf_counter()
    fn()
    while time.perf_counter() - start < settle:
        fn()
    times: list[float] = []
    start = time.perf_counter()
    while len(times) < min_reps or time.perf_counter() - start < min_time:
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


#: :class:`PeerProcess`'s child: onnxruntime sessions of the shipped sizes' exports, timed on
#: request (pickles over its stdin / stdout; the parent is this bench, nothing else talks to it)
_PEER_CHILD = r"""
import pickle, sys, time
import numpy as np
import tpnet_ref
from tpnet_ref.conformance.onnx_peer import onnx_session
from _common import median_seconds               # bench/ on PYTHONPATH (PeerProcess)
inp, out = sys.stdin.buffer, sys.stdout.buffer
sessions = {}


while True:
    cmd, *a = pickle.load(inp)
    if cmd == "quit":
        break
    if cmd == "session":
        name, size, path, threads, world = a
        model = tpnet_ref.load(path) if path else tpnet_ref.load(size=size)
        sessions[name] = onnx_session(model.astype("float32"), n_points=None, threads=threads,
                                      world_units=world)
        res = None
    else:
        name, x, steps, min_time, min_reps, settle = a
        s = sessions[name]
        if steps:
            def fn():
                win = x
                for _ in range(steps):
                    win = np.concatenate([win[:, 1:], s.run(None, {"window": win})[0][:, None]],
                                         axis=1)
                return win
        else:
            def fn():
                return s.run(None, {"window": x})[0]
        if cmd == "run":
            res = fn()
        elif cmd == "once":                      # one call, no warm-up: its seconds
            t = time.perf_counter()
            fn()
            res = time.perf_counter() - t
        else:
            res = median_seconds(fn, min_time, min_reps, settle)
    pickle.dump(res, out)
    out.flush()
"""


class PeerProcess:
    """onnxruntime in a process of its own, as a deployment runs it: sessions of weights files'
    exports (``tpnet export onnx``), each timed there on request, in blocks (:meth:`timer`) or
    call by call (:meth:`call`). In one process with this engine, each runtime's idle threads
    (onnxruntime's spinning pool, numba's) take the core the other's second thread wants: on a
    2-core VM that made onnxruntime's two threads twice as slow as one, by process, and this
    engine's two-thread plan stall for milliseconds at a time."""

    def __init__(self) -> None:
        here = str(Path(__file__).resolve().parent)
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(
            [here] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
        self._proc = subprocess.Popen([sys.executable, "-c", _PEER_CHILD], env=env,
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE)

    def _ask(self, *msg):
        pickle.dump(msg, self._proc.stdin)
        self._proc.stdin.flush()
        return pickle.load(self._proc.stdout)

    def session(self, name: str, size: str | None, threads: int | None, path: str | None = None,
                world_units: bool = True) -> None:
        """A session ``name`` of the export of the shipped ``size`` (or of the weights file
        ``path``), float32, ``threads`` intra-op threads (None: onnxruntime's default), world
        units in and out (else model units)."""
        self._ask("session", name, size, path, threads, world_units)

    def run(self, name: str, x: np.ndarray, steps: int = 0) -> np.ndarray:
        """Session ``name``'s output on ``x``, or its window after ``steps`` predictions fed
        back (a rollout)."""
        return self._ask("run", name, x, steps, 0.0, 0, 0.0)

    def timer(self, name: str, x: np.ndarray, steps: int = 0) -> "RemoteTimer":
        return RemoteTimer(self, name, x, steps)

    def call(self, name: str) -> "RemoteCall":
        return RemoteCall(self, name)

    def close(self) -> None:
        try:
            self._ask("quit")
        except (EOFError, BrokenPipeError):
            pass
        self._proc.wait()


class RemoteTimer:
    """A peer's call timed in its own process (:meth:`PeerProcess.timer`): :meth:`time` gives
    the median seconds of calls over ``min_time`` seconds (and ``min_reps`` calls), after calls
    not timed for ``settle`` seconds (at least one)."""

    def __init__(self, peer: PeerProcess, name: str, x: np.ndarray, steps: int) -> None:
        self.peer, self.name, self.x, self.steps = peer, name, x, steps

    def time(self, min_time: float, min_reps: int, settle: float = 0.0) -> float:
        return self.peer._ask("time", self.name, self.x, self.steps, min_time, min_reps, settle)


class RemoteCall:
    """Session ``name`` of a :class:`PeerProcess` on one window ``w (m, N, dim)``: called, its
    output; :meth:`timed`, the seconds of one call as its own process measured it (the pipe's
    time not counted), which :func:`alternate` takes instead of timing the call itself."""

    def __init__(self, peer: PeerProcess, name: str) -> None:
        self.peer, self.name = peer, name

    def __call__(self, w: np.ndarray) -> np.ndarray:
        return self.peer.run(self.name, w[None])

    def timed(self, w: np.ndarray) -> float:
        return self.peer._ask("once", self.name, w[None], 0, 0.0, 0, 0.0)
