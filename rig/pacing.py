"""Software pacing helpers for the simulated rig's clock (and the benchmark's bare loop).

On this kind of VM, sleeping to 0.5 ms before a deadline and then spinning on
``perf_counter`` wakes within ~1 us (median) where a plain sleep is ~100 us
late (see docs/performance.md). A 1 ns timer slack makes the sleep tighter.
When other processes load the machine, only a real-time scheduling class keeps
the loop on time: ``realtime_priority`` puts the calling thread in SCHED_FIFO
where the OS permits it (root or CAP_SYS_NICE / an rtprio limit), for one
thread (the calling one, or a given thread of this process; child processes and
other threads keep their class).
``pin_to_cpu`` likewise pins the calling thread only to one CPU (Linux CPU
affinity is per thread), as a real-time lab PC pins its control loop to a core.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import time

PR_SET_TIMERSLACK = 29
SPIN_S = 0.0005


def set_timer_slack(ns: int = 1) -> bool:
    """Ask Linux for a tight timer slack for this thread; False where unsupported."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return bool(libc.prctl(PR_SET_TIMERSLACK, ns, 0, 0, 0) == 0)
    except (OSError, AttributeError):
        return False


def sleep_until(deadline: float, spin_s: float = SPIN_S) -> float:
    """Sleep, then spin, until perf_counter() >= deadline; returns the wake time."""
    now = time.perf_counter()
    if deadline - now > spin_s:
        time.sleep(deadline - now - spin_s)
    while (now := time.perf_counter()) < deadline:
        pass
    return now


def realtime_priority(priority: int, tid: int = 0) -> bool:
    """Put the calling thread (or thread ``tid`` of this process) in SCHED_FIFO at ``priority``
    (1-99); False where not permitted."""
    if priority <= 0:
        return False
    try:
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, OSError):
        return False
    return True


def usable_cpus() -> set[int] | None:
    """The CPUs the calling thread may run on; None where the OS has no CPU affinity."""
    try:
        return set(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return None


def pin_to_cpu(cpu: int) -> set[int] | None:
    """Pin the calling thread (only it) to ``cpu``; returns the CPUs it could use before (for
    ``set_cpus``), None where the OS cannot pin threads or refused."""
    before = usable_cpus()
    if before is None:
        return None
    try:
        os.sched_setaffinity(0, {cpu})
    except (AttributeError, OSError):
        return None
    return before


def set_cpus(cpus: set[int]) -> None:
    """Let the calling thread run on ``cpus`` (undoes ``pin_to_cpu``)."""
    with contextlib.suppress(AttributeError, OSError):
        os.sched_setaffinity(0, cpus)


def cpu_list(cpus: set[int]) -> str:
    """``{0, 1, 2, 5}`` -> ``"0-2, 5"``."""
    out: list[str] = []
    for c in sorted(cpus):
        if out and out[-1].split("-")[-1] == str(c - 1):
            out[-1] = f"{out[-1].split('-')[0]}-{c}"
        else:
            out.append(str(c))
    return ", ".join(out)


def normal_priority(tid: int = 0) -> None:
    """Back to the normal time-sharing class (SCHED_OTHER) for the calling thread (or ``tid``)."""
    with contextlib.suppress(AttributeError, OSError):
        os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
