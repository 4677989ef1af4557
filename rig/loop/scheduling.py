"""The torque loop's OS set-up (``loop_cpu``, ``LoopScheduling``); the simulated clock's
software pacing is rig.sim_backend.clock.

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
import gc
import os
import sys
from collections.abc import Callable, Sequence
from typing import Any

from rig.errors import InputError
from rig.inputs.config import RigConfig


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


def loop_cpu(cfg: RigConfig, say: Callable[[str], None]) -> int | None:
    """The CPU to pin the loop's thread to (``loop.cpu``), checked against this machine before
    anything starts (one-line ValueError); None = unpinned, said once where unsupported."""
    cpu = cfg.loop.cpu
    if cpu is None:
        return None
    cpus = usable_cpus()
    if cpus is None:
        say(f"loop.cpu: {cpu} ignored: this OS cannot pin a thread to a CPU; the loop runs "
            "unpinned")
        return None
    if cpu not in cpus:
        raise InputError(f"loop.cpu: CPU {cpu} is not available here (this process may use "
                         f"CPUs {cpu_list(cpus)})")
    return cpu


def helper_threads(*owners: Any) -> list[int]:
    """Native ids of the live threads the run started in its own process (``owner._thread``:
    the drive monitor, the simulated drive's server, a multiprocessing queue's feeder)."""
    out = []
    for owner in owners:
        th = getattr(owner, "_thread", None)
        if th is not None and th.is_alive() and th.native_id is not None:
            out.append(int(th.native_id))
    return out


class LoopScheduling:
    """The loop thread's OS set-up for a run (``apply``) and its undoing (``undo``, always):
    the garbage collector frozen and off, the GIL handed back quickly (a short switch
    interval), the thread pinned to ``loop.cpu``, the real-time class for it and one below
    for the run's helper threads."""

    def __init__(self) -> None:
        self.old_switch = sys.getswitchinterval()
        self.realtime = False              # the loop's thread got the real-time class
        self.pinned: set[int] | None = None  # the CPUs the loop's thread could use before
        self.helpers: list[int] = []       # the run's other threads, raised with the loop

    def apply(self, cpu: int | None, priority: int, helper_owners: tuple[Any, ...],
              say: Callable[[str], None], helper_pids: Sequence[int] = ()) -> None:
        gc.collect()
        gc.freeze()  # keep the collector out of the loop (it would scan these objects)
        gc.disable()
        # the loop's thread gets the GIL back quickly from the drive monitor's thread, and
        # (where permitted) a real-time class so other processes cannot delay its ticks; with
        # loop.cpu, this thread (only it) stays on that CPU
        sys.setswitchinterval(2e-4)
        if cpu is not None:
            self.pinned = pin_to_cpu(cpu)
            if self.pinned is None:
                say(f"loop.cpu: the OS refused to pin the loop to CPU {cpu}; running unpinned")
        self.realtime = realtime_priority(priority)
        if self.realtime:
            # the run's other threads in this process (drive monitor, simulated drive, the
            # command queue's feeder) take the GIL too: one preempted by another process while
            # holding it would hold the loop for milliseconds, so they get the real-time class
            # one below
            helper_priority = max(1, priority - 1)
            # and the processes that make the loop's samples beside it (the simulated plant:
            # Daq.helper_processes), whose lag would be the loop's reading old forces
            self.helpers = [tid for tid in [*helper_threads(*helper_owners), *helper_pids]
                            if realtime_priority(helper_priority, tid)]

    def undo(self) -> None:
        if self.realtime:
            normal_priority()
        for tid in self.helpers:
            normal_priority(tid)
        if self.pinned is not None:
            set_cpus(self.pinned)
        sys.setswitchinterval(self.old_switch)
        gc.enable()
        gc.unfreeze()
