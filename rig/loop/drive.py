"""The Kollmorgen ServoStar CE drive's serial link (pyserial).

ASCII commands ending in CR; the drive echoes, answers with the value, CR LF
and a ``-->`` prompt; errors start with BEL (0x07). The command words are
taken from the rig configuration (``drive:``) because the CE series' set is
unconfirmed (see docs/rig-config.md). ``DriveMonitor`` polls the status in a
thread so a fault is seen within one poll period without slowing the loop.
"""

from __future__ import annotations

import threading
import time

import serial

from rig.errors import InputError, RigError
from rig.inputs.config import DriveLink


class DriveError(RigError, RuntimeError):
    """The drive refused a command or did not answer."""


class Drive:
    """A command/answer session with the drive."""

    def __init__(self, cfg: DriveLink, port: str | None = None) -> None:
        self.cfg = cfg
        self.port = port or cfg.port
        try:
            self.serial = serial.Serial(self.port, baudrate=cfg.baudrate, bytesize=8,
                                        parity=serial.PARITY_NONE, stopbits=1,
                                        timeout=cfg.timeout_s, write_timeout=cfg.timeout_s)
        except serial.SerialException as exc:
            raise InputError(f"drive.port: cannot open {self.port!r} ({exc})") from None
        self.lock = threading.Lock()
        self.enabled = False

    def command(self, text: str) -> str:
        """Send one command; the drive's answer without echo and prompt."""
        if not text or "\r" in text:
            raise InputError(f"text: expected one command without CR, got {text!r}")
        prompt = self.cfg.prompt.encode()
        with self.lock:
            try:
                self.serial.reset_input_buffer()
                self.serial.write(text.encode("ascii") + b"\r")
                buf = b""
                end = time.monotonic() + self.cfg.timeout_s
                while not buf.endswith(prompt):
                    chunk = self.serial.read(max(1, self.serial.in_waiting))
                    buf += chunk
                    if time.monotonic() > end:
                        raise DriveError(f"drive on {self.port}: no answer to {text!r} "
                                         f"within {self.cfg.timeout_s} s (got {buf!r})")
            except (serial.SerialException, OSError) as exc:  # the link itself failed
                raise DriveError(f"drive on {self.port}: the link failed on {text!r} "
                                 f"({type(exc).__name__}: {exc})") from exc
            except TypeError as exc:  # pyserial's fd went to None under a read: closed
                if self.serial.is_open:
                    raise
                raise DriveError(f"drive on {self.port}: the link failed on {text!r} "
                                 "(the port was closed)") from exc
        body = buf[: -len(prompt)].decode("ascii", "replace")
        if body.startswith(text):
            body = body[len(text):]
        body = body.strip("\r\n ")
        if body.startswith("\x07"):
            raise DriveError(f"drive refused {text!r}: {body.lstrip(chr(7)).strip()}")
        return body

    def fault(self) -> str | None:
        """None when the drive reports no fault, else a description."""
        ok = self.command(self.cfg.status)
        code = self.command(self.cfg.fault)
        if ok == self.cfg.status_ok and code == self.cfg.no_fault:
            return None
        return f"drive fault (status {self.cfg.status}={ok}, {self.cfg.fault}={code})"

    def enable(self) -> None:
        """Send the setup commands, enable, and check the drive is active without fault."""
        fault = self.fault()
        if fault:
            raise DriveError(f"drive not ready: {fault}")
        for cmd in self.cfg.setup:
            self.command(cmd)
        self.command(self.cfg.enable)
        if self.command(self.cfg.active) != "1":
            raise DriveError("drive did not become active after enable")
        self.enabled = True

    def disable(self) -> None:
        self.command(self.cfg.disable)
        self.enabled = False

    def close(self) -> None:
        """Close the port, after any command in progress (another thread's, the monitor's
        poll) has its answer or its timeout: closed under a read, pyserial's descriptor
        goes to None and the read fails with a TypeError, not a link error."""
        with self.lock:
            self.serial.close()


class DriveMonitor:
    """Polls the drive's status in a thread; ``fault`` is set when the drive reports one,
    or when the link fails on ``drive.link_failures`` polls in a row (one failed poll is
    not a lost link: a busy machine can hold this thread past pyserial's write timeout
    although the bytes went out, as CI saw). ``link_errors`` counts every failed poll."""

    def __init__(self, drive: Drive, period_s: float) -> None:
        self.drive = drive
        self.period = period_s
        self.fault: str | None = None
        self.link_errors = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="drive-monitor", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        in_a_row = 0
        while not self._stop.wait(self.period):
            try:
                fault = self.drive.fault()
            except DriveError as exc:
                if self._stop.is_set():  # the run is over and its port closing: no fault
                    return
                self.link_errors += 1
                in_a_row += 1
                if in_a_row < self.drive.cfg.link_failures:
                    continue
                fault = f"drive link: {exc} ({in_a_row} polls in a row)"
            else:
                in_a_row = 0
            if fault:
                self.fault = fault
                return

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2 * self.drive.cfg.timeout_s + self.period)
