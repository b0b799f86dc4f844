"""Can a specialised model skip the max-pooled features its scene never uses, exactly?

    PYTHONPATH=bench python bench/probes/feature_bound_probe.py            # 36 training-grid trajectories to calibrate
    PYTHONPATH=bench python bench/probes/feature_bound_probe.py --quick    # 12

On the scene's windows 260 of the 512 max-pooled features of the shipped m = 4 model are exactly
zero (the last per-point layer's pre-activation is <= 0 at every point of every frame). The last
layer is about 70 % of the feature extractor's multiply-adds, so leaving those columns out would
cut the extractor by about a third -- but only if a window on which one of them would be
non-zero is detected, which needs a bound on ``max_p w_j . h_p + b_j`` (``h_p >= 0``, the
layer's input at point ``p``) cheaper than computing it. This probe measures, on the
calibration windows (training grid, as ``bench/bench_specialize.py`` calibrates) and on the
60 test cases' simulated windows (checked, never used to choose anything):

- the margins: how far below zero the dropped features' pre-activations stay;
- bounds, each exact in real arithmetic (a window counts as certified when every dropped
  feature of its m frames is bounded by ``<= -tol``, ``tol`` a rounding allowance of
  ``1e-5 |w_j| |h_p|``):
  * column maxima: ``w_j+ . max_p h_p + b_j`` (the weights' positive parts, per frame);
  * Cauchy-Schwarz about the frame's centroid ``c``: ``w_j . c + b_j + |w_j| max_p |h_p - c|``;
  * the same with the rank-r principal subspace ``Q`` of the calibration points' ``h - c``
    taken out exactly: ``w_j . c + b_j + max_p (Q^T w_j) . a_p + |w_j - Q Q^T w_j| |e_p|`` with
    ``a_p = Q^T (h_p - c)`` and ``|e_p|^2 = |h_p - c|^2 - |a_p|^2``;
- what each bound costs per window (multiply-adds, the reads of the used input columns ``k``
  counted as the full model counts them) against what leaving the columns out saves, and the
  expected extractor multiply-adds, against the full model's, in two policies: a window a bound
  cannot certify computed in full, or (the best case: the extractor treats frames and features
  independently) only the (frame, feature) pairs it cannot certify computed exactly.
"""
from __future__ import annotations

import sys

import numpy as np

import tpnet_ref
from tpnet_ref.sim import dataset as D
from tpnet_ref.sim.protocol import FRAME_EVERY
from tpnet_ref.sim.cases import TEST_CASES
from tpnet_ref.sim.scene import simulate
from bench_specialize import parse_quick, windows

RANKS = (4, 8, 16, 32, 48, 64, 96)
TOL = 1e-5


def last_layer_inputs(model, wins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(B, m, N, 2)`` world windows -> the last per-point layer's input ``(B, m, N, C)`` and
    the extractor's multiply-adds per window ``(B,)`` as the full model computes them (each
    layer reads the weight rows up to its input's last non-zero column over the window)."""
    b, m, n, _ = wins.shape
    x = model.normalize(wins.reshape(b, m * n, 2))
    layers = model.features.mlp1 + model.features.mlp2
    macs = np.zeros(b)
    for w, bias in layers[:-1]:
        k = x.shape[-1] if x.shape[-1] <= 2 else \
            x.shape[-1] - np.argmax((x != 0).any(axis=1)[:, ::-1], axis=1)
        macs += m * n * k * w.shape[1]
        x = np.maximum(x @ w + bias, 0)
    k = x.shape[-1] - np.argmax((x != 0).any(axis=1)[:, ::-1], axis=1)
    macs += m * n * k * layers[-1][0].shape[1]
    return x.reshape(b, m, n, -1), macs


def main(argv: list[str] | None = None) -> int:
    n_cal = 12 if parse_quick(__doc__, argv) else 36
    model = tpnet_ref.load(dtype="float64")        # the shipped weights, exact arithmetic here
    m = model.config.m
    cal = D.calibration_windows(tpnet_ref.load(), n_cal, seed=0, rollout=40)
    test = np.concatenate([windows(simulate(*c)[::FRAME_EVERY], m) for c in TEST_CASES])
    w, b = model.features.mlp2[-1]
    h_cal, _ = last_layer_inputs(model, cal)
    pre = h_cal @ w + b                                        # (B, m, N, 512)
    drop = ~(pre.max(axis=(0, 1, 2)) > 0)
    wd, bd = w[:, drop], b[drop]
    nd, c_in = int(drop.sum()), w.shape[0]
    print(f"calibration: {len(cal)} windows of {n_cal} training-grid trajectories; "
          f"{nd} of {w.shape[1]} max-pooled features never > 0 there (input width {c_in})")

    # the principal subspace of the calibration points about their frames' centroids
    xc = (h_cal - h_cal.mean(axis=2, keepdims=True)).reshape(-1, c_in)
    _, _, vt = np.linalg.svd(xc[:: max(1, len(xc) // 200_000)], full_matrices=False)
    del pre, xc

    def report(name: str, wins: np.ndarray) -> None:
        h, macs = last_layer_inputs(model, wins)
        k = c_in - np.argmax((h != 0).any(axis=(1, 2))[:, ::-1], axis=1)  # used inputs, (B,)
        pts = m * h.shape[2]
        top = (h @ wd + bd).max(axis=2)                        # (B, m, nd) exact maxima
        print(f"\n{name}: {len(wins)} windows; the dropped features' largest pre-activation "
              f"per window: quantiles 0/1/50/99/100 % = "
              + " / ".join(f"{q:.4f}" for q in np.quantile(top.max(axis=(1, 2)), [0, .01, .5, .99, 1])))
        nonzero = (top > 0).any(axis=(1, 2)).mean()
        print(f"  windows on which a dropped feature is non-zero (must be computed in full): "
              f"{nonzero:.2%}")
        hn = np.linalg.norm(h, axis=3)                         # (B, m, N)
        tol = TOL * np.linalg.norm(wd, axis=0) * hn.max(axis=2)[..., None]   # (B, m, nd)
        c = h.mean(axis=2, keepdims=True)                      # (B, m, 1, C)
        base = (c[:, :, 0] @ wd + bd)                          # (B, m, nd)
        x = h - c
        xn2 = (x ** 2).sum(axis=3)
        exact_cols = pts * k * nd                              # what leaving them out saves
        rows = [("column maxima x positive weights", np.maximum(wd, 0),
                 lambda wp: h.max(axis=2) @ wp + bd, m * k * nd + pts * k)]
        rows.append(("Cauchy-Schwarz about the centroid", None,
                     lambda _: base + np.sqrt(xn2.max(axis=2))[..., None] * np.linalg.norm(wd, axis=0),
                     m * k * nd + 2 * pts * k))
        for r in RANKS:
            q = vt[:r].T                                       # (C, r)
            def bound(_, q=q):
                a = x @ q                                      # (B, m, N, r)
                e = np.sqrt(np.maximum(xn2 - (a ** 2).sum(axis=3), 0))
                wq = q.T @ wd
                perp = np.linalg.norm(wd - q @ wq, axis=0)
                return base + (a @ wq + e[..., None] * perp).max(axis=2)
            rows.append((f"rank-{r} subspace + Cauchy-Schwarz", None, bound,
                         m * k * nd + pts * (k * r + r * nd + 2 * k + r)))
        print(f"  {'bound':38s} {'windows certified':>17s} {'bound cost / columns saved':>27s} "
              f"{'extractor: per window':>22s} {'per (frame, feature)':>21s}")
        best = (np.inf, "")
        for label, arg, fn, cost in rows:
            pairs = fn(arg) <= -tol                            # (B, m, nd)
            ok = pairs.all(axis=(1, 2))
            # certified windows pay the bound and skip the columns; the others pay both
            spent = np.where(ok, cost - exact_cols, cost)
            # or: each uncertified (frame, feature) pair's column computed over the frame
            fine = cost - exact_cols + h.shape[2] * k * (~pairs).sum(axis=(1, 2))
            per_window = np.mean((macs + spent) / macs)
            per_pair = np.mean((macs + fine) / macs)
            best = min(best, (per_pair, label))
            print(f"  {label:38s} {ok.mean():17.2%} {np.mean(cost / exact_cols):27.2f} "
                  f"{per_window:21.2f}x {per_pair:20.2f}x")
        print(f"  best: {best[1]}, the extractor's multiply-adds x{best[0]:.2f} "
              f"(leaving the columns out for free would give x{np.mean((macs - exact_cols) / macs):.2f})")

    report("calibration windows (training grid)", cal)
    report("test cases, simulated windows", test)
    print("\n(extractor multiply-adds: the full model's = 1.00x; below 1 the bound pays)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
