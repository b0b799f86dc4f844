"""The README's picture of the camera path: render a video, observe the window, predict, draw.

    python bench/probes/observe_figure.py -o docs/observe_example.png

Runs the three commands of the README (`tpnet sim render`, `tpnet observe`, `tpnet predict`) in a
temporary directory, then draws the four input frames (crops) with the points `tpnet observe`
extracted, and the whole box at a later frame with the predicted rings beside the true particle
centres. Needs the vision and plot extras.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from tpnet_ref.cli import main as tpnet

STEPS = 60                 # predictions
SHOW = (10, 30, 60)        # horizons drawn


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-o", "--output", default="docs/observe_example.png")
    args = ap.parse_args(argv)
    import cv2
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tpnet_ref.observe import Camera

    tmp = Path(tempfile.mkdtemp(prefix="tpnet-observe-"))
    t0 = time.time()
    run = [["sim", "render", "--steps", "320", "--distractors", "3", "-o", str(tmp / "run.mp4")],
           ["observe", str(tmp / "run.mp4"), "--camera", str(tmp / "run.json"),
            "-o", str(tmp / "window.npy")],
           ["predict", str(tmp / "window.npy"), "--steps", str(STEPS),
            "-o", str(tmp / "pred.npy")]]
    for argv_ in run:
        print("tpnet " + " ".join(argv_))
        if tpnet(argv_) != 0:
            return 1
    print(f"the three commands took {time.time() - t0:.1f} s")
    window = np.load(tmp / "window.npy")
    pred = np.load(tmp / "pred.npy")
    truth = np.load(tmp / "run.truth.npy")             # one row per video frame (45 fps)
    cam = Camera.parse(str(tmp / "run.json"))
    cap = cv2.VideoCapture(str(tmp / "run.mp4"))
    frames = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        frames.append(cv2.cvtColor(img, cv2.COLOR_BGR2RGB))
    cap.release()

    fig = plt.figure(figsize=(12.5, 7.4), dpi=100)
    grid = fig.add_gridspec(2, 4, width_ratios=[1, 1, 1.6, 1.6])
    for k in range(4):
        ax = fig.add_subplot(grid[k // 2, k % 2])
        img = frames[4 * k]
        px = cam.to_pixels(window[k])
        c = px.mean(axis=0)
        half = 55
        x0, y0 = int(c[0]) - half, int(c[1]) - half
        ax.imshow(img[max(y0, 0):y0 + 2 * half, max(x0, 0):x0 + 2 * half],
                  extent=(max(x0, 0), max(x0, 0) + 2 * half, max(y0, 0) + 2 * half, max(y0, 0)))
        ax.plot(px[:, 0], px[:, 1], "o", ms=6, mfc="none", mec="blue", mew=0.9)
        tp = cam.to_pixels(truth[4 * k])                # on top of the circles, so both show
        ax.plot(tp[:, 0], tp[:, 1], "o", ms=2.2, mfc="white", mec="black", mew=0.5, zorder=5)
        ax.set_title(f"video frame {4 * k} (t = {4 * k / 45:.3f} s)", fontsize=9)
        ax.tick_params(labelsize=7)
        ax.set_xlabel("column (px)", fontsize=7)
        ax.set_ylabel("row (px)", fontsize=7)
    ax = fig.add_subplot(grid[:, 2:])
    last = 4 * (3 + SHOW[-1])
    img = frames[last]
    # the video frame in world units (the calibration maps pixel edges to the scene's units)
    (xl, yt), (xr, yb) = cam.to_world([[0.0, 0.0], [img.shape[1], img.shape[0]]])
    ax.imshow(img, extent=(xl, xr, yb, yt))
    ax.plot(*window.reshape(-1, 2).T, "o", ms=2, mfc="none", mec="blue", mew=0.6,
            label="observed window, frames 0-12 (tpnet observe)")
    placed = [window.reshape(-1, 2)]
    for j, h in enumerate(SHOW):
        t = truth[4 * (3 + h)]
        p = pred[h - 1]
        ax.plot(*np.vstack([t, t[:1]]).T, "-", color="black", lw=1.2,
                label="true particle centres" if j == 0 else None)
        ax.plot(p[:, 0], p[:, 1], "x", ms=3.5, color="red",
                label="prediction (tpnet predict)" if j == 0 else None)
        placed += [t, p]
    everything = np.vstack(placed)
    labels: list[np.ndarray] = []          # a label is about 2.5 times as wide as it is high
    for j, h in enumerate(SHOW):                       # label each ring, where nothing is drawn
        for ring, col, what in ((truth[4 * (3 + h)], "black", "true"),
                                (pred[h - 1], "red", "predicted")):
            c = ring.mean(axis=0)
            cands = [c + r * np.array([np.cos(a), np.sin(a)])
                     for r in (4.0, 5.5) for a in np.linspace(0, 2 * np.pi, 12, endpoint=False)]
            cands = [q for q in cands if 3 < q[0] < 42 and 3 < q[1] < 42]
            spot = max(cands, key=lambda q: min(
                [np.linalg.norm(everything - q, axis=1).min()]
                + [max(abs(q[0] - o[0]) / 2.5, abs(q[1] - o[1])) for o in labels]))
            labels.append(spot)
            ax.annotate(f"+{h} {what}", c, xytext=spot, ha="center", va="center", fontsize=8,
                        color=col, weight="bold",
                        arrowprops=dict(arrowstyle="-", color=col, lw=0.7, shrinkB=6),
                        bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.8))
    ax.set_xlim(xl, xr)
    ax.set_ylim(yb, yt)
    ax.set_xlabel("x (world units)", fontsize=8)
    ax.set_ylabel("y (world units)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.set_title(f"video frame {last}: predictions {', '.join(f'+{h}' for h in SHOW)} "
                 "(model frames, 4/45 s each)", fontsize=9)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=3, fontsize=8,
              frameon=False)
    fig.suptitle("tpnet sim render -> tpnet observe -> tpnet predict (640 px video, noise, "
                 "3 distractor blobs per frame)\nleft: the 4 input frames, the points tpnet "
                 "observe extracted (blue circles) and the true particle centres (white dots)",
                 fontsize=10)
    fig.tight_layout()
    from tpnet_ref.evaluation.plots import save_png
    save_png(fig, args.output)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
