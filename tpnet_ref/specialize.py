"""A scene-specialised prediction network: only the units a scene uses, exact on every input.

On the windows of one scene many units of a ReLU TP-Net are exactly zero on every window (shipped
m = 4 model, training-grid windows and the model's own rollouts: 83 of 128 global features, 563 of
1024 BiLSTM-1 outputs, 243 of 512 BiLSTM-2, 130 of 512 BiLSTM-3). :func:`calibrate` finds them;
:class:`SceneHead` runs the prediction network on the other units only, and guards every window:

- a global feature is kept or its value is checked to be exactly 0 (the extractor computes all 128:
  cheap);
- a ReLU-LSTM unit starts with c = h = 0; with ``c_t = f c_{t-1} + i relu(g_t)`` and
  ``h_t = o relu(c_t)`` it stays exactly 0 while its cell pre-activation ``g_t <= 0``. The head
  computes ``g`` of every dropped unit in the same products as the kept units (one extra column
  per dropped unit instead of four gates, and only the kept units' recurrent rows) and flags the
  window as soon as one is ``> 0``;
- a dropped unit's zero output still enters the LayerNorm (mean and variance over all units) and,
  through it, the next layer as the affine term ``(0 - mean) rstd gamma_k + beta_k``: folded into
  the next layer's bias (``beta``) and one vector times ``-mean rstd`` per row (``gamma``).

A flagged window (or one whose specialised result is not finite) is recomputed by the full
network, so the output equals the full model's up to rounding on every input.
:meth:`tpnet_ref.model.TPNet.specialize` builds one; :func:`save` / :func:`attach` keep it in the
native weights file as a group ``specialization`` beside ``config`` and ``params`` (the native
reader ignores groups it does not know).
"""
from __future__ import annotations

import os
from typing import Any

import numpy as np

from . import layers as L
from .unit_order import measure
from .weights.hdf5 import read_vectors, write_vectors

#: name of the HDF5 group that holds a specialisation in the native weights file
GROUP = "specialization"
FORMAT = "tpnet_ref.specialization/1"


def calibrate(model: Any, windows: np.ndarray, normalized: bool = False,
              chunk: int = 512) -> dict[str, np.ndarray]:
    """Which units are used on ``windows`` ``(B, m, N, dim)``: ``{"global": (k,), "lstm1":
    (2u_1,), ...}`` boolean masks, True where the unit is non-zero on at least one window (at any
    time step for the LSTMs, both directions concatenated as [forward, backward])."""
    cfg = model.config
    if cfg.lstm_activation != "relu":
        raise ValueError("specialize: only a ReLU-LSTM network has units that stay exactly zero "
                         f"(this one uses {cfg.lstm_activation!r})")
    use = measure(model, windows, normalized, chunk, mlp=False)
    return {k: v > 0 for k, v in use.items()}


def calibration_cases(n_trajectories: int = 36, seed: int = 0) -> np.ndarray:
    """``(n, 4)`` (force, angle_deg, x, y): ``n_trajectories`` training-grid cases
    (:func:`tpnet_ref.data.train_grid`) drawn without replacement with ``seed``; never a held-out
    test case (any grid row equal to one is left out)."""
    from .data import train_grid
    from .sim.cases import TEST_CASES
    grid = train_grid()
    test = np.asarray(TEST_CASES, dtype=float)
    grid = grid[~(grid[:, None, :] == test[None]).all(axis=2).any(axis=1)]
    if isinstance(n_trajectories, bool) or not 1 <= int(n_trajectories) <= len(grid):
        raise ValueError(f"n_trajectories: must be in 1..{len(grid)}, got {n_trajectories!r}")
    pick = np.random.default_rng(seed).choice(len(grid), int(n_trajectories), replace=False)
    return grid[pick]


def calibration_windows(model: Any, n_trajectories: int = 36, seed: int = 0,
                        rollout: int = 40) -> np.ndarray:
    """Calibration windows ``(B, m, N, 2)`` (world units) of training-grid trajectories for
    :meth:`tpnet_ref.model.TPNet.specialize`: for each of :func:`calibration_cases`, every window
    of its simulated trajectory (default scene, one frame every ``FRAME_EVERY`` rows) and every
    window of the model's own ``rollout``-frame rollout from its first m frames (the rollouts
    stepped together). ``B = n_trajectories * (F - m + 1 + rollout + 1)`` with ``F`` frames per
    trajectory (150: 188 windows each for m = 4). Simulates with :mod:`tpnet_ref.sim`."""
    from .protocol import FRAME_EVERY
    from .sim import scene
    m = model.config.m
    if isinstance(rollout, bool) or int(rollout) < 0:
        raise ValueError(f"rollout: must be >= 0, got {rollout!r}")
    trajs = np.stack([scene.simulate(*case)[::FRAME_EVERY]
                      for case in calibration_cases(n_trajectories, seed)])    # (n, F, N, 2)
    if trajs.shape[1] < m:
        raise ValueError(f"calibration trajectories have {trajs.shape[1]} frames, fewer than m={m}")
    parts = [trajs]
    if rollout:
        own = np.asarray(model.rollout_batch(trajs[:, :m], int(rollout)), dtype=np.float64)
        parts.append(np.concatenate([trajs[:, :m], own], axis=1))
    out = []
    for t in parts:                     # every window of every trajectory, trajectory by trajectory
        idx = np.arange(t.shape[1] - m + 1)[:, None] + np.arange(m)        # (W, m)
        out.append(t[:, idx])                                              # (n, W, m, N, 2)
    # interleave: trajectory 0's simulated windows, its rollout windows, trajectory 1's ...
    return np.concatenate([np.concatenate([o[i] for o in out]) for i in range(len(trajs))])


def _pad(keep: np.ndarray, u: int) -> tuple[np.ndarray, np.ndarray]:
    """Kept units of both directions, padded to the same count with dropped units (computed in
    full, which is always exact): ``(2, L)`` kept and ``(2, u - L)`` dropped unit indices."""
    fwd, bwd = keep[:u], keep[u:]
    n = max(int(fwd.sum()), int(bwd.sum()), 1)
    kept, dropped = [], []
    for k in (fwd, bwd):
        k = k.copy()
        for j in np.flatnonzero(~k)[:n - int(k.sum())]:
            k[j] = True
        kept.append(np.flatnonzero(k))
        dropped.append(np.flatnonzero(~k))
    return np.array(kept), np.array(dropped)


class SceneHead:
    """The prediction network of ``model`` on the units ``used`` marks (from :func:`calibrate`),
    with the guards of the module docstring. ``head(features (B, m, k))`` -> ``(y (B, n_out*dim)
    in [0, 1], ok (B,) bool)``; rows with ``ok`` False must be recomputed in full."""

    def __init__(self, model: Any, used: dict[str, np.ndarray]) -> None:
        cfg, p, dt = model.config, model.params, model.dtype
        self.used = {k: np.asarray(v, bool).copy() for k, v in used.items()}
        expect = {"global": cfg.global_features,
                  **{f"lstm{i}": 2 * u for i, u in enumerate(cfg.lstm_units, 1)}}
        for k, n in expect.items():
            if k not in self.used or self.used[k].shape != (n,):
                raise ValueError(f"specialization: mask {k!r} must have shape ({n},)")
        if set(self.used) != set(expect):
            raise ValueError(f"specialization: unexpected masks {sorted(set(self.used) - set(expect))}")
        self.eps = dt.type(cfg.layer_norm_eps)
        self.g_keep = np.flatnonzero(self.used["global"])
        self.g_drop = np.flatnonzero(~self.used["global"])
        self.layers = []
        in_keep = self.g_keep                   # input units this layer sees (positions)
        in_drop = np.array([], dtype=np.intp)   # input units that are LayerNorm's affine term
        gamma_prev = beta_prev = None
        for i, u in enumerate(cfg.lstm_units, 1):
            kept, dropped = _pad(self.used[f"lstm{i}"], u)
            n_keep, n_drop = kept.shape[1], dropped.shape[1]
            ks, rs, bs, a_s, bf_s = [], [], [], [], []
            for d, name in enumerate(("fwd", "bwd")):
                kern, rec, bias = (p[f"lstm{i}.{name}.{x}"] for x in ("kernel", "recurrent", "bias"))
                # Keras gate blocks i, f, c, o -> kept units' i, f, o (negated), c | dropped c
                cols = np.concatenate([kept[d], u + kept[d], 3 * u + kept[d], 2 * u + kept[d],
                                       2 * u + dropped[d]])
                sign = np.ones(len(cols), dt)
                sign[:3 * n_keep] = -1
                ks.append(kern[in_keep][:, cols] * sign)
                rs.append(rec[kept[d]][:, cols] * sign)
                b = bias[cols] * sign
                if len(in_drop):   # dropped inputs are LayerNorm's affine term s*gamma + beta
                    b = b + (beta_prev[in_drop] @ kern[in_drop][:, cols]) * sign
                    a_s.append((gamma_prev[in_drop] @ kern[in_drop][:, cols]) * sign)
                bs.append(b)
            kernel = np.ascontiguousarray(np.concatenate(ks, axis=1), dtype=dt)
            self.layers.append(dict(
                kernel=kernel, recurrent=np.ascontiguousarray(np.stack(rs), dtype=dt),
                bias=np.concatenate(bs).astype(dt),
                affine=(np.concatenate(a_s).astype(dt) if a_s else None),
                n_keep=n_keep, n_drop=n_drop, n_out=2 * u,
                gamma=p[f"ln{i}.gamma"][np.concatenate([kept[0], u + kept[1]])],
                beta=p[f"ln{i}.beta"][np.concatenate([kept[0], u + kept[1]])]))
            in_keep = np.concatenate([kept[0], u + kept[1]])
            in_drop = np.concatenate([dropped[0], u + dropped[1]])
            gamma_prev, beta_prev = p[f"ln{i}.gamma"], p[f"ln{i}.beta"]
        hw, hb = p["head.w"], p["head.b"]
        self.head_w = np.ascontiguousarray(hw[in_keep], dtype=dt)
        self.head_b = (hb + beta_prev[in_drop] @ hw[in_drop]).astype(dt)
        self.head_a = (gamma_prev[in_drop] @ hw[in_drop]).astype(dt)

    def num_params(self) -> int:
        """Parameters the specialised head reads (guards included)."""
        n = sum(ly["kernel"].size + ly["recurrent"].size + ly["bias"].size for ly in self.layers)
        return int(n + self.head_w.size + self.head_b.size)

    def _layer_norm(self, x: np.ndarray, ly: dict, dt: np.dtype) -> tuple[np.ndarray, np.ndarray]:
        """LayerNorm over all ``n_out`` units of which only ``x (..., n_keep2)`` are non-zero:
        -> (normalised kept units, ``-mean * rstd`` ``(..., 1)`` for the dropped ones)."""
        n = dt.type(ly["n_out"])
        mean = x.sum(axis=-1, keepdims=True) / n
        d = x - mean
        var = (np.sum(d * d, axis=-1, keepdims=True) + (n - x.shape[-1]) * mean * mean) / n
        rstd = (1.0 / np.sqrt(var + self.eps)).astype(dt, copy=False)
        d *= rstd
        s = -mean * rstd
        d *= ly["gamma"]
        d += ly["beta"]
        return d, s

    def __call__(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dt = features.dtype
        bsz, steps = features.shape[0], features.shape[1]
        ok = ~(features[..., self.g_drop] != 0).any(axis=(1, 2))
        x = np.ascontiguousarray(features.transpose(1, 0, 2)[..., self.g_keep])  # (T, B, C)
        s = None
        one = dt.type(1.0)
        last = len(self.layers) - 1
        with np.errstate(over="ignore", invalid="ignore"):
            for li, ly in enumerate(self.layers):
                nk, nd = ly["n_keep"], ly["n_drop"]
                width = 4 * nk + nd
                xp = (x.reshape(steps * bsz, -1) @ ly["kernel"]).reshape(steps, bsz, 2, width)
                if s is not None:
                    xp += s.reshape(steps, bsz, 1, 1) * ly["affine"].reshape(2, width)
                xs = np.empty((steps, 2, bsz, width), dtype=dt)
                np.add(xp[:, :, 0], ly["bias"][:width], out=xs[:, 0])
                np.add(xp[::-1, :, 1], ly["bias"][width:], out=xs[:, 1])
                c = np.empty((2, bsz, nk), dtype=dt)
                tmp = np.empty((2, bsz, nk), dtype=dt)
                hs = np.empty((steps, 2, bsz, nk), dtype=dt)
                for t in range(steps):
                    if t == 0:
                        z = xs[0]
                    else:
                        z = np.matmul(hs[t - 1], ly["recurrent"], out=xs[t - 1])
                        z += xs[t]
                    if nd:      # a dropped unit's cell pre-activation > 0: it would wake up
                        ok &= ~(z[..., 4 * nk:] > 0).any(axis=(0, 2))
                    gates = z[..., :3 * nk]
                    np.exp(gates, out=gates)
                    gates += one
                    np.divide(one, gates, out=gates)
                    g = z[..., 3 * nk:4 * nk]
                    np.maximum(g, 0, out=g)
                    if t == 0:
                        np.multiply(z[..., :nk], g, out=c)
                    else:
                        c *= z[..., nk:2 * nk]
                        np.multiply(z[..., :nk], g, out=tmp)
                        c += tmp
                    h = hs[t]
                    np.maximum(c, 0, out=h)
                    h *= z[..., 2 * nk:3 * nk]
                if li < last:
                    y = np.concatenate([hs[:, 0], hs[::-1, 1]], axis=-1)     # (T, B, 2 nk)
                else:
                    y = np.concatenate([hs[-1, 0], hs[-1, 1]], axis=-1)      # (B, 2 nk)
                x, s = self._layer_norm(y, ly, dt)
            out = x @ self.head_w
            out += s * self.head_a
            out += self.head_b
            out = L.sigmoid(out)
        ok &= np.isfinite(out).all(axis=1)
        return out, ok


def fraction_used(used: dict[str, np.ndarray]) -> dict[str, tuple[int, int]]:
    """``{mask name: (used units, all units)}``."""
    return {k: (int(v.sum()), int(v.size)) for k, v in used.items()}


# ------------------------------------------------------------------ native file
def write(path: str | os.PathLike, used: dict[str, np.ndarray], **attrs: Any) -> None:
    """Add the masks as group ``specialization`` (uint8 datasets, ``format`` attribute) to an
    existing native weights file; any existing group of that name is replaced."""
    write_vectors(path, GROUP, FORMAT, used, np.uint8, **attrs)


def read(path: str | os.PathLike) -> dict[str, np.ndarray] | None:
    """The masks of a native weights file's ``specialization`` group, or None without one. The
    file is untrusted: links, external storage and oversized datasets are refused
    (:mod:`tpnet_ref.weights.hdf5`)."""
    masks = read_vectors(path, GROUP, FORMAT, "mask", kinds="uib")
    if masks is None:
        return None
    for k, a in masks.items():
        if not np.isin(a, (0, 1)).all():
            raise ValueError(f"{path}: {GROUP}/{k} holds values other than 0 and 1")
    return {k: a.astype(bool) for k, a in masks.items()}


def save(model: Any, path: str | os.PathLike, **provenance: Any) -> None:
    """Write a (specialised) model to a native weights file, its masks included."""
    model.save(path, **provenance)
    if model.specialization is not None:
        write(path, model.specialization.used)


def attach(model: Any, path: str | os.PathLike) -> Any:
    """``model`` (just read from the native file ``path``) specialised as the file says, or
    ``model`` itself when the file has no ``specialization`` group."""
    used = read(path)
    return model if used is None else model.with_specialization(used)


__all__ = ["calibrate", "calibration_cases", "calibration_windows", "SceneHead", "fraction_used", "write", "read", "save", "attach",
           "GROUP", "FORMAT"]
