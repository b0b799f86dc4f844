"""The scene-specialised head on one window (B = 1): its buffers and views, made once per thread,
and the pass that runs on them (:class:`OneWindow`);
:class:`tpnet_ref.engines.specialised.SceneHead` runs larger batches itself."""
from __future__ import annotations

import time
from typing import Any, NamedTuple

import numpy as np


class _DirStep(NamedTuple):
    """One direction's views for one step of :class:`OneWindow`, into its layer's buffers."""

    vrow: np.ndarray        # [one-hot | h] from the step's time on: times it gives the gates
    h: np.ndarray           # the state before the step (the direction's computed units)
    rows: np.ndarray        # the gates' matrix from the step's time on: [projections | recurrent]
    z: np.ndarray           # this direction's pre-activations in the step's row
    x0: np.ndarray          # the step's input projection (the first step copies it to z)
    g: np.ndarray           # relu(g)                        (first step: c = g / i)
    i: np.ndarray           # 1 + exp(-i)
    dividend: np.ndarray    # [c | g]                        (later steps: [c | g] /= [f | i])
    divisor: np.ndarray     # [f | i]
    c_part: np.ndarray      # c / (1 + exp(-f)), the dividend's first half
    g_part: np.ndarray      # relu(g) / (1 + exp(-i)), its second half
    c: np.ndarray           # the new cell state (in the next step's row)
    o: np.ndarray           # 1 + exp(-o)
    h_next: np.ndarray      # the new state: c / (1 + exp(-o))
    d: int                  # direction (0 forward, 1 backward)
    base: int               # rows of ``rows`` before the recurrent ones: T - the step's time


class _RunLayer(NamedTuple):
    """One BiLSTM's buffers and views in :class:`OneWindow`."""

    ly: Any                 # the layer's weights (tpnet_ref.engines.specialised's layout)
    proj: np.ndarray        # (T, Wp): the steps' input projections
    v_all: np.ndarray       # (2, T + 1, T + nk): [one-hot | h] of each direction and step
    xa: np.ndarray          # (T, aug + C): the input rows [1 | mean * rstd | inputs]
    idx: np.ndarray         # where the inputs are in the previous layer's v_all (or features)
    xb: np.ndarray          # the gathered inputs
    steps: list             # per step: (sigmoid columns, relu-to-sigmoid columns, [_DirStep])
    extra: tuple | None     # the folded LayerNorm's weights and buffers (BiLSTM 2, 3)
    guards: list            # per direction with dropped units: (d, all steps' v, g rows, out)
    guard: np.ndarray       # (2, T, nd): the dropped units' g at every step
    copies: list            # (destination, source): projections into the gates' matrices


class OneWindow:
    """One thread's buffers and views for :class:`~tpnet_ref.engines.specialised.SceneHead` on one
    window (B = 1).

    Per BiLSTM and direction, two contiguous matrices ``[the steps' input projections (T rows,
    time order, bias included) | the recurrent rows (nk)]``: of its gates' columns and of its
    dropped units' ``g`` columns; and ``V (2, T + 1, T + nk)``: the vector of each direction and
    step, ``[one-hot | h]`` with the one at the step's time and ``h`` the state after the step
    before. Then ``V[d, s, a:T+n] @ gates[d][a:T+n]`` (``a``: the step's time, ``n``: one past
    the last non-zero unit of ``h``) is the pre-activation of step ``s``: one matrix-vector
    product per direction and step, reading only the recurrent rows that non-zero units
    multiply; the dropped units' ``g`` at every step is one product per direction after the
    layer (all steps' rows of ``V``). Each step's gates sit in one row ``[c, g, f, i, o
    forward | o, i, f, g, c backward]`` (``c``: the cell state before the step), so that most
    of the element-wise work of both directions is one call each."""

    def __init__(self, head: Any) -> None:
        dt, T = head.dtype, head.steps
        self.head, self.T = head, T
        self.one, self.zero = dt.type(1.0), dt.type(0.0)
        self.layers = []
        prev = None
        for li, ly in enumerate(head.layers):
            aug, c_in, wp = ly.aug, ly.kernel.shape[0] - ly.aug, ly.kernel.shape[1]
            (n0, n1), (d0, d1) = ly.nk, ly.nd
            proj = np.zeros((T, wp), dt)                        # the input projections
            gates, drops, copies = [], [], []
            for d, (nk, nd, off) in enumerate(zip(ly.nk, ly.nd, ly.off)):
                lo_g, lo_d = (0, 4 * nk) if d == 0 else (nd, 0)     # in this direction's columns
                for lo, n, out in ((lo_g, 4 * nk, gates), (lo_d, nd, drops)):
                    a = np.zeros((T + nk, n), dt)                   # [the steps' projections |
                    a[T:] = ly.recurrent[d][:, lo:lo + n]           #  the recurrent rows]
                    out.append(a)
                    if n:
                        copies.append((a[:T], proj[:, off + lo:off + lo + n]))
            v_all = np.zeros((2, T + 1, T + max(n0, n1)), dt)   # v_all[:, 0, T:] stays 0
            b = 5 * n0
            z_all = np.zeros((T + 1, b + 5 * n1), dt)
            guard = np.zeros((2, T, max(d0, d1)), dt)          # the dropped units' g, all steps
            # per direction: where its gates go in a row of z_all, the cell state before
            # ([c | g] / [f | i] forward, [g | c] / [i | f] backward), o
            at = [(n0, b), (b, b + 4 * n1)]
            cell = [(0, n0, 3 * n0, 0, 2 * n0, 4 * n0),         # c, g, i, dividend, divisor, o
                    (b + 4 * n1, b + 3 * n1, b + n1, b + 3 * n1, b + n1, b)]
            steps = []
            for s in range(T):
                z, znext = z_all[s], z_all[s + 1]
                per_d = []
                for d, nk in enumerate(ly.nk):
                    t = s if d == 0 else T - 1 - s                 # the step's time
                    v_all[d, s, t] = 1
                    c, g, i, dvd, dvs, o = cell[d]
                    per_d.append(_DirStep(
                        vrow=v_all[d, s, t:], h=v_all[d, s, T:T + nk], rows=gates[d][t:],
                        z=z[at[d][0]:at[d][1]], x0=gates[d][t],
                        g=z[g:g + nk], i=z[i:i + nk],
                        dividend=z[dvd:dvd + 2 * nk], divisor=z[dvs:dvs + 2 * nk],
                        c_part=z[dvd:dvd + nk], g_part=z[dvd + nk:dvd + 2 * nk],
                        c=znext[c:c + nk], o=z[o:o + nk], h_next=v_all[d, s + 1, T:T + nk],
                        d=d, base=T - t))
                steps.append((z[2 * n0:b + 3 * n1], z[n0:b + 4 * n1], per_d))   # sigmoids; g..g
            guards = [(d, v_all[d, :T], drops[d], guard[d, :, :nd])
                      for d, nd in enumerate(ly.nd) if nd]
            if li == 0:     # the kept global features at each time, then the dropped ones
                idx = np.concatenate([(np.arange(T)[:, None] * head.n_global + ly.src_pos).ravel(),
                                      (np.arange(T)[:, None] * head.n_global + head.g_drop).ravel()])
                xb = np.empty(idx.size, dt)
                extra = None
            else:           # the previous layer's states, and a last column that is always 0
                pv = prev.shape
                idx = (ly.src_d * pv[1] + ly.src + 1) * pv[2] + T + ly.src_pos
                idx = np.concatenate([idx, np.full((T, 1), T, np.intp)], axis=1)   # prev[0, 0, T]
                xb = np.empty(idx.shape, dt)
                extra = self._weights(ly.n_in, c_in, (T,))
            xa = np.zeros((T, aug + c_in), dt)
            xa[:, 0] = 1
            self.layers.append(_RunLayer(ly, proj, v_all, xa, idx, xb, steps, extra, guards, guard,
                                         copies))
            prev = v_all
        src_d, src_pos, n = head.head_src
        self.h_idx = np.concatenate([(src_d * prev.shape[1] + T) * prev.shape[2] + T + src_pos,
                                     [T]])[None]
        self.h_x = np.empty(self.h_idx.shape, dt)
        self.h_xa = np.zeros((1, 1 + self.h_idx.shape[1]), dt)
        self.h_xa[0, 0] = 1
        self.h_extra = self._weights(n, src_pos.size, (1,))
        self.h_y = np.empty(head.head_w.shape[1], dt)

    def _weights(self, n: int, c: int, shape: tuple) -> tuple:
        """LayerNorm over ``n`` units, ``c`` of them in the buffer (and one more column, always
        0, for the ``n - c`` zeros): the weights of the mean and of the variance, and buffers."""
        dt = self.head.dtype
        wmean = np.zeros(c + 1, dt)
        wmean[:c] = 1.0 / n
        wvar = wmean.copy()
        wvar[c] = (n - c) / n               # (0 - mean)^2 of each unit that is 0
        return (wmean, wvar, np.empty(shape, dt), np.empty(shape, dt),
                np.empty(shape + (c + 1,), dt))

    def _fold(self, x: np.ndarray, xa: np.ndarray, extra: tuple) -> None:
        """``xa[..., 1:] = [mean * rstd | x * rstd]``: LayerNorm of ``x (..., C + 1)`` (its last
        column 0) to fold into the next product."""
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

    def __call__(self, f: np.ndarray, marks: list | None = None) -> tuple[np.ndarray, np.ndarray]:
        head, T, one, zero = self.head, self.T, self.one, self.zero
        exp, add, div, maximum, matmul, copyto = (np.exp, np.add, np.divide, np.maximum,
                                                  np.matmul, np.copyto)
        prev_v = self.layers[0].v_all   # the states of the layer before (BiLSTM 1: unused)
        for li, run in enumerate(self.layers):
            ly, proj, v_all, xa, idx, xb = run.ly, run.proj, run.v_all, run.xa, run.idx, run.xb
            aug = ly.aug
            if li == 0:
                f.take(idx, mode="clip", out=xb)
                n = xa.shape[0] * (xa.shape[1] - 1)
                x = xb[:n].reshape(T, -1)
                if head.g_drop.size and xb[n:].any():
                    return self._flagged()
                copyto(xa[:, 1:], x)
            else:
                prev_v.take(idx, mode="clip", out=xb)
                self._fold(xb, xa, run.extra)
                x = xb[:, :-1]
            nz = x.any(axis=0).nonzero()[0]
            if marks is not None:
                marks.append((f"BiLSTM {li + 1} input" + (" (LayerNorm folded)" if li else ""),
                              time.perf_counter()))
            head._project(ly, xa, aug + 1 + nz[-1] if len(nz) else aug, proj)
            for dst, src in run.copies:
                copyto(dst, src)
            if marks is not None:
                marks.append((f"BiLSTM {li + 1} input projection", time.perf_counter()))
            used = [0, 0]           # state units the guards read: up to the longest state
            for s, (sig, gg, per_d) in enumerate(run.steps):
                if s == 0:
                    for p in per_d:                 # the step's input projection
                        copyto(p.z, p.x0)
                else:
                    for p in per_d:
                        nz = p.h.nonzero()[0]
                        n = 1 + nz[-1] if len(nz) else 0     # units up to the last non-zero
                        if n > used[p.d]:
                            used[p.d] = n
                        matmul(p.vrow[:p.base + n], p.rows[:p.base + n], out=p.z)
                exp(sig, out=sig)           # 1 + exp(-x) of o, i, f of both directions
                add(sig, one, out=sig)
                maximum(gg, zero, out=gg)   # relu(g) (the sigmoids between are >= 1)
                if s == 0:                  # c = relu(g) / (1 + exp(-i)), h = c / (1 + exp(-o))
                    for p in per_d:
                        div(p.g, p.i, out=p.c)
                        div(p.c, p.o, out=p.h_next)
                else:                       # c = relu(g) / (..i) + c / (..f)
                    for p in per_d:
                        div(p.dividend, p.divisor, out=p.dividend)
                        add(p.c_part, p.g_part, out=p.c)
                        div(p.c, p.o, out=p.h_next)
            if marks is not None:
                marks.append((f"BiLSTM {li + 1} steps", time.perf_counter()))
            for d, vg, drop, out in run.guards:     # the dropped units' g at every step
                matmul(vg[:, :T + used[d]], drop[:T + used[d]], out=out)
            if run.guards and not run.guard.max() <= 0:
                return self._flagged()       # a dropped unit would wake up (or NaN)
            if not v_all[:, 1:, T:].max() < head.limit:
                return self._flagged()
            if marks is not None:
                marks.append((f"BiLSTM {li + 1} guards", time.perf_counter()))
            prev_v = v_all
        x = prev_v.take(self.h_idx, mode="clip", out=self.h_x)
        xa = self.h_xa
        self._fold(x, xa, self.h_extra)
        nz = x[0, :-1].nonzero()[0]
        k = 3 + nz[-1] if len(nz) else 2
        y = np.dot(xa[0, :k], head.head_w[:k], out=self.h_y)
        exp(y, out=y)
        add(y, one, out=y)
        out = div(one, y)[None]
        s = out.sum()
        if marks is not None:
            marks.append(("LayerNorm and dense head", time.perf_counter()))
        return out, np.array([s == s])

    def _flagged(self) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros((1, self.h_y.size), self.head.dtype), np.zeros(1, bool)


__all__ = ["OneWindow"]
