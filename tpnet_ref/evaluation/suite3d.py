"""``tpnet eval`` of 3-D models: the 60 held-out 3-D throws (docs/spec.md §8), every model
beside copy-last and constant velocity, and error against run time.

The 2-D protocol in 3-D (:func:`tpnet_ref.evaluation.run.evaluate`): model frames every 4
simulator rows, the first m frames in, recursive predictions to the end, E_p / E_s at 40 and 80
predictions in the three readings on normalised coordinates, each cell the mean over the cases
with its 95 % bootstrap interval and the median. The front: each model's parameters and its
B = 1 latency (median of ``predict`` on one window of every case, the default engine, float32)
against its E_p at 40 and 80 predictions. Writes ``results3d.md``, ``eval3d_curves.csv``,
``eval3d_cases.csv`` and (with matplotlib) ``front3d.png``.
"""
from __future__ import annotations

import datetime as _dt
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..model import load
from ..sim.cases3d import TEST_CASES3D
from ..sim.dataset import load_trajectories
from ..sim.protocol import FRAME_EVERY, SIM_ROWS
from .report import CELL_TEXT, md_table, results_tables, write_cases_csv, write_curves_csv
from .run import HEADLINE, Curve, ModelSpec, evaluate, progress_bar

#: the input orderings of the 3-D tables: as simulated and shuffled
ORDERINGS3D = ("given", "shuffle")


def simulate_cases3d(cases: Any, rows: int = SIM_ROWS, progress: bool = False) -> np.ndarray:
    """Model frames ``(C, ceil(rows/4), N, 3)`` (world units) of each 3-D throw ``(force,
    azimuth_deg, elevation_deg, x, y, z)``: rows 0, 4, ... of
    :func:`tpnet_ref.sim.scene3d.simulate3d` (the ``sim3d`` extra)."""
    from ..sim.scene3d import simulate3d
    cases = np.asarray(cases, dtype=float).reshape(-1, 6)
    out = [simulate3d(*map(float, c), rows)[::FRAME_EVERY]
           for c in progress_bar(cases, progress, len(cases), "simulate 3-D")]
    return np.stack(out)


def n_parameters(model: Any) -> int:
    """Trained numbers in a model's layers."""
    return int(sum(np.asarray(v).size for v in model.params.values()))


def latency_b1(model: Any, windows: np.ndarray, repeats: int = 3) -> float:
    """Median seconds of one ``predict`` (B = 1) over ``windows (C, m, N, 3)`` (world units),
    the best of ``repeats`` passes over them; the first call (compilation) is not timed."""
    model.predict(windows[0])
    best = np.inf
    for _ in range(max(1, repeats)):
        times = []
        for w in windows:
            t0 = time.perf_counter()
            model.predict(w)
            times.append(time.perf_counter() - t0)
        best = min(best, float(np.median(times)))
    return best


def front_rows(curves: list[Curve], models: list[ModelSpec], frames: np.ndarray,
               repeats: int, paths: dict[str, str] | None = None) -> list[dict[str, Any]]:
    """Per model: parameters, B = 1 latency and E_p (squared) at 40 / 80 predictions (given
    order). The latency is the default engine's: the file in ``paths[label]`` loaded again
    (the rollouts ran on the NumPy engine), else the model as it is."""
    paths = paths or {}
    rows = []
    for spec in models:
        m = spec.model.config.m
        windows = frames[:, :m]
        c = next(c for c in curves if c.name == spec.label and c.ordering == "given")
        hs = [h for h in (40, 80) if h <= c.err[f"Ep_{HEADLINE}"].shape[1]]
        fast = load(paths[spec.label], dtype="float32") if spec.label in paths else spec.model
        rows.append({"name": spec.label, "params": n_parameters(spec.model),
                     "latency_us": 1e6 * latency_b1(fast, windows, repeats),
                     **{f"Ep@{h}": c.at(h) for h in hs}})
    return rows


def _front_md(rows: list[dict[str, Any]], curves: list[Curve]) -> str:
    hs = [h for h in (40, 80) if rows and f"Ep@{h}" in rows[0]]
    base = {c.name: c for c in curves if c.ordering == "given" and not c.name.startswith("TP-Net")}
    table = [[r["name"], f"{r['params']:,}", f"{r['latency_us']:.0f}"]
             + [f"{r[f'Ep@{h}']:.3g}" for h in hs] for r in rows]
    table += [[name, "0", "–"] + [f"{c.at(h):.3g}" for h in hs] for name, c in base.items()]
    return md_table(["method", "parameters", "B = 1 latency (µs)"] + [f"E_p @{h}" for h in hs],
                    table)


def _plot_front(rows: list[dict[str, Any]], curves: list[Curve], path: Path) -> Path | None:
    try:
        from .plots import pyplot, save_png
        plt = pyplot()
    except ImportError:
        return None
    fig, ax = plt.subplots(figsize=(5.2, 3.4))
    for h, marker in ((40, "o"), (80, "s")):
        pts = [(r["latency_us"], r[f"Ep@{h}"], r["name"]) for r in rows if f"Ep@{h}" in r]
        if pts:
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker, label=f"TP-Net 3-D, E_p @{h}")
            for x, y, name in pts:
                ax.annotate(name.replace("TP-Net ", ""), (x, y), fontsize=7,
                            xytext=(3, 3), textcoords="offset points")
        cl = next((c for c in curves if c.name == "copy last" and c.ordering == "given"), None)
        if cl is not None and h <= cl.err[f"Ep_{HEADLINE}"].shape[1]:
            ax.axhline(cl.at(h), ls="--", lw=0.8, color="0.5" if h == 40 else "0.2",
                       label=f"copy last, E_p @{h}")
    from matplotlib.ticker import FormatStrFormatter, NullFormatter
    ax.set_xscale("log")
    ax.set_yscale("log")
    lat = [r["latency_us"] for r in rows if r.get("latency_us")]
    for axis in (ax.xaxis, ax.yaxis):               # plain numbers; minor labels on y
        axis.set_major_formatter(FormatStrFormatter("%g"))
        axis.set_minor_formatter(FormatStrFormatter("%g") if axis is ax.yaxis else NullFormatter())
    if lat:                                         # x: each model's own latency marked
        ax.set_xticks(sorted({float(round(v)) for v in lat}))
    ax.set_xlabel("B = 1 latency (µs, the machine in results3d.md)")
    ax.set_ylabel("E_p (squared, normalised)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_png(fig, path, dpi=110)
    plt.close(fig)
    return path


def run_eval3d(weights: list[str], *, data: str | None = None, cases: int | None = None,
               horizon: int | None = None, seed: int = 0, out: str | Path = "tpnet-eval3d",
               repeats: int = 3, plots: bool = True, progress: bool = False,
               command: str = "tpnet eval", log: Any = None) -> Path:
    """Evaluate the 3-D ``weights`` (or the baselines alone when empty); returns the path of
    ``results3d.md`` in ``out``."""
    log = log or sys.stderr
    t0 = time.perf_counter()
    models, paths = [], {}
    for w in weights:
        model = load(w, dtype="float32", engine="numpy")
        if model.config.dim != 3:
            raise ValueError(f"{w}: a {model.config.dim}-D model among 3-D ones; evaluate "
                             "each dimension on its own")
        models.append(ModelSpec(f"TP-Net {Path(w).name}", model))
        paths[models[-1].label] = w
    if data:
        frames, params = load_trajectories(data, "test", dim=3)
        frames, source = frames.astype(np.float64), f"test split of {data}"
    else:
        params = np.asarray(TEST_CASES3D, dtype=float)
        frames, source = None, "the 60 held-out 3-D throws, simulated (tpnet_ref.sim.scene3d)"
    if cases is not None:
        if cases < 1:
            raise ValueError(f"--cases: must be >= 1, got {cases}")
        params = params[:cases]
        frames = None if frames is None else frames[:cases]
    if frames is None:
        print(f"simulating {len(params)} 3-D cases ...", file=log)
        frames = simulate_cases3d(params, progress=progress)
    ms = sorted({s.model.config.m for s in models} or {4})
    curves = evaluate(frames, models, ms=ms, horizon=horizon, orderings=ORDERINGS3D, seed=seed,
                      progress=progress)
    rows = front_rows(curves, models, frames, repeats, paths)
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_curves_csv(curves, out_dir / "eval3d_curves.csv")
    write_cases_csv(curves, out_dir / "eval3d_cases.csv")
    png = _plot_front(rows, curves, out_dir / "front3d.png") if plots and rows else None
    from ..engines.blas import describe
    now = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    busy = f", load average {os.getloadavg()[0]:.1f}" if hasattr(os, "getloadavg") else ""
    text = [f"# TP-Net in 3-D: {len(params)} held-out throws", "",
            f"Made by `{command}` ({now}, {time.perf_counter() - t0:.0f} s; python "
            f"{platform.python_version()}, numpy {np.__version__}, {os.cpu_count()} CPU cores, "
            f"{platform.machine()}{busy}; BLAS {describe()}); cases: {source}. Squared reading, "
            "normalised coordinates (docs/spec.md §3), input as simulated.", "",
            CELL_TEXT, "", results_tables(curves, with_paper=False), "",
            "## Shuffled input", "", results_tables(curves, ordering="shuffle", with_paper=False),
            "", "## Error against run time", "", _front_md(rows, curves), ""]
    if png is not None:
        text += [f"![E_p against B = 1 latency]({png.name})", ""]
    path = out_dir / "results3d.md"
    path.write_text("\n".join(text))
    return path


__all__ = ["run_eval3d", "simulate_cases3d", "latency_b1", "n_parameters", "ORDERINGS3D"]
