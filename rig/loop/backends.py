"""The one place that picks a backend by ``cfg.backend`` ("ni" or "sim") and the only
module naming them: the loop side, the acquisition side and the calibration bench. A
new backend is one package with the same inner layout (``daq``, ``bench``) and one
branch in each function here (and the drive's link: a serial port, or the simulated drive
on a pseudo-terminal). NI never falls back to simulation."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rig.daq import Bench, Daq, Reader
from rig.errors import InputError
from rig.inputs.config import RigConfig

BACKENDS = ("ni", "sim")


def _unknown(backend: object) -> InputError:
    return InputError(f"backend: expected 'ni' or 'sim', got {backend!r}")


def open_daq(config: RigConfig, *, lockstep: bool = False,
             on_line: Callable[[str], None] | None = None) -> Daq:
    """The loop side for the configured backend; ``on_line`` hears about slow starts (the
    simulated rig compiling its model)."""
    if config.backend == "ni":
        from rig.ni_backend.daq import NiDaq

        if lockstep:
            raise InputError("lockstep: only the simulated rig can run in lock-step")
        return NiDaq(config)
    if config.backend == "sim":
        from rig.sim_backend.daq import SimDaq

        if on_line is not None:  # (seconds of silence otherwise: say what the start is doing)
            on_line("building the simulated rig's action model ..." if lockstep
                    or not config.sim.realtime
                    else "starting the simulated rig's process (it builds the action model) ...")
        return SimDaq(config, lockstep=lockstep, on_line=on_line)
    raise _unknown(config.backend)


def open_reader(spec: dict[str, Any]) -> Reader:
    """The acquisition side, in the acquisition process, from ``Daq.reader_spec()``."""
    backend = spec.get("backend")
    if backend == "ni":
        from rig.ni_backend.daq import NiReader

        return NiReader(spec)
    if backend == "sim":
        from rig.sim_backend.daq import SimReader

        return SimReader(spec)
    raise _unknown(backend)


def open_bench(cfg: RigConfig) -> Bench:
    """The calibration bench of the configured backend."""
    if cfg.backend == "sim":
        from rig.sim_backend.bench import SimBench

        return SimBench(cfg)
    if cfg.backend == "ni":
        from rig.ni_backend.bench import NiBench

        return NiBench(cfg)
    raise _unknown(cfg.backend)


def load_cell_noise_n(cfg: RigConfig) -> float:
    """The load cell's noise, 1 sigma (N), as the learner weighs trials: the simulated
    rig's configured noise; on NI, the data sheet's 0.67 N error bound taken as 3 sigma."""
    if cfg.backend == "sim":
        return cfg.sim.load_cell_noise_n
    if cfg.backend == "ni":
        return 0.67 / 3
    raise _unknown(cfg.backend)


def trial_rig(cfg: RigConfig, k: int) -> RigConfig:
    """The rig for learning trial ``k`` (1, 2, ...): on the simulated rig its sensors draw
    noise stream ``k`` (``sim.noise_stream``): each trial's load-cell noise is fresh, as a
    real one's, on the same rig (its true calibration is the seed's); NI: the rig itself."""
    if cfg.backend == "sim":
        return cfg.model_copy(update={"sim": cfg.sim.model_copy(update={"noise_stream": k})})
    if cfg.backend == "ni":
        return cfg
    raise _unknown(cfg.backend)


def serial_drive(cfg: RigConfig) -> bool:
    """Whether the drive is a real one on its serial port (``drive.port`` a device), not
    the simulated drive (``drive.port: sim``)."""
    return cfg.drive.port != "sim"


def open_drive_port(cfg: RigConfig, daq: Daq) -> tuple[str | None, Any]:
    """The drive's serial port for ``rig.loop.drive.Drive``: ``(None, None)`` for the
    configured port; with ``drive.port: sim``, the simulated drive on a pseudo-terminal
    (the simulated rig only) as ``(its port, the simulated drive)``, closed by the caller."""
    if serial_drive(cfg):
        return None, None
    if cfg.backend != "sim":
        raise InputError("drive.port: 'sim' (the simulated drive) needs backend: sim")
    from rig.sim_backend.daq import SimDaq
    from rig.sim_backend.drive_pty import SimDrive

    assert isinstance(daq, SimDaq)
    sim_drive = SimDrive(cfg.drive, daq.drive_state)
    return sim_drive.port, sim_drive


def check_drive_port(cfg: RigConfig) -> None:
    """Refuse, before anything starts, a drive link this backend cannot open."""
    if cfg.backend != "sim" and not serial_drive(cfg):
        raise InputError("drive.port: 'sim' (the simulated drive) needs backend: sim")


def reader_calibration(cfg: RigConfig, records: list[dict[str, Any]]) -> dict[str, Any]:
    """What the acquisition side calibrates before a run, for the run's metadata and
    ``open_reader``'s spec: NI nulls and shunt-calibrates its fresh bridge channels
    (``{"bridge_cal": ...}``); the simulated rig, nothing."""
    if cfg.backend == "ni":
        from rig.ni_backend.daq import bridge_calibration

        return {"bridge_cal": bridge_calibration(cfg, records)}
    return {}
