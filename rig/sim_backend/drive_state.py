"""What the simulated drive is doing (enabled, fault code), shared by the simulated serial
drive (rig.sim_backend.drive_pty), the simulated rig and the plant process: ``DriveState``
in one process, ``rig.sim_backend.rig_process.SharedDriveState`` over shared memory across
processes; both satisfy ``DriveStatus``."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any, Protocol


class DriveStatus(Protocol):
    """The drive's state as the rig reads it and the serial drive sets it."""

    enabled: bool
    fault: int
    lock: Any

    @property
    def pushing(self) -> bool: ...


@dataclass
class DriveState:
    """What the simulated drive is doing; shared by the pty drive and the rig."""

    enabled: bool = False
    fault: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    @property
    def pushing(self) -> bool:
        return self.enabled and self.fault == 0
