"""Weights of fewer bits (bf16, int8) in the Numba engine (docs/deployment.md, "Weights of fewer
bits"; :mod:`tpnet_ref.weights.quantize`): the grids are exact and re-derived exactly, the
file (``tpnet quantize``) loads with no flag and refuses a corrupted scale, corrupted bf16
planes or an unknown scheme in one line, and the guarantees of the float engines hold on the
quantized ones: the same bits on every call and thread count, batch == single, per-frame
permutation invariance bit for bit, within float32 rounding of the float64 reference run on the
same (dequantized) weights; the quantization's own error, per layer, within the bounds
docs/tolerances.md states; a 600-step rollout finite and bounded. On the shipped quarter size
(fast to compile and run)."""
from __future__ import annotations

import subprocess
import sys
import warnings

import numpy as np
import pytest

import tpnet_ref
from tpnet_ref import testing
from tpnet_ref.engines import reference
from tpnet_ref.engines.blas import one_thread
from tpnet_ref.model import TPNet
from tpnet_ref.weights import quantize as Q
from tpnet_ref.weights.native import read_native, seal
from tpnet_ref.weights.shipped import shipped_weights_path

pytest.importorskip("numba")
pytestmark = pytest.mark.lane("fewer-bits")   # in a second test process (tests/lane.py)
SCHEMES = ["bf16", "int8"]
#: the largest move of one prediction (world units) from the float32 model's that quantizing
#: one BiLSTM's matrices alone, or all of them, may cause on the quarter size
#: (docs/tolerances.md, "Weights of fewer bits": measured on 64 windows, x 2)
LAYER_BOUNDS = {"bf16": {1: 0.03, 2: 0.03, 3: 0, "all": 0.045},
                "int8": {1: 0.07, 2: 0.23, 3: 0.12, "all": 0.33}}


@pytest.fixture(scope="module")
def base():
    return tpnet_ref.load(size="quarter", engine="numba")


@pytest.fixture(scope="module")
def models(base):
    from tpnet_ref.weights.convert import with_weights
    return {s: with_weights(base, s) for s in SCHEMES}


@pytest.fixture(scope="module")
def scene():
    """Windows of a simulated test case (world units): 12 windows of m = 4 frames."""
    pytest.importorskip("pymunk")
    from tpnet_ref.sim.cases import TEST_CASES
    from tpnet_ref.sim.protocol import FRAME_EVERY
    from tpnet_ref.sim.scene import simulate
    traj = simulate(*TEST_CASES[3])[::FRAME_EVERY]
    return np.stack([traj[s:s + 4] for s in np.linspace(0, len(traj) - 4, 12).astype(int)])


# ----------------------------------------------------------------------------- the grids
@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("wide", [False, True])
def test_grid_is_exact_and_rederived_exactly(scheme, wide):
    rng = np.random.default_rng(0)
    w = (rng.normal(size=(64, 48)) * 0.07).astype(np.float32)
    w[:, 5] = 0.0
    w[3, 7] = 1e-31                                   # a column below TINY: zeros, scale 1
    d = Q.round_to(w, scheme, wide)
    assert d.dtype == np.float32 and np.isfinite(d).all()
    codes, scales = Q.codes_of(d, scheme, "w", wide)
    back = Q.check_codes(codes, scales, scheme, w.shape, "w", wide)
    assert np.array_equal(back, d)                    # the codes give the weights back exactly
    assert np.array_equal(Q.round_to(d, scheme, wide), d)       # and the grid is a fixed point
    step = np.abs(w).max(0) / (127 * (256 if wide and scheme == "int8" else 1))
    if scheme == "int8":
        assert (np.abs(d - w) <= 0.51 * step + np.abs(w).max(0) * 2.0 ** -9).all()
    else:
        assert (np.abs(d - w) <= np.abs(w) * 2.0 ** -8).all()


def test_off_grid_weights_are_refused_in_one_line():
    w = np.random.default_rng(1).normal(size=(8, 16)).astype(np.float32)
    with pytest.raises(ValueError, match=r"^w: not on the int8 grid") as exc:
        Q.codes_of(w, "int8", "w")
    assert "\n" not in str(exc.value)


def test_which_layers_are_quantized(base, models):
    names = set(Q.quantized_names(base.config))
    assert names == {f"lstm{i}.{d}.{t}" for i in (1, 2, 3) for d in ("fwd", "bwd")
                     for t in ("kernel", "recurrent")}
    for s, m in models.items():
        assert m.meta["quantization"] == s and "tpnet-m4-quarter.h5" in m.meta["quantized_from"]
        wide = set(Q.wide_names(base.config, s))
        for k, v in base.params.items():
            if s == "bf16" and k in wide:      # 16 bits: the quarter's 15-bit weights exactly
                assert np.abs(m.params[k] - v).max() <= np.abs(v).max() * 2.0 ** -16, k
            else:
                assert np.array_equal(m.params[k], v) == (k not in names), (s, k)
        head = m.head_for(1)
        assert head.name == "numba" and head.weights == s
        want = np.int8 if s == "int8" else np.uint16
        assert {a.dtype for a in head.kernels + head.recs} == {np.dtype(want)}
        units, c_in = base.config.lstm_units, base.config.global_features
        for i, (k, r) in enumerate(zip(head.kernels, head.recs), start=1):   # two planes
            rows = c_in if i == 1 else 2 * units[i - 2]
            assert k.shape[1] == rows * (2 if f"lstm{i}.fwd.kernel" in wide else 1), (s, i)
            assert r.shape[1] == units[i - 1] * (2 if f"lstm{i}.fwd.recurrent" in wide else 1)
    assert Q.wide_names(base.config, "int8") == [
        "lstm1.fwd.kernel", "lstm1.bwd.kernel", "lstm3.fwd.recurrent", "lstm3.bwd.recurrent"]
    assert set(Q.wide_names(base.config, "bf16")) == set(Q.wide_names(base.config)) | {
        "lstm3.fwd.kernel", "lstm3.bwd.kernel"}


def test_bf16_planes_are_exact(models):
    """bf16's two planes: ``hi = bf16(w)``, ``lo = bf16((w - hi) * 256)``, and the dequantized
    float32 weight is ``hi + lo / 256`` exactly (the sum float64 computes), within 2^-16 of
    ``w``; ties, exact bf16 values, tiny and zero weights included; and so in ``model.params``
    of the quarter and of the full size (whose weights have more than 16 bits)."""
    rng = np.random.default_rng(3)
    w = (rng.normal(size=(96, 64)) * 0.07).astype(np.float32)
    top = w[:32].view(np.uint32) & np.uint32(0xFFFF0000)
    w[:32] = (top | np.uint32(0x8000)).view(np.float32)      # halfway between two bf16
    w[32:40] = (top[:8] | np.uint32(0x7FFF)).view(np.float32)
    w[40:44] = top[:4].view(np.float32)                       # already bf16
    w[44, :4] = [0.0, -0.0, 1e-31, 3e-39]
    codes, scales = Q.encode(w, "bf16", wide=True)
    assert scales is None and codes.dtype == np.uint16 and codes.shape == (192, 64)
    hi, lo = (Q.decode(c, None, "bf16").astype(np.float64) for c in (codes[:96], codes[96:]))
    assert np.array_equal(hi, Q.round_to(w, "bf16").astype(np.float64))
    d = Q.round_to(w, "bf16", wide=True)
    assert np.array_equal(d.astype(np.float64), hi + lo / 256)        # exact in float32
    big = np.abs(w) >= Q.TINY
    assert (np.abs(d - w)[big] <= np.abs(w[big]) * 2.0 ** -16).all()
    assert np.array_equal(np.signbit(d), np.signbit(w)) and (lo[~big] == 0).all()  # -0
    assert np.array_equal(Q.check_codes(*Q.codes_of(d, "bf16", "w", True), "bf16", w.shape,
                                        "w", True), d)
    full = tpnet_ref.load(engine="numpy", weights="bf16")
    for m in (models["bf16"], full):
        for n in Q.wide_names(m.config, "bf16"):
            codes, _ = Q.codes_of(m.params[n], "bf16", n, wide=True)
            c = len(codes) // 2
            hi, lo = (Q.decode(p, None, "bf16").astype(np.float64) for p in (codes[:c], codes[c:]))
            assert np.array_equal(m.params[n].astype(np.float64), hi + lo / 256), n
            assert m.config is not full.config or (lo != 0).mean() > 0.9, n


def test_load_argument_and_errors(base):
    with pytest.raises(ValueError, match=r"^weights must be None, 'float32', 'bf16' or 'int8'"):
        tpnet_ref.load(size="quarter", weights="int4")
    q = tpnet_ref.load(size="quarter", engine="numpy", weights="int8")
    assert q.meta["quantization"] == "int8" and q.engine == "numpy"
    assert tpnet_ref.load(size="quarter", engine="numpy", weights="float32").meta.get(
        "quantization") is None
    from tpnet_ref.weights.convert import with_weights
    with pytest.raises(ValueError, match=r"already int8.*quantize the float32 file"):
        with_weights(q, "bf16")
    # float64: the same quantized network, computed by the float kernels
    q64 = q.astype("float64").with_engine("numba")
    assert q64.meta["quantization"] == "int8" and q64.head_for(1).weights is None


# ----------------------------------------------------------------------------- the file
def _quantize(src, scheme, out):
    return subprocess.run([sys.executable, "-m", "tpnet_ref.cli", "quantize", "--weights",
                           str(src), "--to", scheme, "-o", str(out)],
                          capture_output=True, text=True, check=False)


@pytest.mark.parametrize("scheme", SCHEMES)
def test_quantize_command_writes_a_file_that_loads_with_no_flag(scheme, tmp_path, models):
    src = shipped_weights_path(4, "quarter")
    out = tmp_path / f"q-{scheme}.h5"
    r = _quantize(src, scheme, out)
    assert r.returncode == 0, r.stderr
    assert f"BiLSTM matrices as {scheme}" in r.stdout
    loaded = tpnet_ref.load(out, engine="numba")
    assert loaded.meta["quantization"] == scheme
    assert loaded.meta["quantized_from"].startswith("tpnet-m4-quarter.h5 (sha256:")
    for k, v in models[scheme].params.items():
        assert np.array_equal(loaded.params[k], v), k
    assert loaded.unit_order is not None                       # the source's unit order kept
    raw = sum(a.nbytes for a in models[scheme].params.values())
    assert out.stat().st_size < (0.62 if scheme == "bf16" else 0.42) * raw
    # saved again (TPNet.save): the same codes, the same weights
    again = tmp_path / "again.h5"
    loaded.save(again)
    got = read_native(again)[1]
    assert list(got) == list(loaded.params)
    assert all(np.array_equal(got[k], v) for k, v in loaded.params.items())


def _tamper(path, edit):
    import h5py
    with h5py.File(path, "r+") as f:
        edit(f)
    seal(path)                                         # a matching digest: the checks must see it


@pytest.mark.parametrize("edit, message", [
    (lambda f: f["scales/lstm2.fwd.kernel"].__setitem__(3, np.nan), "corrupted int8 scales"),
    (lambda f: f["scales/lstm2.fwd.kernel"].__setitem__(3, -0.01), "corrupted int8 scales"),
    (lambda f: f["scales/lstm2.fwd.kernel"].__setitem__(3, 0.0123456789), "corrupted int8 scales"),
    (lambda f: f.attrs.__setitem__("quantization", "int4"), "unknown quantization scheme 'int4'"),
    (lambda f: f.attrs.__setitem__("quantization", "bf16"), "bf16 codes must be uint16"),
    (lambda f: f.__delitem__("scales/lstm3.bwd.recurrent"), "without the scales"),
])
def test_a_corrupted_scale_or_a_wrong_scheme_is_one_line(edit, message, tmp_path):
    _assert_tampered_file_refused("int8", edit, message, tmp_path)


def _assert_tampered_file_refused(scheme, edit, message, tmp_path):
    """The quarter quantized to ``scheme``, ``edit``-ed: its load fails in one line that names
    the file and matches ``message``."""
    out = tmp_path / "q.h5"
    assert _quantize(shipped_weights_path(4, "quarter"), scheme, out).returncode == 0
    _tamper(out, edit)
    with pytest.raises(ValueError, match=message) as exc:
        tpnet_ref.load(out, engine="numpy")
    assert "\n" not in str(exc.value) and str(out) in str(exc.value)


def _set_code(name, row, value):
    def edit(f):
        codes = f[f"params/{name}"][...]
        codes[row, 3] = value
        f[f"params/{name}"][...] = codes
    return edit


def _one_plane(f):
    hi = f["params/lstm3.bwd.recurrent"][...]
    del f["params/lstm3.bwd.recurrent"]
    f["params/lstm3.bwd.recurrent"] = hi[:len(hi) // 2]


@pytest.mark.parametrize("edit, message", [
    (_set_code("lstm1.fwd.kernel", -1, 0x3F80), "corrupted bf16 codes"),     # lo = 1.0
    (_set_code("lstm3.fwd.recurrent", 0, 0x0001), "corrupted bf16 codes"),   # hi far from hi + lo
    (_set_code("lstm2.fwd.kernel", 0, 0x7FC0), "decode to NaN"),
    (_set_code("lstm3.bwd.kernel", -1, 0x7F80), "decode to NaN or infinite"),
    (_one_plane, r"bf16 codes must be uint16 of shape \(128, 256\), got uint16 \(64, 256\)"),
])
def test_corrupted_bf16_codes_or_a_missing_plane_is_one_line(edit, message, tmp_path):
    """A bf16 file's two planes must be the ones ``encode`` makes (the sum exact in float32) and
    of twice the rows; NaN or infinite codes are refused as in one plane."""
    _assert_tampered_file_refused("bf16", edit, message, tmp_path)


def test_a_changed_scale_without_a_new_digest_is_refused(tmp_path):
    import h5py
    out = tmp_path / "q.h5"
    assert _quantize(shipped_weights_path(4, "quarter"), "int8", out).returncode == 0
    with h5py.File(out, "r+") as f:
        f["scales/lstm1.fwd.recurrent"][0] *= 2
    with pytest.raises(ValueError, match="does not match its content_sha256"):
        tpnet_ref.load(out, engine="numpy")


# ------------------------------------------------------------------------ the guarantees
@pytest.mark.parametrize("scheme", SCHEMES)
def test_same_bits_every_call_thread_count_and_batch(scheme, models, scene):
    """As the float32 Numba engine: a batch the compiled extractor serves (up to 8 windows) gives
    each window's bits alone; the head gives them for any batch (12 windows here), on one
    thread or two."""
    m = models[scheme]
    x = m.normalize(scene.astype(np.float32))
    single = np.stack([m.predict(w, normalized=True) for w in x])
    assert np.array_equal(single, np.stack([m.predict(w, normalized=True) for w in x]))
    assert np.array_equal(m.predict_batch(x[:8], normalized=True), single[:8])  # batch == single
    head = m.head_for(len(x))
    feats = m.window_features(x, normalized=True)
    alone = np.concatenate([np.asarray(head(feats[i:i + 1])) for i in range(len(x))])
    assert np.array_equal(np.asarray(head(feats)), alone)
    proj = head.project_rows(feats.transpose(1, 0, 2).reshape(-1, feats.shape[2]), False,
                             len(x))
    with one_thread():                                 # where the two-thread kernels may run
        a = head.run(proj, 4, len(x), parallel=True)
    b = head.run(proj, 4, len(x), parallel=False)
    assert a[1] == b[1] == 0 and np.array_equal(a[0], b[0])
    flat = np.asarray(head(feats)).reshape(len(x), -1)
    assert np.array_equal(flat, b[0])


def test_bf16_engine_is_the_float32_engine_on_the_same_weights(models, scene):
    """bf16 widened in registers is exact, two planes' pairs included: the bf16 kernels give the
    float32 kernels' bits on the dequantized weights."""
    q = models["bf16"]
    f = TPNet(q.config, q.params, "float32", {}, "numba", unit_order=q.unit_order)
    x = q.normalize(scene.astype(np.float32))
    assert np.array_equal(q.predict_batch(x, normalized=True), f.predict_batch(x, normalized=True))


@pytest.mark.parametrize("scheme", SCHEMES)
def test_permutation_invariant_bit_for_bit(scheme, models):
    m = models[scheme]
    testing.permutation_invariant(lambda w: m.predict(w), testing.windows(m=4, n=(1, 40)),
                                  tol=0.0, max_examples=15, seed=58)


@pytest.mark.parametrize("scheme", SCHEMES)
def test_within_float32_rounding_of_the_float64_reference(scheme, models):
    """The quantized kernels (int8: the scale applied after the sum; two planes) against the
    float64 reference on the same dequantized weights: the float32 rule of ``tpnet vectors``
    (:func:`tpnet_ref.testing.agrees_with_reference`'s measured tolerance)."""
    m = models[scheme]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        testing.agrees_with_reference(lambda w: m.predict(w), m,
                                      windows=testing.windows(m=4, n=30, centre=(15.0, 30.0),
                                                      scales=(1.0, 3.0)),
                                      max_examples=8, seed=58)


@pytest.mark.parametrize("scheme", SCHEMES)
def test_quantization_error_per_layer_within_the_stated_bounds(scheme, base, scene):
    """The float64 reference on the weights with one layer's matrices quantized (or all of
    them), against the float64 reference on the float32 weights: docs/tolerances.md's bounds."""
    cfg = base.config
    p64 = {k: np.asarray(v, dtype=np.float64) for k, v in base.params.items()}
    want = np.stack([reference.forward(cfg, p64, list(w)) for w in scene])
    wide = set(Q.wide_names(cfg, scheme))
    for layer, bound in LAYER_BOUNDS[scheme].items():
        names = [n for n in Q.quantized_names(cfg) if layer == "all" or n.startswith(f"lstm{layer}.")]
        p = dict(p64)
        for n in names:
            p[n] = Q.round_to(base.params[n], scheme, n in wide).astype(np.float64)
        got = np.stack([reference.forward(cfg, p, list(w)) for w in scene])
        d = float(np.abs(got - want).max())
        assert (d == 0) if bound == 0 else (0 < d <= bound), (scheme, layer, d)


@pytest.mark.parametrize("scheme", SCHEMES)
def test_rollout_600_steps_finite_and_bounded(scheme, models, scene):
    m = models[scheme]
    traj = m.rollout_batch(scene[:2], 600)
    assert np.isfinite(traj).all()
    lo, hi = m.config.norm_lo, m.config.norm_hi
    assert traj.min() >= lo - 1e-3 and traj.max() <= hi + 1e-3     # the sigmoid keeps it in
    ref = models[scheme].with_engine("numpy").rollout(scene[0], 600)
    assert np.isfinite(ref).all()


def test_a_specialised_quantized_model_keeps_its_scheme_and_agrees(models, scene):
    """``specialize`` and ``with_engine`` keep the scheme; the specialised head (the dequantized
    weights, float kernels) agrees with the quantized engine within float32 rounding."""
    m = models["int8"]
    spec = m.specialize(scene[:6])
    assert spec.meta["quantization"] == "int8" and spec.specialization is not None
    assert spec.head_for(1).weights == "int8"
    got = spec.predict_batch(scene)              # 12 windows: past the numba head's 8
    assert spec.counts["windows"] == len(scene)
    d = np.abs(got - np.stack([m.predict(w) for w in scene])).max()
    assert d <= 5e-5, d


_CHILD = """
import hashlib, sys, warnings
import numpy as np
import tpnet_ref
warnings.simplefilter("ignore")
rng = np.random.default_rng(5)
t = np.linspace(0, 2 * np.pi, 30, endpoint=False)
ring = np.stack([np.cos(t), np.sin(t)], 1) * 2
wins = np.stack([np.stack([ring + [20 + 0.3 * k + i, 25 - 0.2 * k] for k in range(4)])
                 + rng.normal(0, 0.05, (4, 30, 2)) for i in range(12)])
h = hashlib.sha256()
for s in ("bf16", "int8"):
    m = tpnet_ref.load(size="quarter", engine="numba", weights=s)
    for w in wins:
        h.update(m.predict(w).tobytes())
    h.update(m.predict_batch(wins[:8]).tobytes())
    h.update(m.rollout(wins[0], 20).tobytes())
print(h.hexdigest())
"""


@pytest.mark.slow
@pytest.mark.late                       # its processes load the kernels the suite compiled
def test_same_bits_under_every_openblas_kernel_and_thread_count():
    """The quantized engines' predictions, a batch and a rollout hashed in fresh processes under
    each OpenBLAS kernel this CPU runs, with one and two BLAS / numba threads: one digest."""
    import os
    from determinism_probe import KERNELS, runnable_kernels
    kernels = [k for k, why in runnable_kernels().items() if why is None] or [None]
    digests = {}
    for kernel in dict.fromkeys(kernels[:2] + kernels[-1:]):
        for threads in (1, 2):
            env = dict(os.environ, OPENBLAS_NUM_THREADS=str(threads),
                       NUMBA_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads))
            if kernel is not None:
                env["OPENBLAS_CORETYPE"] = kernel
            r = subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True,
                               env=env, timeout=600, check=False)
            assert r.returncode == 0, r.stderr[-2000:]
            digests[kernel, threads] = r.stdout.strip()
    assert len(set(digests.values())) == 1, digests
    assert set(KERNELS) >= {k for k, _ in digests if k is not None}
