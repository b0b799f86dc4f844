"""Weights of fewer bits, measured in one run: every shipped size (full, half, quarter) x the
Numba engine's float32, bf16 and int8 weights, beside onnxruntime float32 and onnxruntime's own
dynamic int8 (``onnxruntime.quantization.quantize_dynamic``, ``QuantType.QInt8``, of the graph
``tpnet export onnx`` builds).

    PYTHONPATH=.:bench python bench/probes/bench_quantized.py            # speed, error, file sizes
    PYTHONPATH=.:bench python bench/probes/bench_quantized.py --errors   # also E_p@40/@80, 60 cases
    PYTHONPATH=.:bench python bench/probes/bench_quantized.py --calibrate data/grid-m4.h5  # + calibrated
    PYTHONPATH=.:bench python bench/probes/bench_quantized.py --errors --plot docs/eval_error_vs_precision.png
    PYTHONPATH=.:bench python bench/probes/bench_quantized.py --sizes full --rounds 9
    PYTHONPATH=.:bench python bench/probes/bench_quantized.py --layers   # error per layer only
    PYTHONPATH=.:bench python bench/probes/bench_quantized.py --rollout  # 600-step rollouts only
    PYTHONPATH=.:bench python bench/probes/bench_quantized.py --wide-choice data/grid-m4.h5
    PYTHONPATH=.:bench python bench/probes/bench_quantized.py --noise --sizes full   # E_p's spread
    PYTHONPATH=.:bench python bench/probes/bench_quantized.py --blocks --sizes full  # one-plane int8

Per row: B = 1 latency (median over 64 windows of the scene, every peer called in turn, window
by window: this VM's speed drifts), B = 256 throughput (one call on 256 windows, peers in turn),
one prediction's largest and median move from this engine's float32 prediction over the 256
windows (world units; the ring's radius is 2), and the file a deployment ships (native file
for the engine, ONNX for onnxruntime). The windows are simulated held-out test cases
(``_common.scene_windows``), only timed and compared, never used to choose anything.
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

import _common
import tpnet_ref

SCHEMES = ("float32", "bf16", "int8")
#: the targets (full size): int8 B = 1 <= 0.5 x float32 and <= 0.7 x onnxruntime int8, B = 256
#: throughput >= onnxruntime int8's, within 0.05 world units; bf16 B = 1 <= 0.75 x float32,
#: within 0.01; the int8 file <= 8 MB
TARGETS = {"int8 / float32 B=1": 0.5, "int8 / ort int8 B=1": 0.7, "bf16 / float32 B=1": 0.75}


def _ort_sessions(model, threads, tmp: Path) -> dict:
    """onnxruntime float32 on the export's graph (model coordinates, N = 30) and its dynamic
    int8 quantization; {label: (run, file bytes)}, or {} without onnxruntime."""
    try:
        import onnxruntime as ort
        from onnxruntime.quantization import QuantType, quantize_dynamic
    except ImportError:
        print("onnxruntime not installed: its rows are skipped")
        return {}
    from tpnet_ref.conformance.onnx_peer import build_onnx
    f32 = tmp / "f32.onnx"
    i8 = tmp / "int8.onnx"
    f32.write_bytes(build_onnx(model, 30).SerializeToString())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        quantize_dynamic(str(f32), str(i8), weight_type=QuantType.QInt8)
    opts = ort.SessionOptions()
    if threads:
        opts.intra_op_num_threads = threads
    out = {}
    for label, path in (("ort float32", f32), ("ort int8", i8)):
        sess = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        out[label] = ((lambda x, s=sess: s.run(None, {"window": x})[0]), path.stat().st_size)
    return out


def _engines(size: str, tmp: Path, calibrate: str | None = None,
             files: dict | None = None) -> dict:
    """The Numba engine on ``size`` in each scheme: {label: (model, file bytes)} (the float32
    file is the shipped one; the others written by ``tpnet quantize``'s code, gzip); with
    ``calibrate`` (a dataset file) also "bf16 cal" and "int8 cal", ``tpnet quantize
    --calibrate``'s."""
    from tpnet_ref.weights.native import extra_groups, write_replacing
    from tpnet_ref.weights.shipped import shipped_weights_path
    src = shipped_weights_path(4, size)
    out = {"float32": (tpnet_ref.load(src, engine="numba"), src.stat().st_size)}
    for s in SCHEMES[1:]:
        q = tpnet_ref.load(src, engine="numba", weights=s)
        path = tmp / f"{size}-{s}.h5"
        write_replacing(path, q.config, q.params, q.meta, extra_groups(src), "gzip")
        out[s] = (tpnet_ref.load(path, engine="numba"), path.stat().st_size)
    if calibrate:
        from tpnet_ref.weights import calibrate as C
        f32 = out["float32"][0]
        c = f32.config
        wins = C.training_windows(calibrate, c.m, c.dim)
        for s in SCHEMES[1:]:
            q = C.calibrated(f32, wins, Path(calibrate).name, s)
            path = tmp / f"{size}-{s}-cal.h5"
            write_replacing(path, q.config, q.params, q.meta, extra_groups(src), "gzip")
            out[f"{s} cal"] = (tpnet_ref.load(path, engine="numba"), path.stat().st_size)
    for label, path in (files or {}).items():        # --file: rows of other files of this network
        m = tpnet_ref.load(path, engine="numba")
        if m.config == out["float32"][0].config:
            out[label] = (m, Path(path).stat().st_size)
    return out


def _case_errors(models: dict) -> dict:
    """E_p of each of the 60 test cases over 80 predictions, ``{label: (60, 80) array}``
    (headline reading, points as given)."""
    from tpnet_ref.evaluation import HEADLINE, TEST_CASES, ModelSpec, evaluate, simulate_cases
    frames = simulate_cases(TEST_CASES, workers=1)
    specs = [ModelSpec(k, m) for k, m in models.items()]
    curves = evaluate(frames, specs, orderings=("given",), horizon=80)
    return {c.name: c.err[f"Ep_{HEADLINE}"] for c in curves if c.name in models}


def _errors(models: dict) -> dict:
    """Mean E_p at 40 and 80 frames on the 60 test cases (headline reading, points as given)."""
    return {k: (float(e[:, 39].mean()), float(e[:, 79].mean()))
            for k, e in _case_errors(models).items()}


def run_size(size: str, rounds: int, threads, errors: bool, tmp: Path,
             calibrate: str | None = None, files: dict | None = None) -> dict:
    eng = _engines(size, tmp, calibrate, files)
    base = eng["float32"][0]
    x1, x256 = _common.scene_windows(base)
    wins = list(x256[::4])
    calls1, calls256, sizes, preds = {}, {}, {}, {}
    for k, (m, nbytes) in eng.items():
        m.threads = threads
        calls1[k] = lambda x, m=m: m.predict(x, normalized=True)
        calls256[k] = lambda x, m=m: m.predict_batch(x, normalized=True)
        sizes[k] = nbytes
        preds[k] = m.predict_batch(x256, normalized=True)
    for k, (fn, nbytes) in _ort_sessions(base, threads, tmp).items():
        calls1[k] = lambda x, fn=fn: fn(x[None])
        calls256[k] = fn
        sizes[k] = nbytes
        preds[k] = fn(x256)
    for f in calls1.values():                        # warm: compile, caches
        f(wins[0])
    for f in calls256.values():
        f(x256)
    t1 = _common.alternate(calls1, wins, rounds)
    t256 = _common.alternate(calls256, [x256], rounds)
    scale = base.config.norm_hi - base.config.norm_lo
    rows = {}
    for k in calls1:
        per = np.abs(preds[k] - preds["float32"]).max(axis=(1, 2)) * scale
        rows[k] = {"b1_ms": t1[k] * 1e3, "b256_ms": t256[k] * 1e3,
                   "b256_wps": 256 / t256[k], "max_d": float(per.max()),
                   "median_d": float(np.median(per)), "file_mb": sizes[k] / 1e6}
    if errors:
        for k, (ep40, ep80) in _errors({k: m for k, (m, _) in eng.items()}).items():
            rows[k].update(ep40=ep40, ep80=ep80)
    return rows


def layers(size: str) -> None:
    """``--layers``: the largest move of one prediction (world units, 256 windows of the scene)
    from the float32 model's when one BiLSTM's matrices alone are on a scheme's grid, or all
    of them: the float64 reference on those weights against the float64 reference on the
    float32 weights (docs/tolerances.md, "Weights of fewer bits")."""
    from tpnet_ref.engines import reference
    from tpnet_ref.weights import quantize as Q
    base = tpnet_ref.load(size=size, engine="numpy")
    cfg = base.config
    _, x256 = _common.scene_windows(base)
    wins = x256[::4]                                     # 64 windows: the reference is slow
    p64 = {k: np.asarray(v, dtype=np.float64) for k, v in base.params.items()}

    def run(p):
        return np.stack([reference.forward(cfg, p, list(w), normalized=True) for w in wins])

    want = run(p64)
    scale = cfg.norm_hi - cfg.norm_lo
    for scheme in SCHEMES[1:]:
        wide = set(Q.wide_names(cfg, scheme))
        row = []
        for layer in list(range(1, len(cfg.lstm_units) + 1)) + ["all"]:
            p = dict(p64)
            for n in Q.quantized_names(cfg):
                if layer == "all" or n.startswith(f"lstm{layer}."):
                    p[n] = Q.round_to(base.params[n], scheme, n in wide).astype(np.float64)
            row.append(f"{layer}: {np.abs(run(p) - want).max() * scale:.4f}")
        print(f"  {size:8s} {scheme:5s} BiLSTM " + ", ".join(row))


def rollouts(size: str, steps: int = 600, files: dict | None = None) -> None:
    """``--rollout``: each scheme's (and each ``--file``'s of this size) rollout of ``steps``
    predictions from the first window of each of the 60 test cases (one batch): finite, the
    points' range (the box is [0, 45]), the largest distance of a point from its frame's
    centroid (the ring's radius is 2), and the largest distance from the float32 engine's
    rollout at 10, 100 and ``steps`` predictions."""
    from tpnet_ref.evaluation import TEST_CASES, simulate_cases
    frames = simulate_cases(TEST_CASES, rows=20, workers=1)[:, :4]       # (60, 4, 30, 2)
    ref = None
    models = {s: tpnet_ref.load(size=size, engine="numba", weights=None if s == "float32" else s)
              for s in SCHEMES}
    extra = {k: tpnet_ref.load(p, engine="numba") for k, p in (files or {}).items()}
    models.update({k: m for k, m in extra.items() if m.config == models["float32"].config})
    for scheme, m in models.items():
        t = time.perf_counter()
        out = m.rollout_batch(frames.astype(np.float32), steps)            # (60, steps, 30, 2)
        dt = time.perf_counter() - t
        ref = out if ref is None else ref
        radius = np.linalg.norm(out - out.mean(axis=2, keepdims=True), axis=-1).max()
        far = [np.abs(out[:, k - 1] - ref[:, k - 1]).max() for k in (10, 100, steps)]
        print(f"  {size:8s} {scheme:8s} finite {bool(np.isfinite(out).all())}, points in "
              f"[{out.min():.2f}, {out.max():.2f}], largest radius {radius:.2f}, from float32 "
              f"@10/@100/@{steps} {far[0]:.3f} / {far[1]:.3f} / {far[2]:.3f} ({dt:.1f} s)")


def _print(size: str, rows: dict) -> None:
    print(f"\n{size}")
    print(f"  {'weights':12s} {'B=1 ms':>7s} {'B=256 ms':>9s} {'win/s':>7s} {'max |d|':>8s} "
          f"{'median':>7s} {'file MB':>8s}" + ("  E_p@40  E_p@80" if "ep40" in rows["float32"] else ""))
    for k, r in rows.items():
        err = f"  {r['ep40']:6.4f}  {r['ep80']:6.4f}" if "ep40" in r else ""
        print(f"  {k:12s} {r['b1_ms']:7.3f} {r['b256_ms']:9.1f} {r['b256_wps']:7.0f} "
              f"{r['max_d']:8.4f} {r['median_d']:7.4f} {r['file_mb']:8.2f}{err}")
    f = rows["float32"]
    for i8 in [k for k in rows if "int8" in k and not k.startswith("ort")]:
        bf = i8.replace("int8", "bf16")
        i, b = rows[i8], rows.get(bf)
        ratios = {f"{i8} / float32 B=1": i["b1_ms"] / f["b1_ms"]}
        if b is not None:
            ratios[f"{bf} / float32 B=1"] = b["b1_ms"] / f["b1_ms"]
        if "ort int8" in rows:
            o = rows["ort int8"]
            ratios[f"{i8} / ort int8 B=1"] = i["b1_ms"] / o["b1_ms"]
            ratios[f"{i8} / ort int8 B=256 throughput"] = i["b256_wps"] / o["b256_wps"]
        print("  " + ", ".join(f"{k} {v:.2f}" for k, v in ratios.items()))
        if size != "full":
            continue
        checks = [(k, ratios[k] <= v) for k, v in
                  ((t.replace("int8", i8, 1).replace("bf16", bf, 1), v)
                   for t, v in TARGETS.items()) if k in ratios]
        if f"{i8} / ort int8 B=256 throughput" in ratios:
            checks.append((f"{i8} B=256 throughput >= ort int8",
                           ratios[f"{i8} / ort int8 B=256 throughput"] >= 1))
        checks += [(f"{i8} within 0.05", i["max_d"] <= 0.05), (f"{i8} file <= 8 MB", i["file_mb"] <= 8.0)]
        if b is not None:
            checks += [(f"{bf} within 0.01", b["max_d"] <= 0.01)]
        print("  targets: " + "; ".join(f"{k}: {'met' if ok else 'NOT met'}" for k, ok in checks))


def plot(rows: dict, path: str) -> None:
    """``--plot``: the front on two axes: E_p@80 (with ``--errors``) and one prediction's
    largest move from float32 against B = 1 latency, every size x scheme (onnxruntime's rows
    on the second panel)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(11.5, 4))
    marks = {"full": "o", "half": "s", "quarter": "^"}
    colours = {"float32": "C0", "bf16": "C1", "int8": "C2", "bf16 cal": "C5", "int8 cal": "C4",
               "ort float32": "C7", "ort int8": "C3"}
    for size, by in rows.items():
        for k, r in by.items():
            kw = dict(marker=marks.get(size, "o"), color=colours.get(k, "k"), s=40)
            if "ep80" in r:
                axes[0].scatter(r["b1_ms"], r["ep80"], **kw)
            if k not in ("float32", "ort float32"):
                axes[1].scatter(r["b1_ms"], max(r["max_d"], 1e-3), **kw)
    from matplotlib.ticker import FormatStrFormatter, NullFormatter
    for ax, label in zip(axes, ("E_p@80, 60 test cases (squared)",
                                "max move from float32 (world units)")):
        ax.set_xscale("log")
        ax.set_yscale("log" if ax is axes[1] else "linear")   # E_p@80 spans less than a decade
        for axis in (ax.xaxis, ax.yaxis):        # plain numbers, no 2x10^-1 labels crowding
            axis.set_major_formatter(FormatStrFormatter("%g"))
            axis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("B = 1 latency (ms)")
        ax.set_ylabel(label)
    handles = [plt.Line2D([], [], ls="", marker="o", color=c, label=k) for k, c in colours.items()]
    handles += [plt.Line2D([], [], ls="", marker=m, color="k", label=k) for k, m in marks.items()]
    axes[1].legend(handles=handles, fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    fig.tight_layout()
    from tpnet_ref.evaluation.plots import save_png
    save_png(fig, path, dpi=90)
    print(f"wrote {path}")


def wide_choice(data: str, size: str = "full") -> None:
    """``--wide-choice DATA``: bf16's largest and median move from float32 over 256 windows of
    DATA's *validation* trajectories (the training grid; the choice of which matrices get two
    bf16 planes rests on these, never on the test cases), with no matrix in two planes, with
    int8's four (:func:`tpnet_ref.weights.quantize.wide_names`) and with bf16's own set."""
    from tpnet_ref.training.recipe import WindowData
    from tpnet_ref.weights import quantize as Q
    from tpnet_ref.weights.shipped import shipped_weights_path
    d = WindowData(data, 0.05, 0)
    rows = d.val_win[np.random.default_rng(0).choice(len(d.val_win), 256, replace=False)]
    x, _ = d.gather(rows)
    path = shipped_weights_path(4, size)
    f32 = tpnet_ref.load(path, engine="numpy")
    ref = f32.predict_batch(x, normalized=True)
    scale = f32.config.norm_hi - f32.config.norm_lo
    own = Q.wide_names
    for label, names in (("one plane everywhere", lambda c, s="int8": []),
                         ("int8's four in two planes", lambda c, s="int8": own(c, "int8")),
                         ("bf16's set in two planes", own)):
        Q.wide_names = names
        try:
            y = tpnet_ref.load(path, engine="numpy", weights="bf16").predict_batch(
                x, normalized=True)
        finally:
            Q.wide_names = own
        per = np.abs(y - ref).max(axis=(1, 2)) * scale
        print(f"{size} bf16, {label:26s} largest move {per.max():.4f}, median "
              f"{np.median(per):.4f} (world units, 256 validation windows)")


def noise(size: str, seeds: int = 3) -> None:
    """``--noise``: how far E_p@40 / @80 on the 60 test cases moves when every BiLSTM matrix is
    multiplied by ``1 + eps * N(0, 1)`` (eps 1e-5, 1e-4, 1e-3; ``seeds`` draws each), beside
    bf16's and int8's own change of those matrices (RMS of the change over RMS of the weights).
    A quantization moves the weights by about 1e-3 (bf16) to 1e-2 (int8): this is the spread of
    E_p that weight changes of that size give with no rounding scheme at all."""
    from tpnet_ref.model import TPNet
    from tpnet_ref.weights.shipped import shipped_weights_path
    src = shipped_weights_path(4, size)
    base = tpnet_ref.load(src, engine="numba")
    lstm = [k for k in base.params if k.startswith("lstm") and not k.endswith(".bias")]
    for s in SCHEMES[1:]:
        q = tpnet_ref.load(src, engine="numpy", weights=s).params
        rel = [float(np.sqrt(np.mean((q[k] - base.params[k]) ** 2) / np.mean(base.params[k] ** 2)))
               for k in lstm]
        print(f"{size} {s}: the BiLSTM matrices' relative RMS change {min(rel):.1e} to {max(rel):.1e}")
    models = {"float32": base}
    for eps in (1e-5, 1e-4, 1e-3):
        for seed in range(seeds):
            rng = np.random.default_rng(seed)
            p = {k: (v * (1 + eps * rng.standard_normal(v.shape))).astype(v.dtype)
                 if k in lstm else v for k, v in base.params.items()}
            models[f"eps {eps:g} seed {seed}"] = TPNet(base.config, p, base.dtype, base.meta,
                                                      "numba", unit_order=base.unit_order)
    err = _case_errors(models)
    ref = err["float32"]
    print(f"{'weights':20s} {'E_p@40':>7s} {'E_p@80':>7s} {'/ f32 @40':>9s} {'@80':>6s} "
          f"{'largest case move @80':>22s}")
    for k, e in err.items():
        d = np.abs(e[:, 79] - ref[:, 79])
        print(f"{k:20s} {e[:, 39].mean():7.4f} {e[:, 79].mean():7.4f} "
              f"{e[:, 39].mean() / ref[:, 39].mean():9.2f} {e[:, 79].mean() / ref[:, 79].mean():6.2f}"
              f" {d.max():12.3f} (case {d.argmax()})")


def blocks(size: str) -> None:
    """``--blocks``: the largest and median move of one prediction (world units, the 256 windows
    of the scene, the NumPy engine in float32) when every BiLSTM matrix is int8 in one plane,
    symmetric, with a scale per column (the shipped scheme's grid, one plane) or per block of
    128, 64, 32 or 16 rows of a column: whether finer scales (outliers) or the grid's step
    keep one plane from 0.05 world units."""
    from tpnet_ref.model import TPNet
    base = tpnet_ref.load(size=size, engine="numpy")
    cfg = base.config
    _, x256 = _common.scene_windows(base)
    want = base.predict_batch(x256, normalized=True)
    lstm = [k for k in base.params if k.startswith("lstm") and not k.endswith(".bias")]

    def one_plane(w: np.ndarray, rows: int) -> np.ndarray:
        out = np.empty_like(w)
        for r in range(0, w.shape[0], rows):
            s = np.abs(w[r:r + rows]).max(axis=0) / 127
            s[s == 0] = 1
            out[r:r + rows] = np.clip(np.rint(w[r:r + rows] / s), -127, 127) * s
        return out

    for rows in (None, 128, 64, 32, 16):
        p = {k: one_plane(v, rows or v.shape[0]) if k in lstm else v
             for k, v in base.params.items()}
        got = TPNet(cfg, p, base.dtype, base.meta, "numpy",
                    unit_order=base.unit_order).predict_batch(x256, normalized=True)
        move = np.abs(got - want).max(axis=(1, 2)) * (cfg.norm_hi - cfg.norm_lo)
        rel = max(float(np.sqrt(np.mean((p[k] - base.params[k]) ** 2)
                                / np.mean(base.params[k] ** 2))) for k in lstm)
        print(f"{size} int8 one plane, a scale per {f'{rows} rows' if rows else 'column':9s}: "
              f"largest move {move.max():.4f}, median {np.median(move):.4f} (world units); "
              f"relative RMS change up to {rel:.1e}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="full,half,quarter",
                    help="comma-separated shipped sizes (default: full,half,quarter)")
    ap.add_argument("--rounds", type=int, default=5,
                    help="rounds over the 64 B = 1 windows and of the B = 256 call (default: 5)")
    ap.add_argument("--threads", type=int, default=None,
                    help="threads of every peer (default: each one's own policy)")
    ap.add_argument("--layers", action="store_true",
                    help="only the quantization's error per BiLSTM (float64 reference, 64 windows)")
    ap.add_argument("--rollout", action="store_true",
                    help="only 600-step rollouts from the 60 test cases: finite, bounded")
    ap.add_argument("--wide-choice", default=None, metavar="DATA",
                    help="only bf16's move from float32 on DATA's validation windows with each "
                         "choice of two-plane matrices (the choice's evidence)")
    ap.add_argument("--noise", action="store_true",
                    help="only E_p@40 / @80 under random relative changes of the BiLSTM "
                         "matrices (1e-5, 1e-4, 1e-3): E_p's spread at a quantization's size")
    ap.add_argument("--blocks", action="store_true",
                    help="only one prediction's move with one-plane int8 BiLSTM matrices, a "
                         "scale per column or per block of 128 .. 16 rows")
    ap.add_argument("--json", default=None, metavar="FILE",
                    help="also write every row to this JSON file")
    ap.add_argument("--plot", default=None, metavar="PNG",
                    help="also draw the front (E_p@80 with --errors; the move from float32)")
    ap.add_argument("--errors", action="store_true",
                    help="also E_p@40 / @80 on the 60 test cases (simulates them: minutes)")
    ap.add_argument("--file", action="append", default=[], metavar="LABEL=PATH",
                    help="also a row for this native file (e.g. a quantization-aware run's, "
                         "'int8 qat=runs/q.h5'), for each size whose network it has")
    ap.add_argument("--calibrate", default=None, metavar="DATA",
                    help="also bf16 and int8 calibrated on DATA's training windows (`tpnet "
                         "quantize --calibrate`), rows 'bf16 cal' and 'int8 cal'")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    print(_common.machine())
    print(f"load average at start: {_common.load_average()}")
    files = dict(f.split("=", 1) for f in args.file)            # --file LABEL=PATH
    t0 = time.time()
    if args.wide_choice:
        for size in args.sizes.split(","):
            wide_choice(args.wide_choice, size)
        return 0
    if args.layers or args.rollout or args.noise or args.blocks:
        for size in args.sizes.split(","):
            if args.rollout:
                rollouts(size, files=files)
                continue
            (layers if args.layers else noise if args.noise else blocks)(size)
        return 0
    every = {}
    with tempfile.TemporaryDirectory() as d:
        for size in args.sizes.split(","):
            every[size] = run_size(size, args.rounds, args.threads, args.errors, Path(d),
                                   args.calibrate, files)
            _print(size, every[size])
    if args.plot:
        plot(every, args.plot)
    if args.json:
        import json
        Path(args.json).write_text(json.dumps({"machine": _common.machine(), "rows": every,
                                               "load": _common.load_average()}, indent=1))
    print(f"\nload average at end: {_common.load_average()} ({time.time() - t0:.0f} s, "
          f"pid {os.getpid()})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
