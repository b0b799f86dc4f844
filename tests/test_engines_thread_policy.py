"""The thread policy: the measured choice between one thread and two for single windows, that
every plan runs the BLAS on one thread, and that neither the plan nor the BLAS's own thread
setting changes a result (so the choice is free to follow the load)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import threadpoolctl

from tpnet_ref.engines import blas, load_monitor, thread_policy
from tpnet_ref.model import init_random


def _blas_threads() -> list[int]:
    return [d["num_threads"] for d in threadpoolctl.threadpool_info() if d["user_api"] == "blas"]


def _run(policy: thread_policy.ThreadPolicy, kind, latency: dict[int, float], calls: int) -> list[int]:
    """Drive the policy with fake latencies per choice; returns the choices made."""
    out = []
    for _ in range(calls):
        c = policy.choose(kind)
        policy.record(kind, c, latency[c])
        out.append(c)
    return out


def test_policy_runs_the_faster_choice_and_probes_the_other():
    p = thread_policy.ThreadPolicy(probe_every=8, keep=4)
    choices = _run(p, "k", {1: 5.0, 0: 4.0}, 4 + 80)     # all threads faster (an idle machine)
    assert p.preferred("k") == 0
    steady = choices[4:]
    assert steady.count(1) == 10                         # one probe every 8 calls
    assert all(c == 0 for i, c in enumerate(steady, 1) if i % 8)


def test_policy_follows_a_change_of_load_within_a_few_calls():
    p = thread_policy.ThreadPolicy(probe_every=8, keep=4)
    _run(p, "k", {1: 5.0, 0: 4.0}, 40)
    assert p.preferred("k") == 0
    later = _run(p, "k", {1: 5.5, 0: 40.0}, 20)          # the other core got busy
    # switched after two slow calls; then a probe of two threads (two calls: a warm-up, then
    # the measured one) every probe_every calls at first
    assert later[2:].count(0) <= 4
    assert p.preferred("k") == 1
    back = _run(p, "k", {1: 5.5, 0: 4.0}, 200)           # and idle again
    assert p.preferred("k") == 0 and back[-8:].count(0) >= 7


def test_losing_probes_get_rarer():
    p = thread_policy.ThreadPolicy(probe_every=8, keep=4)
    choices = _run(p, "k", {1: 5.0, 0: 100.0}, 4 + 2000)
    probes = choices[4:].count(0)
    assert 0 < probes < 2000 // 8 // 4                   # backed off: far fewer than every 8th
    assert p.preferred("k") == 1


def test_a_small_win_of_the_blas_threads_keeps_one_thread_and_their_probes_get_rare():
    """Two threads 5 % faster (within the margin): one thread runs, the steadier choice beside
    a busy core, and the two-thread probes back off as losing ones do."""
    p = thread_policy.ThreadPolicy(probe_every=8, keep=4, margin=0.1)
    choices = _run(p, "k", {1: 5.0, 0: 4.75}, 4 + 2000)
    assert p.preferred("k") == 1
    assert 0 < choices[4:].count(0) < 2000 // 8 // 4
    # a clear win (20 %) still moves the choice to the BLAS's threads, and back when it is gone
    _run(p, "k", {1: 5.0, 0: 4.0}, 3000)
    assert p.preferred("k") == 0
    _run(p, "k", {1: 5.0, 0: 4.9}, 40)
    assert p.preferred("k") == 1


def test_a_gain_between_the_two_margins_keeps_whichever_plan_runs():
    """Hysteresis: two threads 5 % faster (between HOLD_MARGIN and MARGIN) are not taken from
    one thread, and are kept once taken; plans within HOLD_MARGIN go back to one thread."""
    assert thread_policy.HOLD_MARGIN < 0.05 < thread_policy.MARGIN
    p = thread_policy.ThreadPolicy(probe_every=8, keep=4)
    _run(p, "k", {1: 5.0, 0: 4.75}, 400)
    assert p.preferred("k") == 1
    _run(p, "k", {1: 5.0, 0: 4.0}, 400)                   # a clear win: taken
    assert p.preferred("k") == 0
    kept = _run(p, "k", {1: 5.0, 0: 4.75}, 400)           # 5 %: kept, one-thread probes only
    assert p.preferred("k") == 0 and kept[-80:].count(1) == 10
    _run(p, "k", {1: 5.0, 0: 4.9}, 40)                    # 2 %: back to one thread
    assert p.preferred("k") == 1


def test_every_plan_runs_a_one_thread_blas_and_restores_the_threads(monkeypatch):
    # the machine's load must not decide the plans here (a busy machine gets one thread only):
    # the load monitor's part is tested with fakes below
    monkeypatch.setattr(thread_policy.adaptive, "monitor", None)
    before = _blas_threads()
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        with blas.one_thread():
            with thread_policy.adaptive("stand aside") as choice:     # nested: one thread, no choice
                assert choice == -1 and not thread_policy.two_threads()
                assert all(n == 1 for n in _blas_threads())
        seen = set()
        for _ in range(12):
            with thread_policy.adaptive("restores") as choice:
                seen.add(choice)
                assert all(n == 1 for n in _blas_threads())  # both plans: a one-thread BLAS
                assert thread_policy.two_threads() == (choice == 0)
            assert all(n == 2 for n in _blas_threads()) and not thread_policy.two_threads()
        assert seen == {0, 1}                               # both plans were tried
    assert _blas_threads() == before


def test_environment_fixes_the_choice(monkeypatch):
    p = thread_policy.ThreadPolicy()
    for var, one, two in (("TPNET_THREADS", "1", "2"), ("TPNET_BLAS_THREADS", "1", "all")):
        monkeypatch.setenv(var, one)
        assert {p.choose("k") for _ in range(20)} == {1}
        monkeypatch.setenv(var, two)
        assert {p.choose("k") for _ in range(20)} == {0}
        monkeypatch.delenv(var)


@pytest.mark.parametrize("engine", ["numpy", "numba"])
@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_a_single_window_gives_the_same_bits_whatever_the_threads(engine, dtype, monkeypatch):
    """predict and rollout of one window give the same bits with the BLAS set to one or two
    threads outside, and with the policy's plan fixed to one or two threads."""
    base = init_random(seed=3, dtype=dtype)
    rng = np.random.default_rng(4)
    cases = []
    for m, sizes in ((4, [30] * 4), (1, [7]), (6, [64] * 6), (3, [5, 64, 17]), (4, [1, 2, 40, 33])):
        model = type(base)(dataclasses.replace(base.config, m=m), base.params, dtype,
                           engine=engine)
        frames = [rng.uniform(5, 40, (n, 2)) for n in sizes]
        cases.append((model, frames))

    def outputs(plan: str, blas_threads: int) -> list[np.ndarray]:
        monkeypatch.setenv("TPNET_THREADS", plan)
        with threadpoolctl.threadpool_limits(limits=blas_threads, user_api="blas"):
            return [f(model, frames) for model, frames in cases
                    for f in (lambda mo, fr: mo.predict(fr), lambda mo, fr: mo.rollout(fr, 3))]

    first = outputs("1", 1)
    for plan, n in (("2", 2), ("1", 2), ("2", 1)):
        for a, b in zip(first, outputs(plan, n)):
            assert np.array_equal(a, b)


@pytest.mark.parametrize("engine", ["numpy", "numba"])
def test_feature_blocks_on_two_threads_give_the_same_bits(engine, monkeypatch):
    """A batch of more than one feature block (fast_numpy.BLOCK_POINTS points) that split_batch
    does not cut: its blocks run on one thread or two, the same bits, ragged frames included."""
    model = init_random(seed=5, dtype="float32").with_engine(engine)
    rng = np.random.default_rng(6)
    windows = rng.uniform(5, 40, (40, 4, 30, 2))                    # 4800 points: 3 blocks
    ragged = [rng.uniform(5, 40, (n, 2)) for n in rng.integers(200, 900, 4)]
    runs = {}
    for plan in ("1", "2", "1"):
        monkeypatch.setenv("TPNET_THREADS", plan)
        runs.setdefault(plan, []).append((model.predict_batch(windows), model.predict(ragged),
                                          model.rollout_batch(windows[:20], 2)))
    (a,), (b, c) = runs["2"], runs["1"]
    for x, y, z in zip(a, b, c):
        assert np.array_equal(x, y) and np.array_equal(y, z)


def test_a_two_thread_probe_is_measured_after_a_warm_up_call():
    """Waking the second thread's sleeping workers makes the first two-thread call after a run
    of one-thread calls slower: that call is not recorded, so two threads that are faster once
    awake win."""
    p = thread_policy.ThreadPolicy(probe_every=8, keep=4, margin=0.1)
    _run(p, "k", {1: 5.0, 0: 6.0}, 40)                  # two threads slower: one thread runs
    assert p.preferred("k") == 1
    prev, choices = 1, []
    for _ in range(400):                                # now: 4.0 warm, 6.0 the first call
        c = p.choose("k")
        p.record("k", c, (4.0 if prev == 0 else 6.0) if c == 0 else 5.0)
        prev = c
        choices.append(c)
    assert p.preferred("k") == 0 and choices[-16:].count(0) >= 14


# ------------------------------------------------------------------ the load monitor
# The policy watches the machine: ``load_monitor.CoreMonitor`` reads how many cores other
# processes at normal priority take now (/proc/stat less this process's own time, at most every
# ``SAMPLE_S``), and ``ThreadPolicy`` runs one thread while the other core is taken and measures
# both plans afresh when the machine changes. Fakes stand in for /proc/stat and the clocks, so
# these run the same on any machine.
class Machine:
    """A fake /proc/stat, process clock and wall clock: ``run(seconds, others, own)``."""

    def __init__(self, cores: int = 2) -> None:
        self.t, self.busy, self.nice, self.mine, self.reads = 0.0, 100.0, 50.0, 1.0, 0

    def read(self):
        self.reads += 1
        return self.busy, self.nice

    def run(self, seconds: float, others: float, own: float = 1.0, niced: float = 0.0) -> None:
        self.t += seconds
        self.busy += seconds * (others + own)
        self.nice += seconds * niced
        self.mine += seconds * own

    def monitor(self) -> load_monitor.CoreMonitor:
        return load_monitor.CoreMonitor(read=self.read, clock=lambda: self.t, own=lambda: self.mine,
                                count_nice=False)


def test_a_spinning_process_is_seen_and_its_end_too(monkeypatch):
    monkeypatch.setattr(load_monitor, "cpu_count", lambda: 2)
    m = Machine()
    mon = m.monitor()
    assert not mon.taken()                               # the first look sets the baseline
    m.run(0.06, others=0.0, own=1.5)                     # our two threads alone
    assert not mon.taken() and mon.generation == 0
    m.run(0.06, others=1.0)                              # another process spins a core
    assert mon.taken() and mon.generation == 1 and abs(mon.others - 1.0) < 1e-9
    m.run(0.06, others=0.5)                              # between the thresholds: still taken
    assert mon.taken()
    m.run(0.06, others=0.1)
    assert not mon.taken() and mon.generation == 2


def test_niced_background_jobs_do_not_take_a_core(monkeypatch):
    monkeypatch.setattr(load_monitor, "cpu_count", lambda: 2)
    m = Machine()
    mon = m.monitor()
    mon.taken()
    m.run(0.06, others=0.0, own=1.8, niced=0.2)          # nice 19 training: yields to us
    assert not mon.taken()


def test_niced_jobs_count_where_the_kernel_groups_by_session(monkeypatch):
    monkeypatch.setattr(load_monitor, "cpu_count", lambda: 2)
    m = Machine()
    mon = load_monitor.CoreMonitor(read=m.read, clock=lambda: m.t, own=lambda: m.mine, count_nice=True)
    mon.taken()
    m.run(0.06, others=0.0, own=1.0, niced=1.0)          # autogroup: nice orders one session only
    assert mon.taken()


def test_proc_stat_is_read_at_most_every_sample(monkeypatch):
    monkeypatch.setattr(load_monitor, "cpu_count", lambda: 2)
    m = Machine()
    mon = m.monitor()
    for _ in range(100):                                 # 100 calls of 0.1 ms
        mon.taken()
        m.run(1e-4, others=0.0)
    assert m.reads == 1
    m.run(load_monitor.SAMPLE_S, others=0.0)
    mon.taken()
    assert m.reads == 2


def test_the_policy_runs_one_thread_while_taken_and_measures_afresh_after(monkeypatch):
    monkeypatch.setattr(load_monitor, "cpu_count", lambda: 2)
    monkeypatch.delenv("TPNET_THREADS", raising=False)
    monkeypatch.delenv("TPNET_BLAS_THREADS", raising=False)
    m = Machine()
    p = thread_policy.ThreadPolicy(probe_every=8, keep=4, monitor=m.monitor())
    kind = "predict"
    for _ in range(12):                                  # idle: two threads measure faster
        c = p.choose(kind)
        p.record(kind, c, 1.0e-3 if c == 0 else 1.6e-3)
        m.run(1e-3, others=0.0, own=1.8)
    assert p.preferred(kind) == 0
    m.run(load_monitor.SAMPLE_S, others=1.0)                     # a core is taken
    plans = []
    for _ in range(40):
        c = p.choose(kind)
        plans.append(c)
        p.record(kind, c, 2.9e-3 if c == 0 else 1.6e-3)
        m.run(1e-3, others=1.0)
    assert plans == [1] * 40                             # no two-thread probe while taken
    plans = []                                           # free again, calls of 1 ms
    for _ in range(200):
        c = p.choose(kind)
        plans.append(c)
        p.record(kind, c, 1.0e-3 if c == 0 else 1.6e-3)
        m.run(1e-3, others=0.0, own=1.8)
    # seen within two windows of SAMPLE_S (the first still averages in the busy end), then a
    # few calls measure both plans afresh: two threads again
    first = plans.index(0)
    assert first <= 2 * load_monitor.SAMPLE_S / 1e-3 + 4
    assert plans[first + 4:].count(1) <= len(plans[first + 4:]) // 8 + 1   # probes only


def test_without_proc_stat_the_monitor_stays_free(monkeypatch):
    mon = load_monitor.CoreMonitor(read=lambda: None)
    assert not mon.taken() and not mon.taken() and mon.generation == 0
