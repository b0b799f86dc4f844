"""Where a test run spends its time compiling Numba kernels: a pytest plugin and its summary.

    PYTHONPATH=tools NUMBA_COMPILE_LOG=/tmp/compiles.jsonl python -m pytest -p numba_compile_log
    python tools/numba_compile_log.py /tmp/compiles.jsonl        # totals by module, kernel, test

The plugin listens to numba's ``numba:compile`` events in the test process (a compile that
loads from numba's on-disk cache raises none) and writes one JSON line per compiled signature:
its own seconds (the compiles it triggered inside subtracted), its seconds with them, the
function's module and name, its argument types and the test running. Child processes are not
seen. Use an empty ``NUMBA_CACHE_DIR`` (or a fresh clone) to count a first run's compiles.
"""
from __future__ import annotations

import collections
import json
import os
import sys
import time

_STACK: list[list[float]] = []


def listen(on_compile) -> None:
    """Call ``on_compile(own_s, total_s, fn, args)`` at the end of every numba compile in this
    process: its seconds without and with the compiles it triggered inside, the Python function
    compiled (None if numba names none) and its argument types."""
    from numba.core import event

    class Listener(event.Listener):
        def on_start(self, ev):
            _STACK.append([time.perf_counter(), 0.0])

        def on_end(self, ev):
            t0, inner = _STACK.pop()
            took = time.perf_counter() - t0
            if _STACK:
                _STACK[-1][1] += took
            data = ev.data if isinstance(ev.data, dict) else {}
            on_compile(took - inner, took, getattr(data.get("dispatcher"), "py_func", None),
                       data.get("args"))

    event.register("numba:compile", Listener())


def _install(path: str) -> None:
    def write(own, took, fn, args):
        row = [round(own, 4), round(took, 4), getattr(fn, "__module__", "?"),
               getattr(fn, "__qualname__", "?"), str(args),
               os.environ.get("PYTEST_CURRENT_TEST", "").rsplit(" (", 1)[0]]
        with open(path, "a") as f:
            f.write(json.dumps(row) + "\n")

    listen(write)


def pytest_configure(config):
    path = os.environ.get("NUMBA_COMPILE_LOG")
    if path:
        _install(path)


def summary(path: str, top: int = 15) -> str:
    rows = [json.loads(line) for line in open(path)]
    total = sum(r[0] for r in rows)
    out = [f"{len(rows)} compiles, {total:.1f} s"]
    for title, key in (("by module", lambda r: r[2]), ("by kernel", lambda r: f"{r[2]}.{r[3]}"),
                       ("by test file", lambda r: r[5].split("::")[0] or "(no test)")):
        sums: collections.Counter = collections.Counter()
        for r in rows:
            sums[key(r)] += r[0]
        out += ["", title] + [f"{s:8.1f} s  {k}" for k, s in sums.most_common(top)]
    return "\n".join(out)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python tools/numba_compile_log.py LOG.jsonl")
    print(summary(sys.argv[1]))
