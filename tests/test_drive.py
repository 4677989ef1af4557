"""The drive's serial link against the simulated drive on a real pseudo-terminal."""

from __future__ import annotations

import time

import pytest

from rig import config
from rig.loop.drive import Drive, DriveError, DriveMonitor
from rig.sim_backend.drive_pty import SimDrive


@pytest.fixture
def link():
    cfg = config.builtin_sim(drive={"port": "sim", "setup": ["ILIM 6"], "timeout_s": 1.0,
                                    "poll_period_s": 0.02}).drive
    sim = SimDrive(cfg)
    drive = Drive(cfg, sim.port)
    yield cfg, sim, drive
    drive.close()
    sim.close()


def test_enable_disable_status(link) -> None:
    cfg, sim, drive = link
    assert drive.fault() is None
    drive.enable()
    assert sim.state.enabled and drive.enabled
    assert drive.command(cfg.active) == "1"
    assert sim.settings["ILIM"] == "6"
    drive.disable()
    assert not sim.state.enabled
    assert sim.log.index("ILIM 6") < sim.log.index(cfg.enable) < sim.log.index(cfg.disable)


def test_unknown_command_and_fault(link) -> None:
    cfg, sim, drive = link
    with pytest.raises(DriveError, match="ERR 01"):
        drive.command("NOSUCH")
    drive.enable()
    sim.inject_fault(2)
    assert not sim.state.pushing
    assert "ERRCODE=2" in (drive.fault() or "")
    drive.disable()
    with pytest.raises(DriveError, match="not ready"):
        drive.enable()


def test_monitor_sees_a_fault(link) -> None:
    _, sim, drive = link
    mon = DriveMonitor(drive, 0.02)
    mon.start()
    time.sleep(0.1)
    assert mon.fault is None
    sim.inject_fault(7)
    end = time.monotonic() + 2
    while mon.fault is None and time.monotonic() < end:
        time.sleep(0.01)
    mon.stop()
    assert mon.fault is not None and "7" in mon.fault


def test_bad_port_names_the_field() -> None:
    cfg = config.builtin_sim(drive={"port": "/dev/does-not-exist"}).drive
    with pytest.raises(ValueError, match="drive.port"):
        Drive(cfg)


def test_a_link_that_fails_is_a_drive_error_and_the_monitor_reports_it(link) -> None:
    """The serial port failing under the link (a write timeout, a closed pseudo-terminal)
    is a DriveError, not pyserial's own exception: the monitor thread reports it as a
    fault instead of dying with it (seen in CI: a write timeout in the monitor thread as
    the run's end closed the simulated drive)."""
    _, sim, drive = link
    mon = DriveMonitor(drive, 0.02)
    mon.start()
    time.sleep(0.1)
    drive.serial.close()  # the port under the link goes away
    with pytest.raises(DriveError, match="the link failed"):
        drive.command("DRIVEOK")
    end = time.monotonic() + 2
    while mon.fault is None and time.monotonic() < end:
        time.sleep(0.01)
    mon.stop()
    assert mon.fault is not None and mon.fault.startswith("drive link:"), mon.fault
