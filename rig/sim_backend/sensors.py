"""Sensor models for the simulated rig, with seeded true sensitivities and offsets.

One model per entry of the sensor table (``rig.sensors.table.sensors``), built from its
kind's ``SimChain`` (``SIM_CHAINS``, by ``Sensor.kind``): a true value is (optionally)
low-pass filtered, gets its noise and becomes what the card reads (V/V or counts) through
the sensor's own ``to_raw`` with its *true* calibration, which differs from the
data-sheet (nominal) one by a seeded spread; ``truth()`` returns the true calibrations so
calibration can check that it recovers them. The simulated rig, its calibration bench and
`rig synth` use these models.

    sensors = SensorSet.from_config(cfg, seed=4)
    ratio = sensors["load_cell"].measure(force_n)       # V/V, noisy (filtered if set)
    counts = sensors["hammer"].measure(angle)           # integer counts from the offset
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import signal

from rig.errors import InputError
from rig.inputs.config import RigConfig
from rig.sensors.table import Sensor, sensors

Truth = Callable[[Mapping[str, np.ndarray]], np.ndarray | None]


@dataclass(frozen=True)
class SimChain:
    """How the simulated rig (and `rig synth`) makes a sensor's reading from the action.

    reading = to_raw(filtered true value + noise, true sensitivity, true offset); the true
    calibration is the nominal one moved by seeded spreads (``SensorSet``)."""

    truth: Truth               # true value from the model's channels ("force": the drive's
                               # force on the key top); None: the model lacks it (see needs)
    noise: float | None = None         # 1 sigma added to the true value (SI); None: none drawn
    spread: float = 0.0                # relative 1 sigma of the true sensitivity around nominal
    offset_sd: float | None = None     # 1 sigma of the true offset around 0; None: not drawn
    filter_hz: float | None = None     # a 4-pole low-pass in the chain (before the noise)
    counts_from_start: bool = False    # a counter: count 0 at the start (true offset = the
                                       # true value then)
    needs: str = ""                    # what the model must have for ``truth`` (the error)


def _load_cell(cfg: RigConfig, s: Sensor) -> SimChain:
    return SimChain(lambda ch: ch["force"], noise=cfg.sim.load_cell_noise_n,
                    spread=cfg.sim.sensor_spread, offset_sd=0.02e-3,
                    filter_hz=cfg.sim.load_cell_filter_hz)


def _strain_gauge(cfg: RigConfig, s: Sensor) -> SimChain:
    return SimChain(lambda ch: ch.get("shank_strain"), noise=cfg.sim.strain_noise,
                    spread=cfg.sim.sensor_spread, offset_sd=0.1e-3,
                    needs="the flexible_shank effect (or set channels.strain_gauge.enabled: "
                          "false)")


def _encoder(cfg: RigConfig, s: Sensor) -> SimChain:
    enc = cfg.channels.encoders[s.name]
    if enc.kind == "angular":
        true = f"{enc.body}_angle"
    elif enc.body == "key":
        true = "key_dip"
    else:
        true = ""

    def truth(ch: Mapping[str, np.ndarray], name: str = s.name, key: str = true) -> np.ndarray:
        if not key:
            raise InputError(f"channels.encoders.{name}: the simulated rig measures "
                             f"linear motion only on the key (key dip)")
        return ch[key]

    # mounting (eccentricity, cosine error) makes the true scale differ slightly
    return SimChain(truth, spread=0.1 * cfg.sim.sensor_spread, counts_from_start=True)


# each kind of sensor in the sensor table -> its simulated chain (docs/architecture.md,
# "Add a sensor")
SIM_CHAINS: dict[str, Callable[[RigConfig, Sensor], SimChain]] = {
    "load_cell": _load_cell, "strain_gauge": _strain_gauge, "encoder": _encoder}


def sim_chain(cfg: RigConfig, sensor: Sensor) -> SimChain:
    """``sensor``'s simulated chain (its kind's entry in ``SIM_CHAINS``)."""
    how = SIM_CHAINS.get(sensor.kind)
    if how is None:
        raise InputError(f"channels: sensor {sensor.name!r} (kind {sensor.kind!r}) has no "
                         f"simulated chain (SIM_CHAINS in rig/sim_backend/sensors.py)")
    return how(cfg, sensor)


@dataclass
class SensorModel:
    """One sensor's simulated chain with its true calibration (``chain`` says how).

    The load cell's 4-pole Butterworth filter (``sim.load_cell_filter_hz``) is off on the
    simulated rig: its drive model already contains the SCXI-1520's 100 Hz filter
    (rig.sim_backend.drive_model), so it is counted once."""

    spec: Sensor
    sensitivity: float          # true, in the calibration-record conventions
    offset: float               # true; a counter's: the true value at count 0
    rate_hz: float
    rng: np.random.Generator
    chain: SimChain
    _sos: np.ndarray | None = field(init=False, repr=False)
    _zi: np.ndarray | None = field(init=False, repr=False)

    def __post_init__(self) -> None:
        hz = self.chain.filter_hz
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
        if self.chain.noise is not None:
            x = x + self.rng.normal(0.0, self.chain.noise, x.shape)
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
        """The seed draws the true sensitivities and offsets (the rig) and then, on stream 0,
        the noise; ``sim.noise_stream`` K > 0 draws the noise from ``[seed, K]`` instead:
        the same rig, another run's noise."""
        base = cfg.sim.seed if seed is None else seed
        rng = np.random.default_rng(base)
        drawn = [(s, sim_chain(cfg, s)) for s in sensors(cfg)]
        true = [(s.sensitivity * (1 + chain.spread * rng.standard_normal()),
                 0.0 if chain.offset_sd is None else chain.offset_sd * rng.standard_normal())
                for s, chain in drawn]
        if cfg.sim.noise_stream:
            rng = np.random.default_rng([base, cfg.sim.noise_stream])
        return cls({s.name: SensorModel(s, sens, off, cfg.rates.acquisition_hz, rng, chain)
                    for (s, chain), (sens, off) in zip(drawn, true, strict=True)})

    def truth(self) -> dict[str, dict[str, Any]]:
        """True sensitivities and offsets, in the calibration-record conventions."""
        return {n: {"sensitivity": m.sensitivity, "offset": m.offset}
                for n, m in self.models.items()}
