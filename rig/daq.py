"""The DAQ interface: what the torque loop and the acquisition process need from the cards.

One abstract interface per side, two implementations, chosen by ``rig.loop.backends`` (the
only module naming the backends) from the rig configuration: ``rig.ni_backend``
(NI-DAQmx cards) and ``rig.sim_backend`` (the simulated rig), packages with the same
inner layout (``daq``: loop and acquisition sides; ``bench``: what calibrations read).
A config asking for NI never falls back to simulation: if the NI driver or cards are
missing, ``rig.loop.backends.open_daq`` raises.

Loop side (the run's process):  zero_output() [then the drive is enabled] -> arm() ->
wait_for_tick() -> write_volts() -> write_lateness(tick) ...
Acquisition side (its own process): open_reader(daq.reader_spec()) -> start()
-> read() blocks of rows in the columns of ``rig.sensors.table.raw_names`` (sample, then
one per sensor of the sensor table).
Calibration bench (``Bench``): apply_mass, read_bridge, null_offset, shunt,
drive_static, key_travel (docs/calibration.md).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from rig.errors import InputError, RigError
from rig.inputs.config import RigConfig


class DaqFault(RigError, RuntimeError):
    """The cards reported a condition that must stop the run (overflow, missing hardware...)."""


@dataclass(frozen=True)
class Tick:
    """One loop cycle: its index on the hardware clock, how late the software woke, missed ticks."""

    index: int
    lateness_s: float
    missed: int


class Daq(ABC):
    """Loop side of a rig's cards: pacing and the drive's analog output."""

    def __init__(self, config: RigConfig) -> None:
        self.config = config
        self.dt = 1.0 / config.rates.control_hz

    @abstractmethod
    def reader_spec(self) -> dict[str, Any]:
        """Picklable description from which ``open_reader`` builds the acquisition side."""

    def zero_output(self) -> float | None:
        """Put the drive's demand at 0 V before the drive is enabled; the read-back volts
        where the cards allow (else None). DaqFault if it does not read 0 V."""
        self.write_volts(0.0)
        return None

    @abstractmethod
    def arm(self) -> None:
        """Configure and start the output and pacing (NI: waits for the acquisition's start)."""

    @abstractmethod
    def wait_for_tick(self) -> Tick:
        """Block until the next 500 Hz tick of the rig's clock."""

    @abstractmethod
    def write_volts(self, volts: float) -> None:
        """Set the drive's torque demand (V), effective at once."""

    def write_lateness(self, tick: Tick) -> float:
        """How late the last ``write_volts`` of ``tick`` reached the output (s) on the rig's
        clock; by default the tick's own lateness."""
        return tick.lateness_s

    @abstractmethod
    def feedback_ratio(self) -> tuple[int, float]:
        """Latest load-cell sample: (sample index, bridge ratio V/V), for the controller hook."""

    @abstractmethod
    def close(self) -> None:
        """Write 0 V and release everything (idempotent)."""

    def helper_processes(self) -> list[int]:
        """The pids of processes that make the loop's samples alongside it and must keep its
        pace (the simulated plant in real time): the run gives them the real-time class one
        below the loop's, as its helper threads. A real card needs none."""
        return []

    def stop_at_once(self) -> None:  # noqa: B027 - optional: only a simulator has a backlog
        """After an abort: ``close`` stops at once what makes the samples (the simulated
        plant, which may run behind the loop on a loaded machine) instead of letting it
        finish the control periods the loop ran. A real card's samples are never behind."""


class Reader(ABC):
    """Acquisition side: the 2 kHz sample clock and its buffered channels."""

    @abstractmethod
    def start(self) -> None: ...

    @abstractmethod
    def read(self, timeout_s: float) -> np.ndarray:
        """Rows read since the last call (may be empty); DaqFault on overflow."""

    @abstractmethod
    def close(self) -> None: ...

    def publish_feedback(self, sample: int, ratio: float) -> None:  # noqa: B027 - optional
        """Make the latest load-cell sample visible to the loop (NI); no-op by default."""

    def safe_stop(self) -> None:
        """The loop's process died: put the drive demand at 0 V from here (rig.loop.supervisor)."""
        raise NotImplementedError(f"{type(self).__name__} cannot zero the drive output")

    def release_orphaned(self) -> None:  # noqa: B027 - optional
        """After ``safe_stop``: remove the shared blocks the dead loop's process owned."""


# ---- the calibration bench side ----
Live = Callable[[float], None] | None
BRIDGES = ("load_cell", "strain_gauge")


def check_bridge(sensor: str) -> None:
    if sensor not in BRIDGES:
        raise InputError(f"sensor: expected one of {BRIDGES}, got {sensor!r}")


def bridge_range(cfg: RigConfig, sensor: str) -> float:
    """+- input range of a bridge channel, V/V."""
    check_bridge(sensor)
    ch = cfg.channels
    mv = ch.load_cell.input_range_mv_per_v if sensor == "load_cell" else \
        ch.strain_gauge.input_range_mv_per_v
    return mv * 1e-3


class Bench(ABC):
    """The readings a calibration needs, on one rig."""

    def __init__(self, cfg: RigConfig) -> None:
        self.cfg = cfg
        self.rate_hz = cfg.rates.acquisition_hz

    @abstractmethod
    def apply_mass(self, mass_kg: float, gravity_m_s2: float) -> None:
        """The user placed ``mass_kg`` on the key top (the simulated bench loads its cell)."""

    @abstractmethod
    def read_bridge(self, sensor: str, seconds: float, live: Live = None) -> np.ndarray:
        """Bridge ratio samples (V/V) for ``seconds``; ``live`` gets the running mean."""

    @abstractmethod
    def null_offset(self, sensor: str) -> dict[str, Any]:
        """Bridge offset nulling with the sensor at rest; what the hardware reported."""

    @abstractmethod
    def shunt(self, sensor: str, on: bool, resistor_ohm: float) -> None:
        """Engage or release the shunt-calibration resistor across the gauge arm."""

    def driver_shunt_cal(self, sensor: str, resistor_ohm: float) -> float | None:
        """The card driver's own shunt calibration; its gain adjustment (None if not available)."""
        return None

    @abstractmethod
    def drive_static(self, demand_n: np.ndarray) -> np.ndarray:
        """Hold each demand (N) for one control period with the arm on a static surface;
        load-cell ratios (V/V) at the acquisition rate, ``samples_per_cycle`` per demand."""

    @abstractmethod
    def key_travel(self, force_n: np.ndarray) -> dict[str, np.ndarray]:
        """Press the key with ``force_n`` (N, one per control period); counts per encoder."""

    def close(self) -> None:  # noqa: B027 - nothing to release by default
        """Release cards and tasks."""
