"""The DAQ interface: what the torque loop and the acquisition process need from the cards.

One abstract interface, two implementations chosen by ``open_daq`` from the
rig configuration: ``rig.ni_daq`` (NI-DAQmx cards) and ``rig.sim_backend.daq``
(the simulated rig). A config asking for NI never falls back to simulation:
if the NI driver or cards are missing, ``open_daq`` raises.

Loop side (the run's process):  arm() -> wait_for_tick() -> write_volts() ...
Acquisition side (its own process): open_reader(daq.reader_spec()) -> start()
-> read() blocks of rows [sample, load_cell_ratio, (strain_ratio), counts...].
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from rig.config import RigConfig
from rig.errors import InputError


class DaqFault(RuntimeError):
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

    @abstractmethod
    def arm(self) -> None:
        """Configure and start the output and pacing (NI: waits for the acquisition's start)."""

    @abstractmethod
    def wait_for_tick(self) -> Tick:
        """Block until the next 500 Hz tick of the rig's clock."""

    @abstractmethod
    def write_volts(self, volts: float) -> None:
        """Set the drive's torque demand (V), effective at once."""

    @abstractmethod
    def feedback_ratio(self) -> tuple[int, float]:
        """Latest load-cell sample: (sample index, bridge ratio V/V), for the controller hook."""

    @abstractmethod
    def close(self) -> None:
        """Write 0 V and release everything (idempotent)."""


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
        """The loop's process died: put the drive demand at 0 V from here (rig.supervisor)."""
        raise NotImplementedError(f"{type(self).__name__} cannot zero the drive output")

    def release_orphaned(self) -> None:  # noqa: B027 - optional
        """After ``safe_stop``: remove the shared blocks the dead loop's process owned."""


def open_daq(config: RigConfig, *, lockstep: bool = False,
             on_line: Callable[[str], None] | None = None) -> Daq:
    """The loop side for the configured backend (NI never falls back to simulation).

    ``on_line`` hears about slow starts (the simulated rig compiling its model).
    """
    if config.backend == "ni":
        from rig.ni_daq import NiDaq

        if lockstep:
            raise InputError("lockstep: only the simulated rig can run in lock-step")
        return NiDaq(config)
    if config.backend == "sim":
        from rig.sim_backend.daq import SimDaq

        return SimDaq(config, lockstep=lockstep, on_line=on_line)
    raise InputError(f"backend: expected 'ni' or 'sim', got {config.backend!r}")


def open_reader(spec: dict[str, Any]) -> Reader:
    """The acquisition side, in the acquisition process, from ``Daq.reader_spec()``."""
    backend = spec.get("backend")
    if backend == "ni":
        from rig.ni_daq import NiReader

        return NiReader(spec)
    if backend == "sim":
        from rig.sim_backend.daq import SimReader

        return SimReader(spec)
    raise InputError(f"backend: expected 'ni' or 'sim', got {backend!r}")
