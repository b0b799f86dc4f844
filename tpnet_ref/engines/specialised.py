"""A scene-specialised prediction network: only the units a scene uses, on every input the same
function as the full network (up to rounding: the sums run over fewer terms, docs/tolerances.md).

On the windows of one scene many units of a ReLU TP-Net are exactly zero on every window (shipped
m = 4 model, training-grid windows and the model's own rollouts: 83 of 128 global features, 563 of
1024 BiLSTM-1 outputs, 243 of 512 BiLSTM-2, 130 of 512 BiLSTM-3). :func:`calibrate` finds them;
:class:`SceneHead` runs the prediction network on the other units only, and guards every window:

- a global feature is kept or its value is checked to be exactly 0 (the extractor computes all 128:
  cheap);
- a ReLU-LSTM unit starts with c = h = 0; with ``c_t = f c_{t-1} + i relu(g_t)`` and
  ``h_t = o relu(c_t)`` it stays exactly 0 while its cell pre-activation ``g_t <= 0``. The head
  computes ``g`` of every dropped unit (one column per dropped unit instead of four gates, from
  the kept units' states only) and flags the window if one is ``> 0`` at any step;
- a dropped unit's zero output still enters the LayerNorm (mean and variance over all units):
  the statistics count it, and the LayerNorm is folded into the next layer's input projection,
  ``LN(h) @ K = r (h @ gamma K) - r mean (gamma @ K) + beta @ K`` with the sums over all units
  (two extra input rows, for the bias and ``r mean``);
- an LSTM output beyond half the bound above which the full network refuses to answer
  (``NonFiniteResultError``) flags the window too, and so does a result that is not finite.

A flagged window is recomputed by the full network, so the output equals the full model's up to
rounding on every input. Like the full NumPy engine, the head reads only the weight rows that
non-zero inputs multiply: the kept units are laid out in the model's unit order (most used
first, :mod:`tpnet_ref.engines.unit_order`), each recurrent product stops after its direction's last
non-zero state unit and each input projection after the last non-zero input.

:meth:`tpnet_ref.model.TPNet.specialize` builds one; :func:`save` / :func:`attach` keep it in the
native weights file as a group ``specialization`` beside ``config`` and ``params`` (the native
reader ignores groups it does not know); the masks are in the file's order of units, whatever
the model's layout.
"""
from __future__ import annotations

import os
import threading
from typing import Any, NamedTuple

import numpy as np

from . import layers as L
from .blas import BLOCK_COLUMNS, SMALL_PRODUCT
from .specialised_window import OneWindow
from .unit_order import measure
from ..weights.hdf5 import read_vectors, write_vectors
from ..weights.native import seal

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


#: a window goes to the full network when an LSTM output reaches this share of the bound above
#: which the full network refuses to answer (``sqrt(max) / 4``, :class:`tpnet_ref.engines.numpy_engine.NumpyHead`): a margin
#: for the two networks' different rounding
LIMIT_SHARE = 0.5


def _layout(keep: np.ndarray, order: np.ndarray | None, u: int):
    """One BiLSTM's units. ``keep (2u,)``: used units, file order [forward | backward];
    ``order``: the model's unit order of the layer (None: the file's).

    Returns per direction the computed units ``rec[d]`` (its kept units in the unit order; one
    dropped unit, computed in full, when it keeps none) and the dropped ones ``drop[d]``
    (guarded), and the layer's outputs in the order the next layer reads them (the unit order):
    ``out_d``, ``out_pos`` (direction, position in ``rec``) and ``out_file`` (index in the
    file's 2u outputs)."""
    po = np.arange(2 * u) if order is None else np.asarray(order, dtype=np.intp)
    rec, drop = [], []
    computed = np.zeros(2 * u, bool)
    for d in range(2):
        pd = po[(po >= d * u) & (po < (d + 1) * u)] - d * u     # this direction, unit order
        r = pd[keep[d * u + pd]]
        rec.append(r if r.size else pd[:1])
        drop.append(np.setdiff1d(np.arange(u), rec[d]))
        computed[d * u + rec[d]] = True
    out_file = po[computed[po]]
    out_d = (out_file >= u).astype(np.intp)
    pos = np.zeros((2, u), np.intp)
    for d in range(2):
        pos[d, rec[d]] = np.arange(rec[d].size)
    return rec, drop, out_d, pos[out_d, out_file - u * out_d], out_file


class _Layer(NamedTuple):
    """One BiLSTM of a :class:`SceneHead`. Direction ``d``'s pre-activations are the columns
    ``off[d] : off[d] + width[d]`` of the input projection and its recurrent product's:
    forward ``[g, f, i, o of the computed units (nk each) | g of the dropped units (nd)]``,
    backward ``[g of the dropped | o, i, f, g of the computed]`` (mirrored, so that the two
    directions' sigmoid gates, whose columns are negated, can sit side by side in one buffer).
    The input rows are ``[1 | mean * rstd | inputs]`` (bias and the previous LayerNorm folded
    in, ``aug`` = 2; BiLSTM 1: ``[1 | global features]``)."""

    nk: tuple[int, int]
    nd: tuple[int, int]
    width: tuple[int, int]
    off: tuple[int, int]
    aug: int
    kernel: np.ndarray             # (aug + C, Wp): both directions, padded to whole blocks
    blocks: np.ndarray             # (Wp / nb, aug + C, nb): the kernel's column blocks
    recurrent: tuple[np.ndarray, np.ndarray]    # (nk[d], width[d])
    src: np.ndarray                # (T, C): step of the previous layer's state each input is
    src_d: np.ndarray              # (C,)    and its direction and position there (BiLSTM 1:
    src_pos: np.ndarray            # (C,)    src_pos is the global feature)
    n_in: int                      # units under the previous LayerNorm (2u; 0 for BiLSTM 1)


def _sources(out_d: np.ndarray, steps: int) -> np.ndarray:
    """``(T, C)``: the step after which direction ``out_d[j]``'s state is the layer's output
    ``j`` at time ``t`` (``t`` forward, ``T-1-t`` backward)."""
    t = np.arange(steps)[:, None]
    return np.where(out_d[None, :] == 0, t, steps - 1 - t)


class SceneHead:
    """The prediction network of ``model`` on the units ``used`` marks (from :func:`calibrate`),
    with the guards of the module docstring. ``head(features (B, m, k))`` -> ``(y (B, n_out*dim)
    in [0, 1], ok (B,) bool)``; rows with ``ok`` False must be recomputed in full.

    Like the full NumPy engine it reads only the weight rows that non-zero inputs multiply:
    computed units in the model's unit order (most used first), each recurrent product cut
    after its direction's last non-zero state unit, the input projection of both directions
    after the last non-zero input (as column blocks, see :func:`tpnet_ref.engines.layers.fuse_bilstm`),
    LayerNorm folded into the next input projection. One window (B = 1) runs on buffers kept
    per thread (:class:`~tpnet_ref.engines.specialised_window.OneWindow`)."""

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
        src = np.broadcast_to(np.arange(T)[:, None], (T, src_file.size))
        src_d, src_pos = np.zeros(src_file.size, np.intp), self.g_keep
        ln = None                               # previous LayerNorm (gamma, beta), file order
        n_in = 0
        for i, u in enumerate(cfg.lstm_units, 1):
            rec, drop, out_d, out_pos, out_file = _layout(self.used[f"lstm{i}"],
                                                          order.get(f"lstm{i}"), u)
            nk = tuple(r.size for r in rec)
            nd = tuple(u - n for n in nk)
            width = tuple(a + 4 * n for a, n in zip(nd, nk))
            off = (0, width[0])
            aug, c_in = (1 if ln is None else 2), src_file.size
            nb = max(1, min(BLOCK_COLUMNS, SMALL_PRODUCT // (T * (aug + c_in))))
            wp = -(-sum(width) // nb) * nb
            kernel = np.zeros((aug + c_in, wp))
            recurrent = []
            for d, name in enumerate(("fwd", "bwd")):
                k, r, b = (p[f"lstm{i}.{name}.{x}"].astype(np.float64)
                           for x in ("kernel", "recurrent", "bias"))
                # Keras gates i, f, c, o -> forward: g, f, i, o of the computed | g of the
                # dropped; backward: g of the dropped | o, i, f, g of the computed
                gates = [2 * u + rec[d], u + rec[d], rec[d], 3 * u + rec[d]]
                if d:
                    gates = gates[::-1]
                cols = np.concatenate([*gates, 2 * u + drop[d]] if d == 0 else
                                      [2 * u + drop[d], *gates])
                sign = np.ones(cols.size)
                a = nk[d] if d == 0 else nd[d]               # the sigmoid gates' columns
                sign[a:a + 3 * nk[d]] = -1.0
                kc = k[:, cols] * sign
                if ln is None:
                    rows = [b[cols][None] * sign, kc[src_file]]
                else:   # LN(h) @ K = r*(h @ gamma K) - r*mean*(gamma @ K) + beta @ K
                    gamma, beta = ln
                    rows = [(b[cols] * sign + beta @ kc)[None], -(gamma @ kc)[None],
                            gamma[src_file, None] * kc[src_file]]
                kernel[:, off[d]:off[d] + width[d]] = np.concatenate(rows)
                recurrent.append(np.ascontiguousarray(r[rec[d]][:, cols] * sign, dtype=dt))
            kernel = kernel.astype(dt)
            blocks = np.ascontiguousarray(kernel.reshape(aug + c_in, wp // nb, nb).transpose(1, 0, 2))
            self.layers.append(_Layer(nk, nd, width, off, aug, kernel, blocks, tuple(recurrent),
                                      np.ascontiguousarray(src), src_d, src_pos, n_in))
            ln = (p[f"ln{i}.gamma"].astype(np.float64), p[f"ln{i}.beta"].astype(np.float64))
            src_file, src, src_d, src_pos, n_in = out_file, _sources(out_d, T), out_d, out_pos, 2 * u
        gamma, beta = ln
        hw, hb = p["head.w"].astype(np.float64), p["head.b"].astype(np.float64)
        # negated: the output is 1 / (1 + exp(x @ head_w))
        self.head_w = (-np.concatenate([(hb + beta @ hw)[None], -(gamma @ hw)[None],
                                        gamma[src_file, None] * hw[src_file]])).astype(dt)
        self.head_src = (src_d, src_pos, n_in)     # final states: step T-1 of both directions
        self._local = threading.local()

    def num_params(self) -> int:
        """Parameters the specialised head reads (guards included)."""
        n = sum(ly.kernel[:, :sum(ly.width)].size + sum(r.size for r in ly.recurrent)
                for ly in self.layers)
        return int(n + self.head_w.size)

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "_local"}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state, _local=threading.local())

    def __call__(self, features: np.ndarray, marks: list | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
        """``features (B, m, k)`` -> ``(y (B, n_out*dim), ok (B,))``. ``marks``: for profiling a
        single window, a list that gets ``(stage, time.perf_counter())`` at each stage's end."""
        f = np.asarray(features, dtype=self.dtype)
        with np.errstate(all="ignore"):
            if f.shape[0] == 1:
                run = getattr(self._local, "run", None)
                if run is None:
                    run = self._local.run = OneWindow(self)
                return run(f, marks)
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

    def _project(self, ly: _Layer, xa: np.ndarray, k: int, out: np.ndarray) -> None:
        """``out (R, Wp) = xa[:, :k] @ kernel[:k]`` (:func:`tpnet_ref.engines.layers.project_spans`:
        one stacked product over the kernel's column blocks when each is small enough)."""
        L.project_spans(xa, ly.kernel, ly.blocks, [(0, k)], out=out)

    def _batch(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Any batch ``f (B, T, k)``, buffers made per call."""
        dt, T, one = self.dtype, self.steps, self.dtype.type(1.0)
        bsz = f.shape[0]
        if bsz == 0:
            return np.empty((0, self.head_w.shape[1]), dt), np.empty(0, bool)
        ok = ~(f[..., self.g_drop] != 0).any(axis=(1, 2))
        h = None
        for li, ly in enumerate(self.layers):
            if li == 0:                                 # (T, B, C)
                x = f[..., ly.src_pos].transpose(1, 0, 2)
            else:
                x = h[ly.src_d, ly.src, :, ly.src_pos].transpose(0, 2, 1)    # (T, C, B) ->
            c_in, aug = x.shape[-1], ly.aug
            xa = np.empty((T, bsz, aug + c_in), dt)
            xa[..., 0] = one
            if li == 0:
                xa[..., 1:] = x
            else:
                x = np.ascontiguousarray(x)
                mean, r = self._stats(x, ly.n_in)
                np.multiply(mean, r, out=xa[..., 1])
                np.multiply(x, r[..., None], out=xa[..., 2:])
            k = aug + L.used_columns(np.ascontiguousarray(x).reshape(T * bsz, c_in))
            proj = np.empty((T * bsz, ly.kernel.shape[1]), dt)
            self._project(ly, xa.reshape(T * bsz, -1), k, proj)
            proj = proj.reshape(T, bsz, -1)
            h = np.zeros((2, T, bsz, max(ly.nk)), dt)
            for d in range(2):
                nk, nd, width, rec = ly.nk[d], ly.nd[d], ly.width[d], ly.recurrent[d]
                # rows of z_all: forward [c before | g, f, i, o | g dropped], backward
                # [g dropped | o, i, f, g | c before]
                z_all = np.empty((T + 1, bsz, width + nk), dt)
                at = nk if d == 0 else 0                  # the projections' columns
                z_all[:T, :, at:at + width] = \
                    (proj if d == 0 else proj[::-1])[..., ly.off[d]:ly.off[d] + width]
                if d == 0:
                    sig, g0, c0, i0, dvd, dvs, o0, gd = 2 * nk, nk, 0, 3 * nk, 0, 2 * nk, 4 * nk, 5 * nk
                else:
                    sig, g0, c0, i0, dvd, dvs, o0, gd = nd, nd + 3 * nk, width, nd + nk, nd + 3 * nk, nd + nk, nd, 0
                hd = h[d, :, :, :nk]
                for s in range(T):
                    z = z_all[s]
                    if s:
                        kk = L.used_columns(hd[s - 1])
                        z[:, at:at + width] += hd[s - 1, :, :kk] @ rec[:kk]
                    e = z[:, sig:sig + 3 * nk]               # 1 + exp(-x): o, i, f
                    np.exp(e, out=e)
                    e += one
                    g = z[:, g0:g0 + nk]
                    np.maximum(g, 0, out=g)
                    c = z_all[s + 1, :, c0:c0 + nk]
                    if s == 0:                               # c = i relu(g)
                        np.divide(g, z[:, i0:i0 + nk], out=c)
                    else:                                    # c = i relu(g) + f c
                        q = z[:, dvd:dvd + 2 * nk]           # [c | g] / [f | i] or [g | c] / [i | f]
                        np.divide(q, z[:, dvs:dvs + 2 * nk], out=q)
                        np.add(q[:, :nk], q[:, nk:], out=c)
                    np.divide(c, z[:, o0:o0 + nk], out=hd[s])     # h = o c (c >= 0)
                if nd:      # a dropped unit's cell pre-activation > 0 (or NaN): it would wake up
                    ok &= z_all[:T, :, gd:gd + nd].max(axis=(0, 2)) <= 0
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


class SpecialisedHead:
    """The :class:`tpnet_ref.engines.interface.Head` of a specialised model: the :class:`SceneHead` on every
    window, the full network on the windows it flags: the first of the heads ``full`` (fastest
    first, the last one takes any batch) that runs that many; outputs ``(B, n_out, dim)``
    (``out_shape``). ``counts`` (a dict with "windows" and "fallbacks", shared with the model)
    counts both. It projects its own inputs (:meth:`project` gives None: a rollout does not
    cache BiLSTM 1's projection)."""

    name = "specialised"
    max_batch: int | None = None
    threaded = False

    def __init__(self, scene: SceneHead, full: list, counts: dict[str, int],
                 out_shape: tuple[int, int]) -> None:
        self.scene, self.full, self.counts, self.out_shape = scene, full, counts, out_shape

    def project(self, features: np.ndarray, batch: int = 1) -> None:
        return None

    def __call__(self, features: np.ndarray, proj1: np.ndarray | None = None) -> np.ndarray:
        """``features (B, m, k)`` -> ``(B, n_out, dim)`` in [0, 1], equal to the full network's
        up to rounding."""
        y, ok = self.scene(features)
        y = y.reshape(-1, *self.out_shape)
        bad = np.flatnonzero(~ok)
        if bad.size:
            head = next(h for h in self.full if h.max_batch is None or bad.size <= h.max_batch)
            y[bad] = head(features[bad])
        self.counts["windows"] += len(ok)
        self.counts["fallbacks"] += int(bad.size)
        return y


def fraction_used(used: dict[str, np.ndarray]) -> dict[str, tuple[int, int]]:
    """``{mask name: (used units, all units)}``."""
    return {k: (int(v.sum()), int(v.size)) for k, v in used.items()}


# ------------------------------------------------------------------ native file
def group(used: dict[str, np.ndarray]) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The masks as the native file's ``specialization`` group: ``(attrs, {mask: uint8
    array})`` (:func:`tpnet_ref.weights.native.write_native`'s ``groups``)."""
    return {"format": FORMAT}, {k: np.asarray(v, dtype=np.uint8) for k, v in used.items()}


def write(path: str | os.PathLike, used: dict[str, np.ndarray], **attrs: Any) -> None:
    """Add the masks as group ``specialization`` (uint8 datasets, ``format`` attribute) to an
    existing native weights file, replacing any group of that name, and renew the file's
    content digest."""
    write_vectors(path, GROUP, FORMAT, used, np.uint8, **attrs)
    seal(path)


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


def attach(model: Any, path: str | os.PathLike) -> Any:
    """``model`` (just read from the native file ``path``) specialised as the file says, or
    ``model`` itself when the file has no ``specialization`` group."""
    used = read(path)
    return model if used is None else model.with_specialization(used)


__all__ = ["calibrate", "SceneHead", "SpecialisedHead", "fraction_used", "group", "write", "read",
           "attach",
           "GROUP", "FORMAT"]
