"""Error against run time across network sizes: one row per weights file, full size included.

    PYTHONPATH=. python bench/sizes.py WEIGHTS.h5 ... [--data data/grid-m4.h5] [--plot out.png]

For each file (the same TP-Net architecture at different widths, m = 4): trained parameters,
file size, E_p / E_s at 40 and 80 predictions in the squared reading (the paper comparison's;
``docs/evaluation.md``) on the 60 held-out test cases of the faithful scene (frames 0..3 in, 80
recursive predictions, ``tpnet eval``'s protocol), and the B = 1 latency of one prediction on
both engines (``engine="numpy"`` and ``engine="numba"``; median over the 64 scene windows
``x256[::4]`` of ``_common.scene_windows``, engines alternating call by call, float32), beside
onnxruntime running each size's exported graph when it is installed (each session in a process
of its own, ``_common.PeerProcess``).

The Pareto front (which sizes are worth shipping) is chosen WITHOUT the test cases: with
``--data`` (a ``tpnet data generate`` file), the same protocol runs on its validation
trajectories (``tpnet train score``'s, squared reading), and a size is on the front when no
other is at least as fast on both engines and at least as accurate on validation E_p@40 and
E_p@80 (one of them strictly); copying the last frame counts as a size of no run time, so a
size that copying beats at both horizons is not on the front. ``--plot``: E_p@40 / @80 on the
test cases against B = 1 latency, both engines, copy-last dashed, the front marked. Prints the load average: latency on a shared machine
is only comparable within one run.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import tpnet_ref
from _common import PeerProcess, alternate, scene_windows
from tpnet_ref import evaluation as E
from tpnet_ref.evaluation.report import cell
from tpnet_ref.sim.cases import TEST_CASES

HORIZONS = (40, 80)


def n_params(model) -> int:
    return int(sum(np.asarray(v).size for v in model.params.values()))


ORT = "onnxruntime"


def latency_b1(models: dict[str, dict[str, object]], x: np.ndarray, reps: int,
               paths: dict[str, str]) -> dict:
    """Median seconds of one ``predict_batch`` of one window, per (label, engine), alternating
    label by label and engine by engine within each round; with onnxruntime installed, also
    (label, :data:`ORT`): onnxruntime running the exported graph of that label's weights file
    (``paths``; model units in and out, like the calls it is timed beside), each session in a
    process of its own (``_common.PeerProcess``), at its default threads and at one thread,
    whichever is faster (on a 2-core VM its two threads are, by the minute, now faster and now
    twice as slow as one)."""
    calls = {(k, e): (lambda w, mo=mo: mo.predict_batch(w[None], normalized=True))
             for k in models for e, mo in models[k].items()}
    peers = []
    try:
        import onnxruntime  # noqa: F401
        for k in models:
            for key, threads in ((ORT, None), (ORT + " 1t", 1)):
                peers.append(PeerProcess())           # each session in a process of its own
                peers[-1].session(k, None, threads, path=paths[k], world_units=False)
                calls[(k, key)] = peers[-1].call(k)
    except ImportError as exc:
        print(f"onnxruntime skipped ({exc})")
    for f in calls.values():                           # warm up (compile, caches)
        f(x[0])
    got = alternate(calls, list(x), reps)
    for peer in peers:
        peer.close()
    for k in models:
        if (k, ORT) in got:
            got[(k, ORT)] = min(got[(k, ORT)], got.pop((k, ORT + " 1t")))
    return got


COPY_LAST = "copy last frame"


def errors_on(frames_n: np.ndarray, models: dict[str, object], m: int = 4) -> dict[str, dict]:
    """Squared-reading E_p / E_s at :data:`HORIZONS`, mean over cases, per model and for
    copying the last input frame (:data:`COPY_LAST`: no network, no run time)."""
    windows, truth = E.split_protocol(frames_n, m, max(HORIZONS))
    out = {}
    preds = {COPY_LAST: lambda: E.copy_last(windows, max(HORIZONS))}
    preds.update({k: (lambda mo=mo: E.batched_rollout(mo, windows, max(HORIZONS)))
                  for k, mo in models.items()})
    for k, fn in preds.items():
        err = E.errors(truth, fn())
        out[k] = {f"{q}@{h}": err[f"{q}_squared"][:, h - 1].copy()     # per case
                  for h in HORIZONS for q in ("Ep", "Es")}
    return out


def pareto(lat: dict[str, tuple[float, float]], err: dict[str, tuple[float, float]]) -> list[str]:
    """Labels no other label dominates (faster or as fast on both engines and as accurate or
    better on both horizons, strictly better somewhere)."""
    front = []
    for a in lat:
        dominated = False
        for b in lat:
            if b == a:
                continue
            le = all(lb <= la for lb, la in zip(lat[b], lat[a])) and \
                all(eb <= ea for eb, ea in zip(err[b], err[a]))
            lt = any(lb < la for lb, la in zip(lat[b], lat[a])) or \
                any(eb < ea for eb, ea in zip(err[b], err[a]))
            dominated |= le and lt
        if not dominated:
            front.append(a)
    return front


def plot(rows: list[dict], front: list[str], path: str) -> None:
    import matplotlib
    import matplotlib.ticker
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.4), sharey=False)
    for ax, h in zip(axes, HORIZONS):
        engines = [("numpy", "o", "tab:blue"), ("numba", "s", "tab:orange")]
        if all(r.get(f"ms_{ORT}") for r in rows):
            engines.append((ORT, "^", "tab:green"))
        for eng, mk, col in engines:
            xs = [r[f"ms_{eng}"] for r in rows]
            ys = [r[f"Ep@{h}"] for r in rows]
            ax.plot(xs, ys, mk + "-", color=col, alpha=0.85,
                    label=f"{eng} on each size's export" if eng == ORT else f"{eng} engine")
            for r, xv, yv in zip(rows, xs, ys):
                if eng != "numpy":          # one label per size, beside its NumPy point
                    continue
                on = r["label"] in front
                ax.annotate(r["label"] + (" *" if on else ""), (xv, yv), textcoords="offset points",
                            xytext=(5, 4), fontsize=8)
        ax.axhline(rows[0][f"copy@{h}"], color="grey", ls="--", lw=1,
                   label="copy last frame (no network)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        for axis, subs in ((ax.xaxis, (1, 2, 3, 5)), (ax.yaxis, (1, 2, 5))):   # plain numbers
            axis.set_major_locator(matplotlib.ticker.LogLocator(subs=subs))
            axis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
            axis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ms = [r[f"ms_{e}"] for r in rows for e, _, _ in engines]
        ax.set_xlim(min(ms) / 1.25, max(ms) * 1.6)     # room for the labels right of the points
        ax.set_xlabel("B = 1 latency of one prediction (ms, log)")
        ax.set_ylabel(f"E_p@{h}, squared reading, 60 test cases (log)")
        ax.set_title(f"error at {h} predictions against run time")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("TP-Net sizes (m = 4); * = on the Pareto front chosen on validation trajectories",
                 fontsize=10)
    fig.tight_layout()
    from tpnet_ref.evaluation.plots import save_png
    save_png(fig, path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("weights", nargs="+", help="native weights files (m = 4), any sizes")
    ap.add_argument("--data", default=None,
                    help="tpnet data generate file: choose the front on its validation trajectories")
    ap.add_argument("--plot", default=None, help="write the plot (PNG) here")
    ap.add_argument("--reps", type=int, default=3, help="rounds over the 64 latency windows")
    ap.add_argument("--md", default=None, help="also write the table as the section 'Network "
                    "sizes' of this markdown file (docs/results.md; kept by tpnet eval)")
    args = ap.parse_args(argv)

    warnings.simplefilter("ignore")
    t_start = time.perf_counter()
    load0 = os.getloadavg()[0]
    print(f"load average {load0:.1f}, {os.cpu_count()} CPUs")
    lines: list[str] = []
    emit = lines.append
    models, paths = {}, {}
    for w in args.weights:
        label = Path(w).stem
        models[label] = {e: tpnet_ref.load(w, engine=e) for e in ("numpy", "numba")}
        paths[label] = str(w)
        if models[label]["numpy"].config.m != 4:
            raise SystemExit(f"{w}: m = {models[label]['numpy'].config.m}, this table is m = 4")
    _, x256 = scene_windows(models[next(iter(models))]["numpy"])
    lat = latency_b1(models, x256[::4], args.reps, paths)

    frames = E.simulate_cases(np.asarray(TEST_CASES), rows=4 * (4 + max(HORIZONS)), workers=0)
    test = errors_on(E.normalize(frames), {k: v["numpy"] for k, v in models.items()})
    val = None
    if args.data:
        from tpnet_ref.training.recipe import Recipe, WindowData
        d = Recipe()                      # the default split of every run: 5 %, split seed
        data = WindowData(args.data, d.val_fraction, d.split_seed)
        val = errors_on(data.frames[data.val_traj].astype(np.float64),
                        {k: v["numpy"] for k, v in models.items()})
    per_case = test
    test = {k: {q: float(a.mean()) for q, a in v.items()} for k, v in per_case.items()}
    if val is not None:
        val = {k: {q: float(a.mean()) for q, a in v.items()} for k, v in val.items()}
    rows = []
    for w, (k, v) in zip(args.weights, models.items()):
        rows.append({"label": k, "params": n_params(v["numpy"]), "bytes": os.path.getsize(w),
                     "ms_numpy": 1e3 * lat[(k, "numpy")], "ms_numba": 1e3 * lat[(k, "numba")],
                     f"ms_{ORT}": 1e3 * lat[(k, ORT)] if (k, ORT) in lat else None,
                     **test[k], **{f"copy@{h}": test[COPY_LAST][f"Ep@{h}"] for h in HORIZONS}})
    rows.sort(key=lambda r: -r["params"])
    front = []
    if val is not None:        # copy-last costs nothing: a size it beats on both horizons is out
        front = pareto({**{r["label"]: (r["ms_numpy"], r["ms_numba"]) for r in rows},
                        COPY_LAST: (0.0, 0.0)},
                       {k: (val[k]["Ep@40"], val[k]["Ep@80"]) for k in val})
        front = [k for k in front if k != COPY_LAST]
    emit("60 held-out test cases, squared reading, each error `mean [95 % bootstrap interval] med "
         "median` over the cases (docs/glossary.md, \"spread\"); validation columns: means; "
         "B = 1 latency, float32, median ms:")
    emit("")
    head = ["weights", "trained parameters", "file (MB)", "E_p@40", "E_s@40", "E_p@80", "E_s@80",
            "B=1 numpy (ms)", "B=1 numba (ms)"]
    ort = all(r[f"ms_{ORT}"] for r in rows)
    if ort:
        head += ["B=1 onnxruntime (ms)", "numba / onnxruntime"]
    if val is not None:
        head += ["val E_p@40", "val E_p@80", "front"]
    emit("| " + " | ".join(head) + " |")
    emit("|" + "---|" * len(head))
    for r in rows:
        cells = [f"`{r['label']}`", f"{r['params']:,}", f"{r['bytes'] / 1e6:.1f}",
                 *(cell(per_case[r["label"]][q]) for q in ("Ep@40", "Es@40", "Ep@80", "Es@80")),
                 f"{r['ms_numpy']:.3g}", f"{r['ms_numba']:.3g}"]
        if ort:
            cells += [f"{r[f'ms_{ORT}']:.3g}", f"{r['ms_numba'] / r[f'ms_{ORT}']:.2f}"]
        if val is not None:
            v = val[r["label"]]
            cells += [f"{v['Ep@40']:.3g}", f"{v['Ep@80']:.3g}",
                      "yes" if r["label"] in front else "no"]
        emit("| " + " | ".join(cells) + " |")
    cells = [COPY_LAST, "0", "–",
             *(cell(per_case[COPY_LAST][q]) for q in ("Ep@40", "Es@40", "Ep@80", "Es@80")),
             "–", "–"] + (["–", "–"] if ort else [])
    if val is not None:
        cells += [f"{val[COPY_LAST]['Ep@40']:.3g}", f"{val[COPY_LAST]['Ep@80']:.3g}", "–"]
    emit("| " + " | ".join(cells) + " |")
    print("\n" + "\n".join(lines))
    if args.plot:
        plot(rows, front, args.plot)
        print(f"\nwrote {args.plot}")
    if args.md:
        import datetime
        import platform

        from tpnet_ref.evaluation import put_kept_section
        md = Path(args.md)
        cmd = "PYTHONPATH=. python bench/sizes.py " + " ".join(
            argv if argv is not None else sys.argv[1:])
        when = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        body = ["## Network sizes: error against run time", "",
                f"Made by `{cmd}` ({when}, "
                f"{time.perf_counter() - t_start:.0f} s; {platform.machine()}, {os.cpu_count()} "
                f"CPU cores, load average {load0:.1f} at the start: latencies are comparable "
                f"within this table only).", "",
                "The same TP-Net at smaller widths (`tpnet train run --size half|quarter`, "
                "docs/training.md). Errors: the 60 held-out test cases, squared reading, "
                "frames 0..3 in, 80 recursive predictions. Latency: one prediction of one window "
                "(B = 1), float32, median over 64 scene windows, the two engines and "
                "onnxruntime on each size's exported graph (`tpnet export onnx`, here in model "
                "units like the engines' calls; each graph run in a process of its own, the "
                "faster of its default threads and one) alternating call by call, so each call "
                "finds its weights evicted by the others' (cold caches; one model called "
                "again and again, as `python bench/bench_inference.py --sizes` times it, "
                "runs faster, each peer likewise). "
                "The front ('front') is chosen on the validation trajectories of the training "
                "grid (`val E_p`, same protocol and reading), never on the test cases; copying "
                "the last frame counts as a size of no run time. A file given by a path "
                "outside `weights/` is not tracked by git (weights/README.md, \"What git "
                "tracks\").", "", *lines]
        if args.plot:
            rel = os.path.relpath(args.plot, md.parent)
            body += ["", f"![error against run time by network size]({rel})"]
        text = md.read_text() if md.is_file() else ""
        md.write_text(put_kept_section(text, "sizes", "\n".join(body)))
        print(f"wrote the section 'Network sizes' of {md}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
