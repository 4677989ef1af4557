"""The supervisor: the acquisition process watches the loop's process and makes the rig safe
when it dies, whatever killed it (SIGKILL included).

Why the acquisition process: it outlives the loop's process already (it owns the run file),
it holds the card side (the simulated plant's shared block; on NI it can open tasks), and a
separate watchdog process would be one more process to leak. How it learns of the death:
``os.pidfd_open`` on the loop's pid, waited on by a thread with ``select``: the kernel wakes it
the moment the process exits (no polling delay; unlike a pipe's EOF it needs no descriptor
kept out of other children, and unlike ``PR_SET_PDEATHSIG`` it does not kill the watcher).
Where pidfd is missing (Linux < 5.3, other systems) the thread polls ``os.getppid()`` every
millisecond (a dead parent re-parents the process).

On the death, in that thread (``make_safe``), in this order:
1. the drive demand goes to 0 V: ``Reader.safe_stop()`` (the simulated plant: its drive is
   disabled in the shared block and told to stop; NI: a new task writes 0 V on the drive's AO
   channel, since an NI analog output holds its last value when its task's process dies);
2. a real drive (``serial_drive``: rig.loop.backends.serial_drive, the drive's port not the
   simulated drive) is disabled over its serial link (the dead process released the port);
then the acquisition loop drains the samples already buffered, closes the file
``aborted: the controller process ... died`` and exits; the reader releases the shared blocks
the dead process owned.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
from collections.abc import Callable
from typing import Any


class ControllerWatch:
    """Calls ``on_death`` (once, in its own thread) when process ``pid`` ends."""

    def __init__(self, pid: int, on_death: Callable[[], None]) -> None:
        self.pid = pid
        self.on_death = on_death
        self.dead = threading.Event()   # the process died (set before on_death runs)
        self.safe = threading.Event()   # on_death has finished
        self.error: str | None = None   # what on_death raised, if anything
        self.died_at = float("nan")     # time.time() when the death was seen
        self._wake_r, self._wake_w = os.pipe()
        self.fd: int | None = None
        with contextlib.suppress(AttributeError, OSError):
            self.fd = os.pidfd_open(pid)
        self._thread = threading.Thread(target=self._run, name="rig-supervisor", daemon=True)

    @property
    def method(self) -> str:
        return "pidfd" if self.fd is not None else "getppid poll"

    def start(self) -> ControllerWatch:
        self._thread.start()
        return self

    def _gone(self) -> bool:
        if self.fd is not None:
            return False
        return os.getppid() != self.pid

    def _run(self) -> None:
        if self.fd is not None:
            ready, _, _ = select.select([self.fd, self._wake_r], [], [])
            if self._wake_r in ready and self.fd not in ready:
                return
        else:
            while not self._gone():
                ready, _, _ = select.select([self._wake_r], [], [], 0.001)
                if ready:
                    return
        self.died_at = time.time()
        self.dead.set()
        try:
            self.on_death()
        except Exception as exc:  # keep going: the file must still be closed
            self.error = f"{type(exc).__name__}: {exc}"
        finally:
            self.safe.set()

    def stop(self) -> None:
        """Stop watching (the run ended normally)."""
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)
        for fd in (self.fd, self._wake_r, self._wake_w):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self.fd = None


def make_safe(reader: Any, cfg: Any, *, serial_drive: bool) -> None:
    """Zero the demand and disable the drive after the loop's process died (see module doc);
    ``serial_drive``: the drive is a real one, disabled over its serial link
    (rig.loop.backends.serial_drive)."""
    errors = []
    try:
        reader.safe_stop()
    except Exception as exc:
        errors.append(f"zeroing the output: {type(exc).__name__}: {exc}")
    if serial_drive:
        from rig.loop.drive import Drive

        try:
            drive = Drive(cfg.drive)
            try:
                drive.disable()
            finally:
                drive.close()
        except Exception as exc:
            errors.append(f"disabling the drive: {type(exc).__name__}: {exc}")
    if errors:
        raise RuntimeError("; ".join(errors))
