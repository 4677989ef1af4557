"""The simulated rig's physics in its own OS process (real-time mode).

In real time the torque loop must not wait for the action model: near impact
one 2 ms step of the flexible-shank model costs up to ~3 ms. As on the real
rig, where the cards' clock and buffers decouple the loop from the plant, the
loop only paces and writes its demand; the plant process integrates the
drive, the action and the sensors alongside and writes the card rows into the
simulated input buffer (``SharedFifo``), which the acquisition process drains.

They share one block of memory, ``PlantLink``:

* the analog output, as a ring of (tick, volts) slots: the loop writes the
  demand of tick i into slot i (a missed tick gets the held output when the
  loop wakes, as the card held it); the plant simulates control period i
  with slot i's volts as soon as it is there, so the physics is the same as
  in lock-step whatever the scheduling, only later;
* the latest load-cell sample (for the loop's controller hook);
* the simulated drive's state (enabled, fault), written by the simulated
  serial drive in the loop's process and read by the plant;
* the clock's start, a stop request, and the plant's error message.

The plant never runs ahead of the loop (it waits for each tick's demand); if
it falls more than the ring behind (``acquisition.buffer_s``) it stops with
an error, which the loop and the acquisition report as a card fault.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import threading
import time
import traceback
from multiprocessing import shared_memory
from typing import Any

import numpy as np

from rig.errors import InputError

_T_START, _STOP, _ERROR, _LAST_SAMPLE, _LAST_RATIO, _ENABLED, _FAULT, _DONE, _READY = range(9)
_HEADER = 16
_MSG_BYTES = 1024
POLL_S = 0.0002


class PlantLink:
    """Shared memory between the loop (owner) and the plant process (attached)."""

    def __init__(self, slots: int, name: str | None = None) -> None:
        if slots < 2:
            raise InputError(f"slots: expected at least 2, got {slots}")
        self.slots = slots
        self.owner = name is None
        size = 8 * (_HEADER + 2 * slots) + _MSG_BYTES
        self.shm = shared_memory.SharedMemory(name=name, create=self.owner, size=size)
        self.h = np.ndarray((_HEADER,), np.float64, self.shm.buf, 0)
        self.tags = np.ndarray((slots,), np.float64, self.shm.buf, 8 * _HEADER)
        self.volts = np.ndarray((slots,), np.float64, self.shm.buf, 8 * (_HEADER + slots))
        self.msg = np.ndarray((_MSG_BYTES,), np.uint8, self.shm.buf, 8 * (_HEADER + 2 * slots))
        if self.owner:
            self.h[:] = 0.0
            self.h[_T_START] = math.nan
            self.tags[:] = -1.0
            self.volts[:] = 0.0

    @property
    def spec(self) -> tuple[str, int]:
        return self.shm.name, self.slots

    @classmethod
    def attach(cls, spec: tuple[str, int]) -> PlantLink:
        return cls(spec[1], spec[0])

    # -- analog output (loop writes, plant reads) -------------------------------------
    def put(self, tick: int, volts: float) -> None:
        """The demand of control period ``tick`` (volts first, then the tag publishes it)."""
        j = tick % self.slots
        self.volts[j] = volts
        self.tags[j] = float(tick)

    def get(self, tick: int) -> float | None:
        """Slot ``tick``'s volts, None while not yet written; RuntimeError if overwritten."""
        j = tick % self.slots
        tag = self.tags[j]
        if tag == tick:
            return float(self.volts[j])
        if tag > tick:
            raise RuntimeError(f"the simulated rig fell more than {self.slots} control periods "
                               f"behind the loop (acquisition.buffer_s)")
        return None

    # -- header fields -----------------------------------------------------------------
    @property
    def t_start(self) -> float:
        return float(self.h[_T_START])

    @t_start.setter
    def t_start(self, value: float) -> None:
        self.h[_T_START] = value

    def request_stop(self, now: bool = False) -> None:
        """Stop once the periods written are simulated, or ``now`` (at the next period)."""
        self.h[_STOP] = 2.0 if now else max(1.0, float(self.h[_STOP]))

    @property
    def stop_requested(self) -> bool:
        return bool(self.h[_STOP])

    @property
    def stop_now(self) -> bool:
        return bool(self.h[_STOP] >= 2.0)

    def publish(self, sample: int, ratio: float, cycles: int) -> None:
        self.h[_LAST_RATIO] = ratio
        self.h[_LAST_SAMPLE] = sample
        self.h[_DONE] = cycles

    def feedback(self) -> tuple[int, float]:
        return int(self.h[_LAST_SAMPLE]), float(self.h[_LAST_RATIO])

    @property
    def cycles_done(self) -> int:
        return int(self.h[_DONE])

    @property
    def ready(self) -> bool:
        return bool(self.h[_READY])

    def set_ready(self) -> None:
        self.h[_READY] = 1.0

    def fail(self, message: str) -> None:
        data = message.encode("utf-8", "replace")[: _MSG_BYTES - 1]
        self.msg[:] = 0
        self.msg[: len(data)] = np.frombuffer(data, np.uint8)
        self.h[_ERROR] = 1.0

    @property
    def error(self) -> str | None:
        if not self.h[_ERROR]:
            return None
        return bytes(self.msg).split(b"\0", 1)[0].decode("utf-8", "replace")

    def close(self) -> None:
        del self.h, self.tags, self.volts, self.msg
        self.shm.close()
        if self.owner:
            self.shm.unlink()


class SharedDriveState:
    """``DriveState`` over the shared block: the simulated serial drive (loop's process)
    sets it, the plant process reads it (``pushing``)."""

    def __init__(self, link: PlantLink) -> None:
        self._h = link.h
        self.lock = threading.Lock()

    @property
    def enabled(self) -> bool:
        return bool(self._h[_ENABLED])

    @enabled.setter
    def enabled(self, value: bool) -> None:
        self._h[_ENABLED] = 1.0 if value else 0.0

    @property
    def fault(self) -> int:
        return int(self._h[_FAULT])

    @fault.setter
    def fault(self, value: int) -> None:
        self._h[_FAULT] = float(value)

    @property
    def pushing(self) -> bool:
        return self.enabled and self.fault == 0


def run_plant(cfg_data: dict[str, Any], link_spec: tuple[str, int],
              fifo_spec: tuple[str, int, int]) -> None:
    """Entry point of the plant process: simulate each control period once its demand is in."""
    from rig.inputs.config import from_mapping
    from rig.sim_backend.fifo import SharedFifo
    from rig.sim_backend.simrig import SimRig

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the run's process decides on Ctrl-C
    signal.signal(signal.SIGHUP, signal.SIG_IGN)  # ... and on a closed terminal
    parent = os.getppid()
    link = PlantLink.attach(link_spec)
    fifo = SharedFifo.attach(fifo_spec)
    log = DriveLog(os.environ.get(DRIVE_LOG_ENV))
    idle = 0
    try:
        cfg = from_mapping(cfg_data)
        state = SharedDriveState(link)
        state.enabled = True  # as the lock-step rig's DriveState: the serial drive decides
        rig = SimRig(cfg, state)
        if rig.width != fifo.width:
            raise RuntimeError(f"card rows of {rig.width} columns for a buffer of {fifo.width}")
        link.set_ready()
        cycle = 0
        drill = cfg.sim.drive_fault_at_s  # a fault drill: the drive faults at this cycle
        fault_cycle = -1 if drill is None else max(1, round(drill * cfg.rates.control_hz))
        while True:
            log.state(cycle, state)
            if link.stop_now:  # the run aborted: the periods it ran that are not simulated yet
                log.demand(cycle, 0.0, state)  # are dropped; the card's output goes to 0 V
                log.event(cycle, "stopped at once (the run aborted)")
                break
            volts = link.get(cycle)
            if volts is None:
                if link.stop_requested:
                    log.event(cycle, "stop requested")
                    break
                idle += 1
                if idle % 2500 == 0 and os.getppid() != parent:  # ~0.5 s: orphaned and nobody
                    state.enabled = False                          # asked us to stop
                    log.state(cycle, state)
                    log.event(cycle, "the run's process is gone: drive disabled, plant stopped")
                    break
                time.sleep(POLL_S)
                continue
            idle = 0
            if cycle == fault_cycle:  # as SimDrive.inject_fault: the output drops at once
                state.fault = cfg.sim.drive_fault_code
                log.event(cycle, f"drive fault {cfg.sim.drive_fault_code} (drill)")
            log.demand(cycle, volts, state)
            rows = rig.cycle(volts)
            fifo.write(rows)  # the card never waits: a slow reader overflows, loudly
            cycle += 1
            link.publish(rig.sample - 1, rig.last_ratio, cycle)
    except Exception as exc:  # the loop and the acquisition report it as a card fault
        link.fail(f"the simulated rig failed: {type(exc).__name__}: {exc}\n"
                  + traceback.format_exc(limit=4))
    finally:
        with contextlib.suppress(Exception):
            log.state(-1, SharedDriveState(link))
            log.event(-1, "plant exits")
        log.close()
        fifo.close()
        link.close()
    # all is written and released: skip the interpreter's teardown (the action model's numba
    # code loaded: about a second, more under load) that the run's process would wait for
    os._exit(0)


DRIVE_LOG_ENV = "RIG_SIM_DRIVE_LOG"


class DriveLog:
    """The simulated drive's own log, kept by the plant process (it outlives the run's
    process) and by the simulated serial drive: one JSON line per command received
    (``command``), per change of the demand (volts applied to a control period) or of
    the drive's state (enabled, fault), with the wall-clock time ``t`` (s, time.time()) and
    the control period ``tick``. Written only when ``$RIG_SIM_DRIVE_LOG`` names a file (the
    fault tests read it); line-buffered, so a killed plant leaves every line so far."""

    def __init__(self, path: str | None) -> None:
        self.f = open(path, "a", buffering=1, encoding="utf-8") if path else None  # noqa: SIM115
        self.last_volts: float | None = None
        self.last_state: tuple[bool, int] | None = None

    def _write(self, entry: dict[str, Any]) -> None:
        if self.f is not None:
            self.f.write(json.dumps({"t": time.time(), **entry}) + "\n")

    def demand(self, tick: int, volts: float, state: Any) -> None:
        if self.f is not None and volts != self.last_volts:
            self.last_volts = volts
            self._write({"tick": tick, "volts": volts, "enabled": state.enabled,
                         "fault": state.fault})

    def state(self, tick: int, state: Any) -> None:
        if self.f is None:
            return
        now = (bool(state.enabled), int(state.fault))
        if now != self.last_state:
            self.last_state = now
            self._write({"tick": tick, "enabled": now[0], "fault": now[1]})

    def command(self, text: str) -> None:
        """A command received over the serial link (the simulated drive's side)."""
        self._write({"command": text})

    def event(self, tick: int, what: str) -> None:
        self._write({"tick": tick, "event": what})

    def close(self) -> None:
        if self.f is not None:
            self.f.close()
            self.f = None


def read_drive_log(path: str) -> list[dict[str, Any]]:
    """The entries of a simulated drive log (see ``DriveLog``)."""
    with open(path, encoding="utf-8") as f:
        return [json.loads(ln) for ln in f if ln.strip()]
