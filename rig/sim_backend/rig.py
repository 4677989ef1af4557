"""SimRig: the action, the drive and the sensors stepped one loop cycle at a time.

Each ``cycle(volts)`` holds the analog output for one control period (2 ms):
the drive model turns the demand into the force on the key top, the action
model is advanced under that force, and the sensors produce the rows the
cards would buffer at 2 kHz: [sample, load_cell_ratio, (strain_ratio),
counts per encoder]. The drive only pushes while it is enabled and not
faulted (see ``DriveState``, shared with the simulated serial drive).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rig.config import RigConfig
from rig.errors import InputError
from rig.model.action import ANGLE_CHANNELS, ActionModel
from rig.sim_backend.drive_model import DriveModel
from rig.sim_backend.drive_state import DriveState, DriveStatus
from rig.sim_backend.sensors import SensorSet


class SimRig:
    """The simulated action, drive and sensors (one writer of the simulated card buffer)."""

    def __init__(self, config: RigConfig,
                 drive_state: DriveStatus | None = None,
                 model: ActionModel | None = None) -> None:
        self.config = config
        rate = config.rates.acquisition_hz
        self.n_per_cycle = config.rates.samples_per_cycle
        self.dt_sample = 1.0 / rate
        for name, enc in config.channels.encoders.items():
            if enc.kind == "linear" and enc.body != "key":
                raise InputError(f"channels.encoders.{name}: the simulated rig measures linear "
                                 f"motion only on the key (key dip)")
        self.model = model or ActionModel(effects=config.sim.effects, output_rate=rate)
        if abs(self.model.output_rate - rate) > 1e-9:
            raise InputError(f"model: expected output_rate {rate} Hz, got {self.model.output_rate}")
        self.strain_on = config.channels.strain_gauge.enabled
        if self.strain_on and "flexible_shank" not in self.model.effect_names:
            raise InputError("sim.effects: the strain gauge needs the flexible_shank effect "
                             "(or set channels.strain_gauge.enabled: false)")
        self.drive_state: DriveStatus = drive_state or DriveState(enabled=True)
        self.drive = DriveModel(self.dt_sample, config.sim.drive_model,
                                config.sim.process_time_unit_s, self.model.params)
        self.sensors = SensorSet.from_config(config)
        self.volts_per_newton = config.drive_scaling.volts_per_newton
        rest = self.model.rest_state()
        warm = self.model.stepper()  # compile/warm the numba paths before the clock starts
        for j in range(1, 4):
            c = warm.advance(j * 2e-3, 0.0, 0.0)
            self.model.channels(c.time, c.states, c.force)
        self.stepper = self.model.stepper(keep_history=False)  # flat memory over long runs
        self._rest = {n: float(rest[i]) for n, i in ANGLE_CHANNELS.items()}
        self.sample = 0
        self._pending = self._physical(np.zeros(1), rest[None, :], np.zeros(1))
        self.force_now = 0.0
        self.last_ratio = float(self.sensors.load_cell.offset)
        self.width = 2 + int(self.strain_on) + len(config.channels.encoders)

    def truth(self) -> dict[str, dict[str, Any]]:
        """True sensor parameters; encoder offsets are the bodies' rest values (rad or m)."""
        t = self.sensors.truth()
        for name, enc in self.config.channels.encoders.items():
            t[name]["offset"] = 0.0 if enc.kind == "linear" else self._rest[f"{enc.body}_angle"]
        return t

    def _physical(self, time: np.ndarray, states: np.ndarray, force: np.ndarray) -> np.ndarray:
        """True values the sensors see: force, (shank strain), encoder motions from rest."""
        ch = self.model.channels(time, states, force)
        cols = [force]
        if self.strain_on:
            cols.append(ch["shank_strain"])
        for enc in self.config.channels.encoders.values():
            if enc.kind == "linear":
                cols.append(ch["key_dip"])
            else:
                key = f"{enc.body}_angle"
                cols.append(ch[key] - self._rest[key])
        return np.column_stack(cols)

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
        rows[:, 1] = self.sensors.load_cell.measure(phys[:, 0])
        col = 2
        if self.strain_on:
            assert self.sensors.strain_gauge is not None
            rows[:, col] = self.sensors.strain_gauge.measure(phys[:, col - 1])
            col += 1
        for name in self.config.channels.encoders:
            rows[:, col] = self.sensors.encoders[name].counts(phys[:, col - 1])
            col += 1
        self.sample += m
        self.last_ratio = float(rows[-1, 1])
        return rows
