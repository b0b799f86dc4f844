"""tpnet_ref.engines.numba_rollout: a rollout's steps in one compiled call give the step-by-step loop's
bits, take over only where the thread plan is one thread, and raise its errors."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("numba")

import tpnet_ref  # noqa: E402
from tpnet_ref.engines import thread_policy as TP  # noqa: E402
from tpnet_ref.engines import numba_rollout as ER  # noqa: E402
from tpnet_ref.checks import NonFiniteResultError  # noqa: E402
from ring_helpers import ring_windows  # noqa: E402


_windows = ring_windows                                   # fixed windows of a moving ring


@pytest.fixture
def calls(monkeypatch):
    """How often a rollout handed its steps to the compiled loop."""
    seen = []
    run_rest = ER.run_rest

    def counted(*args):
        seen.append(args[4])                              # the first fused step
        return run_rest(*args)
    monkeypatch.setattr(ER, "run_rest", counted)
    return seen


def _both(model, x, steps, monkeypatch):
    """The rollout with the plan fixed at one thread (the compiled loop takes over) and at two
    (step by step)."""
    roll = model.rollout if x.ndim == 3 else model.rollout_batch
    monkeypatch.setenv("TPNET_THREADS", "1")
    one = roll(x, steps)
    monkeypatch.setenv("TPNET_THREADS", "2")
    two = roll(x, steps)
    monkeypatch.delenv("TPNET_THREADS")
    return one, two


@pytest.mark.parametrize("size", ["quarter", "full"])            # both with a unit order
@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_the_compiled_steps_are_the_step_by_step_bits(size, dtype, calls, monkeypatch):
    model = tpnet_ref.load(size=size, dtype=dtype)
    for x, steps in ((_windows(1)[0], 30), (_windows(3), 12), (_windows(8), 9)):
        one, two = _both(model, x, steps, monkeypatch)
        assert one.tobytes() == two.tobytes()
    assert calls == [0] * 3                               # one thread fixed: every step fused


def test_a_network_without_a_unit_order_and_short_rollouts(released_random64, calls,
                                                          monkeypatch):
    model = released_random64.astype("float32").with_engine("numba")
    assert model.head_for(1).feature_order is None
    w = _windows(1)[0]
    for steps in (1, ER.STEPS_FIRST, ER.STEPS_FIRST + 1, 20):
        one, two = _both(model, w, steps, monkeypatch)
        assert one.tobytes() == two.tobytes() and one.shape == (steps, 30, 2)
    assert calls == [0] * 4                               # one thread fixed: from the start


def test_a_settled_plan_hands_over_at_the_first_step_and_refreshes_its_measure(
        released_random64, calls, monkeypatch):
    """Where the policy's latencies say one thread (by ``FUSED_GAIN``), a rollout runs every
    step in the compiled call, except every ``REFRESH_EVERY``-th, which runs its first steps
    one by one (the policy measures them); before any latency, the first steps too."""
    from tpnet_ref.engines import rollout as R

    class Settled:
        measured = False

        def one_thread_plan(self, kind, held=False, margin=None):
            return self.measured

        def preferred(self, kind):
            return 1 if self.measured else None
    policy = Settled()
    monkeypatch.setattr(R, "adaptive", policy)
    monkeypatch.setattr(R, "_ROLLOUTS", {})
    monkeypatch.delenv("TPNET_THREADS", raising=False)
    model = released_random64.astype("float32").with_engine("numba")
    w = _windows(1)[0]
    want = model.rollout(w, 12)                           # nothing measured: one by one
    assert calls == []
    policy.measured = True
    for _ in range(R.REFRESH_EVERY + 1):
        assert model.rollout(w, 12).tobytes() == want.tobytes()
    assert calls == [ER.STEPS_FIRST] + [0] * (R.REFRESH_EVERY - 1) + [ER.STEPS_FIRST]


def test_only_the_numba_engines_own_batches_are_fused(released_random64, calls, monkeypatch):
    model = released_random64.astype("float32").with_engine("numba")
    monkeypatch.setenv("TPNET_THREADS", "1")
    model.with_engine("numpy").rollout(_windows(1)[0], 10)
    model.with_point_sort(False).rollout(_windows(1)[0], 10)
    assert calls == []
    model.rollout_batch(_windows(8), 10)
    model.rollout_batch(_windows(9), 10)                   # its extractor serves every batch
    assert calls == [0, 0]                                # one thread fixed: from the start


def test_an_overflow_in_the_compiled_steps_is_the_step_by_step_error(released_random64,
                                                                     monkeypatch):
    import warnings
    model = released_random64.astype("float32").with_engine("numba")
    w = _windows(1)[0] * 1e30                             # the float32 network overflows
    errors = []
    for first in (0, 10 ** 6):                            # fused from the start, never fused
        monkeypatch.setattr(ER, "STEPS_FIRST", first)
        monkeypatch.setenv("TPNET_THREADS", "1")
        with pytest.raises(NonFiniteResultError) as got, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model.rollout(w, 20)
        errors.append(str(got.value))
    assert errors[0] == errors[1] and "overflowed in float32" in errors[0]


def test_the_one_thread_plan_reads_the_policy_without_changing_it(monkeypatch):
    p = TP.ThreadPolicy(monitor=None)
    monkeypatch.delenv("TPNET_THREADS", raising=False)
    monkeypatch.delenv("TPNET_BLAS_THREADS", raising=False)
    monkeypatch.setattr(TP, "cpu_count", lambda: 2)
    assert not p.one_thread_plan("k")                     # nothing measured: not settled
    for _ in range(8):
        choice = p.choose("k")
        p.record("k", choice, 1.0 if choice == 1 else 2.0)
    assert p.preferred("k") == 1 and p.one_thread_plan("k")
    before = repr(p._kinds)
    p.one_thread_plan("k")
    assert repr(p._kinds) == before
    q = TP.ThreadPolicy(monitor=None)
    for _ in range(8):
        choice = q.choose("k")
        q.record("k", choice, 2.0 if choice == 1 else 1.0)
    assert q.preferred("k") == 0 and not q.one_thread_plan("k")
    with TP.one_thread():
        assert q.one_thread_plan("k") and not q.one_thread_plan("k", held=True)
    monkeypatch.setenv("TPNET_THREADS", "1")
    assert q.one_thread_plan("k")
    monkeypatch.setenv("TPNET_THREADS", "2")
    assert not p.one_thread_plan("k")
    monkeypatch.delenv("TPNET_THREADS")
    monkeypatch.setattr(TP, "cpu_count", lambda: 1)
    assert q.one_thread_plan("k")

    class Taken:
        generation = 0

        def taken(self):
            return True
    r = TP.ThreadPolicy(monitor=Taken())
    monkeypatch.setattr(TP, "cpu_count", lambda: 2)
    assert r.one_thread_plan("k")
    assert r.one_thread_plan("k", margin=0.15)


def test_with_a_margin_the_one_thread_plan_holds_unless_two_threads_win_by_it(monkeypatch):
    """The rollout's gate of its one-thread compiled rest (``rollout.FUSED_GAIN``): two threads
    10 % faster by the policy still leave it to one thread; 20 % faster, not."""
    monkeypatch.delenv("TPNET_THREADS", raising=False)
    monkeypatch.delenv("TPNET_BLAS_THREADS", raising=False)
    monkeypatch.setattr(TP, "cpu_count", lambda: 2)
    for two, want in ((0.9, True), (0.8, False), (1.2, True)):
        p = TP.ThreadPolicy(monitor=None)
        assert not p.one_thread_plan("k", margin=0.15)    # nothing measured: not settled
        for _ in range(40):
            choice = p.choose("k")
            p.record("k", choice, 1.0 if choice == 1 else two)
        assert p.one_thread_plan("k", margin=0.15) is want
        assert p.one_thread_plan("k") is (two > 1)
