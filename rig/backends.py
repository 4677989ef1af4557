"""The one place that picks a backend by ``cfg.backend`` ("ni" or "sim") and the only
module naming them: the loop side, the acquisition side and the calibration bench. A
new backend is one package with the same inner layout (``daq``, ``bench``) and one
branch in each function here. NI never falls back to simulation."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rig.config import RigConfig
from rig.daq import Bench, Daq, Reader
from rig.errors import InputError

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
