"""The Numba engine (``load()``'s default where numba is installed): TP-Net's prediction
network (BiLSTMs, LayerNorms, head) as one compiled function, :class:`NumbaHead`, for every
batch, and its feature extractor as another, :class:`NumbaFeatures`, for batches of up to
:data:`tpnet_ref.engines.interface.ENGINE_MAX_BATCH` windows. ``TPNet(..., engine="numba")`` or
``model.with_engine("numba")``; needs numba (the ``metrics`` extra). The NumPy path
(:func:`tpnet_ref.engines.layers.bilstm_steps`, :func:`tpnet_ref.engines.layers.project_layer_norm`,
:class:`tpnet_ref.engines.numpy_engine.NumpyFeatures`, specified by :mod:`tpnet_ref.engines.reference`) is the
reference; ``tests/test_engines_numba.py`` checks they agree.

What it does that NumPy cannot:

- one call per prediction instead of ~100 NumPy calls (plus one for BiLSTM 1's input
  projection, which a rollout computes once per frame): the gates, cell and output of each unit
  are computed right after their pre-activations, LayerNorm and head included;
- every product reads only the weight rows that a non-zero input multiplies, each one, not all
  rows up to the last used one (a ReLU network's activations are mostly zeros): BiLSTM 1's
  input projection (the global features, ~80 % zeros on the scene), every recurrent product
  (the state ``h``), and BiLSTM 2's and 3's input projections, whose input is a LayerNorm output
  (no zeros): LayerNorm is affine per row, so with ``r = 1 / sqrt(var + eps)`` and the row mean
  ``mu``, ``LN(h) @ K = r * ((h * gamma) @ K) - r * mu * (gamma @ K) + beta @ K``, and
  ``h * gamma`` has ``h``'s zeros (``gamma @ K`` and ``beta @ K + bias`` computed at load in
  float64). With tanh (no zeros) LayerNorm is applied first, then the plain product;
- the products stream whole weight rows: a kernel written in LLVM IR (:func:`_row_kernel`)
  reads :data:`CHAIN` of the needed rows side by side, each sequentially (what the hardware
  prefetcher streams best: a window's products mostly read weights from memory), and adds
  them into up to :data:`GROUP_ROWS` accumulator rows (a window's m steps share their
  non-zero inputs, so at B = 1 each needed weight row is read once per layer and direction);
- the weights are laid out at load, each matrix row-major with its gate columns padded to
  whole 64-byte vectors, in the model's unit order when given one (:mod:`tpnet_ref.engines.unit_order`:
  the rows a window needs lie closer together; a few percent here, as the rows are streamed
  one by one anyway);
- the gates are vectorised (a branch-free ``exp``, :func:`_exp_neg`, within 1.5 ulp);
- with ``parallel``, the two directions of a layer on two threads (``prange``), only beside a
  one-thread BLAS (:func:`_two_threads`).

Determinism: each output number is one chain of fused multiply-adds (``llvm.fma``, explicit,
not left to the compiler) over its group's non-zero inputs in increasing order, starting from
+0. An input that is zero in this row but not in another row of its group adds
``fma(0, w, s) = s`` exactly (the weights are finite, and a sum that starts at +0 is never -0),
so a row's result is the same bits whatever the other rows of its group and however rows are
grouped: the result does not depend on the other windows of a batch, nor on the thread count
(each number is computed by one thread, by the same code); the canonical point order before the
extractor keeps permutation invariance exact. Element-wise work uses no fast-math flags.
Products accumulate in the model's dtype (as the BLAS does); LayerNorm statistics in float64.
"""
from __future__ import annotations

import threading
from typing import Any

import numpy as np

from . import compile_watch
from .blas import in_one_thread
from .thread_policy import two_threads
from ..checks import overflow_error
from ..extras import require

numba = require("numba", "metrics", "the Numba inference engine (engine='numba')")
from llvmlite import ir  # noqa: E402
from numba import njit, prange, types  # noqa: E402
from numba.core import cgutils  # noqa: E402
from numba.extending import intrinsic, overload  # noqa: E402

#: weight rows each call of the product kernel streams together (a chain of this many fused
#: multiply-adds per accumulator load and store; 8 rows read side by side, each sequentially)
CHAIN = 8
#: input rows that share each weight row read (one window's m = 4 steps at B = 1); the
#: kernels below are instantiated for 1 .. 4 rows
GROUP_ROWS = 4
_VECTOR_BYTES = 64


def padded_columns(n: int, dtype: Any) -> int:
    """``n`` columns rounded up to whole vectors of ``dtype`` (64 bytes)."""
    lanes = _VECTOR_BYTES // np.dtype(dtype).itemsize
    return -(-n // lanes) * lanes


def pad_columns(w: np.ndarray, dtype: Any) -> np.ndarray:
    """``w (C, N)`` or ``(N,)`` with zero columns appended up to :func:`padded_columns`, in
    ``dtype``, C-contiguous."""
    n = w.shape[-1]
    out = np.zeros(w.shape[:-1] + (padded_columns(n, dtype),), dtype=dtype)
    out[..., :n] = w
    return out


# ------------------------------------------------------------------ the product kernel

def _row_kernel(rows: int, chain: int):
    """An intrinsic ``k(x, r0, rstep, w, act, j0, out)``: for the rows ``r = r0 + i * rstep``,
    ``i < rows``, ``out[r, :] = fma(x[r, k_last], w[k_last], ... fma(x[r, k_0], w[k_0], out[r]))``
    over the ``chain`` weight rows ``k = act[j0 .. j0 + chain - 1]`` in that order, every column
    of ``w (C, N)`` (C-contiguous, ``N`` whole 64-byte vectors), ``out`` 2-D with contiguous
    rows. The ``chain`` weight rows are streamed side by side, each sequentially, one vector
    of each per step; each accumulator is loaded and stored once per call."""

    @intrinsic
    def kernel(typingctx, x, r0, rstep, w, act, j0, out):
        ok = (isinstance(x, types.Array) and isinstance(w, types.Array)
              and isinstance(out, types.Array) and x.ndim == w.ndim == out.ndim == 2
              and x.dtype == w.dtype == out.dtype and w.layout == "C"
              and isinstance(x.dtype, types.Float) and isinstance(act, types.Array))
        if not ok:
            return None
        sig = types.void(x, r0, rstep, w, act, j0, out)

        def codegen(context, builder, signature, args):
            xt, wt, at, ot = (signature.args[i] for i in (0, 3, 4, 6))
            xa, wa, aa, oa = (context.make_array(t)(context, builder, v) for t, v in
                              ((xt, args[0]), (wt, args[3]), (at, args[4]), (ot, args[6])))
            r0i, rs, j0i = (context.cast(builder, args[i], signature.args[i], types.intp)
                            for i in (1, 2, 5))
            elt = context.get_value_type(xt.dtype)
            size = xt.dtype.bitwidth // 8
            lanes = _VECTOR_BYTES // size
            vty = ir.VectorType(elt, lanes)
            intp = context.get_value_type(types.intp)
            i8p = ir.IntType(8).as_pointer()
            fma = cgutils.get_or_insert_function(
                builder.module, ir.FunctionType(vty, [vty] * 3), f"llvm.fma.v{lanes}f{size * 8}")
            undef = ir.Constant(vty, ir.Undefined)
            splat = ir.Constant(ir.VectorType(ir.IntType(32), lanes), [0] * lanes)
            i32_0 = ir.Constant(ir.IntType(32), 0)
            ncol = builder.extract_value(wa.shape, 1)

            def row_ptr(arr, row):       # element pointer of arr[row, 0] (byte strides)
                stride = builder.extract_value(arr.strides, 0)
                p = builder.gep(builder.bitcast(arr.data, i8p), [builder.mul(row, stride)])
                return builder.bitcast(p, elt.as_pointer())

            rowi = [builder.add(r0i, builder.mul(rs, ir.Constant(intp, r))) for r in range(rows)]
            xrows = [row_ptr(xa, r) for r in rowi]
            orows = [row_ptr(oa, r) for r in rowi]
            ks = [builder.load(builder.gep(aa.data, [builder.add(j0i, ir.Constant(intp, q))]))
                  for q in range(chain)]
            wrows = [builder.gep(wa.data, [builder.mul(k, ncol)]) for k in ks]
            avs = [[builder.shuffle_vector(builder.insert_element(
                undef, builder.load(builder.gep(xr, [k])), i32_0), undef, splat) for k in ks]
                for xr in xrows]
            nvec = builder.udiv(ncol, ir.Constant(intp, lanes))
            with cgutils.for_range(builder, nvec) as loop:
                off = builder.mul(loop.index, ir.Constant(intp, lanes))
                ws = [builder.load(builder.bitcast(builder.gep(wr, [off]), vty.as_pointer()),
                                   align=size) for wr in wrows]
                for r in range(rows):
                    p = builder.bitcast(builder.gep(orows[r], [off]), vty.as_pointer())
                    acc = builder.load(p, align=size)
                    for q in range(chain):
                        acc = builder.call(fma, [avs[r][q], ws[q], acc])
                    builder.store(acc, p, align=size)
            return context.get_dummy_value()

        return sig, codegen

    return kernel


_KC = tuple(_row_kernel(r, CHAIN) for r in range(1, GROUP_ROWS + 1))
_K1 = tuple(_row_kernel(r, 1) for r in range(1, GROUP_ROWS + 1))
_KC1, _KC2, _KC3, _KC4 = _KC
_K11, _K12, _K13, _K14 = _K1


@njit(cache=True, nogil=True, inline="always")
def _groups(steps, bsz, per_window):
    """Row groups ``(first, stride, count)`` of ``T*B`` time-major rows (row ``t*B + b``):
    ``per_window``: each window's steps, up to ``GROUP_ROWS`` at a time (a window's steps
    share most of their non-zero inputs); else runs of up to ``GROUP_ROWS`` consecutive rows."""
    if per_window:
        chunks = -(-steps // GROUP_ROWS)
        grp = np.empty((bsz * chunks, 3), dtype=np.intp)
        for b in range(bsz):
            for ci in range(chunks):
                t0 = ci * GROUP_ROWS
                g = b * chunks + ci
                grp[g, 0] = t0 * bsz + b
                grp[g, 1] = bsz
                grp[g, 2] = min(GROUP_ROWS, steps - t0)
    else:
        rows = steps * bsz
        grp = np.empty((-(-rows // GROUP_ROWS), 3), dtype=np.intp)
        for gi in range(grp.shape[0]):
            grp[gi, 0] = gi * GROUP_ROWS
            grp[gi, 1] = 1
            grp[gi, 2] = min(GROUP_ROWS, rows - gi * GROUP_ROWS)
    return grp


@njit(cache=True, nogil=True, inline="always")
def _active(x, grp, act, ns):
    """For each row group ``(first, stride, count)`` of ``x (R, C)``, the columns ``k``
    non-zero (or NaN) in some row of the group, in increasing order, into ``act[group]``, and
    how many into ``ns[group]``."""
    for gi in range(grp.shape[0]):
        r0, rs, g = grp[gi, 0], grp[gi, 1], grp[gi, 2]
        a = act[gi]
        n = 0
        for k in range(x.shape[1]):
            for i in range(g):
                if x[r0 + i * rs, k] != 0:
                    a[n] = k
                    n += 1
                    break
        ns[gi] = n


@njit(cache=True, nogil=True, inline="always")
def _chain(x, r0, rs, g, w, act, j, out):
    """:func:`_row_kernel`'s ``CHAIN`` rows ``act[j ..]`` for a group of ``g`` rows."""
    if g == 4:
        _KC4(x, r0, rs, w, act, j, out)
    elif g == 3:
        _KC3(x, r0, rs, w, act, j, out)
    elif g == 2:
        _KC2(x, r0, rs, w, act, j, out)
    else:
        _KC1(x, r0, rs, w, act, j, out)


@njit(cache=True, nogil=True, inline="always")
def _single(x, r0, rs, g, w, act, j, out):
    """:func:`_row_kernel`'s single row ``act[j]`` for a group of ``g`` rows."""
    if g == 4:
        _K14(x, r0, rs, w, act, j, out)
    elif g == 3:
        _K13(x, r0, rs, w, act, j, out)
    elif g == 2:
        _K12(x, r0, rs, w, act, j, out)
    else:
        _K11(x, r0, rs, w, act, j, out)


@njit(cache=True, nogil=True)
def _product(x, w, grp, act, ns, out):
    """``out[r] = x[r] @ w`` for every row of ``x (R, C)`` in the groups ``grp``,
    ``w (C, N)``, ``out (R, N)``: each group streams the weight rows of its own non-zero inputs
    (:func:`_active`'s ``act``, ``ns``), ``CHAIN`` at a time, in increasing order, every
    column's sum one chain of fused multiply-adds from +0."""
    for gi in range(grp.shape[0]):
        r0, rs, g = grp[gi, 0], grp[gi, 1], grp[gi, 2]
        for i in range(g):
            out[r0 + i * rs, :] = 0
        a, n = act[gi], ns[gi]
        j = 0
        while j + CHAIN <= n:
            _chain(x, r0, rs, g, w, a, j, out)
            j += CHAIN
        while j < n:
            _single(x, r0, rs, g, w, a, j, out)
            j += 1


@njit(cache=True, nogil=True)
def _project_dir(x, kern, out, steps, bsz):
    """One direction's product ``out = x @ kern`` (no bias) for the ``T*B`` time-major rows of
    ``x``, each window's steps in groups reading only the kernel rows of their non-zero inputs."""
    grp = _groups(steps, bsz, True)
    act = np.empty((grp.shape[0], x.shape[1]), dtype=np.intp)
    ns = np.empty(grp.shape[0], dtype=np.intp)
    _active(x[:, :], grp, act, ns)        # [:, :]: every call of _product one layout
    _product(x[:, :], kern, grp, act, ns, out)


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
def _recur_dir(xs, d, rec, hs, u, steps, bsz, relu, one):
    """One direction's recurrence over ``steps`` steps of ``bsz`` windows.

    ``xs[:, d] (T*B, N)`` this direction's input projections with bias (row ``t*B + b``, gates
    i, f, c, o of ``u`` columns, then padding), ``rec (u, N)`` the recurrent matrix (row ``k``:
    what ``h[k]`` adds to the pre-activations), ``hs (T*B, 2u)`` receives ``h`` at columns
    ``d*u ..`` (Keras's re-aligned backward output: row ``t`` of the backward direction is its
    state after consuming steps ``T-1 .. t``). Windows go in groups of ``GROUP_ROWS``; each
    step reads only the rows of ``rec`` that a non-zero ``h[k]`` of the group multiplies."""
    dt = hs.dtype
    h = np.zeros((bsz, u), dtype=dt)
    c = np.zeros((bsz, u), dtype=dt)
    acc = np.zeros((bsz, rec.shape[1]), dtype=dt)
    grp = _groups(1, bsz, False)
    act = np.empty((grp.shape[0], u), dtype=np.intp)
    ns = np.empty(grp.shape[0], dtype=np.intp)
    for s in range(steps):
        t = s if d == 0 else steps - 1 - s
        if s > 0:                             # h = 0 at the first step
            _active(h[:, :], grp, act, ns)
            _product(h[:, :], rec, grp, act, ns, acc[:, :])
        for b in range(bsz):
            row = t * bsz + b
            if relu:
                _gates_relu(acc[b], xs[row, d], c[b], h[b], u, one)
            else:
                _gates_tanh(acc[b], xs[row, d], c[b], h[b], u, one)
            hb = h[b]
            for k in range(u):                # a loop, not a slice copy: no shape check to
                hs[row, d * u + k] = hb[k]    # compile (its error message costs ~1 s to build)


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
def _layer_dir(d, x, kern, gk, cst, rr, rmu, xs, rec, hs, u, steps, bsz, relu, one):
    """Direction ``d`` of one BiLSTM: its input projection of ``x`` into ``xs[:, d]`` (unless
    ``x`` has no rows: BiLSTM 1's, computed by :meth:`NumbaHead.project`), then its
    recurrence into ``hs``. ``kern``, ``gk``, ``cst``, ``rec``: both directions' (axis 0)."""
    if x.shape[0] > 0:
        _project_dir(x, kern[d], xs[:, d], steps, bsz)
        _finish_dir(xs, d, rr, rmu, gk[d], cst[d])
    _recur_dir(xs, d, rec[d], hs, u, steps, bsz, relu, one)


def _head_impl(parallel: bool):
    """The prediction network after BiLSTM 1's input projection, compiled once one thread
    (``_head_serial``) and once with each layer's two directions on two threads
    (``_head_parallel``): ``head(xp1, kernels, recs, gks, csts, units, gammas, betas, head_w,
    head_b, steps, bsz, relu, one, eps, limit)`` -> ``(y (B, n_out*dim), bad)``.

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
    Here no compiled function calls a parallel one."""

    def head(xp1, kernels, recs, gks, csts, units, gammas, betas, head_w, head_b, steps, bsz,
             relu, one, eps, limit):
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
                _layer_dir(d, x, kern, gk, cst, rr, rmu, xs, rec, hs, u, steps, bsz, relu, one)
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

    head.__name__ = head.__qualname__ = "_head_parallel" if parallel else "_head_serial"
    return njit(cache=True, nogil=True, parallel=parallel, error_model="numpy")(head)


_head_serial = _head_impl(False)
_head_parallel = _head_impl(True)


@njit(cache=True, nogil=True, inline="always")
def _project_one(d, x, kernel, bias, out, steps, bsz):
    empty = bias[0, :0]
    _project_dir(x, kernel[d], out[:, d], steps, bsz)
    _finish_dir(out, d, empty, empty, empty, bias[d])


@njit(cache=True, nogil=True)
def _project_serial(x, kernel, bias, out, steps, bsz):
    """BiLSTM 1's input projection of the ``T*B`` time-major rows ``x`` -> ``out (R, 2, N)``
    (bias added)."""
    for d in range(2):
        _project_one(d, x, kernel, bias, out, steps, bsz)


@njit(cache=True, nogil=True, parallel=True)
def _project_parallel(x, kernel, bias, out, steps, bsz):
    """:func:`_project_serial`, the directions on two threads."""
    for d in prange(2):
        _project_one(d, x, kernel, bias, out, steps, bsz)


# ------------------------------------------------------------------ the feature extractor

#: points of a frame that go through the per-point layers together (their activations stay in
#: cache; a frame's max is taken over its chunks, exact whatever the cut)
FEATURE_CHUNK = 64


@njit(cache=True, nogil=True, inline="always")
def _max_into(dst, src, n):
    """``dst[j] = max(dst[j], src[j])`` for ``j < n``, NaN kept (once NaN, NaN stays);
    branch-free, so it vectorises."""
    for j in range(n):
        v = src[j]
        p = dst[j]
        dst[j] = v if (v > p) | (v != v) else p


@njit(cache=True, nogil=True, error_model="numpy")
def _pool_points(pts, p0, p1, w0, b0, ws, bs, zero, pool):
    """The max over the points ``pts[p0:p1]`` of the per-point MLP's last products (before its
    bias and ReLU) into ``pool (1, C)`` (NaN kept: once NaN, NaN stays). The first layer
    ``w0 (dim, C0)`` directly; every later one (``ws``, ``bs``) by :func:`_product`, reading
    only the weight rows of each group of points' non-zero inputs, ReLU after each but the
    last. Points go through in chunks of :data:`FEATURE_CHUNK`; each point's numbers do not
    depend on the others, and a max does not depend on the order, so neither does ``pool``."""
    dt = pts.dtype
    nl = len(ws)
    c0 = w0.shape[1]
    dim = w0.shape[0]
    cmax = c0
    for li in range(nl):
        cmax = max(cmax, ws[li].shape[1])
    chunk = FEATURE_CHUNK
    a = np.empty((chunk, cmax), dtype=dt)
    b = np.empty((chunk, cmax), dtype=dt)
    act = np.empty(((chunk + GROUP_ROWS - 1) // GROUP_ROWS, cmax), dtype=np.intp)
    ns = np.empty(act.shape[0], dtype=np.intp)
    cl = ws[nl - 1].shape[1]
    for q0 in range(p0, p1, chunk):
        r = min(chunk, p1 - q0)
        for i in range(r):
            for j in range(c0):
                v = zero
                for d in range(dim):
                    v += pts[q0 + i, d] * w0[d, j]
                v += b0[j]
                a[i, j] = zero if v < zero else v
        grp = _groups(r, 1, False)
        cur, nxt, cin = a, b, c0
        for li in range(nl):
            cw = ws[li].shape[1]
            xi = cur[:r, :cin]
            yo = nxt[:r, :cw]
            _active(xi, grp, act, ns)
            _product(xi, ws[li], grp, act, ns, yo)
            if li < nl - 1:
                bb = bs[li]
                for i in range(r):
                    for j in range(cw):
                        v = yo[i, j] + bb[j]
                        yo[i, j] = zero if v < zero else v
            cur, nxt, cin = nxt, cur, cw
        i0 = 0
        if q0 == p0:
            for j in range(cl):               # a loop, not a slice copy (as in _recur_dir)
                pool[0, j] = cur[0, j]
            i0 = 1
        for i in range(i0, r):
            _max_into(pool[0], cur[i], cl)


@njit(cache=True, nogil=True, error_model="numpy")
def _finish_frame(pool, bl, gw, gb, zero, out, f):
    """``out[f] = relu(relu(pool + bl) @ gw + gb)``: the MLP's last bias and ReLU after the max
    (as :func:`tpnet_ref.engines.layers.mlp_max`: the same numbers), then the global layer."""
    cl = pool.shape[1]
    for j in range(cl):
        v = pool[0, j] + bl[j]
        pool[0, j] = zero if v < zero else v
    one_row = _groups(1, 1, False)
    act = np.empty((1, cl), dtype=np.intp)
    ns = np.empty(1, dtype=np.intp)
    g = np.empty((1, gw.shape[1]), dtype=pool.dtype)
    _active(pool[:, :], one_row, act, ns)
    _product(pool[:, :], gw, one_row, act, ns, g[:, :])
    for j in range(gw.shape[1]):
        v = g[0, j] + gb[j]
        out[f, j] = zero if v < zero else v


@njit(cache=True, nogil=True, error_model="numpy")
def _frame_range(pts, starts, counts, f0, f1, w0, b0, ws, bs, gw, gb, zero, out):
    """The global feature of frames ``f0 .. f1-1`` into ``out[f]``: frame ``f`` is the points
    ``pts[starts[f] : starts[f] + counts[f]]`` (model coordinates, canonical order)."""
    nl = len(ws)
    pool = np.empty((1, ws[nl - 1].shape[1]), dtype=pts.dtype)
    for f in range(f0, f1):
        _pool_points(pts, starts[f], starts[f] + counts[f], w0, b0, ws, bs, zero, pool)
        _finish_frame(pool, bs[nl - 1], gw, gb, zero, out, f)


@njit(cache=True, nogil=True, parallel=True)
def _features_parallel(pts, starts, counts, w0, b0, ws, bs, gw, gb, zero, out):
    """:func:`_frame_range` of every frame on two threads: two frames or more, in two halves; one frame
    (a rollout's new frame), its points in two halves, whose maxes are then combined (exact:
    a max of the same numbers, NaN kept)."""
    nf = counts.shape[0]
    if nf > 1:
        half = (nf + 1) // 2
        for h in prange(2):
            _frame_range(pts, starts, counts, h * half, min(nf, (h + 1) * half), w0, b0, ws,
                         bs, gw, gb, zero, out)
        return
    nl = len(ws)
    n = counts[0]
    mid = starts[0] + (n + 1) // 2
    pools = np.empty((2, 1, ws[nl - 1].shape[1]), dtype=pts.dtype)
    for h in prange(2):
        if h == 0:
            _pool_points(pts, starts[0], mid, w0, b0, ws, bs, zero, pools[0])
        else:
            _pool_points(pts, mid, starts[0] + n, w0, b0, ws, bs, zero, pools[1])
    _max_into(pools[0, 0], pools[1, 0], pools.shape[2])
    _finish_frame(pools[0], bs[nl - 1], gw, gb, zero, out, 0)


class NumbaFeatures:
    """The feature extractor as one compiled function (frames of any size, ragged included):
    ``(points (P, dim), counts (F,))`` -> global features ``(F, k)`` in the file's order of
    units, each frame computed on its own by the same code (the same bits alone, in a batch,
    on one thread or two). Only for networks whose transform nets are the identity (the
    released ones; :meth:`supports`). A call where the model's thread policy offers a second
    thread runs on two: two frames or more in two halves, one frame (a rollout's new one) its
    points in two halves (:func:`_features_parallel`); the same bits either way."""

    def __init__(self, config: Any, params: dict[str, np.ndarray], dtype: Any) -> None:
        if not self.supports(config):
            raise ValueError("NumbaFeatures: trained transform nets are not supported")
        dt = self.dtype = np.dtype(dtype)
        names = ([f"mlp1.{i}" for i in range(len(config.mlp1))]
                 + [f"mlp2.{i}" for i in range(len(config.mlp2))])
        # the products stream whole vectors: every layer's columns padded with zeros to whole
        # vectors, and its rows (inputs) to the previous layer's padded width
        w = [np.asarray(params[f"{n}.w"], dtype=dt) for n in names + ["global"]]
        b = [np.asarray(params[f"{n}.b"], dtype=dt) for n in names + ["global"]]
        rows = [w[0].shape[0]] + [padded_columns(x.shape[1], dt) for x in w[:-1]]
        ws = [np.pad(pad_columns(x, dt), ((0, r - x.shape[0]), (0, 0))) for x, r in zip(w, rows)]
        bs = [pad_columns(x, dt) for x in b]
        self.w0, self.b0 = ws[0], bs[0]
        self.ws, self.bs = tuple(ws[1:-1]), tuple(bs[1:-1])
        self.gw, self.gb = ws[-1], bs[-1]
        self.k = int(config.global_features)
        self._loaded: dict[Any, bool] = {}        # _available's answers for this layout

    @staticmethod
    def supports(config: Any) -> bool:
        return not (config.input_transform_trained or config.feature_transform_trained)

    def __call__(self, points: np.ndarray, counts: np.ndarray, parallel: bool = False) -> np.ndarray:
        """Global feature of every frame (see the class); ``parallel``: on two threads if
        :func:`_two_threads` allows."""
        pts = np.ascontiguousarray(points, dtype=self.dtype)
        counts = np.ascontiguousarray(counts, dtype=np.intp)
        starts = np.zeros(counts.shape[0], dtype=np.intp)
        np.cumsum(counts[:-1], out=starts[1:])
        out = np.empty((counts.shape[0], self.gw.shape[1]), dtype=self.dtype)
        weights = (self.w0, self.b0, self.ws, self.bs, self.gw, self.gb, self.dtype.type(0))
        if (counts.shape[0] > 1 or counts[0] >= 2 * GROUP_ROWS) and _two_threads(
                parallel and _available(_features_parallel, self._loaded,
                                        (pts, starts, counts, *weights, out))):
            try:
                _features_parallel(pts, starts, counts, *weights, out)
            finally:
                _PARALLEL.release()
        else:       # called directly: a wrapper would be one more level to compile
            _frame_range(pts, starts, counts, 0, counts.shape[0], *weights, out)
        return out if out.shape[1] == self.k else np.ascontiguousarray(out[:, :self.k])


#: one parallel call at a time (another thread asking meanwhile runs the serial kernel)
_PARALLEL = threading.Lock()


def _available(kernel: Any, memo: dict[Any, bool], args: tuple[Any, ...]) -> bool:
    """Whether the two-thread ``kernel`` may run on ``args``: always where two-thread kernels
    are compiled on demand (:data:`tpnet_ref.engines.compile_watch.TWO_THREAD_KERNELS_ON_DEMAND`, the
    library's default);
    else (``tpnet demo``, ``predict``, ``animate``) only if numba has it for these argument
    types, compiled in this process or in its cache (loaded then), so that a short command never
    stops to compile it -- the one-thread kernel gives the same bits. ``memo``: the caller's
    answers, by kernel (its argument types do not change)."""
    if compile_watch.TWO_THREAD_KERNELS_ON_DEMAND:
        return True
    got = memo.get(kernel)
    if got is None:
        got = memo[kernel] = _compiled_or_cached(kernel, args)
        if not got:
            _SKIPPED.add(kernel.__name__)
    return got


#: the two-thread kernels that :func:`_available` found missing in this process
_SKIPPED: set[str] = set()


def two_thread_kernels_skipped() -> tuple[str, ...]:
    """The two-thread kernels that ran on one thread in this process because numba did not have
    them and they are not compiled on demand (:func:`_available`), sorted."""
    return tuple(sorted(_SKIPPED))


def _compiled_or_cached(kernel: Any, args: tuple[Any, ...]) -> bool:
    """Whether ``kernel`` (a numba dispatcher) has a version for ``args``' types, compiled or
    loaded now from numba's cache (as its ``compile`` does before compiling); never compiles.
    False where numba's internals differ from those of numba 0.68 that this reads (then the
    one-thread kernel runs: the same bits)."""
    from numba.core.compiler_lock import global_compiler_lock
    try:
        sig = tuple(kernel.typeof_pyval(a) for a in args)
        if sig in kernel.overloads:
            return True
        with global_compiler_lock:
            cres = kernel._cache.load_overload(sig, kernel.targetctx)
            if cres is None:
                return False
            kernel.targetctx.insert_user_function(cres.entry_point, cres.fndesc, [cres.library])
            kernel.add_overload(cres)
        return True
    except Exception:                   # noqa: BLE001 -- numba's internals changed: one thread
        return False


def _two_threads(parallel: bool) -> bool:
    """Whether a call asked to run ``parallel`` takes the two-thread kernels now: only inside a
    :func:`tpnet_ref.engines.blas.one_thread` block (a one-thread BLAS), and one such call at a time.
    Beside a multi-threaded BLAS, whose threads spin between calls, numba's second thread waits
    for a core (measured, 2 cores: predict 1.4 -> 8 ms, rollout 0.9 -> 16 ms per frame); beside
    a one-thread BLAS it pays (predict 1.4 -> 1.2 ms, rollout 0.9 -> 0.6 ms per frame)."""
    return parallel and in_one_thread() and _PARALLEL.acquire(blocking=False)


class NumbaHead:
    """A model's prediction network laid out for the kernels above (built once per model), the
    :class:`tpnet_ref.engines.interface.Head` "numba": ``params`` in the file's order (``model.params``),
    ``unit_order`` the model's (:mod:`tpnet_ref.engines.unit_order`; None: the file's order) -- only the
    layout, and so the order of the sums, depends on it. Its calls take the second thread that
    :data:`tpnet_ref.engines.thread_policy.adaptive` offers (``threaded``); the bits do not depend on it."""

    name = "numba"
    threaded = True

    def __init__(self, config: Any, params: dict[str, np.ndarray], dtype: np.dtype,
                 unit_order: dict[str, np.ndarray] | None = None,
                 max_batch: int | None = None) -> None:
        #: the largest batch it runs (None: any; :data:`tpnet_ref.engines.interface.ENGINE_MAX_BATCH`)
        self.max_batch = max_batch
        self.dtype = dt = np.dtype(dtype)
        self.relu = config.lstm_activation == "relu"
        if not self.relu and config.lstm_activation != "tanh":
            raise ValueError(f"unknown LSTM activation {config.lstm_activation!r}: "
                             "expected 'relu' or 'tanh'")
        order = unit_order or {}
        # the global features' order (BiLSTM 1's kernel rows; project() takes the file's order)
        self.feature_order = order.get("global")
        prev = self.feature_order
        kernels, recs, gks, csts, gammas, betas = [], [], [], [], [], []
        for i, u in enumerate(config.lstm_units, start=1):
            po = order.get(f"lstm{i}")
            per_dir = ((np.arange(u), np.arange(u)) if po is None else
                       (po[po < u], po[po >= u] - u))
            n = padded_columns(4 * u, dt)
            c_in = params[f"lstm{i}.fwd.kernel"].shape[0]
            kern = np.zeros((2, c_in, n), dtype=dt)
            rec = np.zeros((2, u, n), dtype=dt)
            gk = np.zeros((2, n), dtype=dt)
            cst = np.zeros((2, n), dtype=dt)
            for d, name in enumerate(("fwd", "bwd")):
                cols = np.concatenate([g * u + per_dir[d] for g in range(4)])
                k = np.take(params[f"lstm{i}.{name}.kernel"], cols, axis=1)
                if prev is not None:
                    k = np.take(k, prev, axis=0)
                kern[d, :, :4 * u] = k
                rec[d, :, :4 * u] = np.take(np.take(params[f"lstm{i}.{name}.recurrent"],
                                                    per_dir[d], axis=0), cols, axis=1)
                b = np.asarray(params[f"lstm{i}.{name}.bias"], dtype=np.float64)[cols]
                if i > 1 and self.relu:     # LayerNorm i-1 folded into this projection
                    k64 = k.astype(np.float64)
                    gk[d, :4 * u] = gammas[-1] @ k64
                    cst[d, :4 * u] = betas[-1] @ k64 + b
                else:
                    cst[d, :4 * u] = b
            prev = np.concatenate([per_dir[0], u + per_dir[1]])   # this layer's outputs
            gammas.append(np.asarray(params[f"ln{i}.gamma"], dtype=np.float64)[prev])
            betas.append(np.asarray(params[f"ln{i}.beta"], dtype=np.float64)[prev])
            kernels.append(kern)
            recs.append(rec)
            gks.append(gk)
            csts.append(cst)
        self.kernels, self.recs = tuple(kernels), tuple(recs)
        self.gks, self.csts = tuple(gks), tuple(csts)
        self.units = tuple(int(u) for u in config.lstm_units)
        self.gammas = tuple(np.ascontiguousarray(g, dtype=dt) for g in gammas)
        self.betas = tuple(np.ascontiguousarray(b, dtype=dt) for b in betas)
        self.head_w = np.ascontiguousarray(np.asarray(params["head.w"])[prev], dtype=dt)
        self.head_b = np.ascontiguousarray(params["head.b"], dtype=dt)
        t = dt.type
        self.out_shape = (config.n_out, config.dim)
        self.one, self.eps = t(1.0), t(config.layer_norm_eps)
        self.limit = t(np.sqrt(np.finfo(dt).max) / 4)
        self._loaded: dict[Any, bool] = {}        # _available's answers for this layout

    def project(self, features: np.ndarray, batch: int = 1) -> np.ndarray:
        """BiLSTM 1's input projection of each frame's feature ``(F, k)`` -> ``(F, 2N)``, in this
        head's layout (:meth:`project_rows`, bias included)."""
        return self.project_rows(features, two_threads(), batch).reshape(len(features), -1)

    def __call__(self, features: np.ndarray, proj1: np.ndarray | None = None) -> np.ndarray:
        """``features (B, m, k)`` -> ``(B, n_out, dim)`` in [0, 1]; ``proj1`` ``(m, B, 2N)``:
        :meth:`project` of the frames, time-major, if already known."""
        batch, m = features.shape[:2]
        parallel = two_threads()
        if proj1 is None:
            proj1 = self.project_rows(features.transpose(1, 0, 2).reshape(m * batch, -1),
                                      parallel, batch)
        y, bad = self.run(proj1.reshape(m * batch, 2, -1, 4), m, batch, parallel)
        if bad:
            raise overflow_error(self.dtype, f"BiLSTM {bad}")
        if not np.isfinite(y).all():
            raise overflow_error(self.dtype, "the output layer")
        return y.reshape(-1, *self.out_shape)

    def project_rows(self, x: np.ndarray, parallel: bool = False, batch: int = 1) -> np.ndarray:
        """BiLSTM 1's input projection (with bias) of feature rows ``(R, k)`` -> ``(R, 2, N)``
        (each direction's gates i, f, c, o, then zero padding up to ``N``, whole vectors).
        ``parallel``: the two directions on two threads if :func:`_two_threads` allows.
        ``batch``: the rows are ``R / batch`` steps of ``batch`` windows, time-major (only
        groups the rows that share weight reads; the result is the same whatever it is)."""
        k = self.kernels[0]
        rows = x.shape[0]
        out = np.empty((rows, 2, k.shape[2]), dtype=self.dtype)
        if self.feature_order is not None:
            x = x[:, self.feature_order]
        x = np.ascontiguousarray(x, dtype=self.dtype)
        steps, bsz = (rows // batch, batch) if batch > 0 and rows % batch == 0 else (rows, 1)
        if _two_threads(parallel and _available(_project_parallel, self._loaded,
                                                (x, k, self.csts[0], out, steps, bsz))):
            try:
                _project_parallel(x, k, self.csts[0], out, steps, bsz)
            finally:
                _PARALLEL.release()
        else:
            _project_serial(x, k, self.csts[0], out, steps, bsz)
        return out

    def run(self, xp1: np.ndarray, steps: int, batch: int,
            parallel: bool = False) -> tuple[np.ndarray, int]:
        """The network from BiLSTM 1's projection ``xp1`` (:meth:`project_rows`' rows, time-major,
        ``T*B`` of them, any shape with ``2N`` numbers per row) -> ``(y (B, n_out*dim) in
        [0, 1], bad)``, ``bad`` = 1-based layer that overflowed, or 0. ``parallel``: each
        layer's two directions on two threads if :func:`_two_threads` allows."""
        xp1 = np.ascontiguousarray(xp1, dtype=self.dtype).reshape(steps * batch, 2, -1)
        args = (xp1, self.kernels, self.recs, self.gks, self.csts, self.units, self.gammas,
                self.betas, self.head_w, self.head_b, steps, batch, self.relu, self.one,
                self.eps, self.limit)
        if _two_threads(parallel and _available(_head_parallel, self._loaded, args)):
            try:
                return _head_parallel(*args)
            finally:
                _PARALLEL.release()
        return _head_serial(*args)


__all__ = ["NumbaHead", "NumbaFeatures", "two_thread_kernels_skipped", "FEATURE_CHUNK", "CHAIN", "GROUP_ROWS", "padded_columns", "pad_columns"]
