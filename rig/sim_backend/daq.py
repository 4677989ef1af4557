"""The simulated rig as a DAQ (loop side) and its reader (acquisition process side).

The rig's clock is ``perf_counter`` in real time (ticks every control period
from the loop's first wait; a late loop finds the clock has moved on and the
rig keeps holding the last output, like the card) or the loop itself in
lock-step (each tick comes as soon as the loop asks; the card buffer makes
the loop wait for the acquisition process rather than overflow).

Real time: the physics (drive, action, sensors) runs in its own process
(``rig.sim_backend.rig_process``), so the loop only paces and writes, as on the real
cards; each control period is simulated with the demand the loop wrote for
it, so the physics matches lock-step, only later (the loop's feedback sees the
plant's latest sample). Lock-step: the physics runs in the loop's process,
exactly and deterministically, one control period per tick.
"""

from __future__ import annotations

import contextlib
import math
import multiprocessing as mp
import os
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from rig.daq import Daq, DaqFault, Reader, Tick
from rig.errors import InputError
from rig.inputs.config import RigConfig
from rig.model.action import ActionModel
from rig.sensors import table as sensor_table
from rig.sim_backend import clock
from rig.sim_backend.drive_state import DriveState, DriveStatus
from rig.sim_backend.fifo import BufferOverflow, SharedFifo
from rig.sim_backend.rig_process import PlantLink, SharedDriveState, run_plant
from rig.sim_backend.simrig import SimRig

CHECK_EVERY = 25  # ticks between checks that the plant process is alive (real time)
BUILD_NOTICE_S = 3.0  # s: a plant still building its model after this is reported (on_line)


def row_width(config: RigConfig) -> int:
    """Columns of a simulated card row: those of ``rig.sensors.table.raw_names``."""
    return len(sensor_table.raw_names(config))


class SimDaq(Daq):
    """Loop side of the simulated rig."""

    def __init__(self, config: RigConfig, *, lockstep: bool = False,
                 drive_state: DriveState | None = None, model: ActionModel | None = None,
                 on_line: Callable[[str], None] | None = None) -> None:
        super().__init__(config)
        self.lockstep = lockstep or not config.sim.realtime
        spc = config.rates.samples_per_cycle
        cap = max(4 * spc, int(config.acquisition.buffer_s * config.rates.acquisition_hz))
        self.volts = 0.0
        self.cycles = 0          # control periods simulated so far (lock-step)
        self.index = -1          # last tick handed to the loop
        self.t_start = math.nan
        self._closed = False
        self._armed = False
        self._stop_now = False
        self.rig: SimRig | None = None
        self.link: PlantLink | None = None
        self.plant: Any = None
        self.fifo = SharedFifo(cap, row_width(config))
        if self.lockstep:
            self.rig = SimRig(config, drive_state, model)
            self.drive_state: DriveStatus = self.rig.drive_state
            return
        if drive_state is not None or model is not None:
            self.fifo.close()
            raise InputError("drive_state, model: only for the lock-step simulated rig (in real "
                             "time the plant process builds its own)")
        try:
            self.link = PlantLink(max(4, cap // spc))
            self.drive_state = SharedDriveState(self.link)
            ctx = mp.get_context("spawn")
            plant = ctx.Process(target=run_plant, name="rig-sim-plant", daemon=True, args=(
                config.model_dump(mode="json"), self.link.spec, self.fifo.spec))
            plant.start()
            self.plant = plant
            t0 = time.monotonic()
            told = False
            while not self.link.ready:
                if self.link.error or not self.plant.is_alive():
                    raise DaqFault(self._plant_error() or "the simulated rig did not start")
                waited = time.monotonic() - t0
                if waited > config.sim.build_timeout_s:
                    raise DaqFault("the simulated rig did not start within "
                                   f"{config.sim.build_timeout_s} s (sim.build_timeout_s)")
                if on_line is not None and not told and waited > BUILD_NOTICE_S:
                    on_line("building the simulated rig's action model (the first use after "
                            "installing or updating rig compiles it: about a minute)")
                    told = True
                time.sleep(0.01)
        except BaseException:
            self.close()
            raise

    def _plant_error(self) -> str | None:
        assert self.link is not None
        err = self.link.error
        if err:
            return err.splitlines()[0]
        if self.plant is not None and not self.plant.is_alive():
            return f"the simulated rig's process died (exit code {self.plant.exitcode})"
        return None

    def reader_spec(self) -> dict[str, Any]:
        return {"backend": "sim", "fifo": self.fifo.spec,
                "plant": self.link.spec if self.link is not None else None,
                "plant_pid": self.plant.pid if self.plant is not None else None,
                "read_period_s": self.config.acquisition.read_period_s}

    def helper_processes(self) -> list[int]:
        """The plant process in real time: it integrates the action behind the loop's ticks
        and the loop's controller reads its latest load-cell sample, so a plant starved by
        other processes makes the loop read old forces (issue 41: 28-670 ms old on a loaded
        machine)."""
        if self.plant is None or not self.plant.is_alive() or self.plant.pid is None:
            return []
        return [int(self.plant.pid)]

    def arm(self) -> None:
        if self._armed:
            raise RuntimeError("the simulated rig is already armed")
        clock.set_timer_slack()
        self._armed = True

    def _simulate_to(self, cycles: int) -> None:
        assert self.rig is not None
        while self.cycles < cycles:
            rows = self.rig.cycle(self.volts)
            self.fifo.write(rows, wait=True)
            self.cycles += 1

    def wait_for_tick(self) -> Tick:
        if not self._armed:
            raise RuntimeError("arm() the simulated rig before waiting for ticks")
        if self._closed:
            raise RuntimeError("the simulated rig is closed")
        if math.isnan(self.t_start):  # the clock starts with the loop's first wait
            self.t_start = time.perf_counter() + 0.001
            if self.link is not None:
                self.link.t_start = self.t_start
        if self.lockstep:
            self._simulate_to(self.index + 1)
            self.index += 1
            return Tick(self.index, 0.0, 0)
        assert self.link is not None
        target = self.index + 1
        deadline = self.t_start + target * self.dt
        now = clock.sleep_until(deadline)
        behind = int((now - self.t_start) / self.dt)
        missed = max(0, behind - target)
        for j in range(target, target + missed):  # the card held the last output meanwhile
            self.link.put(j, self.volts)
        self.index = target + missed
        if self.index % CHECK_EVERY == 0 or missed:
            err = self._plant_error()
            if err:
                raise DaqFault(err)
        return Tick(self.index, now - (self.t_start + self.index * self.dt), missed)

    def write_volts(self, volts: float) -> None:
        if self._closed:
            raise RuntimeError("the simulated rig is closed")
        self.volts = float(volts)
        if self.lockstep:
            self._simulate_to(self.index + 1)
        elif self.index >= 0:
            assert self.link is not None
            self.link.put(self.index, self.volts)

    def feedback_ratio(self) -> tuple[int, float]:
        if self.rig is not None:
            return self.rig.sample - 1, self.rig.last_ratio
        assert self.link is not None
        return self.link.feedback()

    def stop_at_once(self) -> None:
        self._stop_now = True

    def close(self) -> None:
        """Zero the output, let the plant finish the periods the loop ran (unless
        ``stop_at_once``: it stops at the period it is in), release all."""
        if self._closed:
            return
        self._closed = True
        self.volts = 0.0
        if self.link is not None:
            if self.index >= 0 and self.link.cycles_done <= self.index:
                self.link.put(self.index, 0.0)
            self.link.request_stop(now=self._stop_now)
            if self.plant is not None and not self.link.ready:
                self.plant.kill()  # still building its model (stopped at start): nothing to finish
            if self.plant is not None:
                self.plant.join(timeout=30.0)
                if self.plant.is_alive():
                    self.plant.kill()
                    self.plant.join(timeout=5.0)
            self.link.close()
        self.fifo.mark_closed()
        self.fifo.close()


class SimReader(Reader):
    """Acquisition side of the simulated rig: drains the shared card buffer."""

    def __init__(self, spec: dict[str, Any]) -> None:
        self.spec = spec
        self.fifo = SharedFifo.attach(spec["fifo"])
        self.link = PlantLink.attach(spec["plant"]) if spec.get("plant") else None
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
            if not rows.shape[0] and self.link is not None and self.link.error:
                raise DaqFault(self.link.error.splitlines()[0])
            if rows.shape[0] or time.monotonic() >= end or self.fifo.closed:
                return rows
            time.sleep(min(0.001, self.period))

    def safe_stop(self) -> None:
        """The loop's process died: disable the simulated drive (the plant stops pushing at
        once: its motor force follows a zero demand) and tell the plant to stop after the
        periods it already has. Lock-step: the physics ran in the dead process, nothing moves."""
        if self.link is None:
            return
        link = self.link
        SharedDriveState(link).enabled = False
        nxt = int(link.tags.max()) + 1  # the next control period gets 0 V, as the card would
        if nxt - link.cycles_done < link.slots:
            link.put(nxt, 0.0)
        link.request_stop()

    def release_orphaned(self) -> None:
        """Unlink the card buffer and the plant's block once the plant has stopped (the dead
        loop's process created them; multiprocessing's resource tracker would otherwise warn
        about and remove them only when every process using it has gone)."""
        pid = self.spec.get("plant_pid")
        end = time.monotonic() + 2.0
        while pid and _alive(int(pid)) and time.monotonic() < end:
            time.sleep(0.005)
        for shm in (self.fifo.shm, self.link.shm if self.link is not None else None):
            if shm is not None:
                with contextlib.suppress(FileNotFoundError):
                    shm.unlink()

    def close(self) -> None:
        self.fifo.close()
        if self.link is not None:
            self.link.close()


def _alive(pid: int) -> bool:
    """Process ``pid`` exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return False
    except OSError:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        return True
