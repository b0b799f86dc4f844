"""Numba compilations announced and timed (tpnet_ref.engines.compile_watch): a first run after install
says at once what it does and that it compiles, reports the compile time on a line of its own,
and gives the same bits as a later run that loads the kernels from numba's cache."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

numba = pytest.importorskip("numba")
pytest.importorskip("h5py")

from tpnet_ref.engines.compile_watch import COMPILING, CompileWatch  # noqa: E402
from evaluation_helpers import small_model  # noqa: E402
from background import early  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def test_watch_announces_once_and_times_only_compilations():
    said = []

    @numba.njit                       # not cached: every process compiles it
    def f(x):
        return x + 1

    @numba.njit
    def g(x):
        return f(x) * 2               # compiles f inside g: one top-level compilation

    with CompileWatch(lambda: said.append(COMPILING)) as w:
        assert g(1) == 4 and g(2) == 6
        assert f(1.5) == 2.5          # a new signature of f: a second one
    assert said == [COMPILING] and w.count == 2 and w.seconds > 0
    assert "2 compiled in" in w.report()
    with CompileWatch(lambda: said.append("again")) as w2:
        assert g(3) == 8              # compiled already: nothing to announce or count
    assert said == [COMPILING] and w2.count == 0 and w2.seconds == 0
    assert "none compiled" in w2.report()


def test_a_missing_two_thread_kernel_is_found_missing_not_compiled(monkeypatch):
    from tpnet_ref.engines import compile_watch
    from tpnet_ref.engines import two_thread_gate as G

    @numba.njit(parallel=True)
    def two(x):
        return x * 2

    args = (np.ones(3),)
    memo: dict = {}
    monkeypatch.setattr(compile_watch, "TWO_THREAD_KERNELS_ON_DEMAND", False)
    with CompileWatch() as w:
        assert G.available(two, memo, args) is False          # not compiled, not cached
    assert w.count == 0 and not two.signatures and memo == {two: False}
    assert "two" in G.two_thread_kernels_skipped()
    two(*args)                                                  # compiled: available now
    assert G.available(two, {}, args) is True
    monkeypatch.setattr(compile_watch, "TWO_THREAD_KERNELS_ON_DEMAND", True)
    assert G.available(two, {two: False}, args) is True       # the library's default


def _tpnet(args: list[str], cache: Path, cwd: Path,
           threads: str | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache),
               PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    env.pop("TPNET_THREADS", None)
    if threads:
        env["TPNET_THREADS"] = threads
    r = subprocess.run([sys.executable, "-m", "tpnet_ref.cli", *args], cwd=cwd, env=env,
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    return r


def _first_and_later_runs(tmp_path: Path) -> None:
    """The test below, in processes of their own with an empty cache of their own."""
    weights = tmp_path / "w.h5"
    small_model(4, seed=3, dtype="float32").save(str(weights))
    window = tmp_path / "window.npy"
    import tpnet_ref
    np.save(window, tpnet_ref.example_window())
    cache = tmp_path / "numba-cache"
    cache.mkdir()

    predict = ["predict", str(window), "--weights", str(weights), "--engine", "numba",
               "--steps", "5"]
    cold = _tpnet(predict + ["-o", str(tmp_path / "cold.npy")], cache, tmp_path)
    said = cold.stdout.splitlines()
    assert said[0].startswith("tpnet predict: 5 steps on the Numba engine (a first run")
    assert said[1] == f"tpnet predict: {COMPILING}"         # announced before it compiles
    assert said[2].startswith("tpnet predict: Numba kernels:") and " compiled in " in said[2]
    assert list(cache.rglob("*.nbi"))                       # the kernels were cached
    warm = _tpnet(predict + ["-o", str(tmp_path / "warm.npy")], cache, tmp_path)
    assert COMPILING not in warm.stdout and "compiled in" not in warm.stdout
    # the two-thread plan fixed: its kernels are not in the cache, and a short command does not
    # stop to compile them (the one-thread ones run)
    two = _tpnet(predict + ["-o", str(tmp_path / "two.npy")], cache, tmp_path, threads="2")
    assert COMPILING not in two.stdout and "compiled in" not in two.stdout
    a, b, c = (np.load(tmp_path / f"{n}.npy") for n in ("cold", "warm", "two"))
    assert a.shape == (5, 30, 2) and a.tobytes() == b.tobytes() == c.tobytes()  # the same bits

    demo = ["demo", "--weights", str(weights), "--steps", "6", "--horizons", "1", "6",
            "--no-png"]
    first = _tpnet(demo, cache, tmp_path).stdout.splitlines()   # the simulator still compiles
    assert first[0].startswith("tpnet demo: simulating") and "compiles" in first[0]
    assert first[1] == COMPILING                            # announced before it compiles
    report = [ln for ln in first if ln.startswith("Numba kernels:")]
    assert len(report) == 1 and " compiled in " in report[0], first
    assert first[-1].startswith("total ") and "of it compiling" in first[-1]
    later = _tpnet(demo, cache, tmp_path).stdout.splitlines()
    assert COMPILING not in later and later[0] == first[0]
    assert [ln for ln in later if ln.startswith("Numba kernels:")] == [
        "Numba kernels: none compiled (loaded from numba's cache, or not used)"]
    rows = [[ln for ln in out if ln.strip()[:1].isdigit()] for out in (first, later)]
    assert rows[0] and rows[0] == rows[1]                   # the same errors printed


@pytest.mark.slow
@early(_first_and_later_runs)
def test_first_run_says_it_compiles_and_gives_the_bits_of_a_later_run(early_result):
    """An empty NUMBA_CACHE_DIR is a first run after install: ``tpnet predict`` on the Numba
    engine announces the compilation and times it, and writes the bits that the next run, which
    loads the kernels from that cache, writes; ``tpnet demo`` prints its first line before the
    compilation starts and the compile time as a line of its report (``_first_and_later_runs``)."""
