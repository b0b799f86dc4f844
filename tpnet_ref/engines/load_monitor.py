"""How many cores other processes take now: the load monitor the thread policy
(:mod:`tpnet_ref.engines.thread_policy`) watches, read from ``/proc/stat``."""
from __future__ import annotations

import os
import threading
import time
from typing import Any

from .blas import cpu_count

#: :class:`CoreMonitor`: seconds between two looks at /proc/stat (jiffies are 10 ms, so a
#: shorter window could not tell a spinning core from noise)
SAMPLE_S = 0.05
#: :class:`CoreMonitor`: the other core counts as taken above this many cores' worth of other
#: processes' time at normal priority, and as free again below the second figure (hysteresis)
TAKEN_CORES, FREE_CORES = 0.6, 0.35


def _read_proc_stat() -> tuple[float, float] | None:
    """Seconds all cores spent busy at normal priority (user, system, irq, softirq, steal) and at
    a lower one (nice), from the first line of /proc/stat; None where there is none."""
    try:
        with open("/proc/stat", "rb") as f:
            v = f.readline().split()
    except OSError:
        return None
    if len(v) < 9 or v[0] != b"cpu":
        return None
    user, nice, system, _idle, _io, irq, softirq, steal = (int(x) for x in v[1:9])
    tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    return (user + system + irq + softirq + steal) / tick, nice / tick


def _nice_counts() -> bool:
    """Whether niced processes take cores from this one: when it is niced itself, or when Linux
    groups processes by session (``sched_autogroup_enabled``), where nice only orders the
    processes of one session and another session's ``nice 19`` job gets its share all the same."""
    if hasattr(os, "nice") and os.nice(0) > 0:
        return True
    try:
        with open("/proc/sys/kernel/sched_autogroup_enabled", "rb") as f:
            return f.read().strip() == b"1"
    except OSError:
        return False


class CoreMonitor:
    """How many cores other processes take now, from /proc/stat, read at most every
    :data:`SAMPLE_S` seconds (one ``time.monotonic()`` per call in between). Other processes' time at normal priority is the busy time of all cores less
    this process's own (``os.times``); time of niced processes (a background job at ``nice 19``)
    does not count, since they yield the core to this one -- unless this process is niced itself
    or the kernel groups processes by session (autogroup), where they do not yield
    (:func:`_nice_counts`; ``count_nice`` overrides).
    :meth:`taken` says whether fewer than two cores are free for a call's two threads;
    :attr:`generation` counts the changes, so that a policy can drop latencies measured before
    one. Where /proc/stat cannot be read it says "free" and never changes."""

    def __init__(self, read: Any = _read_proc_stat, clock: Any = time.monotonic,
                 own: Any = None, sample_s: float = SAMPLE_S,
                 count_nice: bool | None = None) -> None:
        self._read, self._clock, self.sample_s = read, clock, sample_s
        self._own = own or (lambda: sum(os.times()[:2]))
        self._niced = _nice_counts() if count_nice is None else bool(count_nice)
        self._last: tuple[float, float, float] | None = None
        self._lock = threading.Lock()
        self.others = 0.0        #: other processes' cores, over the last window
        self.is_taken = False
        self.generation = 0

    def taken(self) -> bool:
        """Whether other processes take so much of the machine that a second thread would wait
        (looked at again when :data:`SAMPLE_S` has passed since the last look)."""
        now = self._clock()
        last = self._last
        if last is not None and now - last[0] < self.sample_s:
            return self.is_taken
        with self._lock:
            if self._last is not last:                  # another thread looked meanwhile
                return self.is_taken
            stat = self._read()
            if stat is None:
                self._last = (now, 0.0, 0.0)
                return self.is_taken
            busy = stat[0] + (stat[1] if self._niced else 0.0)
            own = self._own()
            if last is not None and now > last[0]:
                self.others = max(0.0, (busy - last[1]) - (own - last[2])) / (now - last[0])
                free = cpu_count() - self.others
                taken = free < 2 - TAKEN_CORES if not self.is_taken else free < 2 - FREE_CORES
                if taken != self.is_taken:
                    self.is_taken, self.generation = taken, self.generation + 1
            self._last = (now, busy, own)
            return self.is_taken



__all__ = ["SAMPLE_S", "TAKEN_CORES", "FREE_CORES", "CoreMonitor"]
