"""What a library user's first process compiles: every call of a first session, its seconds and
the kernel signatures numba compiles for it.

    PYTHONPATH=tools python bench/probes/first_process.py [--size full|half|quarter] [--list]

Runs, in this process, with an empty ``NUMBA_CACHE_DIR`` of its own (a first run after
installing; the package's own cache is not touched): ``load``, three ``predict`` calls of the
example window, one ``predict_batch`` of 8 windows and one ``rollout`` of 80 steps. Prints each
call's seconds and how many signatures of ``tpnet_ref``'s kernels numba compiled in it (a kernel
compiled for two argument types counts twice; ``--list`` names each with its argument types and
its own seconds, those of the kernels it compiled inside it left out).
Two callers that give one kernel arguments of different numba types (a literal constant, an
unsigned index, a read-only array) compile it twice: the list shows where.
"""
from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
import time


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="full", choices=["full", "half", "quarter"])
    ap.add_argument("--list", action="store_true", help="name every signature compiled")
    args = ap.parse_args()
    cache = tempfile.TemporaryDirectory(prefix="tpnet-first-process-")
    os.environ["NUMBA_CACHE_DIR"] = cache.name          # before numba is imported
    t_start = time.perf_counter()
    from numba_compile_log import listen                # tools/numba_compile_log.py

    compiled: list[str] = []

    def note(own, took, fn, args):
        if fn is not None and fn.__module__.startswith("tpnet_ref"):
            types = re.sub(r"Array\((\w+), (\d), '(\w)', (\w+), aligned=True\)",
                           lambda m: f"{m[1]}[{m[2]}{m[3]}{', readonly' * (m[4] == 'True')}]",
                           str(args))
            compiled.append(f"{own:5.2f} s {fn.__module__}.{fn.__name__} {types}")

    listen(note)
    import numpy as np

    import tpnet_ref as t

    def timed(name, call):
        before, t0 = len(compiled), time.perf_counter()
        got = call()
        print(f"  {name:26s} {time.perf_counter() - t0:6.1f} s  {len(compiled) - before:3d}"
              " signatures compiled")
        if args.list:
            for sig in compiled[before:]:
                print(f"      {sig[:160]}")
        return got

    window = t.example_window()
    print(f"first process, {args.size} size, empty numba cache ({sys.executable})")
    model = timed("load", lambda: t.load(size=args.size))
    for nth in ("1st", "2nd", "3rd"):
        timed(f"predict ({nth})", lambda: t.predict(window, model=model))
    batch = np.stack([window] * 8)
    timed("predict_batch (8 windows)", lambda: t.predict_batch(batch, model=model))
    timed("rollout (80 steps)", lambda: t.rollout(window, 80, model=model))
    print(f"  {'all, with the imports':26s} {time.perf_counter() - t_start:6.1f} s"
          f"  {len(compiled):3d} signatures compiled")
    cache.cleanup()


if __name__ == "__main__":
    main()
