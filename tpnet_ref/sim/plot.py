"""A picture of one trajectory of the scene (matplotlib: the ``plot`` extra)."""
from __future__ import annotations

import numpy as np

from ..extras import require
from .scene import SceneParams


def show(traj: np.ndarray, path: str, *, every: int = 4, title: str = "",
         params: SceneParams | None = None) -> None:
    """Write a PNG of a ``(steps, N, 2)`` trajectory (world units): every ``every``-th point set
    coloured by time, the start ring, the end ring and the walls."""
    matplotlib = require("matplotlib", "plot")
    matplotlib.use("Agg")
    plt = require("matplotlib.pyplot", "plot")

    p = params or SceneParams()
    fig, ax = plt.subplots(figsize=(6, 6), dpi=100)
    rows = traj[::every]
    colors = plt.cm.viridis(np.linspace(0, 1, len(rows)))
    for r, c in zip(rows, colors):
        ax.scatter(r[:, 0], r[:, 1], s=3, color=c)
    ax.plot(*np.vstack([traj[0], traj[0][:1]]).T, "r-", lw=1, label="start")
    ax.plot(*np.vstack([traj[-1], traj[-1][:1]]).T, "k-", lw=1, label="end")
    lo, hi = p.free_lo, p.free_hi
    ax.plot([lo, hi, hi, lo, lo], [lo, lo, hi, hi, lo], "k-", lw=2)
    ax.set_xlim(0, p.box_size)
    ax.set_ylim(0, p.box_size)
    ax.set_aspect("equal")
    ax.set_xlabel("x (world units)")
    ax.set_ylabel("y (world units)")
    ax.legend(loc="upper right")
    ax.set_title(title or f"{len(traj)} rows, every {every}")
    fig.savefig(path)
    plt.close(fig)


__all__ = ["show"]
