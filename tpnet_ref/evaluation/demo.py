"""``tpnet demo``: one held-out scene, the model beside copy-last and constant velocity, a PNG.

The model gets the first m frames with the points of each frame shuffled (it needs no order);
constant velocity needs matched points and gets them in the simulator's order.
"""
from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..engines.blas import describe as blas_describe
from ..engines.blas import one_thread
from ..engines.compile_watch import COMPILING, CompileWatch
from ..config import normalize
from ..model import load
from ..sim.protocol import FRAME_EVERY, SIM_ROWS, constant_velocity, copy_last, order_points, \
    split_protocol
from ..sim import simulate
from .plots import plot_demo
from .run import PAPER_TABLE, TEST_CASES, errors

#: the demo's built-in scene: the first held-out test case (force, angle, x, y)
DEMO_CASE: tuple[float, float, float, float] = tuple(TEST_CASES[0])  # type: ignore[assignment]
DEMO_HORIZONS = (1, 10, 20, 40, 80, 140)
#: the predictions drawn in the PNG's zoomed panels (those the rollout reaches)
PNG_HORIZONS = (10, 40, 80, 140)


def _g(x: float) -> str:
    """Three significant digits; 0 for what is zero up to rounding."""
    return "0" if abs(x) < 1e-12 else f"{x:.3g}"


def demo(weights: str | None = None, *, case: Sequence[float] = DEMO_CASE, steps: int | None = None,
         horizons: Sequence[int] = DEMO_HORIZONS, png: str | None = "tpnet_demo.png",
         seed: int = 0, dtype: str = "float32", out: Any = None) -> dict[str, Any]:
    """Simulate ``case``, give the model its first m frames with the points of each frame
    shuffled, roll out, print its errors beside copy-last and constant velocity at ``horizons``
    in the ``squared`` and ``released`` readings (docs/spec.md §3), the timings with the threads
    the prediction ran on (and the BLAS inside it), and write a PNG (``png``; the ``plot`` extra).

    The first line says what it does, at once; a run that compiles Numba kernels (the first
    after install) says so when it starts compiling, and the compile time is a line of its own
    in the report (:class:`~tpnet_ref.engines.compile_watch.CompileWatch`), not part of the rollout's.

    Raises ``FileNotFoundError`` (from :func:`tpnet_ref.load`) when there are no weights.
    Returns the numbers printed: ``errors[h][method]`` -> the error dict of
    :func:`~tpnet_ref.evaluation.errors` at horizon ``h``, timings, the PNG path."""
    stream = out or sys.stdout

    def say(s: str = "") -> None:
        print(s, file=stream, flush=True)

    t0 = time.perf_counter()
    say("tpnet demo: simulating a held-out scene and rolling the model out on it (the first run "
        "after install also compiles the Numba kernels, once)")
    with CompileWatch(lambda: say(COMPILING)) as compiled:
        r = _demo(weights, case, steps, horizons, png, seed, dtype, say, compiled)
    total = time.perf_counter() - t0
    say(compiled.report())
    say(f"total {total:.1f} s" + (f" ({compiled.seconds:.1f} s of it compiling)"
                                  if compiled.count else ""))
    r.update(total=total, t_compile=compiled.seconds, compiled=compiled.count)
    return r


def _demo(weights: str | None, case: Sequence[float], steps: int | None,
          horizons: Sequence[int], png: str | None, seed: int, dtype: str, say: Any,
          compiled: CompileWatch) -> dict[str, Any]:
    """:func:`demo`'s work and report, but for its first line and its totals."""
    t0 = time.perf_counter()
    model = load(weights, dtype=dtype)
    m = model.config.m
    t_load = time.perf_counter() - t0
    t, c = time.perf_counter(), compiled.seconds
    frames = simulate(*case, SIM_ROWS)[::FRAME_EVERY]
    t_sim = time.perf_counter() - t - (compiled.seconds - c)    # the simulator's kernel too
    H = int(steps) if steps is not None else frames.shape[0] - m
    inputs, targets = split_protocol(frames[None], m, H)
    window = order_points(inputs, "shuffle", seed)[0]
    model.rollout(window, 1)                                # warm caches before timing
    t, c = time.perf_counter(), compiled.seconds
    pred = model.rollout(window, H)                         # world units
    t_roll = time.perf_counter() - t - (compiled.seconds - c)   # a kernel compiled meanwhile
    truth_n = normalize(targets)
    inputs_n = normalize(inputs)
    methods = {"TP-Net": normalize(pred[None].astype(np.float64)),
               "copy last": copy_last(inputs_n, H),
               "const. velocity": constant_velocity(inputs_n, H)}
    err = {name: errors(truth_n, p) for name, p in methods.items()}
    f, a, x, y = case
    say(f"tpnet demo: {model!r}")
    say(f"scene: force {f:g}, angle {a:g} deg, start ({x:g}, {y:g}) (held-out test case 1); "
        f"simulated {SIM_ROWS} steps in {t_sim * 1e3:.0f} ms")
    say(f"input: frames 0..{m - 1}, the 30 points of each frame shuffled independently "
        f"(constant velocity gets them in the simulator's order: it needs matched points)")
    with one_thread():                  # what every product of a prediction runs on
        blas_inside = blas_describe()
    plan = model.preferred_threads("rollout step", 1, model.config.n_out)
    ran = ("2 threads (the Numba engine's two LSTM directions)" if plan == 0 else "1 thread")
    if plan == 0 and model.engine == "numba":
        from ..engines.numba_engine import two_thread_kernels_skipped
        if two_thread_kernels_skipped():
            plan = 1
            ran = ("1 thread (the two-thread plan was chosen, but numba's cache has no "
                   "two-thread kernels and this command does not stop to compile them)")
    say(f"rollout: {H} recursive predictions in {t_roll * 1e3:.0f} ms "
        f"({t_roll * 1e3 / H:.2f} ms/frame, {model.dtype.name}); model loaded in "
        f"{t_load * 1e3:.0f} ms")
    say(f"threads: the prediction ran on {ran}; every BLAS product inside it on a one-thread "
        f"BLAS: {blas_inside}")
    shown = [h for h in horizons if 1 <= h <= H]
    names = list(methods)
    short = ("TP-Net", "copy last", "const vel")
    for v in ("squared", "released"):
        say("")
        say(f"errors against the simulator, reading \"{v}\" (normalised coordinates"
            + ("; the reading of the paper's table)" if v == "squared"
               else "; the released evaluation script)"))
        say(f"  {'':>11}  {'E_p (position)':^32}  {'E_s (shape)':^32}")
        say(f"  {'step':>5} {'frame':>5}  " + " ".join(f"{n:>10}" for n in short) + "  "
            + " ".join(f"{n:>10}" for n in short))
        for h in shown:
            say(f"  {h:>5} {m - 1 + h:>5}  "
                + " ".join(f"{_g(err[n][f'Ep_{v}'][0, h - 1]):>10}" for n in names) + "  "
                + " ".join(f"{_g(err[n][f'Es_{v}'][0, h - 1]):>10}" for n in names))
    if m in PAPER_TABLE:
        p = PAPER_TABLE[m]
        say(f"paper's TP-Net (m = {m}, mean of 60 cases, squared): E_p {p[0]} / {p[2]}, "
            f"E_s {p[1]} / {p[3]} at 40 / 80 predictions (this is one case)")
    wrote = None
    if png:
        ph = [h for h in PNG_HORIZONS if h <= H] or [H]
        titles = {}
        for h in ph:
            e, c = err["TP-Net"], err["copy last"]
            titles[h] = (f"h = {h}: frame {m - 1 + h}, t = {(m - 1 + h) * FRAME_EVERY / 45:.1f} s\n"
                         f"TP-Net E_p {_g(e['Ep_squared'][0, h - 1])} (copy last "
                         f"{_g(c['Ep_squared'][0, h - 1])})\nTP-Net E_s {_g(e['Es_squared'][0, h - 1])}"
                         f" (copy last {_g(c['Es_squared'][0, h - 1])})")
        plot_demo(png, frames, pred, m, ph, titles, label=f"TP-Net (m={m})",
                  suptitle=f"tpnet demo: force {f:g}, angle {a:g}°, start ({x:g}, {y:g}); "
                           f"TP-Net from {m} shuffled frames, {H} recursive predictions; "
                           "errors in the squared reading (normalised coordinates)")
        wrote = png
        say("")
        say(f"wrote {png} (the box with the centroid paths; simulator vs prediction at "
            f"predictions {', '.join(map(str, ph))})")
    rows = {h: {n: {k: float(v[0, h - 1]) for k, v in err[n].items()} for n in names}
            for h in shown}
    return {"errors": rows, "t_sim": t_sim, "t_rollout": t_roll, "t_load": t_load,
            "blas": blas_inside, "threads": 2 if plan == 0 else 1, "png": wrote, "m": m, "steps": H}


__all__ = ["demo", "DEMO_CASE", "DEMO_HORIZONS"]
