"""Calibration settings: where records live, how old they may be, the references' tolerances.

The rig configuration carries them as its ``calibration:`` section
(``RigConfig.calibration: CalibrationSettings``, defined with the rest of the
configuration's schema in rig.inputs.config and documented in docs/rig-config.md);
records live in ``<data_folder>/calibrations`` unless ``records_folder`` says
otherwise. SI units; tolerances are half-widths of
rectangular distributions (data-sheet style).
"""

from __future__ import annotations

import getpass
from pathlib import Path

from rig.inputs.config import (  # noqa: F401 - the calibration section's schema, re-exported
    SENSORS,
    CalibrationSettings,
    LoadCellCal,
    MotorCal,
    RigConfig,
    StrainCal,
)


def settings_for(cfg: RigConfig) -> CalibrationSettings:
    """The rig's calibration settings (its ``calibration:`` section, validated with the
    rest of the configuration; the defaults when the file has none)."""
    return cfg.calibration


def records_folder(cfg: RigConfig, override: Path | None = None) -> Path:
    """Records folder: override, else the setting, else <data_folder>/calibrations."""
    if override is not None:
        return Path(override)
    s = settings_for(cfg)
    return Path(s.records_folder) if s.records_folder is not None else \
        Path(cfg.data_folder) / "calibrations"


def operator_name(cfg: RigConfig, given: str | None = None) -> str:
    if given:
        return given
    s = settings_for(cfg)
    if s.operator:
        return s.operator
    try:
        return getpass.getuser()
    except Exception:  # no login name (containers): still record something
        return "unknown"
