"""Calibration records: one JSON file per calibration, content-hashed, newest valid wins.

A record holds: sensor, identifier (serial or physical channel), created (UTC),
operator, the rig it was made on (backend, name, simulated seed), software
version and git commit, the raw points, the fit (``sensitivity`` and
``offset`` in the sensor table's conventions (rig.sensors.table), units stated), the
uncertainty budget (k = 2), the checks, and ``content_hash`` = sha256 of the canonical
JSON of everything else. A file whose hash does not match, or that was made
on another backend (or another simulated seed), is not valid and is skipped.

    path = write(folder, build("load_cell", cfg, identifier, operator, ...))
    rec, path = newest_valid(folder, "load_cell", cfg)
    cals = records_for_run(cfg)        # what lookup returns
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import warnings
from pathlib import Path
from typing import Any

from rig.calibration.settings import records_folder, settings_for
from rig.errors import InputError
from rig.inputs.config import RigConfig
from rig.recordings.identity import content_hash, json_ready, rig_identity
from rig.sensors.table import CalRecord, nominal
from rig.version import __version__

FORMAT = "rig-calibration"
FORMAT_VERSION = 1
SENSORS = ("load_cell", "strain_gauge", "motor", "encoders", "touch")


class MissingCalibration(InputError, RuntimeError):
    """A real-hardware run needs a calibration record that does not exist (the user's to
    make with `rig calibrate`: one line, exit 2)."""


class CalibrationAgeWarning(UserWarning):
    """A record in use is older than calibration.max_age_days."""


class InvalidRecordWarning(UserWarning):
    """An unreadable or altered record (its content hash does not match) was skipped."""


def build(sensor: str, cfg: RigConfig, *, identifier: str, operator: str, kind: str,
          units: dict[str, str], raw_points: Any, fit: dict[str, Any],
          uncertainty: dict[str, Any], checks: dict[str, Any] | None = None,
          extra: dict[str, Any] | None = None,
          created: _dt.datetime | None = None) -> dict[str, Any]:
    """A complete record (with its content hash) ready to ``write``."""
    from rig.recordings.runfile import git_commit

    if sensor not in SENSORS:
        raise InputError(f"sensor: expected one of {SENSORS}, got {sensor!r}")
    when = created or _dt.datetime.now(_dt.UTC)
    rec: dict[str, Any] = {
        "format": FORMAT, "format_version": FORMAT_VERSION, "sensor": sensor, "kind": kind,
        "identifier": identifier, "created": when.isoformat(timespec="microseconds"),
        "operator": operator, "rig": rig_identity(cfg), "software_version": __version__,
        "git_commit": git_commit(), "units": units, "raw_points": raw_points, "fit": fit,
        "uncertainty": uncertainty, "checks": checks or {}, **(extra or {})}
    rec = json_ready(rec)
    rec["content_hash"] = content_hash(rec)
    return rec


def write(folder: Path, record: dict[str, Any]) -> Path:
    """Write a new record file (never overwrites); returns its path."""
    if record.get("content_hash") != content_hash(record):
        raise InputError("record: content_hash does not match its content (build() it)")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    stamp = _dt.datetime.fromisoformat(record["created"]).strftime("%Y%m%dT%H%M%S%fZ")
    path = folder / f"{record['sensor']}-{stamp}-{record['content_hash'][7:15]}.json"
    if path.exists():
        raise InputError(f"{path}: a calibration record with this name already exists")
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(record, indent=1, allow_nan=False) + "\n")
    os.replace(tmp, path)
    return path


def read(path: Path) -> dict[str, Any]:
    """Read and verify one record (ValueError with the reason if it is not valid)."""
    try:
        rec = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: not a readable calibration record ({exc})") from None
    if not isinstance(rec, dict) or rec.get("format") != FORMAT:
        raise InputError(f"{path}: not a calibration record (format is not {FORMAT!r})")
    if rec.get("content_hash") != content_hash(rec):
        raise InputError(f"{path}: content_hash does not match: the file was altered")
    for key in ("sensor", "created", "fit", "uncertainty", "rig"):
        if key not in rec:
            raise InputError(f"{path}: {key}: missing")
    return rec


def newest_valid(folder: Path, sensor: str, cfg: RigConfig) -> tuple[dict[str, Any], Path] | None:
    """The newest valid record for ``sensor`` made on this rig's backend (and sim seed)."""
    folder = Path(folder)
    if not folder.is_dir():
        return None
    best: tuple[str, dict[str, Any], Path] | None = None
    want = rig_identity(cfg)
    for path in sorted(folder.glob(f"{sensor}-*.json")):
        try:
            rec = read(path)
        except ValueError as exc:
            warnings.warn(f"skipping {exc}", InvalidRecordWarning, stacklevel=2)
            continue
        if rec["sensor"] != sensor or any(rec["rig"].get(k) != v for k, v in want.items()
                                          if k != "name"):
            continue  # another backend, or another simulated rig (its seed)
        if best is None or rec["created"] > best[0]:
            best = (rec["created"], rec, path)
    return None if best is None else (best[1], best[2])


def age_days(rec: dict[str, Any], now: _dt.datetime | None = None) -> float:
    created = _dt.datetime.fromisoformat(rec["created"])
    return ((now or _dt.datetime.now(_dt.UTC)) - created).total_seconds() / 86400.0


def _source(rec: dict[str, Any], path: Path) -> str:
    return (f"calibration {path.name} ({rec['kind']}, {rec['created']}, operator "
            f"{rec['operator']}, {rec['content_hash']})")


def to_calrecord(rec: dict[str, Any], path: Path) -> CalRecord:
    """The run-time view of a stored record (sensitivity/offset in the sensor table's
    conventions)."""
    fit = rec["fit"]
    units = rec["units"]
    return CalRecord(rec["sensor"], False, float(fit["sensitivity"]), float(fit["offset"]),
                     units["raw"], units["calibrated"], _source(rec, path), str(path))


def records_for_run(cfg: RigConfig, now: _dt.datetime | None = None) -> dict[str, CalRecord]:
    """Calibration records a run uses (the body of ``lookup``).

    Newest valid record per sensor; a record older than ``max_age_days`` is
    used with a ``CalibrationAgeWarning``. On real hardware a sensor listed in
    ``calibration.required`` without a record refuses the run
    (``MissingCalibration``) unless ``calibration.use_raw_units``; the
    simulated rig falls back to the nominal (data-sheet) records, marked nominal.
    """
    settings = settings_for(cfg)
    folder = records_folder(cfg)
    cals = nominal(cfg)
    missing = []
    for sensor in ("load_cell", "strain_gauge", "motor"):
        if sensor == "strain_gauge" and not cfg.channels.strain_gauge.enabled:
            continue
        found = newest_valid(folder, sensor, cfg)
        if found is None:
            if sensor in settings.required:
                missing.append(sensor)
            continue
        rec, path = found
        age = age_days(rec, now)
        if age > settings.max_age_days:
            warnings.warn(f"calibration record {path.name} ({sensor}) is {age:.1f} days old "
                          f"(calibration.max_age_days is {settings.max_age_days:g}): "
                          f"recalibrate soon", CalibrationAgeWarning, stacklevel=2)
        cals[sensor] = to_calrecord(rec, path)
    if missing and not cfg.simulated and not settings.use_raw_units:
        cmds = ", ".join(f"`rig calibrate {'loadcell' if s == 'load_cell' else 'strain'}`"
                         if s in ("load_cell", "strain_gauge") else f"`rig calibrate {s}`"
                         for s in missing)
        raise MissingCalibration(
            f"calibration: no valid record for {', '.join(missing)} in {folder}: run {cmds} "
            f"first, or set calibration.use_raw_units: true to run with data-sheet values")
    if missing and not cfg.simulated:
        for s in missing:
            if s not in cals:  # motor: no data-sheet record; the run leads by loop.advance_s
                continue
            old = cals[s]
            cals[s] = CalRecord(old.sensor, True, old.sensitivity, old.offset, old.raw_units,
                                old.units, "data sheet (calibration.use_raw_units: no record)")
    return cals


def embedded(cals: dict[str, CalRecord], cfg: RigConfig) -> list[dict[str, Any]]:
    """Full stored records behind ``cals`` (for a run file's metadata), by content hash."""
    return [read(Path(rec.record_file)) for rec in cals.values()
            if not rec.nominal and rec.record_file]


def lookup(cfg: RigConfig) -> dict[str, CalRecord]:
    """The calibration record in use for each sensor: the one place a run asks (newest valid
    record per sensor with an age warning, refusal on NI without a required one unless
    calibration.use_raw_units, nominal on the simulated rig)."""
    return records_for_run(cfg)
