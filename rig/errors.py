"""The project's error classes: the user's bad input versus everything else.

    RigError            root of every error rig raises on purpose
      InputError        the user's bad input (a file, a field, an option): the CLI prints
                        one line naming the file and field and exits 2; nothing is written
        MissingCalibration   a real-hardware run without its calibration record
                             (rig.calibration.records)
      DriveError        the drive refused a command or did not answer (rig.loop.drive)
      DaqFault          the cards must stop the run: overflow, missing hardware (rig.daq)
      DiskFull          too little space to write the next block (rig.loop.acquisition;
                        also an OSError)
      BufferOverflow    the simulated cards' buffer overwrote unread samples
                        (rig.sim_backend.fifo)
      RunStopped        a stop signal while the run was starting (rig.services.run)

Any other exception is a failure inside rig or a library (the CLI: one line, exit 1).

``InputError`` is also a ``ValueError`` so callers that catch ``ValueError`` keep working
while the code moves over to it. Raise it with the file and field in the message::

    raise InputError(f"{path}: limits.max_force_n: must be positive, got {value}")
"""

from __future__ import annotations

from pathlib import Path


class RigError(Exception):
    """Root of the errors rig raises on purpose."""


class InputError(RigError, ValueError):
    """The user's bad input: one line naming the file and field; exit 2, nothing written."""


def not_a_file(path: Path) -> str:
    """Why ``path`` cannot be read as a file: a folder, or missing."""
    return "is a folder, expected a file" if Path(path).is_dir() else "file not found"


def refuse_existing(path: Path | None, force: bool, field: str = "out") -> None:
    """The user's existing file is never replaced without ``force`` (--force)."""
    if path is not None and Path(path).exists() and not force:
        raise InputError(f"{field}: {path} exists (use --force to replace it)")
