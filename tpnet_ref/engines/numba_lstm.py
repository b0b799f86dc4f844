"""The Numba engine's prediction network: the BiLSTMs (gates, recurrence, the LayerNorm folded
into the next projection), the last LayerNorm and the output layer, compiled as one function
(:func:`head_serial`, :func:`head_parallel`), and BiLSTM 1's input projection
(:func:`project_serial`, :func:`project_parallel`); :mod:`tpnet_ref.engines.numba_engine` lays the
weights out and calls them.

Argument names (every kernel below; rows are time-major, row t*B + b; each direction's gates
i, f, c, o have u columns each, padded with zeros to N, whole 64-byte vectors)::

    d             the direction: 0 forward, 1 backward
    u, steps, bsz units per direction, T steps, B windows
    x             a layer's input rows (T*B, C): the previous layer's output times LayerNorm's
                  gamma (ReLU: the LayerNorm folded into the product), or its LayerNorm output
                  (tanh); no rows for BiLSTM 1 (projected before)
    kern, kernel  both directions' input kernels (2, C, N)
    rec           both directions' recurrent matrices (2, u, N), row k what h[k] adds to the
                  pre-activations (in _recur_dir: one direction's)
                  (weights in two planes: 2C or 2u rows, tpnet_ref.weights.quantize.wide_names;
                  int8's multiply [x, x * 2^-8] (planes), bf16's x, widened in the kernel)
    gk, cst       (2, N): gamma_{l-1} @ K_l and beta_{l-1} @ K_l + bias_l (the fold), or unused
                  and bias_l (no fold); bias: BiLSTM 1's (2, N)
    rr, rmu       per row, 1 / sqrt(var + eps) and rr * mean of the previous layer's output
                  (the fold; empty: no fold)
    xs, out       each direction's input projection with bias (T*B, 2, N)
    hs            the layer's output h (T*B, 2u): forward at columns 0 .. u-1, backward at
                  u .. 2u-1
    src           rows to normalise; gamma, beta: LayerNorm's scale and shift
    ab, z         one window's pre-activations from the recurrent product and from the input
                  projection; c, h: its cell state and its output
    relu          ReLU cell and output (else tanh)
    one, zero     1 and 0 in the model's dtype; eps: LayerNorm's epsilon
    limit         the ReLU output at which a layer counts as overflowed; li: the layer's index;
                  bad: 0, or 1 + the first layer that overflowed
    xp1 ... head_b  the whole network: BiLSTM 1's projection, per-layer tuples (kernels, recs,
                  gks, csts, units, gammas, betas) and the output layer (head_w, head_b)
    t             _exp_neg's exponent, <= 0
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ..extras import require

numba = require("numba", "metrics", "the Numba inference engine (engine='numba')")
from llvmlite import ir  # noqa: E402
from numba import njit, prange, types  # noqa: E402
from numba.extending import intrinsic, overload  # noqa: E402

from .numba_products import GROUP_ROWS, active, groups, product  # noqa: E402
from .numba_tiles import TILE_BATCH, product_rows, project_dir  # noqa: E402

@intrinsic
def _pow2_of(typingctx, k):
    """``2 ** n`` for a float ``k = n + 1.5 * 2 ** mant`` (``n`` an integer in ``k``'s low
    mantissa bits, the float's exponent range): the bits, no conversion (so a loop of it
    vectorises, and a NaN ``k`` gives some number, not undefined behaviour)."""
    if not isinstance(k, types.Float):
        return None

    def codegen(context, builder, signature, args):
        bits = k.bitwidth
        ity = ir.IntType(bits)
        mant, bias = (23, 127) if bits == 32 else (52, 1023)
        ftype, itype = (np.float32, np.int32) if bits == 32 else (np.float64, np.int64)
        shift = int(np.array(1.5 * 2.0 ** mant, dtype=ftype).view(itype))
        n = builder.sub(builder.bitcast(args[0], ity), ir.Constant(ity, shift))
        e = builder.shl(builder.add(n, ir.Constant(ity, bias)), ir.Constant(ity, mant))
        return builder.bitcast(e, context.get_value_type(k))

    return k(k), codegen


def _exp_neg(t):
    """``exp(t)`` for ``t <= 0`` (or NaN), branch-free so that the gate loops vectorise (libm's
    ``exp`` is a call per number); compiled per dtype below."""


def _exp_neg_impl(dtype: Any, lowest: float, ln2_hi: float, ln2_lo: float, degree: int):
    """``exp(t)`` for ``t <= 0`` in ``dtype``: ``t = n ln2 + r`` (Cody-Waite, ``|r| <= ln2/2``),
    ``exp(r)`` by its Taylor polynomial of ``degree`` (truncation below half an ulp), times
    ``2 ** n``; 0 below ``lowest`` (where ``exp`` leaves the normal range); within 1.5 ulp
    (``tests/test_engines_numba.py``)."""
    f = np.dtype(dtype).type
    log2e, shifter = f(1 / np.log(2.0)), f(1.5 * 2.0 ** np.finfo(dtype).nmant)
    lo, hi_, lo_ = f(lowest), f(ln2_hi), f(ln2_lo)
    coef = tuple(f(1 / np.prod(np.arange(1.0, i + 1))) for i in range(degree, -1, -1))
    zero = f(0)

    def impl(t):
        tc = lo if t < lo else t               # NaN stays NaN
        k = tc * log2e + shifter               # n rounded, in k's low bits
        n = k - shifter
        r = (tc - n * hi_) - n * lo_
        p = coef[0]
        for c in coef[1:]:
            p = p * r + c
        e = p * _pow2_of(k)
        return zero if t < lo else e

    return impl


_EXP_NEG = {types.float32: _exp_neg_impl(np.float32, -87.336, 0.693359375, -2.12194440e-4, 7),
            types.float64: _exp_neg_impl(np.float64, -708.396, 6.93147180369123816490e-01,
                                         1.90821492927058770002e-10, 13)}


@overload(_exp_neg)
def _exp_neg_overload(t):
    return _EXP_NEG.get(t)


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _sigmoid(x, one):
    """The logistic function, never overflowing: ``1 / (1 + e)`` or ``e / (1 + e)`` with
    ``e = exp(-|x|)`` (one division, the numerator selected: vectorises)."""
    pos = x >= 0
    e = _exp_neg(-x if pos else x)         # not abs(): numba's goes through float64
    return (one if pos else e) / (one + e)


@njit(cache=True, nogil=True, inline="always")
def _act(x, relu, zero):
    if relu:
        return zero if x < zero else x
    return np.tanh(x)


def _gates_impl(relu):
    """The gates of every unit from its pre-activations ``ab + z`` (both ``(>= 4u,)``, gates
    i, f, c, o of ``u`` columns each), updating the cell ``c (u,)`` and writing ``h (u,)``.
    Vectorised: unsigned indices (no negative-index wrap-around), the activation fixed per
    compiled loop."""

    def gates(ab, z, c, h, u, one):
        zero = one - one
        n1 = np.uint64(u)
        n2, n3 = n1 + n1, n1 + n1 + n1
        for j in range(n1):
            zi = ab[j] + z[j]
            zf = ab[j + n1] + z[j + n1]
            zc = ab[j + n2] + z[j + n2]
            zo = ab[j + n3] + z[j + n3]
            cc = _sigmoid(zf, one) * c[j] + _sigmoid(zi, one) * _act(zc, relu, zero)
            c[j] = cc
            h[j] = _sigmoid(zo, one) * _act(cc, relu, zero)

    return njit(cache=True, nogil=True, error_model="numpy")(gates)


_gates_relu = _gates_impl(True)
_gates_tanh = _gates_impl(False)


@njit(cache=True, nogil=True, error_model="numpy")
def _recur_dir(xs, d, rec, rsc, hs, u, steps, bsz, relu, one):
    """One direction's recurrence over ``steps`` steps of ``bsz`` windows.

    ``xs[:, d] (T*B, N)`` this direction's input projections with bias (row ``t*B + b``, gates
    i, f, c, o of ``u`` columns, then padding), ``rec (u, N)`` the recurrent matrix (row ``k``:
    what ``h[k]`` adds to the pre-activations), ``hs (T*B, 2u)`` receives ``h`` at columns
    ``d*u ..`` (Keras's re-aligned backward output: row ``t`` of the backward direction is its
    state after consuming steps ``T-1 .. t``). Windows go in groups of ``GROUP_ROWS``; each
    step reads only the rows of ``rec`` that a non-zero ``h[k]`` of the group multiplies
    (batches of ``TILE_BATCH`` windows or more: :func:`product_rows`' 4-row tiles);
    ``rsc (N,)``: int8 weights' scale per column, applied to the sum (empty: none)."""
    dt = hs.dtype
    h = np.zeros((bsz, u), dtype=dt)
    c = np.zeros((bsz, u), dtype=dt)
    acc = np.zeros((bsz, rec.shape[1]), dtype=dt)
    grp = groups(1, bsz, False)
    act = np.empty((grp.shape[0], rec.shape[0]), dtype=np.intp)
    ns = np.empty(grp.shape[0], dtype=np.intp)
    hin = h if rec.shape[0] == u or not _int8(rec) else np.zeros((bsz, rec.shape[0]), dtype=dt)
    for s in range(steps):
        t = s if d == 0 else steps - 1 - s
        if s > 0 and bsz >= TILE_BATCH:       # h = 0 at the first step
            planes(h, hin)
            product_rows(hin[:, :], rec, act[0], acc[:, :])
            scale_rows(acc, rsc)
        elif s > 0:
            planes(h, hin)
            active(hin[:, :], grp, act, ns)
            product(hin[:, :], rec, grp, act, ns, acc[:, :])
            scale_rows(acc, rsc)
        for b in range(bsz):
            row = t * bsz + b
            if relu:
                _gates_relu(acc[b], xs[row, d], c[b], h[b], u, one)
            else:
                _gates_tanh(acc[b], xs[row, d], c[b], h[b], u, one)
            hb = h[b]
            for k in range(u):                # a loop, not a slice copy: no shape check to
                hs[row, d * u + k] = hb[k]    # compile (its error message costs ~1 s to build)


def _int8(w):
    """Whether the weights ``w`` are int8 codes (known when compiled)."""


@overload(_int8)
def _int8_overload(w):
    flag = isinstance(w, types.Array) and w.dtype == types.int8
    return lambda w: flag


@njit(cache=True, nogil=True, inline="always")
def planes(x, xin):
    """Two int8 planes' input: ``xin (R, 2C) = [x, x * 2^-8]`` (exact), for weights stored as
    ``q_hi`` rows then ``q_lo`` rows (:func:`tpnet_ref.weights.quantize.wide_names`); nothing
    when ``xin`` is ``x`` (one plane, or bf16's two planes, which the kernel widens into one
    weight: the same width)."""
    n = x.shape[1]
    if xin.shape[1] == 2 * n:
        for r in range(x.shape[0]):
            for k in range(n):
                v = x[r, k]
                xin[r, k] = v
                xin[r, n + k] = v * 0.00390625         # exact: 2^-8


@njit(cache=True, nogil=True, inline="always")
def _widened(x, w):
    """``x (R, C)`` as the input of weight matrices ``w (2, rows, N)``: ``x`` itself, or its
    two planes (:func:`planes`) when ``w`` is int8 and ``rows == 2C``."""
    rows = w.shape[1]
    if rows == x.shape[1] or not _int8(w):
        return x
    xin = np.empty((x.shape[0], rows), dtype=x.dtype)
    planes(x, xin)
    return xin


@njit(cache=True, nogil=True, inline="always")
def scale_rows(out, sc):
    """``out[r, :] *= sc`` for every row of ``out (R, N)`` (int8 weights' scales, one per output
    column); nothing for an empty ``sc`` (float weights)."""
    if sc.shape[0] > 0:
        for r in range(out.shape[0]):
            o = out[r]
            for q in range(sc.shape[0]):
                o[q] *= sc[q]


@njit(cache=True, nogil=True)
def _finish_dir(out, d, rr, rmu, gk, cst):
    """``out[r, d] = rr[r] * out[r, d] - rmu[r] * gk + cst`` (the LayerNorm folded into the
    product: ``rr = 1 / sqrt(var + eps)``, ``rmu = rr * mean``, ``gk = gamma @ K``,
    ``cst = beta @ K + bias``); with ``rr`` empty (no fold), ``out[r, d] += cst``."""
    fold = rr.shape[0] > 0
    for r in range(out.shape[0]):
        o = out[r, d]
        if fold:
            a, m = rr[r], rmu[r]
            for q in range(o.shape[0]):
                o[q] = a * o[q] - m * gk[q] + cst[q]
        else:
            for q in range(o.shape[0]):
                o[q] += cst[q]


@njit(cache=True, nogil=True)
def _norm_rows(src, gamma, beta, relu, li, limit, one, eps, x, rr, rmu, bad):
    """LayerNorm statistics of each row of ``src (R, 2u)`` (float64 sums, the mean and
    ``1 / sqrt(var + eps)`` rounded to the model's dtype), and ``bad`` set to ``li + 1`` (if
    still 0) when a ReLU output reached ``limit`` (or is NaN). With ``rr`` of length ``R``
    (the fold): ``x = src * gamma``, ``rr``, ``rmu = rr * mean``; else ``x = LN(src)``."""
    cast = np.empty(1, dtype=src.dtype)
    n = src.shape[1]
    fold = rr.shape[0] > 0
    for r in range(src.shape[0]):
        row = src[r]
        s1 = 0.0
        for q in range(n):
            v = row[q]
            if relu and not v < limit:
                bad = li + 1 if bad == 0 else bad
            s1 += v
        cast[0] = s1 / n                     # the mean in the model's dtype
        mean = cast[0]
        s2 = 0.0
        for q in range(n):
            dv = row[q] - mean
            s2 += dv * dv
        cast[0] = s2 / n
        cast[0] = one / np.sqrt(cast[0] + eps)
        rstd = cast[0]
        if fold:
            for q in range(n):
                x[r, q] = row[q] * gamma[q]
            rr[r] = rstd
            rmu[r] = rstd * mean
        else:
            for q in range(n):
                x[r, q] = (row[q] - mean) * rstd * gamma[q] + beta[q]
    return bad


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _layer_dir(d, x, kern, ksc, gk, cst, rr, rmu, xs, rec, rsc, hs, u, steps, bsz, relu, one):
    """Direction ``d`` of one BiLSTM: its input projection of ``x`` into ``xs[:, d]`` (unless
    ``x`` has no rows: BiLSTM 1's, computed by :meth:`NumbaHead.project`), then its
    recurrence into ``hs``. ``kern``, ``gk``, ``cst``, ``rec``: both directions' (axis 0);
    ``ksc``, ``rsc``: their int8 scales ``(2, N)`` (``(2, 0)``: float weights)."""
    if x.shape[0] > 0:
        project_dir(_widened(x, kern), kern[d], xs[:, d], steps, bsz)
        scale_rows(xs[:, d], ksc[d])
        _finish_dir(xs, d, rr, rmu, gk[d], cst[d])
    _recur_dir(xs, d, rec[d], rsc[d], hs, u, steps, bsz, relu, one)


def _head_impl(parallel: bool):
    """The prediction network after BiLSTM 1's input projection, compiled once one thread
    (``head_serial``) and once with each layer's two directions on two threads
    (``head_parallel``): ``head(xp1, kernels, recs, kscs, rscs, gks, csts, units, gammas, betas,
    head_w, head_b, steps, bsz, relu, one, eps, limit)`` -> ``(y (B, n_out*dim), bad)``;
    ``kscs[l]``, ``rscs[l]`` ``(2, N)``: the int8 scales of ``kernels[l]`` and ``recs[l]``
    (``(2, 0)``: float or bf16 weights, nothing applied).

    ``xp1 (T*B, 2, N)``: row ``t*B + b``, bias included, ``N`` = ``4u`` padded to whole vectors;
    ``bad`` is ``l + 1`` when the ReLU output of layer ``l`` reached ``limit`` (or NaN), else 0
    (the caller raises). ``kernels[l]`` ``(2, C, N)``, ``recs[l]`` ``(2, u, N)``,
    ``gks[l]``/``csts[l]`` ``(2, N)``: ``gamma_{l-1} @ K_l`` and ``beta_{l-1} @ K_l + bias_l``
    (ReLU: LayerNorm folded), or unused and ``bias_l`` (tanh).

    Two functions of their own names, each with its ``prange`` inside: numba's cache keeps one
    compiled version per function and signature whatever its ``parallel`` flag, and a cached
    function that calls a ``parallel=True`` one is what numba cannot cache safely (numba
    issues 4807 and 10128: the caller can name the callee's code otherwise than the cached
    callee does, and a later process crashed once networks of two depths had been compiled).
    Here no compiled function calls a parallel one. The direction goes on as ``np.int64(d)``:
    a parallel ``prange``'s index is unsigned, and the callees would be compiled once more for
    it."""

    def head(xp1, kernels, recs, kscs, rscs, gks, csts, units, gammas, betas, head_w, head_b,
             steps, bsz, relu, one, eps, limit):
        dt = xp1.dtype
        nl = len(recs)
        rows = steps * bsz
        bad = 0
        xs = xp1
        x = np.empty((0, 1), dtype=dt)                     # the next layer's input
        rr = np.empty(rows if relu else 0, dtype=dt)
        rmu = np.empty(rows if relu else 0, dtype=dt)
        hs = np.empty((rows, 1), dtype=dt)
        for li in range(nl):
            rec = recs[li]                                  # (2, u, N)
            u = units[li]
            if li > 0:
                xs = np.empty((rows, 2, rec.shape[2]), dtype=dt)
            hs = np.empty((rows, 2 * u), dtype=dt)
            kern, gk, cst = kernels[li], gks[li], csts[li]
            for d in prange(2):                             # range where not parallel
                _layer_dir(np.int64(d), x, kern, kscs[li], gk, cst, rr, rmu, xs, rec, rscs[li],
                           hs, u, steps, bsz, relu, one)
            if li < nl - 1:
                x = np.empty((rows, 2 * u), dtype=dt)
                bad = _norm_rows(hs, gammas[li], betas[li], relu, li, limit, one, eps, x, rr,
                                 rmu, bad)
        # last layer: forward state at T-1, backward at 0, LayerNorm, head
        u = hs.shape[1] // 2
        src = np.empty((bsz, 2 * u), dtype=dt)
        for b in range(bsz):
            for q in range(u):
                src[b, q] = hs[(steps - 1) * bsz + b, q]
                src[b, u + q] = hs[b, u + q]
        last = np.empty((bsz, 2 * u), dtype=dt)
        bad = _norm_rows(src, gammas[nl - 1], betas[nl - 1], relu, nl - 1, limit, one, eps, last,
                         rr[:0], rmu[:0], bad)
        n = head_w.shape[1]
        res = np.zeros((bsz, n), dtype=dt)
        for b in range(bsz):
            for q in range(head_w.shape[0]):
                v = last[b, q]
                for o in range(n):
                    res[b, o] += v * head_w[q, o]
            for o in range(n):
                res[b, o] = _sigmoid(res[b, o] + head_b[o], one)
        return res, bad

    head.__name__ = head.__qualname__ = "head_parallel" if parallel else "head_serial"
    return njit(cache=True, nogil=True, parallel=parallel, error_model="numpy")(head)


head_serial = _head_impl(False)
head_parallel = _head_impl(True)


@njit(cache=True, nogil=True, inline="always")
def _project_one(d, x, kernel, ksc, bias, out, steps, bsz):
    empty = bias[0, :0]
    project_dir(_widened(x, kernel), kernel[d], out[:, d], steps, bsz)
    scale_rows(out[:, d], ksc[d])
    _finish_dir(out, d, empty, empty, empty, bias[d])


@njit(cache=True, nogil=True)
def project_serial(x, kernel, ksc, bias, out, steps, bsz):
    """BiLSTM 1's input projection of the ``T*B`` time-major rows ``x`` -> ``out (R, 2, N)``
    (int8 scales ``ksc (2, N)`` applied unless empty, bias added)."""
    for d in range(2):
        _project_one(d, x, kernel, ksc, bias, out, steps, bsz)


@njit(cache=True, nogil=True, parallel=True)
def project_parallel(x, kernel, ksc, bias, out, steps, bsz):
    """:func:`project_serial`, the directions on two threads."""
    for d in prange(2):
        _project_one(np.int64(d), x, kernel, ksc, bias, out, steps, bsz)


__all__ = ["head_serial", "head_parallel", "project_serial", "project_parallel"]
