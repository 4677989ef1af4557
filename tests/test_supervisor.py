"""The supervisor's parts: the watch on the loop's process and the serial disable."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from typing import Any

from rig.inputs import config
from rig.loop.backends import serial_drive
from rig.loop.supervisor import ControllerWatch, make_safe
from rig.sim_backend.drive_pty import SimDrive
from rig.sim_backend.drive_state import DriveState


def test_watch_sees_a_sigkilled_process_at_once() -> None:
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    seen: dict[str, float] = {}
    watch = ControllerWatch(proc.pid, lambda: seen.setdefault("t", time.monotonic())).start()
    try:
        time.sleep(0.2)
        assert not watch.dead.is_set()  # alive: nothing happens
        t = time.monotonic()
        proc.send_signal(signal.SIGKILL)
        assert watch.safe.wait(timeout=5.0)
        print(f"watch ({watch.method}): on_death {(seen['t'] - t) * 1e3:.2f} ms after SIGKILL")
        assert seen["t"] - t < 0.5
    finally:
        watch.stop()
        proc.wait()


def test_watch_stopped_before_a_death_does_nothing() -> None:
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    calls: list[int] = []
    watch = ControllerWatch(proc.pid, lambda: calls.append(1)).start()
    watch.stop()
    proc.kill()
    proc.wait()
    time.sleep(0.1)
    assert calls == [] and not watch.dead.is_set()


class _Reader:
    def __init__(self) -> None:
        self.zeroed = False

    def safe_stop(self) -> None:
        self.zeroed = True


def test_make_safe_zeroes_then_disables_a_real_drive_over_serial() -> None:
    cfg = config.from_mapping({"backend": "sim", "drive": {"port": "sim"}})
    state = DriveState(enabled=True)
    sim = SimDrive(cfg.drive, state)
    try:
        real = config.from_mapping({"backend": "sim", "drive": {"port": sim.port}})
        reader = _Reader()
        make_safe(reader, real, serial_drive=serial_drive(real))
        assert reader.zeroed
        assert sim.log[-1] == cfg.drive.disable and not state.enabled
    finally:
        sim.close()


def test_make_safe_goes_on_to_the_drive_when_zeroing_fails() -> None:
    cfg = config.from_mapping({"backend": "sim", "drive": {"port": "sim"}})
    state = DriveState(enabled=True)
    sim = SimDrive(cfg.drive, state)

    class Broken:
        def safe_stop(self) -> Any:
            raise OSError("card gone")

    try:
        real = config.from_mapping({"backend": "sim", "drive": {"port": sim.port}})
        try:
            make_safe(Broken(), real, serial_drive=serial_drive(real))
        except RuntimeError as exc:
            assert "card gone" in str(exc)
        else:
            raise AssertionError("make_safe hid the failure")
        assert not state.enabled
    finally:
        sim.close()
