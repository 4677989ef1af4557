"""Software pacing for the simulated rig's clock (and the benchmark's bare loop).

On this kind of VM, sleeping to 0.5 ms before a deadline and then spinning on
``perf_counter`` wakes within ~1 us (median) where a plain sleep is ~100 us
late (see docs/performance.md). A 1 ns timer slack makes the sleep tighter.
"""

from __future__ import annotations

import ctypes
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
