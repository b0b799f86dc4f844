"""The thread policy watches the machine (issue 47): ``load_monitor.CoreMonitor`` reads how many cores
other processes at normal priority take now (/proc/stat less this process's own time, at most
every ``SAMPLE_S``), and ``ThreadPolicy`` runs one thread while the other core is taken and
measures both plans afresh when the machine changes. Fakes stand in for /proc/stat and the
clocks, so these run the same on any machine."""
from __future__ import annotations

from tpnet_ref.engines import load_monitor, thread_policy


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
