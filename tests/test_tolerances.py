"""Every stated tolerance is a test (docs/tolerances.md): the ways of computing the same
prediction that are not bit-identical stay within the bounds the docs state, per prediction
and over an 80-step rollout, in float32 and float64, on the shipped model and windows of a
simulated training-grid trajectory. (Another BLAS kernel: tests/test_determinism.py.)

Each engine is loaded by name and checked to be the one it is named (``load()`` picks Numba
where it is installed, and ``astype`` keeps the engine): the two engines are compared engine
against engine, and every other way (batch, specialised, unit order, dtype) runs on both. A
batch large enough to be split into chunks (65 windows: 64 + 1) is compared with the same
windows one at a time, on both engines, its chunks one after another and on two threads."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import tpnet_ref
from tolerance_bounds import BOUNDS, assert_within

pytest.importorskip("pymunk")
numba = pytest.importorskip("numba")

STEPS = 80
ENGINES = ["numpy", "numba"]
#: a batch that :func:`tpnet_ref.engines.batch_split.split_batch` cuts into chunks (64 + 1 windows)
SPLIT = 65


@pytest.fixture(scope="module")
def windows():
    from tpnet_ref.sim import simulate
    from tpnet_ref.sim.cases import TRAIN_POSITIONS
    traj = simulate(1.3, 195.0, *TRAIN_POSITIONS[7])          # a training-grid trajectory
    return np.stack([traj[s:s + 16:4] for s in (0, 60)])


@pytest.fixture(scope="module")
def shipped():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return tpnet_ref.load(engine="numpy")


def _on(model, engine: str):
    """``model`` run by ``engine``, checked to be run by it: the NumPy engine has no compiled
    head or extractor; the Numba one's first head is the compiled one."""
    model = model.with_engine(engine)
    names = [h.name for h in model.heads]
    assert model.engine == engine
    if engine == "numpy":
        assert "numba" not in names and model.engine_features is None, names
    else:
        assert names[0] == "numba" and model.engine_features is not None, names
    return model


def _single(model, w):
    return (np.stack([model.predict(x) for x in w]),
            np.stack([model.rollout(x, STEPS) for x in w]))


def _batch(model, w):
    return model.predict_batch(w), model.rollout_batch(w, STEPS)


@pytest.fixture(scope="module")
def plain(shipped, windows):
    """Each window alone, per (engine, dtype): ``{(engine, dtype): (predictions, rollouts)}``."""
    return {(e, dt): _single(_on(shipped.astype(dt), e), windows)
            for e in ENGINES for dt in BOUNDS}


def test_each_engine_is_the_one_named(shipped):
    assert shipped.engine == "numpy"                        # loaded by name, not "auto"
    for e in ENGINES:
        for dt in BOUNDS:
            assert _on(shipped.astype(dt), e).astype(dt).engine == e


@pytest.mark.parametrize("dtype", list(BOUNDS))
@pytest.mark.parametrize("engine", ENGINES)
def test_a_window_in_a_batch_against_it_alone(shipped, windows, plain, dtype, engine):
    model = _on(shipped.astype(dtype), engine)
    alone = plain[engine, dtype]
    b = _batch(model, windows)
    assert_within(b[0], alone[0], b[1], alone[1], dtype, f"batch vs single, {engine}")
    assert np.array_equal(alone[1][:, 0], alone[0])        # a rollout starts with predict: bits


@pytest.mark.parametrize("dtype", list(BOUNDS))
def test_the_two_engines(windows, plain, dtype):
    nb, npy = plain["numba", dtype], plain["numpy", dtype]
    assert_within(nb[0], npy[0], nb[1], npy[1], dtype, "numba vs numpy")
    # two computations, not one twice: the engines sum in different orders (float64 gaps
    # measured 1e-15..1e-13 per prediction); exactly equal rollouts would mean one engine
    assert not np.array_equal(nb[1], npy[1]), "the two engines gave the same bits: one engine twice?"


@pytest.mark.parametrize("dtype", list(BOUNDS))
@pytest.mark.parametrize("engine", ENGINES)
def test_a_specialised_model_against_the_plain_one(shipped, windows, plain, dtype, engine):
    from tpnet_ref.sim import simulate
    from tpnet_ref.sim.cases import TRAIN_POSITIONS
    traj = simulate(1.15, 230.0, *TRAIN_POSITIONS[40])       # calibrated on another trajectory
    scene = _on(shipped.astype(dtype), engine).specialize(
        np.stack([traj[i:i + 16:4] for i in range(0, 400, 8)]))
    assert scene.engine == engine and scene.specialization is not None
    sp = _single(scene, windows)
    ref = plain[engine, dtype]
    assert_within(sp[0], ref[0], sp[1], ref[1], dtype, f"specialised vs plain, {engine}")


@pytest.mark.parametrize("dtype", list(BOUNDS))
@pytest.mark.parametrize("engine", ENGINES)
def test_unit_sorted_against_the_file_order(shipped, windows, plain, dtype, engine):
    assert shipped.unit_order is not None                  # the shipped file carries an order
    fo = _single(_on(shipped.astype(dtype), engine).with_unit_order(None), windows)
    ref = plain[engine, dtype]
    assert_within(fo[0], ref[0], fo[1], ref[1], dtype, f"file order vs unit-sorted, {engine}")


@pytest.mark.parametrize("engine", ENGINES)
def test_float32_against_float64(plain, engine):
    f32, f64 = plain[engine, "float32"], plain[engine, "float64"]
    assert_within(f32[0], f64[0], f32[1], f64[1], "float32", f"float32 vs float64, {engine}")


@pytest.fixture(scope="module")
def split_windows():
    """:data:`SPLIT` windows of two simulated training-grid trajectories, each different."""
    from tpnet_ref.sim import simulate
    from tpnet_ref.sim.cases import TRAIN_POSITIONS
    out = []
    for case in (7, 40):
        traj = simulate(1.3, 195.0, *TRAIN_POSITIONS[case])
        out += [traj[s:s + 16:4] for s in range(0, 8 * 33, 8)]
    return np.stack(out[:SPLIT])


_ALONE: dict = {}       # (engine, dtype) -> the split windows' predictions and rollouts alone


@pytest.mark.parametrize("threads", [1, 2], ids=["serial", "threaded"])
@pytest.mark.parametrize("dtype", list(BOUNDS))
@pytest.mark.parametrize("engine", ENGINES)
def test_a_split_batch_against_its_windows_alone(shipped, split_windows, engine, dtype, threads):
    """A batch of 65 windows is run as chunks of 64 + 1 (tpnet_ref.engines.batch_split.split_batch), one
    after another (``threads=1``) or side by side: each window's prediction and 10-step rollout
    are those of the window alone, within the stated bounds, in the batch's order."""
    from tpnet_ref.engines.batch_split import SPLIT_MIN_BATCH
    assert len(split_windows) == SPLIT > SPLIT_MIN_BATCH
    model = _on(shipped.astype(dtype), engine)
    model.threads = threads
    steps = 10
    if (engine, dtype) not in _ALONE:                  # the same for either thread count
        _ALONE[engine, dtype] = (np.stack([model.predict(w) for w in split_windows]),
                                 np.stack([model.rollout(w, steps) for w in split_windows]))
    alone = _ALONE[engine, dtype]
    batch = model.predict_batch(split_windows), model.rollout_batch(split_windows, steps)
    assert_within(batch[0], alone[0], batch[1], alone[1], dtype,
                  f"split batch vs single, {engine}, {threads} thread(s)")
