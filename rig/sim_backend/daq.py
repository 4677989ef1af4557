"""The simulated rig as a DAQ (loop side) and its reader (acquisition process side).

The rig's clock is ``perf_counter`` in real time (ticks every control period
from ``arm``; a late loop finds the clock has moved on and the rig keeps
holding the last output, like the card) or the loop itself in lock-step (each
tick comes as soon as the loop asks; the card buffer makes the loop wait for
the acquisition process rather than overflow).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from rig import pacing
from rig.config import RigConfig
from rig.daq import Daq, DaqFault, Reader, Tick
from rig.model.action import ActionModel
from rig.sim_backend.fifo import BufferOverflow, SharedFifo
from rig.sim_backend.rig import DriveState, SimRig


class SimDaq(Daq):
    """Loop side of the simulated rig."""

    def __init__(self, config: RigConfig, *, lockstep: bool = False,
                 drive_state: DriveState | None = None, model: ActionModel | None = None) -> None:
        super().__init__(config)
        self.lockstep = lockstep or not config.sim.realtime
        self.rig = SimRig(config, drive_state, model)
        cap = max(4 * self.rig.n_per_cycle,
                  int(config.acquisition.buffer_s * config.rates.acquisition_hz))
        self.fifo = SharedFifo(cap, self.rig.width)
        self.volts = 0.0
        self.cycles = 0          # control periods simulated so far
        self.index = -1          # last tick handed to the loop
        self.t_start = math.nan
        self._closed = False
        self._armed = False

    def reader_spec(self) -> dict[str, Any]:
        return {"backend": "sim", "fifo": self.fifo.spec,
                "read_period_s": self.config.acquisition.read_period_s}

    def arm(self) -> None:
        if self._armed:
            raise RuntimeError("the simulated rig is already armed")
        pacing.set_timer_slack()
        self._armed = True

    def _simulate_to(self, cycles: int) -> None:
        while self.cycles < cycles:
            rows = self.rig.cycle(self.volts)
            self.fifo.write(rows, wait=self.lockstep)
            self.cycles += 1

    def wait_for_tick(self) -> Tick:
        if not self._armed:
            raise RuntimeError("arm() the simulated rig before waiting for ticks")
        if math.isnan(self.t_start):  # the clock starts with the loop's first wait
            self.t_start = time.perf_counter() + 0.001
        if self.lockstep:
            self._simulate_to(self.index + 1)
            self.index += 1
            return Tick(self.index, 0.0, 0)
        target = self.index + 1
        deadline = self.t_start + target * self.dt
        now = pacing.sleep_until(deadline)
        behind = int((now - self.t_start) / self.dt)
        missed = max(0, behind - target)
        self._simulate_to(target + missed)  # the card held the last output meanwhile
        self.index = target + missed
        return Tick(self.index, now - (self.t_start + self.index * self.dt), missed)

    def write_volts(self, volts: float) -> None:
        if self._closed:
            raise RuntimeError("the simulated rig is closed")
        self.volts = float(volts)
        self._simulate_to(self.index + 1)

    def feedback_ratio(self) -> tuple[int, float]:
        return self.rig.sample - 1, self.rig.last_ratio

    @property
    def samples_written(self) -> int:
        return self.fifo.written

    def close(self) -> None:
        if self._closed:
            return
        self.volts = 0.0
        self._closed = True
        self.fifo.mark_closed()
        self.fifo.close()


class SimReader(Reader):
    """Acquisition side of the simulated rig: drains the shared card buffer."""

    def __init__(self, spec: dict[str, Any]) -> None:
        self.fifo = SharedFifo.attach(spec["fifo"])
        self.period = float(spec.get("read_period_s", 0.02))
        self.width = self.fifo.width

    def start(self) -> None:
        pass

    def read(self, timeout_s: float) -> np.ndarray:
        end = time.monotonic() + timeout_s
        while True:
            try:
                rows = self.fifo.read()
            except BufferOverflow as exc:
                raise DaqFault(f"acquisition buffer overflow: {exc}") from None
            if rows.shape[0] or time.monotonic() >= end or self.fifo.closed:
                return rows
            time.sleep(min(0.001, self.period))

    def close(self) -> None:
        self.fifo.close()
