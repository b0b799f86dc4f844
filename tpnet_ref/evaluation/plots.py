"""Figures of an evaluation run and of the demo (matplotlib: the ``plot`` extra).

Errors are drawn in the headline reading (``"squared"``, docs/spec.md §3); coordinates in world
units.
"""
from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..extras import require
from ..sim.protocol import HORIZONS
from .run import HEADLINE, Curve, table_horizons
from .timing import TimingRow

WALLS = (1.0, 44.0)          # inner faces of the walls, world units (docs/spec.md §5)
BOX = (0.0, 45.0)            # the whole box, walls included


def pyplot() -> Any:
    """matplotlib's pyplot on the file-writing backend (Agg); the ``plot`` extra."""
    matplotlib = require("matplotlib", "plot", "figures")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def save_png(fig: Any, path: str | os.PathLike, dpi: float | None = None,
             colours: int = 256) -> Path:
    """Write ``fig`` to ``path``: a PNG of at most ``colours`` colours (one palette, taken from
    the figure, no dithering: flat colours stay flat), about a third of the bytes of
    matplotlib's own RGBA PNG and alike to the eye on line plots; another suffix (``.pdf``,
    ``.svg``) as matplotlib writes it."""
    import io
    out = Path(path)
    if out.suffix.lower() != ".png":
        fig.savefig(out, dpi=dpi)
        return out
    from PIL import Image
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    buf.seek(0)
    with Image.open(buf) as im:
        rgb = im.convert("RGB")
    rgb.quantize(colours, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(
        out, format="PNG", optimize=True)
    return out


def _fit(text: str, width_in: float, fontsize: float) -> str:
    """``text`` wrapped to lines that fit ``width_in`` inches at ``fontsize`` points (an average
    character of the default font is about 0.55 em wide)."""
    import textwrap
    return textwrap.fill(text, max(20, int(width_in * 72 / (0.55 * fontsize))))


def plot_models(curves: Sequence[Curve], path: str | os.PathLike) -> Path:
    """Error against prediction step, one column per window length m (each model with the two
    baselines of its m, ordering ``given``), E_p on top and E_s below; reading ``squared``,
    the paper's TP-Net at 40 and 80 as stars."""
    from .run import PAPER_TABLE
    plt = pyplot()
    ms = sorted({c.m for c in curves})
    fig, axes = plt.subplots(2, len(ms), figsize=(4.6 * len(ms), 7), sharex=True, sharey="row",
                             squeeze=False)
    style = {"copy last": ("0.55", "--"), "constant velocity": ("tab:orange", ":")}
    for j, m in enumerate(ms):
        for c in curves:
            if c.m != m or c.ordering != "given":
                continue
            col, ls = style.get(c.name, ("tab:blue", "-"))
            h = np.arange(1, c.err[f"Ep_{HEADLINE}"].shape[1] + 1)
            for i, k in enumerate(("Ep", "Es")):
                axes[i, j].plot(h, c.mean(f"{k}_{HEADLINE}"), color=col, ls=ls, lw=1.5,
                                label=c.name)
        if m in PAPER_TABLE:
            p = PAPER_TABLE[m]
            for i, vals in enumerate(((p[0], p[2]), (p[1], p[3]))):
                axes[i, j].scatter(HORIZONS, vals, marker="*", s=120, color="tab:red",
                                   zorder=5, label="TP-Net, paper")
        axes[0, j].set_title(f"m = {m} input frames")
        axes[1, j].set_xlabel("prediction step h (frame m - 1 + h)")
        for i in range(2):
            axes[i, j].set_yscale("log")
            axes[i, j].grid(True, which="both", alpha=0.3)
    for j in range(len(ms)):                  # each panel names its own model
        axes[0, j].legend(fontsize=7, loc="lower right")
    axes[0, 0].set_ylabel(f"position error E_p ({HEADLINE})")
    axes[1, 0].set_ylabel(f"shape error E_s ({HEADLINE})")
    # one line across several columns; wrapped where one column is too narrow for it
    fig.suptitle(_fit("Rollout error on the held-out cases (mean over cases, normalised "
                      "coordinates)", 4.6 * len(ms), 12))
    fig.tight_layout()
    save_png(fig, path, dpi=90)
    plt.close(fig)
    return Path(path)


def plot_spread(curves: Sequence[Curve], path: str | os.PathLike) -> Path:
    """The per-case distribution of the position error after 40 and 80 predictions (one panel
    each; reading ``squared``, ordering ``given``, log axis): for every m the model(s) and the two
    baselines as a box (quartiles, whiskers 5-95 %) over every case's dot, the mean as a white
    diamond with its 95 % bootstrap interval, the paper's TP-Net mean as a red star."""
    from .run import PAPER_TABLE
    from .spread import spread
    plt = pyplot()
    key = f"Ep_{HEADLINE}"
    given = [c for c in curves if c.ordering == "given"]
    if not given:
        raise ValueError("plot_spread: no curve of input ordering 'given'")
    hs = table_horizons(min(c.err[key].shape[1] for c in given))
    ms = sorted({c.m for c in given})
    order = {"copy last": 1, "constant velocity": 2}
    colours = {"copy last": "0.55", "constant velocity": "tab:orange"}
    fig, axes = plt.subplots(1, len(hs), figsize=(5.6 * len(hs), 4.8), squeeze=False,
                             sharey=True)
    rng = np.random.default_rng(0)                  # the dots' horizontal jitter only
    for j, h in enumerate(hs):
        ax = axes[0, j]
        x, ticks, labels = 0.0, [], []
        for m in ms:
            for c in sorted((c for c in given if c.m == m), key=lambda c: order.get(c.name, 0)):
                v = np.maximum(c.err[key][:, h - 1], 1e-6)      # log axis: an exact 0 at 1e-6
                col = colours.get(c.name, "tab:blue")
                ax.boxplot(v, positions=[x], widths=0.6, whis=(5, 95), showfliers=False,
                           medianprops=dict(color="k", lw=1.5),
                           boxprops=dict(color=col), whiskerprops=dict(color=col),
                           capprops=dict(color=col))
                ax.scatter(x + rng.uniform(-0.18, 0.18, v.size), v, s=7, color=col, alpha=0.6,
                           lw=0, zorder=3)
                s = spread(c.err[key][:, h - 1])
                ax.errorbar([x], [s.mean], yerr=[[s.mean - s.lo], [s.hi - s.mean]], fmt="D",
                            ms=6, mfc="white", mec="k", ecolor="k", capsize=3, zorder=5)
                if c.name not in order and m in PAPER_TABLE and h in HORIZONS:
                    ax.scatter([x + 0.42], [PAPER_TABLE[m][2 * HORIZONS.index(h)]],
                               marker="*", s=140, color="tab:red", zorder=6)   # beside the box
                ticks.append(x)
                labels.append(("TP-Net" if c.name not in order else c.name.replace(" ", "\n"))
                              + f"\nm={m}")
                x += 1.0
            x += 0.6
        ax.set_xticks(ticks)
        ax.set_xticklabels(labels, fontsize=7)
        ax.set_yscale("log")
        ax.grid(True, axis="y", which="both", alpha=0.3)
        ax.set_title(f"after {h} predictions", fontsize=10)
    axes[0, 0].set_ylabel(f"position error E_p ({HEADLINE}), one dot per case")
    from matplotlib.lines import Line2D
    handles = [Line2D([], [], ls="none", marker="D", mfc="white", mec="k", color="k",
                      label="mean with 95 % bootstrap interval"),
               Line2D([], [], color="k", lw=1.5, label="median; box: quartiles; "
                                                     "whiskers: 5-95 %"),
               Line2D([], [], ls="none", marker="*", ms=11, color="tab:red",
                      label="TP-Net, paper (mean)")]
    fig.legend(handles=handles, loc="lower center", ncol=3, fontsize=8, frameon=False)
    fig.suptitle("Per-case position error on the held-out cases", fontsize=11)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    save_png(fig, path, dpi=90)
    plt.close(fig)
    return Path(path)


def plot_groups(groups: dict[str, Sequence[Curve]], path: str | os.PathLike) -> Path:
    """Generalisation: E_p vs prediction step, one panel per group of scenes (ordering given).

    One colour per model (its m in the label), the baselines in grey (copy last, dashed) and
    orange (constant velocity, dotted) for every m; one legend below the panels."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(groups), figsize=(4.6 * len(groups), 4.4), squeeze=False)
    style = {"copy last": ("0.55", "--"), "constant velocity": ("tab:orange", ":")}
    model_colours = ("tab:blue", "tab:green", "tab:purple", "tab:red", "tab:brown")
    handles: dict[str, Any] = {}
    for j, (g, cs) in enumerate(groups.items()):
        ax = axes[0, j]
        ms = sorted({c.m for c in cs})
        for c in cs:
            if c.ordering != "given":
                continue
            h = np.arange(1, c.err[f"Ep_{HEADLINE}"].shape[1] + 1)
            if c.name in style:
                col, ls = style[c.name]
                label = f"{c.name} (m = {', '.join(map(str, ms))})"
                line, = ax.plot(h, c.mean(), color=col, ls=ls, lw=1.0)
            else:
                col = model_colours[ms.index(c.m) % len(model_colours)]
                label = f"{c.name} (m = {c.m})"
                line, = ax.plot(h, c.mean(), color=col, lw=1.6)
            handles.setdefault(label, line)
        ax.set_title(g)
        ax.set_yscale("log")
        ax.set_xlabel("prediction step h")
        ax.set_ylabel(f"position error E_p ({HEADLINE})")
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle("Outside the training ranges: position error against prediction step "
                 "(mean over the group's cases, normalised coordinates)", fontsize=11)
    fig.legend(list(handles.values()), list(handles.keys()), loc="lower center",
               ncol=min(len(handles), 5), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.1 if len(handles) <= 5 else 0.15, 1, 1))
    save_png(fig, path, dpi=90)
    plt.close(fig)
    return Path(path)


def plot_timing(rows: Sequence[TimingRow], path: str | os.PathLike) -> Path:
    """E_p after 40 (hollow) and 80 (filled) predictions against ms per predicted frame (one
    rollout), one colour per row; the legend, beside the axes, says what the markers mean."""
    from matplotlib.lines import Line2D
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(10, 5), layout="constrained")
    handles: list[Any] = []
    horizons: set[tuple[int, ...]] = set()
    for i, r in enumerate(rows):
        ms = r.ms_single if r.ms_single is not None else r.ms_batch
        e = r.err.get(f"Ep_{HEADLINE}")
        if ms is None or e is None:
            continue
        c = plt.cm.tab20(i % 20)       # one colour per row (11+ rows)
        if not e.any():        # the reference itself: no error to draw on a log axis
            handles.append(ax.axvline(ms, color=c, ls="--", lw=1,
                                      label=f"{r.name} (reference, error 0)"))
            continue
        hs = table_horizons(e.shape[1])
        horizons.add(hs)
        for h in hs:
            hollow = h == hs[0] and len(hs) > 1
            dot = ax.scatter(ms, max(float(e[:, h - 1].mean()), 1e-6), color=c, s=45, lw=1.3,
                             facecolors="none" if hollow else c, label=r.name)
        handles.append(dot)
    if len(horizons) == 1 and len(hs := next(iter(horizons))) == 2:   # what the markers mean
        grey = dict(ls="none", marker="o", markersize=7, color="0.3")
        handles = [Line2D([], [], mfc="none", label=f"hollow: after {hs[0]} predictions",
                          **grey),
                   Line2D([], [], label=f"filled: after {hs[1]} predictions", **grey),
                   *handles]
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("ms per predicted frame (one rollout)")
    ax.set_ylabel(f"position error E_p ({HEADLINE})")
    ax.set_title("Position error against run time (held-out cases, mean over cases)",
                 fontsize=11)
    ax.grid(True, which="both", alpha=0.3)
    fig.legend(handles=handles, loc="outside right upper", fontsize=8, frameon=False)
    save_png(fig, path, dpi=90)
    plt.close(fig)
    return Path(path)


def plot_gallery(path: str | os.PathLike, truth: np.ndarray, preds: dict[str, np.ndarray],
                 horizons: Sequence[int], case_labels: Sequence[str] | None = None,
                 m: int | None = None) -> Path:
    """Predicted vs true shapes: one row per case, one column per prediction step.

    ``truth (C, H, N, 2)`` and each ``preds[name] (C, H, N, 2)`` in world units."""
    plt = pyplot()
    C = truth.shape[0]
    hs = [h for h in horizons if h <= truth.shape[1]]
    fig, axes = plt.subplots(C, len(hs), figsize=(2.6 * len(hs), 2.6 * C), squeeze=False)
    for i in range(C):
        for j, h in enumerate(hs):
            ax = axes[i, j]
            t = truth[i, h - 1]
            sets = [t] + [p[i, h - 1] for p in preds.values()]
            allp = np.clip(np.concatenate(sets), -1.0, 46.0)   # far-off predictions: at the edge
            c = 0.5 * (allp.min(0) + allp.max(0))
            r = max(3.0, 0.55 * float((allp.max(0) - allp.min(0)).max()))
            ax.scatter(t[:, 0], t[:, 1], s=8, color="k", label="simulator")
            for k, (name, p) in enumerate(preds.items()):
                q = p[i, h - 1]
                col = plt.cm.tab10((k + 1) % 10)
                ax.scatter(q[:, 0], q[:, 1], s=8, marker="x", color=col, label=name)
                cq = q.mean(0)
                if (cq < -1.0).any() or (cq > 46.0).any():      # left the box: say where
                    ax.text(0.03, 0.97 - 0.08 * k, f"{name}: off panel at ({cq[0]:.0f}, "
                            f"{cq[1]:.0f})", transform=ax.transAxes, fontsize=6, color=col,
                            va="top")
            for w in (1.0, 44.0):   # walls (inner faces)
                ax.axvline(w, color="0.4", lw=2)
                ax.axhline(w, color="0.4", lw=2)
            ax.set_xlim(c[0] - r, c[0] + r)
            ax.set_ylim(c[1] - r, c[1] + r)
            ax.set_aspect("equal")
            ax.tick_params(labelsize=6)
            if i == 0:
                ax.set_title(f"prediction {h}" + (f" (frame {m - 1 + h})" if m else ""),
                             fontsize=8)
            if j == 0:
                ax.set_ylabel((case_labels[i] + "\n" if case_labels is not None else "")
                              + "y (world units)", fontsize=7)
            if i == C - 1:
                ax.set_xlabel("x (world units)", fontsize=7)
    # one legend below the panels, where it covers no ring
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=8,
               frameon=False, markerscale=1.5)
    fig.suptitle("Simulated (dots) and predicted (crosses) rings on held-out cases; each panel "
                 "zoomed on its own, equal aspect, walls in grey", fontsize=10)
    fig.tight_layout(rect=(0, 0.35 / (2.6 * C), 1, 1))
    save_png(fig, path, dpi=90)
    plt.close(fig)
    return Path(path)


def draw_walls(ax: Any) -> None:
    """The four walls (thickness 1 around the free area [1, 44]²) as grey rectangles."""
    from matplotlib.patches import Rectangle
    lo, hi = BOX
    t = WALLS[0] - lo
    for xy, w, h in (((lo, lo), hi - lo, t), ((lo, hi - t), hi - lo, t),
                     ((lo, lo), t, hi - lo), ((hi - t, lo), t, hi - lo)):
        ax.add_patch(Rectangle(xy, w, h, color="0.45", zorder=0, lw=0))


def plot_demo(path: str | os.PathLike, truth: np.ndarray, pred: np.ndarray, m: int,
              horizons: Sequence[int], titles: dict[int, str], *, label: str = "TP-Net",
              suptitle: str = "") -> Path:
    """The demo's figure: the whole box (walls, the true and predicted centroid paths, the
    input frames, true and predicted rings at ``horizons``) and one zoomed panel per horizon,
    all zoomed panels on one scale, equal aspect, world units, one legend.

    ``truth (F, N, 2)``: the simulated frames 0..F-1; ``pred (H, N', 2)``: the predictions of
    frames m..m+H-1; ``titles[h]``: the errors printed above the panel of horizon ``h``."""
    plt = pyplot()
    hs = [h for h in horizons if 1 <= h <= pred.shape[0]][:4]
    fig = plt.figure(figsize=(14, 8.2))
    gs = fig.add_gridspec(2, 3, width_ratios=(2.25, 1, 1), wspace=0.32, hspace=0.5)
    box = fig.add_subplot(gs[:, 0])
    c_true, c_pred = "black", "tab:red"
    last = m - 1 + pred.shape[0]
    tc = truth[: last + 1].mean(axis=1)
    pc = np.concatenate([truth[m - 1: m].mean(axis=1), pred.mean(axis=1)])
    draw_walls(box)
    box.plot(tc[:, 0], tc[:, 1], color=c_true, lw=1.4, label="simulator: centroid path")
    box.plot(pc[:, 0], pc[:, 1], color=c_pred, lw=1.4, ls="--",
             label=f"{label}: predicted centroid path")
    for j in range(m):
        box.scatter(truth[j, :, 0], truth[j, :, 1], s=9, color="tab:blue",
                    label=f"input frames 0..{m - 1}" if j == 0 else None, zorder=3)
    # the box shows the rings of a horizon only where they overlap no ring drawn before (the
    # zoomed panels show every horizon)
    drawn: list[np.ndarray] = [truth[j] for j in range(m)]
    in_box: list[int] = []
    for h in hs:
        pair = np.vstack([truth[m - 1 + h], pred[h - 1]])
        if all(np.linalg.norm(pair[:, None] - d[None], axis=-1).min() > 1.0 for d in drawn):
            in_box.append(h)
            drawn.append(pair)
    obstacles = np.vstack(drawn + [tc, pc])
    for k, h in enumerate(in_box):
        t, q = truth[m - 1 + h], pred[h - 1]
        box.scatter(t[:, 0], t[:, 1], s=9, color=c_true, zorder=3,
                    label="simulator: particles at h" if k == 0 else None)
        box.scatter(q[:, 0], q[:, 1], s=14, marker="x", color=c_pred, zorder=4,
                    label=f"{label}: predicted points" if k == 0 else None)
        # the label where the box is emptiest near the pair, with a leader line to the pair
        centre = 0.5 * (t.mean(0) + q.mean(0))
        cands = [centre + r * np.array([np.cos(a), np.sin(a)])
                 for r in (5.5, 7.5) for a in np.linspace(0, 2 * np.pi, 16, endpoint=False)]
        cands = [c for c in cands if (c > BOX[0] + 3).all() and (c < BOX[1] - 3).all()]
        spot = max(cands, key=lambda c: np.linalg.norm(obstacles - c, axis=1).min())
        obstacles = np.vstack([obstacles, spot[None]])
        box.annotate(f"h = {h}", centre, xytext=spot, ha="center", va="center", fontsize=9,
                     weight="bold", zorder=6,
                     arrowprops=dict(arrowstyle="-", color="0.35", lw=0.8, shrinkB=9),
                     bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="0.6", alpha=0.9))
    box.set_xlim(*BOX)
    box.set_ylim(*BOX)
    box.set_aspect("equal")
    box.set_xlabel("x (world units)")
    box.set_ylabel("y (world units)")
    box.set_title(f"The whole box: inputs (frames 0..{m - 1}), centroid paths to frame {last},\n"
                  f"rings at predictions h = {', '.join(map(str, in_box))}"
                  + (" (the others overlap them: see the panels)" if len(in_box) < len(hs)
                     else ""), fontsize=10)
    # one scale for every zoomed panel: the widest extent any of them needs, at least 7 units
    need = [np.ptp(np.vstack([truth[m - 1 + h], pred[h - 1]]), axis=0).max() for h in hs]
    half = 0.5 * max([7.0] + [n + 1.5 for n in need])
    for k, h in enumerate(hs):
        ax = fig.add_subplot(gs[k // 2, 1 + k % 2])
        t, q = truth[m - 1 + h], pred[h - 1]
        draw_walls(ax)
        ax.plot(*np.vstack([t, t[:1]]).T, color=c_true, lw=1.0)
        ax.scatter(t[:, 0], t[:, 1], s=12, color=c_true)
        ax.scatter(q[:, 0], q[:, 1], s=22, marker="x", color=c_pred)
        c = 0.5 * (t.mean(0) + q.mean(0))
        ax.set_xlim(c[0] - half, c[0] + half)
        ax.set_ylim(c[1] - half, c[1] + half)
        ax.set_aspect("equal")
        ax.set_title(titles.get(h, f"prediction {h}"), fontsize=9)
        ax.tick_params(labelsize=8)
        ax.set_xlabel("x (world units)", fontsize=8)
        ax.set_ylabel("y (world units)", fontsize=8)
    handles, labels = box.get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=10,
               frameon=False)
    if suptitle:
        fig.suptitle(_fit(suptitle, 13.5, 12), fontsize=12)
    fig.subplots_adjust(left=0.05, right=0.98, top=0.84, bottom=0.1)
    save_png(fig, path, dpi=100)
    plt.close(fig)
    return Path(path)


__all__ = ["pyplot", "save_png", "draw_walls", "plot_models", "plot_spread", "plot_groups", "plot_timing",
           "plot_gallery", "plot_demo"]
