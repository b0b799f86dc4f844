"""The learning curve: validation error against cumulative training compute, and what it projects.

    PYTHONPATH=. python bench/learning_curve.py --data data/grid-m4.h5 \
        [--candidate LABEL=PATH.h5 ...] [--plot docs/learning_curve.png] [--md OUT.md]

Every m = 4 weights file the project has shipped is in git's history. This script takes each
version of ``weights/tpnet-m4.h5``, ``weights/tpnet-m4-half.h5`` and
``weights/tpnet-m4-quarter.h5`` from the commits that changed it (``git show COMMIT:PATH``),
plus the ``--candidate`` files (runs not shipped, or not yet), and scores them all on one
yardstick: the test protocol (frames 0..3 in, 80 recursive predictions) on the validation
trajectories of ``--data`` (``tpnet train score``'s, never the test cases), E_p at 40 and 80
predictions in the squared reading (the paper's; docs/glossary.md). The compute of each file is
its own provenance: cumulative epochs and wall time over the whole ``--init-from`` chain
(``tpnet info``); where a run of the chain was on a GPU, :data:`GPU_S` says how many of those
seconds (the chain's entries do not record their device).

The projection fits ``log E_p@80 = a + b log(epochs)`` to the full size's shipped points (a
power law, the usual shape of such curves) and solves it for the paper's E_p@80 (0.164, on the
test cases; validation and test differ, so this is an order of magnitude, not a promise), then
converts epochs to CPU-hours at the 8-step step rate of ``tpnet train bench`` (``--rate``,
windows/s) on this machine.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py
import numpy as np

from tpnet_ref import load
from tpnet_ref.evaluation.run import batched_rollout, errors
from tpnet_ref.sim.protocol import split_protocol
from tpnet_ref.training.recipe import Recipe, WindowData

ROOT = Path(__file__).resolve().parents[1]
HORIZONS = (40, 80)
#: the paper's m = 4 E_p (squared reading, test cases) at 40 and 80 predictions
PAPER = {40: 0.071, 80: 0.164}
#: GPU seconds inside a file's chain, by the commit that shipped it (weights/MODEL_CARD.md: runs
#: 4-6 ran on one H100 for 392 + 319 + 386 s, run 15 on one H200 for 387 s; every other run on
#: the 2-core CPU; 527c0fa, run 18, averages run 17 and run 16, whose chains hold runs 4-6 and 15)
GPU_S = {"a2e0dea": 1097.0, "09f4aac": 1097.0, "8d4bf57": 1097.0, "a91856c": 1097.0 + 387.0,
         "527c0fa": 1097.0 + 387.0}
#: training windows per epoch of the full grid (docs/training.md, "Throughput", "One epoch")
WINDOWS_PER_EPOCH = 167_489


def shipped_versions(path: str) -> list[tuple[str, str]]:
    """``[(short commit, subject)]`` of the commits that changed ``path``, oldest first."""
    out = subprocess.run(["git", "-C", str(ROOT), "log", "--format=%h %s", "--", path],
                         check=True, capture_output=True, text=True).stdout
    rows = [ln.split(" ", 1) for ln in out.splitlines() if ln.strip()]
    return [(c, s) for c, s in reversed(rows)]


def git_file(commit: str, path: str, dest: Path) -> Path:
    blob = subprocess.run(["git", "-C", str(ROOT), "show", f"{commit}:{path}"], check=True,
                          capture_output=True).stdout
    dest.write_bytes(blob)
    return dest


def compute_of(path: Path) -> dict:
    """Cumulative epochs and wall seconds of a file's whole chain (its provenance)."""
    with h5py.File(path, "r") as f:
        a = f.attrs
        return {"epochs": float(a.get("epochs", np.nan)),
                "wall_s": float(a.get("wall_time_s", np.nan)),
                "steps": int(a.get("training_steps", 0)),
                # an average (tpnet train average) has the counters of its longest input
                "average": str(a.get("average_of", ""))}


def score(data: WindowData, models: dict, horizon: int = 80) -> dict[str, dict]:
    frames = data.frames[data.val_traj].astype(np.float64)
    windows, truth = split_protocol(frames, data.m, horizon)
    out = {}
    for label, model in models.items():
        pred = batched_rollout(model, windows, horizon)
        err = errors(truth, pred)["Ep_squared"]
        out[label] = {h: float(err[:, h - 1].mean()) for h in HORIZONS}
        out[label].update({f"median{h}": float(np.median(err[:, h - 1])) for h in HORIZONS})
    return out


def projection(rows: list[dict], rate: float) -> dict | None:
    """Power-law fit of E_p@80 against epochs over the full size's shipped rows."""
    pts = [(r["epochs"], r[80]) for r in rows if r["size"] == "full" and r["shipped"]]
    if len(pts) < 2:
        return None
    x, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    b, a = np.polyfit(x, y, 1)
    out = {"a": float(a), "b": float(b), "points": len(pts)}
    if b < 0:
        ep = float(np.exp((np.log(PAPER[80]) - a) / b))
        out.update(epochs=ep, cpu_hours=ep * WINDOWS_PER_EPOCH / rate / 3600.0)
    return out


def plot(rows: list[dict], proj: dict | None, path: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.4), constrained_layout=True)
    colours = {"full": "C0", "half": "C2", "quarter": "C1"}
    by_size = {size: sorted((r for r in rows if r["size"] == size), key=lambda r: r["epochs"])
               for size in colours}
    # each shipped version's short label (f1, f2, ..., q1) and its key under the plots
    short = {id(r): f"{size[0]}{i + 1}" for size, rs in by_size.items()
             for i, r in enumerate(r for r in rs if r["shipped"])}
    fig.get_layout_engine().set(h_pad=0.1)
    fig.supxlabel("shipped versions: " + "; ".join(
        f"{short[id(r)]} = {r['label']}" for rs in by_size.values() for r in rs if r["shipped"]),
        fontsize=7)
    for ax, h in zip(axes, HORIZONS):
        for size, col in colours.items():
            rs = by_size[size]
            if not rs:
                continue
            ship = [r for r in rs if r["shipped"]]
            ax.plot([r["epochs"] for r in ship], [r[h] for r in ship], "o-", color=col,
                    label=f"{size}: shipped versions")
            cand = [r for r in rs if not r["shipped"]]
            if cand:
                ax.plot([r["epochs"] for r in cand], [r[h] for r in cand], "s", color=col,
                        mfc="none", ms=8, label=f"{size}: candidates")
            # short labels centred on their points (close points stay readable); the key
            # to the shipped versions' labels is under the plots
            for r in ship:
                ax.annotate(short[id(r)], (r["epochs"], r[h]), textcoords="offset points",
                            xytext=(0, 7), ha="center", fontsize=8)
            for r in cand:
                ax.annotate(r["label"], (r["epochs"], r[h]), textcoords="offset points",
                            xytext=(8, -3), ha="left", fontsize=7)
        ax.axhline(PAPER[h], color="k", ls=":", lw=1, label="paper (test cases)")
        if proj is not None and h == 80:
            e = np.geomspace(3, max(proj.get("epochs", 100), 100), 50)
            ax.plot(e, np.exp(proj["a"]) * e ** proj["b"], "--", color="C0", lw=1,
                    label="power-law fit (full)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("cumulative training epochs (whole --init-from chain)")
        ax.set_ylabel(f"validation E_p@{h} (squared reading)")
        ax.set_title(f"E_p after {h} recursive predictions")
        ax.grid(True, which="both", alpha=0.3)
    axes[1].legend(fontsize=7, loc="lower left")
    from tpnet_ref.evaluation.plots import save_png
    save_png(fig, path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default="data/grid-m4.h5")
    ap.add_argument("--candidate", action="append", default=[], metavar="LABEL=PATH",
                    help="a weights file to add (full size unless LABEL starts with 'half' or "
                         "'quarter')")
    ap.add_argument("--rate", type=float, default=None,
                    help="8-step training windows/s of this machine for the projection "
                         "(default: run tpnet train bench's timing at batch 128)")
    ap.add_argument("--plot", default=None)
    ap.add_argument("--md", default=None, help="also write the table to this Markdown file")
    args = ap.parse_args(argv)
    data = WindowData(args.data, Recipe.val_fraction, Recipe.split_seed)
    rows, models = [], {}
    sizes = {"full": "weights/tpnet-m4.h5", "half": "weights/tpnet-m4-half.h5",
             "quarter": "weights/tpnet-m4-quarter.h5"}
    with tempfile.TemporaryDirectory() as tmp:
        for size, path in sizes.items():
            for commit, subject in shipped_versions(path):
                f = git_file(commit, path, Path(tmp) / f"{size}-{commit}.h5")
                label = f"{size} {commit}"
                try:
                    models[label] = load(f)
                except ValueError as e:   # an early storage this reader no longer knows
                    print(f"skipped {label}: {e}", file=sys.stderr)
                    continue
                rows.append({"label": label, "size": size, "shipped": True, "commit": commit,
                             "subject": subject[:60], **compute_of(f)})
        for spec in args.candidate:
            label, _, path = spec.partition("=")
            models[label] = load(path)
            size = next((z for z in sizes if z != "full" and label.startswith(z)), "full")
            rows.append({"label": label, "size": size, "shipped": False, "commit": "",
                         "subject": path, **compute_of(Path(path))})
        # the same file shipped twice (re-stored, re-ordered) keeps one row; an average and
        # its longest input share their counters, not their weights
        seen, uniq = set(), []
        for r in rows:
            key = (r["size"], round(r["epochs"], 6), r["steps"], bool(r["average"]))
            if key not in seen:
                seen.add(key)
                uniq.append(r)
        rows = uniq
        scores = score(data, {r["label"]: models[r["label"]] for r in rows})
    for r in rows:
        r.update(scores[r["label"]])
        r["gpu_s"] = GPU_S.get(r["commit"], 0.0)
        r["cpu_h"] = (r["wall_s"] - r["gpu_s"]) / 3600.0
    rate = args.rate
    if rate is None:
        from tpnet_ref.training.throughput import bench, choose_precision
        from tpnet_ref.training.recipe import size_config
        prec, timing = choose_precision("auto", "cpu", size_config("full"), 128, 8, 2)
        rate = timing.get(prec) or bench(size_config("full"), batch=128, rollouts=(8,),
                                         iters=3, threads=2)[8]
    proj = projection(rows, rate)
    lines = [f"validation trajectories of {args.data}: {len(data.val_traj)}; E_p squared "
             "reading, mean (median) over trajectories",
             "", "| file | size | epochs | wall h (of which GPU) | CPU h | E_p@40 | E_p@80 |",
             "|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: (r["size"], r["epochs"])):
        gpu = f" ({r['gpu_s'] / 3600:.2f} GPU)" if r["gpu_s"] else ""
        lines.append(f"| {r['label']}{'' if r['shipped'] else ' (candidate)'} | {r['size']} | "
                     f"{r['epochs']:.1f} | {r['wall_s'] / 3600:.2f}{gpu} | {r['cpu_h']:.2f} | "
                     f"{r[40]:.3g} ({r['median40']:.3g}) | {r[80]:.3g} ({r['median80']:.3g}) |")
    lines.append("")
    if proj and "epochs" in proj:
        lines.append(f"Projection (power law over {proj['points']} shipped full-size points, "
                     f"E_p@80 ∝ epochs^{proj['b']:.2f}): the paper's E_p@80 {PAPER[80]} at "
                     f"about {proj['epochs']:.0f} epochs, {proj['cpu_hours']:.0f} CPU-hours at "
                     f"{rate:.0f} windows/s.")
    elif proj:
        lines.append(f"Projection: the fit over {proj['points']} points does not fall "
                     f"(exponent {proj['b']:.2f}); no projection.")
    text = "\n".join(lines)
    print(text)
    if args.md:
        Path(args.md).write_text(text + "\n")
    if args.plot:
        plot(rows, proj, args.plot)
        print(f"wrote {args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
