"""Sensor models for the simulated rig, with seeded true sensitivities and offsets.

Each model turns a true physical value into what the card reads (V/V or
counts) using its *true* parameters, which differ from the data-sheet
(nominal) ones by a seeded spread; ``truth()`` returns them so calibration
can check that it recovers them, and `rig synth` can reuse the models.

    sensors = SensorSet.from_config(cfg, seed=4)
    ratio = sensors.load_cell.measure(force_n)          # V/V, filtered, noisy
    counts = sensors.encoders["hammer"].counts(delta)   # integer counts
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import signal

from rig import loadcell, strain
from rig.config import RigConfig


@dataclass
class LoadCellModel:
    """Full-bridge load cell + noise, and a 4-pole Butterworth filter when ``filter_hz``
    is set. The simulated rig leaves it None: its drive model already contains the
    SCXI-1520's 100 Hz filter (rig.sim_backend.drive_model), so it is counted once."""

    sensitivity: float          # true (V/V)/N
    offset: float               # true V/V at zero force
    noise_n: float              # 1-sigma noise, N equivalent
    filter_hz: float | None     # Hz; None: no filter in the sensor chain
    rate_hz: float
    rng: np.random.Generator
    _sos: np.ndarray | None = field(init=False, repr=False)
    _zi: np.ndarray | None = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._sos = None if self.filter_hz is None else signal.butter(
            4, self.filter_hz, fs=self.rate_hz, output="sos")
        self.reset()

    def reset(self, force_n: float = 0.0) -> None:
        """Filter state settled at a constant force."""
        self._zi = None if self._sos is None else signal.sosfilt_zi(self._sos) * force_n

    def measure(self, force_n: np.ndarray) -> np.ndarray:
        """Bridge ratio (V/V) read for true forces (N) sampled at rate_hz."""
        filtered = np.asarray(force_n, float)
        if self._sos is not None:
            filtered, self._zi = signal.sosfilt(self._sos, filtered, zi=self._zi)
        noisy = filtered + self.rng.normal(0.0, self.noise_n, filtered.shape)
        return self.offset + self.sensitivity * noisy


@dataclass
class StrainGaugeModel:
    """Quarter-bridge type I gauge (350 ohm) with a true gage factor and bridge offset."""

    gage_factor: float
    offset: float               # unstrained bridge ratio, V/V
    noise: float                # 1-sigma, m/m equivalent
    lead_wire_ohm: float
    gauge_ohm: float
    rng: np.random.Generator

    def measure(self, strain_mm: np.ndarray) -> np.ndarray:
        e = np.asarray(strain_mm, float)
        e = e + self.rng.normal(0.0, self.noise, e.shape)
        return strain.to_ratio(e, self.gage_factor, self.offset, self.lead_wire_ohm,
                               self.gauge_ohm)


@dataclass
class EncoderModel:
    """Quadrature encoder: counts of the true motion, quantised at the scale's resolution."""

    si_per_count: float         # true rad or m per count, signed as the counter counts
    nominal_si_per_count: float

    def counts(self, delta: np.ndarray) -> np.ndarray:
        """Whole counts for motion delta (rad or m) from the pose at count 0."""
        return np.floor(np.asarray(delta, float) / self.si_per_count + 0.5)


@dataclass
class SensorSet:
    load_cell: LoadCellModel
    strain_gauge: StrainGaugeModel | None
    encoders: dict[str, EncoderModel]

    @classmethod
    def from_config(cls, cfg: RigConfig, seed: int | None = None) -> SensorSet:
        rng = np.random.default_rng(cfg.sim.seed if seed is None else seed)
        spread = cfg.sim.sensor_spread
        ch = cfg.channels
        lc_nom = loadcell.nominal_sensitivity(ch.load_cell)
        lc = LoadCellModel(lc_nom * (1 + spread * rng.standard_normal()),
                           0.02e-3 * rng.standard_normal(), cfg.sim.load_cell_noise_n,
                           cfg.sim.load_cell_filter_hz, cfg.rates.acquisition_hz, rng)
        sg = None
        if ch.strain_gauge.enabled:
            g = ch.strain_gauge
            sg = StrainGaugeModel(g.gage_factor * (1 + spread * rng.standard_normal()),
                                  0.1e-3 * rng.standard_normal(), cfg.sim.strain_noise,
                                  g.lead_wire_resistance_ohm, g.nominal_resistance_ohm, rng)
        encs = {}
        for name, enc in ch.encoders.items():
            # mounting (eccentricity, cosine error) makes the true scale differ slightly
            true = enc.si_per_count * (1 + 0.1 * spread * rng.standard_normal())
            encs[name] = EncoderModel(enc.sign * true, enc.sign * enc.si_per_count)
        return cls(lc, sg, encs)

    def truth(self) -> dict[str, dict[str, Any]]:
        """True sensitivities and offsets, in the calibration-record conventions."""
        out: dict[str, dict[str, Any]] = {
            "load_cell": {"sensitivity": self.load_cell.sensitivity,
                          "offset": self.load_cell.offset}}
        if self.strain_gauge is not None:
            out["strain_gauge"] = {"sensitivity": self.strain_gauge.gage_factor,
                                   "offset": self.strain_gauge.offset}
        for n, e in self.encoders.items():
            out[n] = {"sensitivity": e.si_per_count, "offset": 0.0}
        return out
