"""The optional Numba engine equals the NumPy engine (the reference), is deterministic, keeps
permutation invariance bit for bit, and without numba says which extra to install."""
from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("numba")

import tpnet_ref  # noqa: E402
from tpnet_ref import blas  # noqa: E402
from tpnet_ref import model as M  # noqa: E402
from tpnet_ref.config import TPNetConfig  # noqa: E402
from tpnet_ref.extras import MissingExtraError  # noqa: E402
from tpnet_ref.model import init_random  # noqa: E402

SMALL = TPNetConfig(m=3, n_out=5, mlp1=(8, 8), mlp2=(8, 16), global_features=12,
                    lstm_units=(6, 5, 7), input_tnet_mlp=(4, 6), input_tnet_fc=(5,),
                    feature_tnet_mlp=(6,), feature_tnet_fc=(5,))


@pytest.fixture(scope="module")
def released64():
    return init_random(seed=3, dtype="float64")


@pytest.fixture(scope="module")
def released_nb64(released64):
    return released64.with_engine("numba")


def _windows(rng, b, m=4, n=30):
    return rng.uniform(5.0, 40.0, size=(b, m, n, 2))


@pytest.mark.parametrize("act", ["relu", "tanh"])
@pytest.mark.parametrize("transforms", [False, True])
@pytest.mark.parametrize("dtype,atol", [("float64", 1e-12), ("float32", 2e-5)])
def test_engine_equals_numpy_on_small_random_nets(act, transforms, dtype, atol):
    cfg = dataclasses.replace(SMALL, lstm_activation=act, input_transform_trained=transforms,
                              feature_transform_trained=transforms)
    ref = init_random(cfg, seed=7, dtype=dtype, transform_scale=0.5)
    nb = ref.with_engine("numba")
    assert nb.engine == "numba" and ref.engine == "numpy"
    rng = np.random.default_rng(1)
    ragged = [rng.uniform(0, 1, size=(n, 2)) for n in (4, 1, 9)]
    np.testing.assert_allclose(nb.predict(ragged, normalized=True),
                               ref.predict(ragged, normalized=True), rtol=0, atol=atol)
    wins = rng.uniform(0, 1, size=(5, 3, 7, 2))
    np.testing.assert_allclose(nb.predict_batch(wins, normalized=True),
                               ref.predict_batch(wins, normalized=True), rtol=0, atol=atol)
    np.testing.assert_allclose(nb.rollout(wins[0], 6, normalized=True),
                               ref.rollout(wins[0], 6, normalized=True), rtol=0, atol=10 * atol)


def test_engine_equals_numpy_float64_on_the_released_shape(released64, released_nb64):
    rng = np.random.default_rng(2)
    wins = _windows(rng, 3)
    for w in wins:
        np.testing.assert_allclose(released_nb64.predict(w), released64.predict(w), rtol=0, atol=1e-10)
    np.testing.assert_allclose(released_nb64.predict_batch(wins), released64.predict_batch(wins),
                               rtol=0, atol=1e-10)
    np.testing.assert_allclose(released_nb64.rollout(wins[0], 8), released64.rollout(wins[0], 8),
                               rtol=0, atol=1e-10)
    np.testing.assert_allclose(released_nb64.rollout_batch(wins, 3),
                               released64.rollout_batch(wins, 3), rtol=0, atol=1e-10)


def test_engine_float32_agrees_with_the_float64_reference(released64, released_nb64):
    nb32 = released_nb64.astype("float32")
    assert nb32.engine == "numba"
    rng = np.random.default_rng(4)
    for w in _windows(rng, 3):
        assert np.abs(nb32.predict(w) - released64.predict(w)).max() < 1e-3   # world units
    w = _windows(rng, 1)[0]
    assert np.abs(nb32.rollout(w, 20) - released64.rollout(w, 20)).max() < 1e-2


def test_engine_result_does_not_depend_on_the_thread_count(released_nb64):
    """Each number is computed by one thread in a fixed order: serial and parallel kernels, and
    a window alone or inside a batch, give the same bits."""
    nb32 = released_nb64.astype("float32")
    rng = np.random.default_rng(5)
    wins = _windows(rng, 3).astype(np.float32)
    for model in (released_nb64, nb32):
        par = model.predict(wins[0])                    # outside one_thread: parallel kernels
        with blas.one_thread():
            ser = model.predict(wins[0])
        assert np.array_equal(par, ser)
        assert np.array_equal(model.predict_batch(wins)[0], par)
        assert np.array_equal(model.rollout(wins[0], 4)[0], par)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_permutation_invariance_is_bit_identical_under_the_engine(released_nb64, dtype):
    model = released_nb64.astype(dtype)
    rng = np.random.default_rng(6)
    w = _windows(rng, 1)[0]
    base = model.predict(w)
    for _ in range(3):
        perm = np.stack([f[rng.permutation(len(f))] for f in w])
        assert np.array_equal(model.predict(perm), base)
    roll = model.rollout(w, 3)
    perm = np.stack([f[rng.permutation(len(f))] for f in w])
    assert np.array_equal(model.rollout(perm, 3), roll)


def test_large_batches_take_the_numpy_path_and_agree(released64, released_nb64):
    rng = np.random.default_rng(8)
    wins = _windows(rng, M.ENGINE_MAX_BATCH + 1)
    assert released_nb64._engine_for(len(wins)) is None
    assert released_nb64._engine_for(1) is not None
    np.testing.assert_allclose(released_nb64.predict_batch(wins), released64.predict_batch(wins),
                               rtol=0, atol=1e-10)


def test_engine_reports_overflow_like_numpy():
    cfg = dataclasses.replace(SMALL, lstm_units=(4, 4, 4))
    ref = init_random(cfg, seed=1, dtype="float32")
    big = {k: (v * 1e20 if k.startswith("lstm1") and "kernel" in k else v)
           for k, v in ref.params.items()}
    ref = M.TPNet(cfg, big, "float32")
    nb = ref.with_engine("numba")
    w = np.random.default_rng(0).uniform(0, 1, size=(3, 7, 2))
    with pytest.raises(tpnet_ref.checks.NonFiniteResultError) as e_ref:
        ref.predict(w, normalized=True)
    with pytest.raises(tpnet_ref.checks.NonFiniteResultError) as e_nb:
        nb.predict(w, normalized=True)
    assert str(e_nb.value).split(" at ")[1].split(" (")[0] == \
        str(e_ref.value).split(" at ")[1].split(" (")[0]


def test_specialised_model_keeps_its_numpy_head_under_the_engine(released64):
    rng = np.random.default_rng(9)
    wins = _windows(rng, 4).astype(np.float32)
    model = released64.astype("float32")
    spec = model.specialize(wins).with_engine("numba")
    assert spec.engine == "numba" and spec.specialization is not None
    np.testing.assert_allclose(spec.predict(wins[0]), model.predict(wins[0]), atol=1e-3)


def test_unknown_engine_is_one_line_error(released64):
    with pytest.raises(ValueError, match="engine must be one of"):
        released64.with_engine("torch")


def test_missing_numba_names_the_extra(released64, monkeypatch):
    import tpnet_ref.extras as X
    real = X.importlib.import_module

    def fake(name, *a, **k):
        if name.split(".")[0] == "numba":
            raise ImportError("No module named 'numba'")
        return real(name, *a, **k)

    monkeypatch.setattr(X.importlib, "import_module", fake)
    with pytest.raises(MissingExtraError) as e:
        released64.with_engine("numba")
    msg = str(e.value)
    assert "\n" not in msg and "tpnet-ref[metrics]" in msg and "engine='numba'" in msg


def test_auto_engine_is_numba_when_installed(released64):
    assert released64.with_engine("auto").engine == "numba"


def test_numpy_engine_imports_no_numba(tmp_path):
    path = tmp_path / "w.h5"
    init_random(seed=0).save(path)
    code = ("import sys, numpy as np, tpnet_ref\n"
            f"m = tpnet_ref.load({str(path)!r})\n"
            "m.predict(np.random.default_rng(0).uniform(5, 40, (4, 30, 2)))\n"
            "print('numba' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
