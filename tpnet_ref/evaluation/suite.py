"""``tpnet eval`` end to end: simulate (or read) the held-out cases, evaluate the models and the
baselines, time them, and write ``results.md``, ``eval_curves.csv`` and the figures.

Writes into a new directory (``./tpnet-eval-<UTC timestamp>/``) unless ``out`` is given; the
repository's ``docs/`` only when asked (``--out docs``).
"""
from __future__ import annotations

import datetime as _dt
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..engines.blas import describe as blas_describe
from ..config import denormalize
from ..sim.dataset import load_trajectories
from ..model import load
from ..sim.protocol import FRAME_EVERY, SIM_ROWS, split_protocol
from .report import Report, write_results
from .run import TEST_CASES, Curve, ModelSpec, evaluate, generalisation_cases, simulate_cases
from .timing import CALIBRATION_TRAJECTORIES, missing_peers, timing_table


def default_out_dir() -> str:
    """``tpnet-eval-<UTC timestamp>``: a new directory in the working directory."""
    return "tpnet-eval-" + _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%d-%H%M%S")


def command_line(args: Any = None) -> str:
    """The command that made the report: this process's ``tpnet eval ...`` command line, or
    (when called from Python) the same rebuilt from the parsed arguments."""
    if sys.argv[1:2] == ["eval"] or args is None:
        return " ".join(["tpnet"] + sys.argv[1:])
    parts = ["tpnet eval"] + [f"--weights {w}" for w in args.weights]
    for flag, value in (("--baselines-only", args.baselines_only), ("--data", args.data),
                        ("--cases", args.cases), ("--horizon", args.horizon),
                        ("--generalisation", args.generalisation),
                        ("--no-specialized", getattr(args, "no_specialized", False)),
                        ("--calibration-trajectories",
                         getattr(args, "calibration_trajectories", None)),
                        ("--out", args.out)):
        if value is True:
            parts.append(flag)
        elif value not in (None, False):
            parts.append(f"{flag} {value}")
    if args.m:
        parts.append("--m " + " ".join(map(str, args.m)))
    return " ".join(parts)


def _gallery_model(models: list[ModelSpec]) -> ModelSpec | None:
    """The m = 4 model (the default, docs/spec.md §4's best row), else the first."""
    return next((s for s in models if s.model.config.m == 4), models[0] if models else None)


def run_eval(args: Any, command: str | None = None, log: Any = None) -> Path:
    """``tpnet eval`` with parsed ``args``; returns the path of ``results.md``."""
    log = log or sys.stderr
    t_start = time.perf_counter()
    progress = not args.quiet
    if args.baselines_only and args.weights:
        raise ValueError("--baselines-only and --weights exclude each other")
    if not args.baselines_only and not args.weights:
        raise ValueError("give --weights PATH (repeatable) or --baselines-only")
    if args.cases is not None and args.cases < 1:
        raise ValueError(f"--cases: must be >= 1, got {args.cases}")
    if args.horizon is not None and args.horizon < 1:
        raise ValueError(f"--horizon: must be >= 1, got {args.horizon}")
    n_cal = getattr(args, "calibration_trajectories", None)
    n_cal = CALIBRATION_TRAJECTORIES if n_cal is None else n_cal
    if n_cal < 1:
        raise ValueError(f"--calibration-trajectories: must be >= 1, got {n_cal}")
    if not getattr(args, "no_timing", False) and not getattr(args, "no_peers", False):
        for line in missing_peers():                      # said before any work is done
            print(f"tpnet eval: {line}", file=log)
    out_dir = args.out or default_out_dir()
    names = [Path(w).name for w in args.weights]
    # batched rollouts (the NumPy head either way); the timing rows are the NumPy engine's
    models = [ModelSpec(f"TP-Net {n if names.count(n) == 1 else w}",
                        load(w, dtype="float32", engine="numpy"))
              for n, w in zip(names, args.weights)]
    ms = args.m or ([s.model.config.m for s in models] or [4])
    if args.data:
        kw = {"allow_other_scene": True} if getattr(args, "allow_other_scene", False) else {}
        frames, params = load_trajectories(args.data, "test", **kw)
        frames = frames.astype(np.float64)
        cases = np.asarray(params, dtype=float)
        source = f"test split of {args.data}"
    else:
        cases = np.asarray(TEST_CASES, dtype=float)
        frames = None
        source = "held-out test cases simulated on the fly with tpnet_ref.sim in the faithful scene, docs/glossary.md"
    if args.cases is not None:
        cases = cases[: args.cases]
        frames = None if frames is None else frames[: args.cases]
    # rows so that the longest window plus the horizon fits (model frame j = row 4 j)
    need = max(list(ms) + [s.model.config.m for s in models]) + (args.horizon or 0)
    rows = SIM_ROWS if args.horizon is None else FRAME_EVERY * (need - 1) + 1
    if frames is None:
        print(f"simulating {len(cases)} cases ...", file=log)
        frames = simulate_cases(cases, rows, workers=args.workers, progress=progress)
    keep: dict[str, np.ndarray] = {}
    print("rollouts and errors ...", file=log)
    curves = evaluate(frames, models, ms=ms, horizon=args.horizon, orderings=args.orderings,
                      seed=args.seed, progress=progress, keep=keep)
    horizon = curves[0].err["Ep_squared"].shape[1]
    gal = _gallery_model(models)
    t_m = gal.model.config.m if gal else (4 if 4 in ms else ms[0])
    timing = None
    if not args.no_timing:
        print("timing ...", file=log)
        timing = timing_table(frames, cases, [gal] if gal else [], m=t_m,
                              horizon=min(80, horizon), repeats=args.repeats,
                              peers=not args.no_peers,
                              specialized=not getattr(args, "no_specialized", False),
                              calibration_trajectories=n_cal, progress=progress)
    gen: dict[str, list[Curve]] = {}
    if args.generalisation:
        for g, gc in generalisation_cases(args.gen_cases).items():
            print(f"generalisation: {g} ...", file=log)
            gf = simulate_cases(gc, rows, workers=args.workers, progress=progress, desc=g)
            gen[g] = evaluate(gf, models, ms=ms, horizon=args.horizon, orderings=("given",),
                              seed=args.seed, group=g, progress=progress)
    # gallery: the m = 4 model (else the first; else constant velocity) on 4 cases
    sel = np.linspace(0, len(cases) - 1, min(4, len(cases))).astype(int)
    _, targets = split_protocol(frames, t_m, horizon)
    gal_name = gal.label if gal else f"constant velocity m={t_m}"
    gallery = {"truth": targets[sel],
               "preds": {gal_name: denormalize(keep[gal_name][sel])},
               "horizons": sorted({h for h in (1, 20, 40, 80, horizon) if h <= horizon}),
               "case_labels": [f"F={c[0]:g} {c[1]:g}° ({c[2]:g},{c[3]:g})" for c in cases[sel]],
               "m": t_m}
    rep = Report(command=command or command_line(args), n_cases=len(cases), horizon=horizon,
                 source=source, curves=curves, timing=timing, timing_m=t_m, generalisation=gen,
                 models=list(args.weights), elapsed_s=time.perf_counter() - t_start,
                 blas=blas_describe())
    return write_results(rep, out_dir, plots=not args.no_plots, gallery=gallery)


__all__ = ["run_eval", "command_line", "default_out_dir"]
