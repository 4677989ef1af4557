"""SimRig: the action, the drive and the sensors stepped one loop cycle at a time.

Each ``cycle(volts)`` holds the analog output for one control period (2 ms):
the drive model turns the demand into the force on the key top, the action
model is advanced under that force, and the sensors produce the rows the
cards would buffer at 2 kHz, in the columns of ``rig.sensors.table.raw_names``
(each sensor's true value from its ``SimChain.truth``). The drive only pushes
while it is enabled and not faulted (see ``DriveState``, shared with the
simulated serial drive).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rig.errors import InputError
from rig.inputs.config import RigConfig
from rig.inputs.params import Parameters
from rig.model.action import ActionModel
from rig.model.touch import sticking_parameters
from rig.sensors import table as sensor_table
from rig.sim_backend.drive_model import DriveResponse
from rig.sim_backend.drive_state import DriveState, DriveStatus
from rig.sim_backend.sensors import SensorSet


def sim_parameters(config: RigConfig) -> Parameters:
    """The simulated action's parameters: the shipped model's, with ``sim.friction: stick``
    Dahl's law at every pin and at every contact with friction but the back check (whose
    bristle law already sticks)."""
    params = Parameters.default()
    if config.sim.friction == "stick":
        params = sticking_parameters(params)
    return params


class SimRig:
    """The simulated action, drive and sensors (one writer of the simulated card buffer)."""

    def __init__(self, config: RigConfig,
                 drive_state: DriveStatus | None = None,
                 model: ActionModel | None = None) -> None:
        self.config = config
        rate = config.rates.acquisition_hz
        self.n_per_cycle = config.rates.samples_per_cycle
        self.dt_sample = 1.0 / rate
        self.model = model or ActionModel(sim_parameters(config), effects=config.sim.effects,
                                          output_rate=rate)
        if abs(self.model.output_rate - rate) > 1e-9:
            raise InputError(f"model: expected output_rate {rate} Hz, got {self.model.output_rate}")
        self.table = sensor_table.sensors(config)
        self.sensors = SensorSet.from_config(config)
        rest = self.model.rest_state()
        at_rest = self.model.channels(np.zeros(1), rest[None, :], np.zeros(1))
        self._truths = [self.sensors[s.name].chain.truth for s in self.table]
        for s in self.table:
            chain = self.sensors[s.name].chain
            true = chain.truth(at_rest)
            if true is None:
                raise InputError(f"sim.effects: the {s.name.replace('_', ' ')} needs "
                                 f"{chain.needs}")
            if chain.counts_from_start:  # count 0 at the rest pose
                self.sensors[s.name].offset = float(true[0])
        self.drive_state: DriveStatus = drive_state or DriveState(enabled=True)
        self.drive = DriveResponse(self.dt_sample, config.sim.drive_model,
                                   config.sim.process_time_unit_s, self.model.params)
        self.volts_per_newton = config.drive_scaling.volts_per_newton
        warm = self.model.stepper()  # compile/warm the numba paths before the clock starts
        for j in range(1, 4):
            c = warm.advance(j * 2e-3, 0.0, 0.0)
            self.model.channels(c.time, c.states, c.force)
        self.stepper = self.model.stepper(keep_history=False)  # flat memory over long runs
        self.sample = 0
        self._pending = self._physical(np.zeros(1), rest[None, :], np.zeros(1))
        self.force_now = 0.0
        self.width = 1 + len(self.table)
        self.feedback = sensor_table.column(config, sensor_table.FEEDBACK)
        fb = next(s for s in self.table if s.raw == sensor_table.FEEDBACK)
        self.last_ratio = float(self.sensors[fb.name].offset)  # the reading at zero force

    def truth(self) -> dict[str, dict[str, Any]]:
        """True sensor calibrations; encoder offsets are the bodies' rest values (rad or m)."""
        return self.sensors.truth()

    def _physical(self, time: np.ndarray, states: np.ndarray, force: np.ndarray) -> np.ndarray:
        """True values the sensors see, one column per sensor (the table's order)."""
        ch = self.model.channels(time, states, force)
        return np.column_stack([np.asarray(truth(ch), float) for truth in self._truths])

    def cycle(self, volts: float) -> np.ndarray:
        """Hold ``volts`` for one control period; the card rows of that period."""
        demand = volts / self.volts_per_newton if self.drive_state.pushing else 0.0
        n = self.n_per_cycle
        motor = np.maximum(self.drive.step(demand, n), 0.0)  # the arm can only press
        t0 = self.stepper.t
        knots_t = t0 + self.dt_sample * np.arange(n + 1)
        knots_f = np.r_[self.force_now, motor]
        chunk = self.stepper.advance_table(knots_t[-1], knots_t, knots_f)
        if chunk.status != 0:
            raise RuntimeError(f"the simulated action failed: {chunk.message}")
        self.force_now = float(motor[-1])
        truth = self._physical(chunk.time, chunk.states, chunk.force)
        # sample n is taken at n / rate: this cycle's rows are the tick's own sample (carried
        # from the previous cycle) and the samples before the next tick
        phys = np.vstack([self._pending, truth[:-1]])
        self._pending = truth[-1:]
        m = phys.shape[0]
        rows = np.empty((m, self.width))
        rows[:, 0] = self.sample + np.arange(m)
        for j, s in enumerate(self.table):
            rows[:, 1 + j] = self.sensors[s.name].measure(phys[:, j])
        self.sample += m
        self.last_ratio = float(rows[-1, self.feedback])
        return rows
