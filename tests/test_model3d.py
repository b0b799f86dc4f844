"""TP-Net at dim = 3 (docs/spec.md §8's soft ball): the model a user holds, as in 2-D.

A small random 3-D network (trained 3 x 3 input transform, 42 output points): the NumPy and the
Numba engine and the scene-specialised head against the readable reference; the same bits on
every call, under every thread plan, in processes of one and two threads, and under per-frame
permutations (the canonical order sorts by x, then y, then z); ``predict_batch`` / ``rollout``
against ``predict``; the native file records ``dim`` and loads back bit for bit; the PyTorch and
the Keras (TF-Keras 2 HDF5) importers read 3-D checkpoints; a window of the other dimension gets
a one-line error naming both; the input warnings that carry over to the 3-D scene.

At dim = 3 the Numba engine's compiled first pass (the checks and the sort of an array of
windows) and its fused rollout steps are 2-D kernels: they stand aside, and the Python checks,
``point_order.canonical_order`` and the step-by-step rollout serve every call (the same bits
either way, as the 2-D tests show for the kernels they replace).
"""
from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tpnet_ref import checks as C
from tpnet_ref.config import NORM_HI, NORM_LO
from tpnet_ref.engines import reference
from tpnet_ref.model import SPLIT_MIN_BATCH, TPNet, TPNetConfig, init_random, load
from tpnet_ref.weights.shipped import REPO_WEIGHTS_DIR
from ring_helpers import thrown_ball

pytestmark = pytest.mark.lane("3-D")   # in a second test process (tests/lane.py)

FIX = Path(__file__).parent / "fixtures"
#: the suite's 3-D network: a small released structure (identity transforms, so that the Numba
#: engine runs its compiled feature extractor) with the 3-D ball's 42 points out; TRAINED adds
#: trained transform nets (a 3 x 3 input transform), which the NumPy extractor runs
CFG3 = TPNetConfig(dim=3, n_out=42, input_tnet_mlp=(8, 16, 32), input_tnet_fc=(16, 8),
                   mlp1=(16, 16), feature_tnet_mlp=(8, 16), feature_tnet_fc=(16, 8),
                   mlp2=(32, 64), global_features=32, lstm_units=(48, 32, 32))
TRAINED = dataclasses.replace(CFG3, input_transform_trained=True, feature_transform_trained=True)
#: float64 engines against the reference, float32 against float64 (model coordinates; the 2-D
#: suite's bounds: tests/test_model.py, tests/test_engines_specialised.py)
TOL = {"float64": 1e-12, "float32": 2e-5}

_MODELS: dict = {}


def _model(dtype: str = "float64", engine: str = "numpy", m: int = 4, cfg=CFG3) -> TPNet:
    """One model per (dtype, engine, m, config), built once (hypothesis reuses them)."""
    key = (dtype, engine, m, cfg)
    if key not in _MODELS:
        base = init_random(dataclasses.replace(cfg, m=m), seed=7, dtype=dtype, transform_scale=0.5)
        _MODELS[key] = base.with_engine(engine)
    return _MODELS[key]


def _engines() -> list[str]:
    try:
        import numba  # noqa: F401
    except ImportError:
        return ["numpy"]
    return ["numpy", "numba"]


def _windows(rng, b=6, m=4, n=42, lo=0.2, hi=0.8):
    return rng.uniform(lo, hi, size=(b, m, n, 3))


@st.composite
def windows3d(draw, max_m=4):
    """A 3-D window (m frames, ragged or not, with exact ties: repeated points, and points that
    share x and y so that z alone orders them), and a permutation of every frame."""
    m = draw(st.integers(1, max_m))
    ragged = draw(st.booleans())
    n0 = draw(st.integers(1, 48))
    sizes = [draw(st.integers(1, 48)) if ragged else n0 for _ in range(m)]
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    scale = draw(st.sampled_from([1e-3, 0.3, 1.0]))
    frames = [0.5 + scale * rng.standard_normal((n, 3)) for n in sizes]
    if draw(st.booleans()):
        f = frames[0]
        f[len(f) // 2:] = f[: len(f) - len(f) // 2]
        f[::3, :2] = f[0, :2]
    return frames, [rng.permutation(n) for n in sizes], ragged


def _quiet(fn, *args, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", C.OutsideTrainingRangeWarning)
        return fn(*args, **kw)


# ------------------------------------------------------------------ engines against the reference
@pytest.mark.parametrize("dtype", ["float64", "float32"])
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=windows3d(), trained=st.booleans())
def test_every_engine_agrees_with_the_reference(dtype, data, trained):
    frames, _, _ = data
    m, cfg = len(frames), TRAINED if trained else CFG3
    want = reference.forward(dataclasses.replace(cfg, m=m), _model("float64", m=m, cfg=cfg).params,
                             frames, normalized=True)
    for engine in _engines():
        got = _quiet(_model(dtype, engine, m, cfg).predict, frames, normalized=True)
        assert got.shape == (42, 3) and got.dtype == np.dtype(dtype)
        np.testing.assert_allclose(got, want, rtol=0, atol=TOL[dtype], err_msg=engine)


@pytest.mark.parametrize("engine", _engines())
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_the_specialised_head_and_a_unit_order_keep_the_function(engine, dtype):
    rng = np.random.default_rng(3)
    model = _model(dtype, engine)
    cal, fresh = _windows(rng, 8), np.concatenate([_windows(rng, 4), _windows(rng, 4, lo=-1, hi=2)])
    spec = model.specialize(cal, normalized=True)
    assert spec.specialization is not None
    ordered = model.sort_units(cal, normalized=True)
    full = model.predict_batch(fresh, normalized=True)
    for other in (spec, ordered):
        np.testing.assert_allclose(other.predict_batch(fresh, normalized=True), full, rtol=0,
                                   atol=TOL[dtype])
        np.testing.assert_allclose(other.rollout(fresh[0], 4, normalized=True),
                                   model.rollout(fresh[0], 4, normalized=True), rtol=0,
                                   atol=10 * TOL[dtype])
    # the specialised head itself ran (not only the fallback to the full network)
    head = next(h for h in spec.heads if h.name == "specialised")
    y, ok = head.scene(_quiet(model.window_features, cal, True))
    assert ok.all()
    np.testing.assert_allclose(y.reshape(-1, 42, 3), model.predict_batch(cal, normalized=True),
                               rtol=0, atol=TOL[dtype])


# ------------------------------------------------------------------ the same bits
def _digest(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


def _outputs(model: TPNet, rng) -> dict[str, np.ndarray]:
    """What a 3-D model's calls give on fixed windows (world units): predict, a small batch, a
    batch split into chunks, a rollout and a batch rollout."""
    w = rng.uniform(10, 35, (SPLIT_MIN_BATCH + 3, 4, 42, 3))
    return {"predict": model.predict(w[0]), "batch": model.predict_batch(w[:5]),
            "split": model.predict_batch(w), "rollout": model.rollout(w[0], 6),
            "rollout_batch": model.rollout_batch(w[:3], 4)}


@pytest.mark.parametrize("engine", _engines())
@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_same_bits_on_every_call_every_thread_plan_and_split(engine, dtype, monkeypatch):
    """The thread policy switches plans (one thread, two) on every call; a batch split into
    chunks on one thread or on every core: one output throughout."""
    from tpnet_ref.engines import thread_policy
    plans = itertools.cycle((0, 1))
    monkeypatch.setattr(thread_policy.adaptive, "choose", lambda kind: next(plans))
    model = _model(dtype, engine).astype(dtype)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", C.OutsideTrainingRangeWarning)
        first = _outputs(model, np.random.default_rng(0))
        for _ in range(2):
            again = _outputs(model, np.random.default_rng(0))
            assert all(np.array_equal(first[k], again[k]) for k in first)
        model.threads = 1
        one = _outputs(model, np.random.default_rng(0))
    assert all(np.array_equal(first[k], one[k]) for k in first)
    assert first["split"].shape == (SPLIT_MIN_BATCH + 3, 42, 3)


_CHILD = """
import json, sys, warnings
import numpy as np
sys.path.insert(0, {tests!r})
warnings.simplefilter("ignore")
import test_model3d as T
out = {{}}
for engine in T._engines():
    for dtype in ("float32", "float64"):
        for k, v in T._outputs(T._model(dtype, engine), np.random.default_rng(0)).items():
            out[f"{{engine}} {{dtype}} {{k}}"] = T._digest(v)
print(json.dumps(out))
"""


@pytest.mark.late                       # its processes load the kernels the suite compiled
def test_same_bits_in_processes_of_one_and_two_threads():
    """BLAS and Numba with one thread or two (fresh processes: both read their thread counts
    when imported), and this process: the same digests."""
    import os
    code = _CHILD.format(tests=str(Path(__file__).parent))
    runs = []
    for threads in ("1", "2"):
        env = dict(os.environ, OPENBLAS_NUM_THREADS=threads, NUMBA_NUM_THREADS=threads,
                   OMP_NUM_THREADS=threads)
        env.pop("TPNET_THREADS", None)
        r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                           timeout=300)
        assert r.returncode == 0, r.stderr[-3000:]
        runs.append(json.loads(r.stdout.splitlines()[-1]))
    here = {}
    for engine in _engines():
        for dtype in ("float32", "float64"):
            out = _quiet(_outputs, _model(dtype, engine), np.random.default_rng(0))
            here.update({f"{engine} {dtype} {k}": _digest(v) for k, v in out.items()})
    assert runs[0] == runs[1] == here


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=windows3d(), normalized=st.booleans())
def test_per_frame_permutations_change_no_bit(dtype, data, normalized):
    frames, perms, ragged = data
    shuffled = [f[p] for f, p in zip(frames, perms)]
    other = [f[::-1] * 0.5 for f in frames]
    for engine in _engines():
        model = _model(dtype, engine, len(frames))
        # the points the network sees, in canonical order: the same bits (x, then y, then z)
        seen = model.canonical_points([np.asarray(f, dtype=dtype) for f in frames])[0]
        assert np.array_equal(seen, model.canonical_points(
            [np.asarray(f, dtype=dtype) for f in shuffled])[0])
        a = _quiet(model.predict, frames, normalized=normalized)
        assert np.array_equal(a, _quiet(model.predict, shuffled, normalized=normalized))
        ba = _quiet(model.predict_batch, [frames, other], normalized=normalized)
        bb = _quiet(model.predict_batch, [shuffled, [f[p] for f, p in zip(other, perms)]],
                    normalized=normalized)
        assert np.array_equal(ba, bb)
        ra = _quiet(model.rollout, frames, 3, normalized=normalized)
        assert np.array_equal(ra, _quiet(model.rollout, shuffled, 3, normalized=normalized))
        assert np.array_equal(ra[0], a)
        if not ragged:
            assert np.array_equal(_quiet(model.predict, np.stack(frames), normalized=normalized), a)


def test_the_compiled_first_pass_fused_rollout_and_extractor_run_3d():
    """As in 2-D (tests/test_engines_numba_checks.py holds their bits and words)."""
    if "numba" not in _engines():
        pytest.skip("numba not installed")
    from tpnet_ref.engines import numba_rollout
    model = _model("float32", "numba")
    assert model.screen is not None and numba_rollout.fusable(model, 1)
    assert model.engine_features is not None
    assert _model("float32", "numba", cfg=TRAINED).engine_features is None   # as in 2-D


# ------------------------------------------------------------------ batches and rollouts
@pytest.mark.parametrize("engine", _engines())
def test_predict_batch_and_rollouts_equal_predict(engine):
    rng = np.random.default_rng(1)
    model = _model("float64", engine)
    wins = [list(w) for w in _windows(rng, 5)]
    wins.append([rng.uniform(0.2, 0.8, (n, 3)) for n in (3, 42, 9, 1)])   # ragged
    batch = model.predict_batch(wins, normalized=True)
    assert batch.shape == (6, 42, 3)
    for b, w in enumerate(wins):
        np.testing.assert_allclose(batch[b], model.predict(w, normalized=True), rtol=0, atol=1e-12)
    out = model.rollout(wins[0], 5, normalized=True)
    frames = list(wins[0])
    for s in range(5):
        want = model.predict(frames[-4:], normalized=True)
        np.testing.assert_allclose(out[s], want, rtol=0, atol=1e-12)
        frames.append(want)
    rb = model.rollout_batch(wins, 5, normalized=True)
    assert rb.shape == (6, 5, 42, 3)
    for b, w in enumerate(wins):
        np.testing.assert_allclose(rb[b], model.rollout(w, 5, normalized=True), rtol=0, atol=1e-11)
    world = _quiet(model.rollout, model.denormalize(np.stack(wins[0])), 5)
    np.testing.assert_allclose(world, model.denormalize(out), rtol=0, atol=1e-9)


# ------------------------------------------------------------------ weights files
@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_the_native_file_records_dim_and_loads_back_bit_for_bit(tmp_path, dtype):
    rng = np.random.default_rng(2)
    model = _model(dtype)
    spec = model.specialize(_windows(rng, 4), normalized=True)
    path = tmp_path / "m3.h5"
    spec.save(path)
    with h5py.File(path, "r") as f:
        assert int(f["config"].attrs["dim"]) == 3
    back = load(path, dtype=dtype, engine="numpy")
    assert back.config == dataclasses.replace(CFG3, m=4) and back.config.dim == 3 and back.specialization is not None
    for k, v in model.params.items():
        np.testing.assert_array_equal(back.params[k], v)
    w = _windows(rng, 3)
    assert np.array_equal(back.predict_batch(w, normalized=True), spec.predict_batch(w, normalized=True))


def test_pytorch_checkpoint_imports_at_dim3(tmp_path):
    torch = pytest.importorskip("torch")
    from tpnet_ref.training.torch_model import TorchTPNet
    from tpnet_ref.weights.torch import import_torch
    ref = _model("float64")
    net = TorchTPNet.from_numpy(ref)
    torch.save(net.state_dict(), tmp_path / "m3.pt")
    model = import_torch(tmp_path / "m3.pt", dtype="float64")
    assert model.config == CFG3
    trained = _model("float64", cfg=TRAINED)
    torch.save(TorchTPNet.from_numpy(trained).state_dict(), tmp_path / "t3.pt")
    assert import_torch(tmp_path / "t3.pt", dtype="float64").config == TRAINED
    w = _windows(np.random.default_rng(4), 3)
    with torch.no_grad():
        yt = net(torch.from_numpy(w)).numpy()
        rt = net.rollout(torch.from_numpy(w[:1]), 4).numpy()[0]
    assert np.abs(model.predict_batch(w, normalized=True) - yt).max() <= 1e-5
    assert np.abs(model.rollout(w[0], 4, normalized=True) - rt).max() <= 1e-5


def _keras_3d(src: Path, dst: Path, seed: int) -> dict[str, np.ndarray]:
    """A TF-Keras 2 ``save_weights`` file of the released structure made 3-D: ``src`` (a 2-D
    file written by TF-Keras) with every dimension-bearing dataset rewritten at dim = 3 (the
    first point-wise kernels ``(1, 2, 1, C)`` -> ``(1, 3, 1, C)``, a trained input transform's
    output FC ``(fc, 4)`` -> ``(fc, 9)``, the head ``(2u, 30 * 2)`` -> ``(2u, 30 * 3)``), random
    values in the new ones; returns them by their dataset path."""
    shutil.copy(src, dst)
    rng = np.random.default_rng(seed)
    new: dict[str, np.ndarray] = {}
    with h5py.File(dst, "r+") as f:
        paths = []
        f.visititems(lambda n, o: paths.append(n) if isinstance(o, h5py.Dataset) else None)
        for n in paths:
            s = f[n].shape
            if len(s) == 4 and s[1:3] == (2, 1):
                shape = (1, 3, 1, s[3])
            elif len(s) == 2 and s[1] in (4, 60):
                shape = (s[0], s[1] // 2 * 3 if s[1] == 60 else 9)
            elif len(s) == 1 and s[0] in (4, 60):
                shape = (s[0] // 2 * 3 if s[0] == 60 else 9,)
            else:
                continue
            a = rng.uniform(-0.3, 0.3, shape).astype(f[n].dtype)
            if shape == (9,):
                a += np.eye(3, dtype=a.dtype).ravel()
            del f[n]
            f[n] = new[n] = a
    return new


def test_keras_checkpoint_imports_at_dim3(tmp_path):
    from tpnet_ref.weights.keras import import_keras_h5
    src = FIX / "tf2_released_weights.h5"
    new = _keras_3d(src, tmp_path / "k3d.h5", seed=1)
    two, three = import_keras_h5(src), import_keras_h5(tmp_path / "k3d.h5")
    assert three.config == dataclasses.replace(two.config, dim=3)
    # every parameter is the 2-D file's but the dimension's: the kernels written here
    first = [v for k, v in new.items() if k.endswith("conv2d_3/kernel:0")]
    np.testing.assert_array_equal(three.params["mlp1.0.w"], first[0].reshape(3, -1))
    heads = [v for k, v in new.items() if k.endswith("dense_5/kernel:0")]
    np.testing.assert_array_equal(three.params["head.w"], heads[0])
    for k, v in two.params.items():
        if k not in ("mlp1.0.w", "head.w", "head.b"):
            np.testing.assert_array_equal(three.params[k], v)
    w = _windows(np.random.default_rng(5), 2)
    three64 = three.astype("float64")
    want = np.stack([reference.forward(three.config, three64.params, x, normalized=True) for x in w])
    np.testing.assert_allclose(three64.predict_batch(w, normalized=True), want, rtol=0, atol=1e-12)
    # trained transform nets with BatchNorm folded in: the 3 x 3 input transform
    _keras_3d(FIX / "tf2_trained_bn_weights.h5", tmp_path / "t3d.h5", seed=2)
    trained = import_keras_h5(tmp_path / "t3d.h5")
    assert trained.config.dim == 3 and trained.config.input_transform_trained
    assert trained.params["input_tnet.out.w"].shape[1] == 9
    assert np.isfinite(trained.predict(w[0], normalized=True)).all()


# ------------------------------------------------------------------ the other dimension
@pytest.mark.parametrize("engine", _engines())
def test_a_window_of_the_other_dimension_gets_one_line_naming_both(engine):
    three = _model("float32", engine)
    two = init_random(dataclasses.replace(CFG3, dim=2), seed=1).with_engine(engine)
    rng = np.random.default_rng(6)
    for model, d, other in ((three, 3, 2), (two, 2, 3)):
        w = rng.uniform(10, 35, (4, 30, other))
        for call in (lambda: model.predict(w), lambda: model.rollout(w, 2),
                     lambda: model.predict_batch(w[None]), lambda: model.predict_batch([w, w]),
                     lambda: model.rollout_batch(np.stack([w, w]), 2)):
            with pytest.raises(ValueError) as exc:
                call()
            msg = str(exc.value)
            assert "\n" not in msg and f"the model is {d}-D, these points {other}-D" in msg, msg
        with pytest.raises(ValueError, match=rf"^window\[0\]: expected shape \(N, {d}\), "
                                             rf"got \(30, {other}\)$"):
            model.predict(list(w))                                  # frames as a list: both named


# ------------------------------------------------------------------ warnings in the 3-D scene
def test_the_3d_scene_shares_the_checks_constants():
    from tpnet_ref.sim.scene3d import SceneParams3D
    p = SceneParams3D()
    assert p.gravity == (0.0, 0.0, -C.GRAVITY) and p.dt == C.SIM_DT
    assert p.n_particles == 42


def test_the_warnings_that_carry_over_to_the_3d_scene():
    model = _model("float64")
    w = thrown_ball()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model.predict(w)                                      # a throw of the scene: no warning
        stray = [f.copy() for f in w]
        stray[1] = np.concatenate([stray[1], stray[1][:1] + 6.0])
        model.predict(stray)          # a stray point: the one-body test is the 2-D ring's only
    with pytest.warns(C.FrameSpacingWarning, match="falls freely.*1/45 s apart"):
        model.predict(thrown_ball(rows_apart=1))             # free fall read along z
    with pytest.warns(C.FrameSpacingWarning, match="moves 0 world units"):
        model.predict(np.stack([w[0]] * 4))                   # at rest
    with pytest.warns(C.OutsideTrainingRangeWarning, match="is a ball of radius 2"):
        model.predict((w - w.mean(axis=1, keepdims=True)) * 3 + w.mean(axis=1, keepdims=True))
    with pytest.warns(C.OutsideTrainingRangeWarning, match="outside the training box"):
        model.predict(w + [0.0, 0.0, 20.0])
    with pytest.warns(C.TooFewPointsWarning, match="trained on 42 per frame"):
        model.predict([f[:2] if i == 2 else f for i, f in enumerate(w)])
    assert NORM_LO < w.min() and w.max() < NORM_HI


@pytest.mark.parametrize("name, units", [("tpnet3d-m4-quarter.h5", (128, 64, 64)),
                                         ("tpnet3d-m4-half.h5", (256, 128, 128))])
def test_the_shipped_3d_sizes_load_as_3d_models_and_roll_out_a_ball(name, units):
    """``weights/tpnet3d-m4-quarter.h5`` and ``-half.h5`` (weights/MODEL_CARD.md, "The 3-D
    quarter", "The 3-D half"): 3-D networks of 42 points whose rollout of a resting ball stays
    a ball of about its size."""
    model = load(str(REPO_WEIGHTS_DIR / name))
    assert (model.config.dim, model.config.n_out, model.config.m) == (3, 42, 4)
    assert model.config.lstm_units == units
    rng = np.random.default_rng(0)
    ball = rng.standard_normal((42, 3))
    ball = 2.0 * ball / np.linalg.norm(ball, axis=1, keepdims=True) + np.array([22.5, 22.5, 2.2])
    out = model.rollout(np.stack([ball] * 4), 20)
    assert out.shape == (20, 42, 3) and np.isfinite(out).all()
    radius = np.linalg.norm(out[-1] - out[-1].mean(axis=0), axis=1).mean()
    assert 1.0 < radius < 3.0
