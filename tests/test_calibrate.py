"""Calibrated int8 (:mod:`tpnet_ref.weights.calibrate`, ``tpnet quantize --calibrate``): the
rounding stays on int8's grid with the scales re-derived, is round-to-nearest where inputs do
not co-vary and beats it where they do, the model and its file hold every matrix in one plane
and keep the engines' guarantees, and bad calibration data or a corrupted list of two-plane
matrices is a one-line error. On the shipped quarter size, calibrated on windows of training-
grid trajectories (never the test cases)."""
from __future__ import annotations

import subprocess
import sys
import warnings

import numpy as np
import pytest

import tpnet_ref
from tpnet_ref.weights import calibrate as C
from tpnet_ref.weights import quantize as Q
from tpnet_ref.weights.native import seal
from tpnet_ref.weights.shipped import shipped_weights_path

pytest.importorskip("numba")
pytestmark = pytest.mark.lane("fewer-bits")   # in a second test process (tests/lane.py)


# --------------------------------------------------------------------------- the rounding
def _correlated(rows, n=400, seed=0, draw=0):
    """Inputs whose coordinates co-vary (a few shared factors, ReLU'd, as the network's are):
    ``seed`` fixes how they co-vary, ``draw`` the sample."""
    mix = np.random.default_rng(seed).normal(size=(4, rows))
    rng = np.random.default_rng([seed, draw])
    x = rng.normal(size=(n, 4)) @ mix + 0.3 * rng.normal(size=(n, rows))
    return np.maximum(x, 0.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_rounding_is_on_int8s_grid_with_the_scales_of_the_float_weights(seed):
    rng = np.random.default_rng(seed)
    w = (rng.normal(size=(48, 40)) * 0.05).astype(np.float32)
    x = _correlated(48, seed=seed)
    got = C.round_rows(w, x.T @ x)
    codes, scales = Q.codes_of(got, "int8", "w")               # on the grid, scales re-derived
    assert np.array_equal(scales, Q.int8_scales(w))
    assert (np.abs(codes).max(axis=0) == 127).all()
    top = np.argmax(np.abs(w), axis=0)                         # each column's largest: +-127
    assert np.array_equal(got[top, np.arange(40)], Q.round_to(w, "int8")[top, np.arange(40)])


def test_bf16_rounding_is_on_bf16s_grid():
    w = (np.random.default_rng(3).normal(size=(48, 40)) * 0.05).astype(np.float32)
    x = _correlated(48)
    got = C.round_rows(w, x.T @ x, "bf16")
    assert np.array_equal(Q.round_to(got, "bf16"), got) and not np.array_equal(got, w)
    assert np.abs(got - w).max() < 0.05 * np.abs(w).max()


@pytest.mark.parametrize("scheme", ["int8", "bf16"])
def test_uncorrelated_inputs_round_to_nearest_and_correlated_ones_beat_it(scheme):
    rng = np.random.default_rng(4)
    w = (rng.normal(size=(64, 32)) * 0.05).astype(np.float32)
    nearest = Q.round_to(w, scheme)
    h = np.diag(rng.uniform(0.5, 2.0, 64))                     # no co-variation: nothing to move
    assert np.array_equal(C.round_rows(w, h, scheme), nearest)
    x = _correlated(64)
    x[:, 5] = 0.0                                              # an input that never occurs
    got = C.round_rows(w, x.T @ x, scheme)
    err = [np.linalg.norm(x @ (q.astype(np.float64) - w)) for q in (got, nearest)]
    assert err[0] < 0.7 * err[1], err
    held = _correlated(64, draw=1)                             # inputs it was not fitted on
    held[:, 5] = 0.0
    err = [np.linalg.norm(held @ (q.astype(np.float64) - w)) for q in (got, nearest)]
    assert err[0] < 0.8 * err[1], err


# ---------------------------------------------------------------------- data and the model
@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """A dataset file with the layout ``tpnet data generate`` writes for training: two
    training-grid trajectories (model coordinates) and their windows."""
    pytest.importorskip("pymunk")
    import h5py
    from tpnet_ref.config import normalize
    from tpnet_ref.sim.cases import TRAIN_ANGLES_DEG, TRAIN_FORCES, TRAIN_POSITIONS
    from tpnet_ref.sim.protocol import FRAME_EVERY
    from tpnet_ref.sim.scene import simulate
    trajs = [normalize(simulate(TRAIN_FORCES[i], TRAIN_ANGLES_DEG[3 * i], *TRAIN_POSITIONS[7 * i],
                                steps=400)[::FRAME_EVERY]).astype(np.float32) for i in (1, 3)]
    path = tmp_path_factory.mktemp("cal") / "grid.h5"
    with h5py.File(path, "w") as f:
        f["train/normalized"] = np.stack(trajs)
        f["train/windows"] = np.array([[t, s, 0] for t in range(2) for s in range(0, 90, 3)])
    return path


@pytest.fixture(scope="module")
def base():
    return tpnet_ref.load(size="quarter", engine="numba")


@pytest.fixture(scope="module", params=["int8", "bf16"])
def calibrated(base, data, request):
    return C.calibrated(base, C.training_windows(str(data), 4, 2, n=48), "grid.h5",
                        request.param)


def test_a_calibrated_model_holds_every_matrix_in_one_plane(base, calibrated):
    m = calibrated
    scheme = m.meta[Q.ATTR]
    assert m.meta[Q.WIDE_ATTR] == ""
    assert "48 training windows of grid.h5" in m.meta[C.ROUNDING_ATTR]
    assert "tpnet-m4-quarter.h5" in m.meta[Q.FROM_ATTR]
    names = set(Q.quantized_names(base.config))
    for k, v in base.params.items():
        assert np.array_equal(m.params[k], v) == (k not in names), k
    head = m.head_for(1)
    assert head.weights == scheme
    for k, r, i in zip(head.kernels, head.recs, range(1, 4)):   # one plane: rows as the floats
        assert k.dtype == r.dtype == (np.int8 if scheme == "int8" else np.uint16)
        assert k.shape[1] == base.params[f"lstm{i}.fwd.kernel"].shape[0]
        assert r.shape[1] == base.config.lstm_units[i - 1]


def _scene_windows():
    pytest.importorskip("pymunk")
    from tpnet_ref.sim.cases import TRAIN_POSITIONS
    from tpnet_ref.sim.protocol import FRAME_EVERY
    from tpnet_ref.sim.scene import simulate
    traj = simulate(1.3, 240.0, *TRAIN_POSITIONS[40], steps=300)[::FRAME_EVERY]
    return np.stack([traj[s:s + 4] for s in range(0, len(traj) - 4, 5)])


def test_it_moves_predictions_less_than_round_to_nearest_in_one_plane(base, calibrated):
    x = _scene_windows()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        want = base.predict_batch(x)
        scheme = calibrated.meta[Q.ATTR]
        nearest = {n: (Q.round_to(p, scheme) if n in Q.quantized_names(base.config) else p)
                   for n, p in base.params.items()}
        one_plane = tpnet_ref.model.TPNet(base.config, nearest, "float32", engine="numpy",
                                          unit_order=base.unit_order)
        moves = [float(np.abs(m.predict_batch(x) - want).max()) for m in (calibrated, one_plane)]
    assert 0 < moves[0] < 0.7 * moves[1], moves


def test_its_engine_keeps_the_guarantees(calibrated):
    """The same bits alone and in a batch, on one thread and two, for any order of a frame's
    points; within float32 rounding of the NumPy engine on the same weights."""
    import os
    x = _scene_windows()[:6]
    m = calibrated
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        batch = m.predict_batch(x)
        for plan in ("1", "2"):
            os.environ["TPNET_THREADS"] = plan
            try:
                single = np.stack([m.predict(w) for w in x])
            finally:
                del os.environ["TPNET_THREADS"]
            assert single.tobytes() == batch.tobytes()
        shuffled = x[:, :, np.random.default_rng(1).permutation(x.shape[2])]
        assert m.predict_batch(shuffled).tobytes() == batch.tobytes()
        assert np.abs(m.with_engine("numpy").predict_batch(x) - batch).max() < 1e-3


def _quantize(*extra):
    return subprocess.run([sys.executable, "-m", "tpnet_ref.cli", "quantize", "--weights",
                           str(shipped_weights_path(4, "quarter")), *extra],
                          capture_output=True, text=True, check=False)


def test_the_command_writes_a_smaller_file_that_loads_as_it_was_made(data, calibrated, tmp_path):
    out, nearest = tmp_path / "cal.h5", tmp_path / "rtn.h5"
    scheme = calibrated.meta[Q.ATTR]
    r = _quantize("--to", scheme, "--calibrate", str(data), "--windows", "48", "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert f"{scheme} (calibrated, one plane)" in r.stdout
    assert _quantize("--to", scheme, "-o", str(nearest)).returncode == 0
    assert out.stat().st_size < 0.95 * nearest.stat().st_size    # the full size: 0.88
    got = tpnet_ref.load(out)
    assert got.meta[Q.WIDE_ATTR] == "" and got.meta[C.ROUNDING_ATTR] == calibrated.meta[
        C.ROUNDING_ATTR].replace("grid.h5", data.name)
    for k, v in calibrated.params.items():
        assert np.array_equal(got.params[k], v), k
    again = tmp_path / "again.h5"
    got.save(again)
    assert tpnet_ref.load(again).meta[Q.WIDE_ATTR] == ""


@pytest.mark.parametrize("value, message", [
    ("lstm9.fwd.kernel", "corrupted quantized_wide 'lstm9.fwd.kernel'"),
    ("lstm1.fwd.kernel,lstm1.fwd.kernel", "corrupted quantized_wide"),
    ("lstm1.fwd.kernel", r"int8 codes must be int8 of shape \(64, 512\), got int8 \(32, 512\)"),
])
def test_a_corrupted_list_of_two_plane_matrices_is_one_line(data, tmp_path, value, message):
    import h5py
    out = tmp_path / "cal.h5"
    assert _quantize("--to", "int8", "--calibrate", str(data), "--windows", "8",
                     "-o", str(out)).returncode == 0
    with h5py.File(out, "r+") as f:
        f.attrs[Q.WIDE_ATTR] = value
    seal(out)                                    # a matching digest: the checks must see it
    with pytest.raises(ValueError, match=message) as exc:
        tpnet_ref.load(out, engine="numpy")
    assert "\n" not in str(exc.value) and str(out) in str(exc.value)


def test_bad_calibration_data_is_one_line(data, tmp_path):
    import h5py
    cases = {"missing.h5": "dataset file not found",
             str(shipped_weights_path(4, "quarter")): "no training windows"}
    three = tmp_path / "three.h5"
    with h5py.File(three, "w") as f:
        f.attrs["dim"] = 3
        f["train/normalized"] = np.zeros((1, 10, 42, 3), np.float32)
        f["train/windows"] = np.zeros((1, 3), np.int64)
    cases[str(three)] = "a 3-D dataset, the model is 2-D"
    for path, message in cases.items():
        r = _quantize("--to", "int8", "--calibrate", path, "-o", str(tmp_path / "x.h5"))
        assert r.returncode != 0 and message in r.stderr, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1
    r = _quantize("--to", "int8", "--calibrate", str(data), "--windows", "100000",
                  "-o", str(tmp_path / "x.h5"))
    assert "60 training windows, 100000 asked" in r.stderr
    with pytest.raises(ValueError, match="already int8"):
        C.calibrated(tpnet_ref.load(size="quarter", weights="int8"), np.zeros((1, 4, 30, 2)), "x")


def test_its_engine_is_within_float32_rounding_of_the_float64_reference(calibrated):
    """The Numba engine on the calibrated codes (one plane) against the float64 reference on the
    same dequantized weights: the rule of ``tpnet vectors``, as for every quantized model."""
    from tpnet_ref import testing
    m = calibrated
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        testing.agrees_with_reference(lambda w: m.predict(w), m,
                                      windows=testing.windows(m=4, n=30, centre=(15.0, 30.0),
                                                              scales=(1.0, 3.0)),
                                      max_examples=8, seed=58)
