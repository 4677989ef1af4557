"""Sensor models for the simulated rig, with seeded true sensitivities and offsets.

One model per entry of the sensor table (``rig.sensors.table.sensors``), built from the
entry's ``SimChain``: a true value is (optionally) low-pass filtered, gets its noise and
becomes what the card reads (V/V or counts) through the sensor's own ``to_raw`` with
its *true* calibration, which differs from the data-sheet (nominal) one by a seeded
spread; ``truth()`` returns the true calibrations so calibration can check that it
recovers them. The simulated rig, its calibration bench and `rig synth` use these models.

    sensors = SensorSet.from_config(cfg, seed=4)
    ratio = sensors["load_cell"].measure(force_n)       # V/V, noisy (filtered if set)
    counts = sensors["hammer"].measure(angle)           # integer counts from the offset
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import signal

from rig.inputs.config import RigConfig
from rig.sensors.table import Sensor, sensors


@dataclass
class SensorModel:
    """One sensor's simulated chain with its true calibration (``spec.sim`` says how).

    The load cell's 4-pole Butterworth filter (``sim.load_cell_filter_hz``) is off on the
    simulated rig: its drive model already contains the SCXI-1520's 100 Hz filter
    (rig.sim_backend.drive_model), so it is counted once."""

    spec: Sensor
    sensitivity: float          # true, in the calibration-record conventions
    offset: float               # true; a counter's: the true value at count 0
    rate_hz: float
    rng: np.random.Generator
    _sos: np.ndarray | None = field(init=False, repr=False)
    _zi: np.ndarray | None = field(init=False, repr=False)

    def __post_init__(self) -> None:
        hz = self.spec.sim.filter_hz
        self._sos = None if hz is None else signal.butter(4, hz, fs=self.rate_hz, output="sos")
        self.reset()

    def reset(self, value: float = 0.0) -> None:
        """Filter state settled at a constant true value."""
        self._zi = None if self._sos is None else signal.sosfilt_zi(self._sos) * value

    def measure(self, true: np.ndarray) -> np.ndarray:
        """The readings (raw units) of true values sampled at rate_hz."""
        x = np.asarray(true, float)
        if self._sos is not None:
            x, self._zi = signal.sosfilt(self._sos, x, zi=self._zi)
        if self.spec.sim.noise is not None:
            x = x + self.rng.normal(0.0, self.spec.sim.noise, x.shape)
        return np.asarray(self.spec.to_raw(x, self.sensitivity, self.offset), float)


@dataclass
class SensorSet:
    """The rig's sensor models by sensor name, in the card rows' column order."""

    models: dict[str, SensorModel]

    def __getitem__(self, name: str) -> SensorModel:
        return self.models[name]

    def get(self, name: str) -> SensorModel | None:
        return self.models.get(name)

    @classmethod
    def from_config(cls, cfg: RigConfig, seed: int | None = None) -> SensorSet:
        rng = np.random.default_rng(cfg.sim.seed if seed is None else seed)
        models = {}
        for s in sensors(cfg):
            sens = s.sensitivity * (1 + s.sim.spread * rng.standard_normal())
            off = 0.0 if s.sim.offset_sd is None else s.sim.offset_sd * rng.standard_normal()
            models[s.name] = SensorModel(s, sens, off, cfg.rates.acquisition_hz, rng)
        return cls(models)

    def truth(self) -> dict[str, dict[str, Any]]:
        """True sensitivities and offsets, in the calibration-record conventions."""
        return {n: {"sensitivity": m.sensitivity, "offset": m.offset}
                for n, m in self.models.items()}
