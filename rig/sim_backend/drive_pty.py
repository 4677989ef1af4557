"""A simulated Kollmorgen drive answering on a pseudo-terminal.

It speaks the command set of the rig configuration (``drive:``): echo,
answer, CR LF, prompt; unknown commands get BEL + ``ERR 01``. It shares a
``DriveState`` with the simulated rig, so disabling the drive really stops
the simulated motor, and ``inject_fault`` makes the drive report a fault and
drop its output, as a real drive does.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import tty

from rig.inputs.config import DriveLink
from rig.sim_backend.drive_state import DriveState, DriveStatus
from rig.sim_backend.rig_process import DRIVE_LOG_ENV, DriveLog


class SimDrive:
    """The drive's side of the serial link; ``port`` is the pty path to open with pyserial."""

    def __init__(self, cfg: DriveLink, state: DriveStatus | None = None) -> None:
        self.cfg = cfg
        self.state: DriveStatus = state or DriveState()
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.port = os.ttyname(self.slave)
        self.log: list[str] = []
        # the drive's own log (shared file with the plant's demand log, $RIG_SIM_DRIVE_LOG)
        self.file_log = DriveLog(os.environ.get(DRIVE_LOG_ENV))
        self.settings: dict[str, str] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="sim-drive", daemon=True)
        self._thread.start()

    def inject_fault(self, code: int = 2) -> None:
        """Make the drive fault (e.g. 2 = over-current); the output drops at once."""
        with self.state.lock:
            self.state.fault = code

    def _answer(self, cmd: str) -> str:
        c = self.cfg
        s = self.state
        with s.lock:
            if cmd == c.enable:
                if s.fault:
                    return f"\x07ERR 03 fault {s.fault} active"
                s.enabled = True
                return ""
            if cmd == c.disable:
                s.enabled = False
                return ""
            if cmd == c.status:
                return c.status_ok if s.fault == 0 else "0"
            if cmd == c.active:
                return "1" if s.pushing else "0"
            if cmd == c.fault:
                return c.no_fault if s.fault == 0 else str(s.fault)
        word, _, value = cmd.partition(" ")
        if word and word.isupper() and value:
            self.settings[word] = value
            return ""
        if word in self.settings:
            return self.settings[word]
        return "\x07ERR 01 unknown command"

    def _serve(self) -> None:
        buf = b""
        while not self._stop.is_set():
            ready, _, _ = select.select([self.master], [], [], 0.05)
            if not ready:
                continue
            try:
                data = os.read(self.master, 1024)
            except OSError:
                return
            os.write(self.master, data)  # echo
            buf += data
            while b"\r" in buf:
                line, buf = buf.split(b"\r", 1)
                cmd = line.decode("ascii", "replace").strip()
                self.log.append(cmd)
                self.file_log.command(cmd)
                answer = self._answer(cmd)
                out = (answer + "\r\n" if answer else "\r\n") + self.cfg.prompt
                os.write(self.master, out.encode("ascii"))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self.file_log.close()
        for fd in (self.master, self.slave):
            with contextlib.suppress(OSError):
                os.close(fd)
