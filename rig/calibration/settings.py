"""Calibration settings: where records live, how old they may be, the references' tolerances.

The rig configuration carries them as its ``calibration:`` section
(``RigConfig.calibration: CalibrationSettings``, documented in
docs/rig-config.md); records live in ``<data_folder>/calibrations`` unless
``records_folder`` says otherwise. SI units; tolerances are half-widths of
rectangular distributions (data-sheet style).
"""

from __future__ import annotations

import getpass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from rig.errors import InputError

if TYPE_CHECKING:  # rig.config imports this module for RigConfig.calibration
    from rig.config import RigConfig


SENSORS = ("load_cell", "strain_gauge", "motor")  # what calibration.required may name


class _Strict(BaseModel):
    # strict, finite numbers: no bool or text as a number, no inf or nan
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)


class LoadCellCal(_Strict):
    """Known-mass calibration of the load cell."""

    gravity_m_s2: float = Field(9.80665, gt=9.7, lt=9.9, description="local g; set it for the lab")
    gravity_rel_halfwidth: float = Field(
        0.003, ge=0, le=1, description="0.3 % covers any lab on Earth with standard g; ~1e-5 once "
                                 "the local g is set from a gravity map")
    mass_rel_halfwidth: float = Field(1e-4, ge=0, le=1, description="reference-mass tolerance "
                                                              "(OIML M1 ~ 5e-5 to 1e-4)")
    average_s: float = Field(1.0, gt=0, le=600, description="bridge averaging time per point")
    settle_s: float = Field(0.3, ge=0, le=600, description="discarded after placing a mass")
    min_points: int = Field(5, ge=3, le=1000)
    min_span_fraction: float = Field(0.2, gt=0, le=1, description="points must span this "
                                                                  "fraction of full scale")
    spec_nonlinearity_hysteresis_pct_fs: float = Field(0.5, gt=0, le=100)
    spec_nonrepeatability_pct_fs: float = Field(0.1, gt=0, le=100)
    saturation_fraction: float = Field(0.98, gt=0, le=1, description="a reading beyond this "
                                                                     "fraction of the range is "
                                                                     "saturated")


class StrainCal(_Strict):
    """Offset nulling and shunt calibration of the quarter-bridge gauge."""

    shunt_resistor_ohm: float = Field(100000.0, gt=0, le=1e12)
    shunt_rel_halfwidth: float = Field(0.001, ge=0, le=1, description="shunt resistor tolerance")
    gauge_resistance_rel_halfwidth: float = Field(0.003, ge=0, le=1, description="Rg tolerance")
    gage_factor_rel_halfwidth: float = Field(0.01, ge=0, le=1, description="gauge-factor tolerance "
                                             "(the shunt cannot see it)")
    tolerance: float = Field(0.05, gt=0, lt=1, description="|gain adjustment - 1| allowed")
    average_s: float = Field(1.0, gt=0, le=600)
    settle_s: float = Field(0.05, ge=0, le=600)


class MotorCal(_Strict):
    """Steps and ramps of demanded force with the arm on a static surface."""

    step_levels_n: list[float] = Field(default_factory=lambda: [5.0, 10.0, 15.0, 20.0, 25.0,
                                                                30.0, 35.0, 40.0])
    step_hold_s: float = Field(0.15, gt=0.05, le=60)
    ramp_s: float = Field(0.08, gt=0, le=60)
    max_lag_s: float = Field(0.05, gt=0, le=1)

    @field_validator("step_levels_n")
    @classmethod
    def _levels(cls, v: list[float]) -> list[float]:
        if len(v) > 100 or any(not 0 < x <= 120 for x in v):
            raise InputError("expected at most 100 forces in (0, 120] N")
        return v


class CalibrationSettings(_Strict):
    """The ``calibration:`` section of a rig configuration."""

    records_folder: Path | None = Field(None, strict=False,
                                        description="default <data_folder>/calibrations")
    max_age_days: float = Field(30.0, gt=0, le=36500,
                                description="older records are used with a warning")
    required: list[str] = Field(default_factory=lambda: ["load_cell", "strain_gauge"],
                                description="sensors a real-hardware run refuses to go without")
    use_raw_units: bool = Field(False, description="run on real hardware without records "
                                                   "(data-sheet values, marked nominal)")
    operator: str = Field("", description="default operator name (else the login name)")
    load_cell: LoadCellCal = LoadCellCal()
    strain_gauge: StrainCal = StrainCal()
    motor: MotorCal = MotorCal()

    @field_validator("required")
    @classmethod
    def _known(cls, v: list[str]) -> list[str]:
        unknown = [s for s in v if s not in SENSORS]
        if unknown:
            raise InputError(f"unknown sensor {unknown[0]!r} (expected some of "
                             f"{', '.join(SENSORS)})")
        return v


def settings_for(cfg: RigConfig) -> CalibrationSettings:
    """The rig's calibration settings (its ``calibration:`` section, else the defaults)."""
    raw: Any = getattr(cfg, "calibration", None)
    if raw is None:
        return CalibrationSettings()
    if isinstance(raw, CalibrationSettings):
        return raw
    data = raw.model_dump() if isinstance(raw, BaseModel) else raw
    try:
        return CalibrationSettings.model_validate(data)
    except ValidationError as exc:
        e = exc.errors()[0]
        where = ".".join(str(p) for p in e["loc"])
        raise InputError(f"calibration.{where}: {e['msg']}") from None


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
