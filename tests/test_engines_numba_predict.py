"""tpnet_ref.engines.numba_predict: a prediction's network in one compiled call gives the separate
calls' bits, takes over only where the thread plan is one thread, and raises their errors."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

pytest.importorskip("numba")

import tpnet_ref  # noqa: E402
from tpnet_ref.checks import NonFiniteResultError  # noqa: E402
from tpnet_ref.engines import compile_watch as CW  # noqa: E402
from tpnet_ref.engines.blas import one_thread  # noqa: E402
from tpnet_ref.engines.numba_engine import NETWORK_APART_BYTES  # noqa: E402
from tpnet_ref.engines import numba_predict as NP  # noqa: E402
from ring_helpers import ring_windows, thrown_ball  # noqa: E402


_windows = ring_windows                                   # fixed windows of a moving ring


@pytest.fixture
def calls(monkeypatch):
    """The batch sizes the compiled call ran (not those it declined); ``(batch, True)`` for a
    two-thread plan's."""
    seen = []
    run = NP.run

    def counted(model, points, counts, batch, normalized, two=False):
        got = run(model, points, counts, batch, normalized, two)
        seen.extend([] if got is None else [(batch, two)] if two else [batch])
        return got
    monkeypatch.setattr(NP, "run", counted)
    return seen


def _separate(model):
    """The same network with the compiled call switched off: the separate calls at every plan."""
    out = model._replace()
    out.fused = None
    return out


def _inputs(dim=2):
    rng = np.random.default_rng(7)
    if dim == 3:
        w = thrown_ball()
        return [(w, True), (w.astype(np.float32), True), (rng.uniform(5.4, 39.6, (4, 42, 3)), True),
                (np.stack([thrown_ball(centre=(15.0 + i, 22.0, 30.0)) for i in range(3)]), False)]
    w = _windows(1)[0]
    ragged = [w[0][:25], w[1], w[2][:28], w[3]]
    return [(w, True), (w.astype(np.float32), True), (ragged, True),
            (rng.uniform(5.4, 39.6, (4, 30, 2)), True), (_windows(3), False),
            (_windows(9), False)]


def _predict(model, x, one, normalized=False):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return (model.predict if one else model.predict_batch)(x, normalized=normalized)


@pytest.mark.parametrize("size", ["quarter", "full"])            # both with a unit order
@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_the_compiled_call_gives_the_separate_calls_bits(size, dtype, calls, monkeypatch):
    model = tpnet_ref.load(size=size, dtype=dtype)
    separate = _separate(model)
    monkeypatch.setenv("TPNET_THREADS", "1")
    for x, one in _inputs():
        for normalized in (False, True):
            y = (x / 40.0) if normalized and not isinstance(x, list) else x
            got = _predict(model, y, one, normalized)
            assert got.tobytes() == _predict(separate, y, one, normalized).tobytes()
            monkeypatch.setenv("TPNET_THREADS", "2")               # the two-thread plan
            assert got.tobytes() == _predict(model, y, one, normalized).tobytes()
            monkeypatch.setenv("TPNET_THREADS", "1")
    batches = [1 if one else len(x) for x, one in _inputs()] * 2
    head = model.head_for(1)
    apart = [b for b in batches if head.direction_bytes * b >= NETWORK_APART_BYTES]
    assert sorted(c for c in calls if type(c) is int) == sorted(batches)
    assert sorted(c[0] for c in calls if type(c) is tuple) == [b for b in sorted(batches)
                                                                if b not in apart]
    assert (size, dtype) != ("quarter", "float32") or not apart      # the quarter's: whole
    assert size != "full" or len(apart) == len(batches)              # the full size's: apart


@pytest.mark.lane("fewer-bits")          # their kernels compile there (tests/lane.py)
@pytest.mark.parametrize("weights", ["int8", "bf16"])
def test_weights_of_fewer_bits_through_the_compiled_call(weights, calls, monkeypatch):
    model = tpnet_ref.load(size="quarter", weights=weights)
    monkeypatch.setenv("TPNET_THREADS", "1")
    for x, one in _inputs():
        assert _predict(model, x, one).tobytes() == _predict(_separate(model), x, one).tobytes()
    assert len(calls) == len(_inputs())


def test_a_3d_model_through_the_compiled_call(calls, monkeypatch):
    from tpnet_ref.weights.shipped import REPO_WEIGHTS_DIR
    model = tpnet_ref.load(str(REPO_WEIGHTS_DIR / "tpnet3d-m4-quarter.h5"))
    monkeypatch.setenv("TPNET_THREADS", "1")
    for x, one in _inputs(dim=3):
        got = _predict(model, x, one)
        assert got.shape[-2:] == (42, 3)
        assert got.tobytes() == _predict(_separate(model), x, one).tobytes()
    assert len(calls) == len(_inputs(dim=3))


def test_only_the_one_thread_plan_of_the_numba_engines_own_head_is_compiled_whole(
        released_random64, calls, monkeypatch):
    model = released_random64.astype("float32").with_engine("numba")
    w = _windows(1)[0]
    monkeypatch.setenv("TPNET_THREADS", "2")
    model.predict(w)
    monkeypatch.setenv("TPNET_THREADS", "1")
    model.with_engine("numpy").predict(w)
    assert model.with_engine("numpy").fused is None
    assert calls == []
    model.predict(w)
    model.with_point_sort(False).predict(w)                 # the points as given: still whole
    assert calls == [1, 1]
    with one_thread():                                      # nested: the policy stands aside
        model.predict(w)
    assert calls == [1, 1, 1]


def test_a_specialised_model_compiles_whole_only_what_its_numba_head_runs(released_random64,
                                                                         calls, monkeypatch):
    from tpnet_ref.engines.interface import ENGINE_MAX_BATCH
    model = released_random64.astype("float32").with_engine("numba")
    spec = model.specialize(_windows(2))
    monkeypatch.setenv("TPNET_THREADS", "1")
    big = _windows(ENGINE_MAX_BATCH + 1)
    assert NP.fusable(spec, ENGINE_MAX_BATCH) and not NP.fusable(spec, len(big))
    for x, one in ((big[0], True), (big[:ENGINE_MAX_BATCH], False), (big, False)):
        assert _predict(spec, x, one).tobytes() == _predict(_separate(spec), x, one).tobytes()
    assert calls == [1, ENGINE_MAX_BATCH]                    # the larger batch: its own head
    assert spec.counts["windows"] == len(big)


def test_where_the_kernel_may_not_compile_the_separate_calls_serve(released_random64, calls,
                                                                  monkeypatch):
    model = released_random64.astype("float32").with_engine("numba")
    w = _windows(1)[0]
    monkeypatch.setenv("TPNET_THREADS", "1")
    monkeypatch.setattr(CW, "TWO_THREAD_KERNELS_ON_DEMAND", False)
    monkeypatch.setattr(NP, "_MEMO", {})
    monkeypatch.setattr(NP, "may_compile", lambda *a: False)
    got = model.predict(w)
    assert calls == []                                       # asked, and declined
    assert got.tobytes() == _separate(model).predict(w).tobytes()


def test_an_overflow_in_the_compiled_call_is_the_separate_calls_error(released_random64,
                                                                       monkeypatch):
    model = released_random64.astype("float32").with_engine("numba")
    w = _windows(1)[0] * 1e30                                # the float32 network overflows
    said, kernel = [], NP.network_steps
    monkeypatch.setattr(NP, "network_steps", lambda *a: said.append(kernel(*a)) or said[-1])
    errors = []
    monkeypatch.setenv("TPNET_THREADS", "1")
    for net in (model, _separate(model)):
        with pytest.raises(NonFiniteResultError) as got, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            net.predict(w)
        errors.append(str(got.value))
    assert len(said) == 1 and said[0] != 0                  # the compiled call saw it first
    assert errors[0] == errors[1] and "overflowed in float32" in errors[0]


def test_a_model_with_its_compiled_call_copies_and_pickles(calls, monkeypatch):
    """The model keeps a picklable handle on the compiled call (not the module): a copied or
    pickled model predicts through it, with the same bits."""
    import copy
    import pickle
    model = tpnet_ref.load(size="quarter")
    monkeypatch.setenv("TPNET_THREADS", "1")
    w = _windows(1)[0]
    want = model.predict(w)
    for other in (copy.deepcopy(model), pickle.loads(pickle.dumps(model))):
        assert other.predict(w).tobytes() == want.tobytes()
    assert calls == [1, 1, 1]


@pytest.mark.parametrize("which", [
    "quarter", pytest.param("int8", marks=pytest.mark.lane("fewer-bits")),
    pytest.param("3-D", marks=pytest.mark.lane("3-D"))])      # their kernels compile there
def test_the_two_thread_plan_runs_the_two_thread_kernel_with_the_same_bits(which, calls,
                                                                            monkeypatch):
    from tpnet_ref.weights.shipped import REPO_WEIGHTS_DIR
    if which == "3-D":
        model, dim = tpnet_ref.load(str(REPO_WEIGHTS_DIR / "tpnet3d-m4-quarter.h5")), 3
    else:
        model, dim = tpnet_ref.load(size="quarter", weights="int8" if which == "int8"
                                    else "float32"), 2
    ran, kernel = [], NP.network_parallel
    monkeypatch.setattr(NP, "network_parallel", lambda *a: ran.append(1) or kernel(*a))
    for x, one in _inputs(dim):
        monkeypatch.setenv("TPNET_THREADS", "1")
        want = _predict(model, x, one).tobytes()
        monkeypatch.setenv("TPNET_THREADS", "2")
        assert _predict(model, x, one).tobytes() == want
    assert len(ran) == len(_inputs(dim))                     # every two-thread call took it
    assert len(calls) == 2 * len(_inputs(dim))


def test_where_the_two_thread_kernel_is_missing_the_extractor_takes_the_second_thread(
        calls, monkeypatch):
    """A short command (two-thread kernels only where numba has them) in a process where numba
    has not got :func:`network_parallel`: the extractor's own two-thread call, then the rest."""
    from tpnet_ref.engines import two_thread_gate as G
    model = tpnet_ref.load(size="quarter")          # the full size's directions go apart
    w = _windows(1)[0]
    monkeypatch.setenv("TPNET_THREADS", "1")
    want = model.predict(w).tobytes()
    monkeypatch.setattr(CW, "TWO_THREAD_KERNELS_ON_DEMAND", False)
    monkeypatch.setattr(NP, "_MEMO", {})
    monkeypatch.setattr(CW, "compiled_or_cached",
                        lambda kernel, args: kernel is not NP.network_parallel)
    monkeypatch.setattr(G, "_SKIPPED", set())
    ran, kernel = [], NP.network_parallel

    def network_parallel(*a):                               # a spy of the kernel's name
        ran.append(1)
        return kernel(*a)
    monkeypatch.setattr(NP, "network_parallel", network_parallel)
    monkeypatch.setenv("TPNET_THREADS", "2")
    assert model.predict(w).tobytes() == want
    assert ran == [] and calls == [1, (1, True)], calls
    assert "network_parallel" in G.two_thread_kernels_skipped()


def test_an_overflow_in_the_two_thread_kernel_is_the_one_thread_error(monkeypatch):
    model = tpnet_ref.load(size="quarter")
    w = _windows(1)[0] * 1e30
    errors = []
    for threads in ("1", "2"):
        monkeypatch.setenv("TPNET_THREADS", threads)
        with pytest.raises(NonFiniteResultError) as got, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model.predict(w)
        errors.append(str(got.value))
    assert errors[0] == errors[1] and "overflowed in float32" in errors[0]


def test_the_kernels_compiled_code_called_directly_gives_the_dispatchers_bits(monkeypatch):
    """From the second call of one head on arguments of the same types, ``run`` calls numba's
    compiled code without the dispatcher; arrays whose flags would change the numba type
    (read-only, unaligned) are copied into plain ones, so they compile nothing more and give the
    same bits; a ``normalized`` given as an int runs ``True``'s code."""
    model = tpnet_ref.load(size="quarter")
    monkeypatch.setenv("TPNET_THREADS", "1")
    w = _windows(1)[0]
    pts, counts = model.canonical_points(np.asarray(w, dtype=np.float32).reshape(-1, 30, 2))
    want = NP.network_steps                                  # through the dispatcher
    ro = pts.copy()
    ro.flags.writeable = False
    raw = np.empty(pts.nbytes + 1, dtype=np.uint8)[1:].view(np.float32).reshape(pts.shape)
    raw[...] = pts                                           # an unaligned copy
    assert not raw.flags.aligned
    got, compiled = {}, {}
    for name, p, normalized in [("plain", pts, False), ("again", pts, False), ("ro", ro, False),
                                ("unaligned", raw, False), ("int", pts, 1), ("int again", pts, 1)]:
        got[name] = NP.run(model, p, counts, 1, normalized).tobytes()
        compiled[name] = len(want.signatures)
    assert compiled["plain"] == compiled["ro"] == compiled["unaligned"]
    head = model.head_for(1)
    calls = NP._CONSTANTS[head][3]
    direct = [fn for fn in calls.values() if fn is not want]
    assert len(calls) == 2 and len(direct) == 2              # normalized=1: True's code
    assert len({got[k] for k in ("plain", "again", "ro", "unaligned")}) == 1
    assert got["int"] == got["int again"]
    args = NP._constants(head, model.engine_features, model.dtype)[1]
    out = np.empty((1, 60), dtype=np.float32)
    assert want(pts, counts, 4, 1, *args, False, model._lo, model._scale,
                np.empty((0, 0), np.float32), out) == 0
    assert out.tobytes() == got["plain"]


def test_entry_point_is_none_for_types_numba_has_not_compiled():
    from numba import njit

    @njit
    def twice(x):
        return 2 * x
    assert CW.entry_point(twice, (1.0,)) is None
    assert twice(1.0) == 2.0
    assert CW.entry_point(twice, (1.0,))(3.0) == 6.0
    assert CW.entry_point(twice, (1,)) is None               # int64: not compiled
    assert CW.entry_point(lambda x: x, (1,)) is None         # not a numba dispatcher
