"""Learning curves of training runs side by side: validation E_p@40 / E_p@80 of every snapshot,
the 8-step validation loss of every validation, and the dead units per layer, against the
windows seen (the wall time is in the rows and the CSV).

Each RUN is a ``tpnet train run ... --snapshots`` directory (its ``snapshots/step-*.h5`` and
``log.jsonl``). Every snapshot is scored with the test protocol on the validation trajectories
of DATA (:func:`tpnet_ref.training.score.score_rollouts`: frames 0..m-1 in, 80 recursive
predictions, both readings; never the 60 test cases); scores are cached in
``RUN/snapshots/scores.json`` so a rerun scores only new snapshots. ``--reading`` picks the
reading printed and plotted: ``squared`` (default: the paper comparison's, the one the sizes
table uses) or ``released``.

    python tools/recipe_curves.py data/grid-m4.h5 released=runs/q-released \\
        current=runs/q-current --png docs/recipe_curves.png --csv docs/recipe_curves.csv

A run made with ``--init-from`` is placed after its parents: its windows seen and wall time
count theirs (``inherited`` in its ``checkpoint.json``). Prints one row per snapshot (run,
step, windows seen, wall time, E_p@40, E_p@80, E_s@80,
val_cd8, dead units of each layer) and the copy-last baseline; the CSV has both readings.
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
import warnings
from pathlib import Path

import numpy as np

from tpnet_ref.training.recipe import WindowData
from tpnet_ref.training.score import SNAPSHOT_READINGS as READINGS, score_snapshots

LAYERS = ("mlp1.0", "mlp1.1", "mlp2.0", "mlp2.1", "mlp2.2", "global", "lstm1", "lstm2", "lstm3")


def _log_records(run: Path, kind: str = "val") -> dict[int, dict]:
    """The run's ``log.jsonl`` records of ``kind`` (``val`` or ``train``), by step."""
    out = {}
    for line in (run / "log.jsonl").read_text().splitlines():
        rec = json.loads(line)
        if rec.get("kind") == kind:
            out[int(rec["step"])] = rec
    return out


def inherited(run: Path) -> tuple[int, float]:
    """Windows seen and wall time of the runs ``run`` continues (``--init-from``; 0 for a run
    from scratch): its curve is placed after theirs."""
    ck = run / "checkpoint.json"
    parents = json.loads(ck.read_text()).get("inherited", {}).get("runs", []) if ck.is_file() else []
    return (sum(int(p.get("windows_seen", 0)) for p in parents),
            sum(float(p.get("wall_s", 0.0)) for p in parents))


def run_rows(data: WindowData, label: str, run: Path,
             offset: tuple[int, float] = (0, 0.0)) -> list[dict]:
    """One row per snapshot of ``run`` (scored now or read from its cache), its windows seen
    and wall time counted from ``offset`` (:func:`inherited`)."""
    cache = score_snapshots(data, run)
    # scores kept without their snapshot files (a run restored from a tarball of its state)
    stored = run / "snapshots" / "scores.json"
    cache = {**(json.loads(stored.read_text()) if stored.is_file() else {}), **cache}
    names = sorted(k for k in cache if k.startswith("step-"))
    w0, t0 = offset
    vals = _log_records(run)
    trained = _log_records(run, "train")
    ck = run / "checkpoint.json"
    batch = json.loads(ck.read_text())["recipe"]["batch"] if ck.is_file() else None
    rows = []
    for name in names:
        step = int(name[len("step-"):-len(".h5")])
        rec = vals.get(step, {})
        dead = rec.get("dead", {})
        w, t = rec.get("windows_seen"), rec.get("wall_s")
        if w is None and batch is not None:          # a snapshot between validations
            w = step * batch
        if t is None:
            t = max((r["wall_s"] for st, r in trained.items() if st <= step), default=None)
        rows.append({"run": label, "step": step, "windows_seen": None if w is None else w0 + w,
                     "wall_s": None if t is None else t0 + t, **cache[name],
                     "val_cd8": rec.get("val_cd8"),
                     **{f"dead {k}": dead.get(k) for k in LAYERS},
                     **{f"units {k}": dead.get(k + "/of") for k in LAYERS}})
    return rows, cache.get("copy last")


def column(key: str, reading: str) -> str:
    """The cache's name of ``key`` (``Ep@80``) in ``reading``."""
    return key if reading == "released" else f"{key} {reading}"


def plot(rows: list[dict], copy_last: dict | None, logs: dict[str, dict[int, dict]],
         path: str, reading: str = "squared", offsets: dict[str, int] | None = None) -> None:
    import matplotlib
    matplotlib.use("Agg")
    offsets = offsets or {}
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(20, 4.4))
    runs = list(dict.fromkeys(r["run"] for r in rows))
    colours = {label: f"C{i}" for i, label in enumerate(runs)}
    for label in runs:
        rr = [r for r in rows if r["run"] == label]
        w = np.array([r["windows_seen"] / 1e6 for r in rr])
        for ax, key in zip(axes[:2], ("Ep@40", "Ep@80")):
            ax.plot(w, [_num(r.get(column(key, reading))) for r in rr], "o-",
                    color=colours[label], label=label)
        every = sorted(logs[label].items())          # every validation, not only snapshots
        axes[3].plot([(offsets.get(label, 0) + v["windows_seen"]) / 1e6 for _, v in every
                      if v.get("windows_seen")],
                     [v["val_cd8"] for _, v in every if v.get("windows_seen")], ".-",
                     color=colours[label], label=label)
        vals = [v for _, v in sorted(logs[label].items()) if v.get("dead")]
        w = np.array([(offsets.get(label, 0) + v["windows_seen"]) / 1e6 for v in vals])
        fe = [sum(v["dead"].get(k, 0) for k in LAYERS[:5]) for v in vals]
        fe_of = [sum(v["dead"].get(k + "/of", 0) for k in LAYERS[:5]) for v in vals]
        axes[2].plot(w, 100 * np.array(fe) / np.maximum(1, fe_of), "o-", color=colours[label],
                     label=f"{label}: per-point layers")
        axes[2].plot(w, [100 * v["dead"]["global"] / v["dead"]["global/of"] for v in vals],
                     "s--", color=colours[label], label=f"{label}: global layer")
    for ax, key in zip(axes[:2], ("Ep@40", "Ep@80")):
        if copy_last:
            ax.axhline(copy_last[column(key, reading)], color="grey", ls=":", label="copy last")
        ax.set_ylim(bottom=0)
        ax.set_xlabel("training windows seen (millions)")
        ax.set_ylabel(f"validation {key.replace('@', ' @')} ({reading} reading)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[3].set_xscale("log")
    axes[3].set_yscale("log")
    axes[3].set_xlabel("training windows seen (millions)")
    axes[3].set_ylabel("validation 8-step Chamfer loss (val_cd8, every validation)")
    axes[3].grid(alpha=0.3, which="both")
    axes[3].legend(fontsize=8)
    axes[2].set_xlabel("training windows seen (millions)")
    axes[2].set_ylabel("dead ReLU units (% of the layers' units)")
    axes[2].set_ylim(bottom=0)
    axes[2].grid(alpha=0.3)
    axes[2].legend(fontsize=7)
    fig.suptitle("From scratch: validation trajectories (356), 80 recursive predictions; dead "
                 "units on 1,024 validation windows")
    fig.tight_layout()
    from tpnet_ref.evaluation.plots import save_png
    # 64 colours: a third of the bytes of the RGBA file, the same picture (docs/ has a budget)
    save_png(fig, path, dpi=110, colours=64)


def _num(v) -> float:
    return float("nan") if v is None else float(v)


def fit(rows: list[dict], label: str, reading: str, targets: dict[str, float],
        rates: dict[str, float], first_step: int = 0) -> str:
    """A power law ``E = a * windows^b`` per figure over ``label``'s snapshots from
    ``first_step`` on, and the windows (and hours at each rate) where it meets ``targets``."""
    rr = [r for r in rows if r["run"] == label and r["step"] >= first_step
          and r.get("windows_seen")]
    lines = []
    for key, target in targets.items():
        pts = [(r["windows_seen"], r.get(column(key, reading))) for r in rr]
        pts = [(w, e) for w, e in pts if e is not None and e > 0]
        if len(pts) < 3:
            lines.append(f"fit {label} {key}: {len(pts)} snapshots, too few for a fit")
            continue
        x, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
        b, a = np.polyfit(x, y, 1)
        resid = y - (a + b * x)
        span = f"{min(p[0] for p in pts) / 1e6:.2f}-{max(p[0] for p in pts) / 1e6:.2f} M windows"
        if b >= 0:
            lines.append(f"fit {label} {key} over {len(pts)} snapshots ({span}): exponent "
                         f"{b:+.2f}, not falling: no projection")
            continue
        need = float(np.exp((np.log(target) - a) / b))
        hours = ", ".join(f"{need / r / 3600:,.1f} h at {n} ({r:,.0f} windows/s)"
                          for n, r in rates.items())
        lines.append(f"fit {label} {key} over {len(pts)} snapshots ({span}): E ∝ windows^{b:.2f} "
                     f"(rms log residual {np.sqrt(np.mean(resid ** 2)):.2f}); {target} at "
                     f"{need / 1e6:,.1f} M windows: {hours}")
    return "\n".join(lines)


def summary(rows: list[dict], reading: str) -> str:
    """A Markdown table: per run, the snapshots' mean [min, max] of each figure."""
    keys = [column(k, reading) for k in ("Ep@40", "Ep@80", "Es@80")] + ["val_cd8"]
    lines = ["| run | snapshots (steps) | " + " | ".join(keys) + " |",
             "|---|---|" + "---|" * len(keys)]
    for label in dict.fromkeys(r["run"] for r in rows):
        rr = [r for r in rows if r["run"] == label]
        cells = []
        for k in keys:
            v = np.array([r[k] for r in rr if r.get(k) is not None], dtype=float)
            cells.append(f"{v.mean():.4g} [{v.min():.4g}, {v.max():.4g}]" if v.size else "")
        steps = f"{len(rr)} ({rr[0]['step']}-{rr[-1]['step']})"
        lines.append(f"| {label} | {steps} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", help="the grid file (tpnet data generate) whose validation "
                                 "trajectories score the snapshots")
    ap.add_argument("runs", nargs="+", metavar="LABEL=RUN_DIR",
                    help="run directories made with --snapshots, each with a label")
    ap.add_argument("--png", default=None, help="write the curves to this PNG")
    ap.add_argument("--csv", default=None, help="write the rows (both readings) to this CSV")
    ap.add_argument("--reading", choices=READINGS, default="squared",
                    help="the reading printed and plotted (default: squared)")
    ap.add_argument("--summary", action="store_true",
                    help="also one line per run: the mean (and range) over its snapshots of "
                         "E_p@40, E_p@80, E_s@80 and val_cd8 (ablation arms: one snapshot of "
                         "these rollouts decides nothing)")
    ap.add_argument("--fit", default=None, metavar="LABEL[:FIRST_STEP]",
                    help="fit a power law in windows seen to this run's snapshots (from "
                         "FIRST_STEP on) and say where it meets the --targets")
    ap.add_argument("--targets", nargs="*", default=["Ep@40=0.071", "Ep@80=0.164"],
                    metavar="FIGURE=VALUE",
                    help="the figures the fit projects to (default: the paper's E_p@40 0.071 "
                         "and E_p@80 0.164; a figure may repeat with another value)")
    ap.add_argument("--rates", nargs="*", default=[], metavar="NAME=WINDOWS_PER_S",
                    help="training rates the fit's windows are turned into hours at")
    args = ap.parse_args(argv)
    # an early snapshot's rollouts leave the trained range on purpose: no warning per case
    warnings.filterwarnings("ignore", module="tpnet_ref")
    warnings.filterwarnings("ignore", message=".*training range.*")
    warnings.filterwarnings("ignore", message=".*one body.*")
    data = WindowData(args.data, 0.05, 0)
    rows, copy_last, logs, offsets = [], None, {}, {}
    for spec in args.runs:
        if "=" not in spec:
            ap.error(f"{spec!r}: expected LABEL=RUN_DIR")
        label, run = spec.split("=", 1)
        if not (Path(run) / "snapshots").is_dir():
            ap.error(f"{run}: no snapshots/ (train with --snapshots)")
        off = inherited(Path(run))
        r, copy_last = run_rows(data, label, Path(run), off)
        rows += r
        logs[label] = _log_records(Path(run))
        offsets[label] = off[0]
    cols = ["run", "step", "windows_seen", "wall_s",
            *(column(k, args.reading) for k in ("Ep@40", "Ep@80", "Es@80")), "val_cd8",
            *(f"dead {k}" for k in LAYERS)]
    print(" | ".join(cols))
    for r in rows:
        print(" | ".join(f"{r.get(c):.4g}" if isinstance(r.get(c), float) else str(r.get(c, ""))
                         for c in cols))
    if copy_last:
        print("copy last: " + ", ".join(f"{k} {copy_last[column(k, args.reading)]:.4g}"
                                        for k in ("Ep@40", "Ep@80", "Es@80")))
    if args.summary:
        print(summary(rows, args.reading))
    if args.fit:
        label, _, first = args.fit.partition(":")
        rates = {n: float(v) for n, v in (r.split("=", 1) for r in args.rates)}
        for spec in args.targets:
            key, _, value = spec.partition("=")
            if key not in ("Ep@40", "Ep@80", "Es@80") or not value:
                ap.error(f"--targets {spec!r}: expected Ep@40=, Ep@80= or Es@80=VALUE")
            print(fit(rows, label, args.reading, {key: float(value)}, rates, int(first or 0)))
    if args.csv:
        with open(args.csv, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    if args.png:
        plot(rows, copy_last, logs, args.png, args.reading, offsets)
    return 0


if __name__ == "__main__":
    sys.exit(main())
