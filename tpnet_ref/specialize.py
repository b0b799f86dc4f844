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
import threading
from typing import Any, NamedTuple

import numpy as np

from . import layers as L
from .blas import BLOCK_COLUMNS, SMALL_PRODUCT, small_products_pay
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


#: a window goes to the full network when an LSTM output reaches this share of the bound above
#: which the full network refuses to answer (``sqrt(max) / 4``, ``TPNet._full_head``): a margin
#: for the two networks' different rounding
LIMIT_SHARE = 0.5


def _layout(keep: np.ndarray, order: np.ndarray | None, u: int):
    """One BiLSTM's units. ``keep (2u,)``: used units, file order [forward | backward];
    ``order``: the model's unit order of the layer (None: the file's).

    Returns ``rec (2, n)``: each direction's computed units, its kept ones in the unit order,
    then dropped ones (in the unit order) until both directions have ``n`` (computed in full,
    always exact); ``drop (2, u - n)``: the others (guarded); and the layer's outputs as the next
    layer reads them, kept ones in the unit order then the padding: ``out_d``, ``out_pos``
    (direction, position in ``rec``) and ``out_file`` (index in the file's 2u outputs)."""
    po = np.arange(2 * u) if order is None else np.asarray(order, dtype=np.intp)
    n = max(int(keep[:u].sum()), int(keep[u:].sum()), 1)
    rec, drop = [], []
    for d in range(2):
        pd = po[(po >= d * u) & (po < (d + 1) * u)] - d * u     # this direction, unit order
        k = keep[d * u + pd]
        r = np.concatenate([pd[k], pd[~k][:n - int(k.sum())]])
        rec.append(r)
        drop.append(np.setdiff1d(np.arange(u), r))
    computed = np.zeros(2 * u, bool)
    computed[rec[0]] = computed[u + rec[1]] = True
    out_file = np.concatenate([po[computed[po] & keep[po]], po[computed[po] & ~keep[po]]])
    out_d = (out_file >= u).astype(np.intp)
    pos = np.empty((2, u), np.intp)
    for d in range(2):
        pos[d, rec[d]] = np.arange(n)
    return np.array(rec), np.array(drop), out_d, pos[out_d, out_file - u * out_d], out_file


class _Layer(NamedTuple):
    """One BiLSTM of a :class:`SceneHead`. Each direction's product columns are
    ``[g of the dropped units (nd) | o | i | f | g of the computed units (nk each)]`` (width
    ``W``; the sigmoid gates' columns negated); the input rows ``[1 | mean * rstd | inputs]``
    (bias, the previous LayerNorm folded in: ``aug`` = 2; BiLSTM 1: ``[1 | inputs]``)."""

    nk: int
    nd: int
    width: int
    aug: int
    kernel: np.ndarray             # (2, aug + C, Wp): W padded to whole column blocks
    blocks: np.ndarray             # (2, Wp / nb, aug + C, nb): the kernel's column blocks
    recurrent: np.ndarray          # (2, nk, W)
    src_d: np.ndarray              # (C,) inputs: direction and position of the previous
    src_pos: np.ndarray            #      layer's unit (BiLSTM 1: src_pos = global feature)
    n_in: int                      # units under the previous LayerNorm (2u; 0 for BiLSTM 1)


def _step_of(src_d: np.ndarray, steps: int) -> np.ndarray:
    """``(2, T, C)``: the step whose state of direction ``src_d[j]`` a direction ``dd`` of the
    next layer reads at its step ``s`` (time ``s`` forward, ``T-1-s`` backward)."""
    s = np.arange(steps)[None, :, None]
    same = np.arange(2)[:, None, None] == src_d[None, None, :]
    return np.where(same, s, steps - 1 - s)


class SceneHead:
    """The prediction network of ``model`` on the units ``used`` marks (from :func:`calibrate`),
    with the guards of the module docstring. ``head(features (B, m, k))`` -> ``(y (B, n_out*dim)
    in [0, 1], ok (B,) bool)``; rows with ``ok`` False must be recomputed in full.

    Like the full NumPy engine it reads only the weight rows that non-zero inputs multiply:
    computed units in the model's unit order (most used first), each recurrent product cut
    after its direction's last non-zero state unit, each input projection after the last
    non-zero input (as column blocks, :func:`tpnet_ref.layers.fuse_bilstm`), LayerNorm folded into
    the next input projection. One window (B = 1) runs on buffers kept per thread with the
    recurrent rows stored under the steps' input projections, so one matrix-vector product per
    direction and step gives the whole pre-activation."""

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
        self.dtype, self.steps, T = dt, cfg.m, cfg.m
        self.eps = dt.type(cfg.layer_norm_eps)
        self.limit = dt.type(np.sqrt(np.finfo(dt).max) / 4 * LIMIT_SHARE)
        self.n_global = cfg.global_features
        order = model.unit_order or {}
        g = self.used["global"]
        go = order.get("global")
        go = np.arange(g.size) if go is None else go
        self.g_keep = go[g[go]]                 # kept global features, unit order
        self.g_drop = np.flatnonzero(~g)
        self.layers: list[_Layer] = []
        src_file = self.g_keep
        src_d, src_pos = np.zeros(len(src_file), np.intp), self.g_keep
        ln = None                               # previous LayerNorm (gamma, beta), file order
        n_in = 0
        for i, u in enumerate(cfg.lstm_units, 1):
            rec, drop, out_d, out_pos, out_file = _layout(self.used[f"lstm{i}"],
                                                          order.get(f"lstm{i}"), u)
            nk, nd = rec.shape[1], drop.shape[1]
            width, aug, c_in = nd + 4 * nk, (1 if ln is None else 2), len(src_file)
            nb = max(1, min(BLOCK_COLUMNS, SMALL_PRODUCT // (T * (aug + c_in))))
            wp = -(-width // nb) * nb
            kernel = np.zeros((2, aug + c_in, wp))
            recurrent = np.empty((2, nk, width))
            sign = np.ones(width)
            sign[nd:nd + 3 * nk] = -1.0
            for d, name in enumerate(("fwd", "bwd")):
                k, r, b = (p[f"lstm{i}.{name}.{x}"].astype(np.float64)
                           for x in ("kernel", "recurrent", "bias"))
                # Keras gates i, f, c, o -> g of the dropped | o, i, f, g of the computed
                cols = np.concatenate([2 * u + drop[d], 3 * u + rec[d], rec[d], u + rec[d],
                                       2 * u + rec[d]])
                kc = k[:, cols]
                if ln is None:
                    rows = [b[cols][None], kc[src_file]]
                else:   # LN(h) @ K = r*(h @ gamma K) - r*mean*(gamma @ K) + beta @ K
                    gamma, beta = ln
                    rows = [(b[cols] + beta @ kc)[None], -(gamma @ kc)[None],
                            gamma[src_file, None] * kc[src_file]]
                kernel[d, :, :width] = np.concatenate(rows) * sign
                recurrent[d] = r[rec[d]][:, cols] * sign
            kernel = kernel.astype(dt)
            blocks = np.ascontiguousarray(
                kernel.reshape(2, aug + c_in, wp // nb, nb).transpose(0, 2, 1, 3))
            self.layers.append(_Layer(nk, nd, width, aug, kernel, blocks, recurrent.astype(dt),
                                      src_d, src_pos, n_in))
            ln = (p[f"ln{i}.gamma"].astype(np.float64), p[f"ln{i}.beta"].astype(np.float64))
            src_file, src_d, src_pos, n_in = out_file, out_d, out_pos, 2 * u
        gamma, beta = ln
        hw, hb = p["head.w"].astype(np.float64), p["head.b"].astype(np.float64)
        # negated: the output is 1 / (1 + exp(x @ head_w))
        self.head_w = (-np.concatenate([(hb + beta @ hw)[None], -(gamma @ hw)[None],
                                        gamma[src_file, None] * hw[src_file]])).astype(dt)
        self.head_src = (src_d, src_pos, n_in)
        self._small: bool | None = None
        self._local = threading.local()

    def num_params(self) -> int:
        """Parameters the specialised head reads (guards included)."""
        n = sum(ly.kernel[:, :, :ly.width].size + ly.recurrent.size for ly in self.layers)
        return int(n + self.head_w.size)

    def __call__(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        f = np.asarray(features, dtype=self.dtype)
        if self._small is None:
            self._small = small_products_pay(self.dtype)
        with np.errstate(all="ignore"):
            if f.shape[0] == 1:
                run = getattr(self._local, "run", None)
                if run is None:
                    run = self._local.run = _Run1(self)
                return run(f)
            return self._batch(f)

    def _stats(self, x: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        """LayerNorm's mean and ``rstd`` over ``n`` units of which only ``x (..., C)`` can be
        non-zero (the others are exactly 0 in both networks)."""
        c = x.shape[-1]
        mean = x.sum(axis=-1) / self.dtype.type(n)
        d = x - mean[..., None]
        var = (np.einsum("...i,...i->...", d, d) + self.dtype.type(n - c) * mean * mean) \
            / self.dtype.type(n)
        return mean, (1.0 / np.sqrt(var + self.eps)).astype(self.dtype, copy=False)

    def _batch(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Any batch ``f (B, T, k)``, buffers made per call."""
        dt, T, one = self.dtype, self.steps, self.dtype.type(1.0)
        bsz = f.shape[0]
        ok = ~(f[..., self.g_drop] != 0).any(axis=(1, 2))
        tsel = np.array([np.arange(T), np.arange(T)[::-1]])
        h = None
        for li, ly in enumerate(self.layers):
            nk, nd, width, aug = ly.nk, ly.nd, ly.width, ly.aug
            if li == 0:                                 # (2, T, B, C): each direction's order
                x = f[:, tsel][..., ly.src_pos].transpose(1, 2, 0, 3)
            else:
                x = h[ly.src_d, _step_of(ly.src_d, T), :, ly.src_pos]    # (2, T, C, B)
                x = np.ascontiguousarray(x.transpose(0, 1, 3, 2))
            c_in = x.shape[-1]
            xa = np.empty((2, T, bsz, aug + c_in), dt)
            xa[..., 0] = one
            if li == 0:
                xa[..., 1:] = x
            else:
                mean, r = self._stats(x, ly.n_in)
                np.multiply(mean, r, out=xa[..., 1])
                np.multiply(x, r[..., None], out=xa[..., 2:])
            k = aug + L.used_columns(x[0].reshape(T * bsz, c_in))
            wp = ly.kernel.shape[2]
            wz = max(wp, width + nk)
            z_all = np.empty((2, T + 1, bsz, wz), dt)    # pre-activations; [W:W+nk] c of the step before
            zin = z_all.reshape(2, (T + 1) * bsz, wz)[:, :T * bsz, :wp]
            xin = xa.reshape(2, T * bsz, aug + c_in)[..., :k]
            nb = ly.blocks.shape[3]
            if self._small and T * bsz * k * nb <= SMALL_PRODUCT:
                np.matmul(xin[:, None], ly.blocks[:, :, :k],
                          out=zin.reshape(2, T * bsz, wp // nb, nb).transpose(0, 2, 1, 3))
            else:
                np.matmul(xin, ly.kernel[:, :k], out=zin)
            h = np.empty((2, T, bsz, nk), dt)
            tmp = np.empty((2, bsz, width), dt)
            rec = ly.recurrent
            for s in range(T):
                z = z_all[:, s]
                if s:
                    for d, kk in enumerate(L.used_prefixes(h[:, s - 1])):
                        np.matmul(h[d, s - 1, :, :kk], rec[d, :kk], out=tmp[d])
                    z[..., :width] += tmp
                e = z[..., nd:nd + 3 * nk]               # 1 + exp(-x): o, i, f
                np.exp(e, out=e)
                e += one
                g = z[..., nd + 3 * nk:width]
                np.maximum(g, 0, out=g)
                c = z_all[:, s + 1, :, width:width + nk]
                if s == 0:                               # c = i relu(g)
                    np.divide(g, z[..., nd + nk:nd + 2 * nk], out=c)
                else:                                    # c = i relu(g) + f c
                    gc = z[..., nd + 3 * nk:width + nk]
                    np.divide(gc, z[..., nd + nk:nd + 3 * nk], out=gc)
                    np.add(gc[..., :nk], gc[..., nk:], out=c)
                np.divide(c, z[..., nd:nd + nk], out=h[:, s])   # h = o c (c >= 0)
            if nd:      # a dropped unit's cell pre-activation > 0 (or NaN): it would wake up
                ok &= z_all[:, :T, :, :nd].max(axis=(0, 1, 3)) <= 0
            ok &= h.max(axis=(0, 1, 3)) < self.limit
        src_d, src_pos, n_in = self.head_src
        x = np.ascontiguousarray(h[src_d, T - 1, :, src_pos].T)    # (B, C)
        mean, r = self._stats(x, n_in)
        xa = np.empty((bsz, 2 + x.shape[1]), dt)
        xa[:, 0] = one
        np.multiply(mean, r, out=xa[:, 1])
        np.multiply(x, r[:, None], out=xa[:, 2:])
        k = 2 + L.used_columns(x)
        y = xa[:, :k] @ self.head_w[:k]
        np.exp(y, out=y)
        y += one
        out = np.divide(one, y, out=y)
        ok &= np.isfinite(out).all(axis=1)
        return out, ok


class _Run1:
    """One thread's buffers and views for :class:`SceneHead` on one window (B = 1).

    Per BiLSTM and direction ``M (T + nk, Wp)`` holds the steps' input projections (bias
    included) above the recurrent rows, and ``V (T + 1, T + nk)`` the vector of each step:
    ``V[s] = [one-hot s | h_{s-1}]``; then ``V[s, s:T+k] @ M[s:T+k]`` is the pre-activation of
    step ``s`` (``k``: one past the last non-zero unit of ``h_{s-1}``), one product."""

    def __init__(self, head: SceneHead) -> None:
        dt, T = head.dtype, head.steps
        self.head, self.T = head, T
        self.one, self.zero = dt.type(1.0), dt.type(0.0)
        self.layers = []
        prev = None
        for li, ly in enumerate(head.layers):
            nk, nd, width, aug = ly.nk, ly.nd, ly.width, ly.aug
            c_in, wp = ly.kernel.shape[1] - aug, ly.kernel.shape[2]
            nbf, nb = ly.blocks.shape[1], ly.blocks.shape[3]
            m_all = np.zeros((2, T + nk, wp), dt)
            m_all[:, T:, :width] = ly.recurrent
            v_all = np.zeros((2, T + 1, T + nk), dt)
            v_all[:, np.arange(1, T), np.arange(1, T)] = 1
            z_all = np.zeros((2, T + 1, width + nk), dt)
            xa = np.zeros((2, T, aug + c_in), dt)
            xa[..., 0] = 1
            if li == 0:     # the kept global features of each direction's steps, then the dropped
                t = np.array([np.arange(T), np.arange(T)[::-1]])
                idx = np.concatenate([(t[:, :, None] * head.n_global + ly.src_pos).ravel(),
                                      (np.arange(T)[:, None] * head.n_global + head.g_drop).ravel()])
                xb = np.empty(idx.size, dt)
            else:           # the previous layer's states, and one more column that is always 0
                pv = prev[1]
                flat = (ly.src_d * pv.shape[1] + _step_of(ly.src_d, T) + 1) * pv.shape[2] + T + ly.src_pos
                idx = np.concatenate([flat, np.zeros((2, T, 1), np.intp)], axis=2)   # pv[0, 0, 0] == 0
                xb = np.empty(idx.shape, dt)
            steps = []
            for s in range(T):
                per_d = []
                for d in range(2):
                    z = m_all[d, 0] if s == 0 else z_all[d, s]
                    per_d.append((
                        v_all[d, s], v_all[d, s, T:], m_all[d, :, :width], z_all[d, s, :width],
                        z[nd:nd + 3 * nk],                                  # o, i, f
                        z[nd + 3 * nk:width],                               # g
                        z[nd + 3 * nk:width + nk] if s else None,           # [g | c]
                        z[nd + nk:nd + 3 * nk] if s else z[nd + nk:nd + 2 * nk],   # [i | f]
                        z[width:width + nk] if s else None,                 # c
                        z_all[d, s + 1, width:], z[nd:nd + nk], v_all[d, s + 1, T:]))
                steps.append(per_d)
            extra = None
            if li:
                n = ly.n_in
                wmean = np.zeros(c_in + 1, dt)
                wmean[:c_in] = 1.0 / n
                wvar = wmean.copy()
                wvar[c_in] = (n - c_in) / n        # the units that are 0: (0 - mean)^2 each
                extra = (wmean, wvar, np.empty((2, T), dt), np.empty((2, T), dt),
                         np.empty((2, T, c_in + 1), dt))
            self.layers.append((ly, m_all, v_all, z_all, xa, idx, xb, steps, extra,
                                m_all[:, :T].reshape(2, T, nbf, nb).transpose(0, 2, 1, 3)))
            prev = (ly, v_all)
        ly, pv = prev
        src_d, src_pos, n = head.head_src
        c_in = len(src_pos)
        self.h_idx = np.concatenate([(src_d * pv.shape[1] + T) * pv.shape[2] + T + src_pos, [0]])[None]
        self.h_x = np.empty((1, c_in + 1), dt)
        self.h_xa = np.zeros((1, 2 + c_in), dt)
        self.h_xa[0, 0] = 1
        wmean = np.zeros(c_in + 1, dt)
        wmean[:c_in] = 1.0 / n
        wvar = wmean.copy()
        wvar[c_in] = (n - c_in) / n
        self.h_extra = (wmean, wvar, np.empty(1, dt), np.empty(1, dt), np.empty((1, c_in + 1), dt))
        self.h_y = np.empty(head.head_w.shape[1], dt)

    def _fold(self, x: np.ndarray, xa: np.ndarray, extra: tuple) -> None:
        """``xa[..., 1:] = [mean * rstd | x * rstd]`` of the LayerNorm of ``x (..., C + 1)``
        (its last column 0)."""
        wmean, wvar, mean, var, d = extra
        np.dot(x, wmean, out=mean)
        np.subtract(x, mean[..., None], out=d)
        np.multiply(d, d, out=d)
        np.dot(d, wvar, out=var)
        np.add(var, self.head.eps, out=var)
        np.sqrt(var, out=var)
        np.divide(self.one, var, out=var)
        np.multiply(mean, var, out=xa[..., 1])
        np.multiply(x[..., :-1], var[..., None], out=xa[..., 2:])

    def __call__(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        head, T, one, zero = self.head, self.T, self.one, self.zero
        exp, add, div, maximum, dot, matmul = np.exp, np.add, np.divide, np.maximum, np.dot, np.matmul
        small = head._small
        for li, (ly, m_all, v_all, z_all, xa, idx, xb, steps, extra, m_blocks) in enumerate(self.layers):
            aug, nd = ly.aug, ly.nd
            if li == 0:
                f.take(idx, mode="clip", out=xb)
                c_in = xa.shape[2] - 1
                x = xb[:2 * T * c_in].reshape(2, T, c_in)
                if head.g_drop.size and xb[2 * T * c_in:].any():
                    return self._flagged()
                np.copyto(xa[..., 1:], x)
            else:
                prev_v.take(idx, mode="clip", out=xb)
                self._fold(xb, xa, extra)
                x = xb[..., :-1]
            nz = x[0].any(axis=0).nonzero()[0]
            k = aug + 1 + nz[-1] if len(nz) else aug
            if small:
                matmul(xa[:, None, :, :k], ly.blocks[:, :, :k], out=m_blocks)
            else:
                matmul(xa[:, :, :k], ly.kernel[:, :k], out=m_all[:, :T])
            for _, _, _, _, e, g, _, iv, _, c1, eo, h1 in steps[0]:
                exp(e, out=e)
                add(e, one, out=e)
                maximum(g, zero, out=g)
                div(g, iv, out=c1)
                div(c1, eo, out=h1)
            for s in range(1, T):
                for vrow, h, mr, zw, e, g, gc, iv, c, c1, eo, h1 in steps[s]:
                    nz = h.nonzero()[0]
                    k = T + 1 + nz[-1] if len(nz) else T
                    matmul(vrow[s:k], mr[s:k], out=zw)
                    exp(e, out=e)
                    add(e, one, out=e)
                    maximum(g, zero, out=g)
                    div(gc, iv, out=gc)
                    add(g, c, out=c1)
                    div(c1, eo, out=h1)
            if nd and not (m_all[:, 0, :nd].max() <= 0 and (T == 1 or z_all[:, 1:T, :nd].max() <= 0)):
                return self._flagged()       # a dropped unit would wake up (or NaN)
            if not v_all[:, 1:, T:].max() < head.limit:
                return self._flagged()
            prev_v = v_all
        x = prev_v.take(self.h_idx, mode="clip", out=self.h_x)
        xa = self.h_xa
        self._fold(x, xa, self.h_extra)
        nz = x[0, :-1].nonzero()[0]
        k = 3 + nz[-1] if len(nz) else 2
        y = dot(xa[0, :k], head.head_w[:k], out=self.h_y)
        exp(y, out=y)
        add(y, one, out=y)
        out = div(one, y)[None]
        s = out.sum()
        return out, np.array([s == s])

    def _flagged(self) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros((1, self.h_y.size), self.head.dtype), np.zeros(1, bool)


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
