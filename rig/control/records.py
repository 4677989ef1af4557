"""Learned-feedforward records: what `rig run PROFILE --learn N` learned, reused by later runs.

One JSON file per learning session in ``<data_folder>/learned/``, content-hashed like
the calibration records (rig.calibration.records; the shared parts in
rig.recordings.identity): format, created (UTC), the profile
(name, source, ``content_hash`` of its time and force points), the rig (backend, name,
simulated seed), the calibration records in use (content hashes; the motor record's
matters: its map and lag shaped the first trial and the learning gain), the loop rate,
the learning filter, the trials (max and RMS error of each, % of the peak), the final
(best) trial's error, and the table ``feedforward_n`` (N, one value per loop cycle
from the profile's start, ``1 / control_hz`` apart).

``find(cfg, profile, calibrations)`` returns the newest valid record for exactly this
profile, rig, loop rate and motor calibration, or None: a new profile (any point
changed), a new motor calibration or another rig means relearning.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from rig.errors import InputError
from rig.inputs import profiles
from rig.inputs.config import RigConfig
from rig.recordings.identity import content_hash, json_ready, rig_identity

FORMAT = "rig-learned-feedforward"
FORMAT_VERSION = 1


def profile_hash(profile: profiles.Profile) -> str:
    """sha256 of the profile's points (time s, force N), rounded to 1 us / 1 uN."""
    pts = [[round(float(t), 6), round(float(f), 6)] for t, f in zip(profile.time, profile.force,
                                                                  strict=True)]
    text = json.dumps(pts, separators=(",", ":"))
    return "sha256:" + hashlib.sha256(text.encode()).hexdigest()


def folder(cfg: RigConfig) -> Path:
    return Path(cfg.data_folder) / "learned"


def motor_hash(calibration_records: list[dict[str, Any]]) -> str | None:
    rec = next((r for r in calibration_records if r.get("sensor") == "motor"), None)
    return None if rec is None else str(rec["content_hash"])


def build(cfg: RigConfig, profile: profiles.Profile, calibration_records: list[dict[str, Any]],
          feedforward_n: np.ndarray, trials: list[dict[str, float]], final: dict[str, float],
          learning_filter: dict[str, Any], stopped: str | None,
          created: _dt.datetime | None = None) -> dict[str, Any]:
    when = (created or _dt.datetime.now(_dt.UTC)).isoformat()
    rec: dict[str, Any] = json_ready({
        "format": FORMAT, "format_version": FORMAT_VERSION, "created": when,
        "profile": {"name": profile.name, "source": str(profile.source),
                    "content_hash": profile_hash(profile)},
        "rig": rig_identity(cfg), "drive_model": cfg.sim.drive_model
        if cfg.simulated else None,
        "calibration_records": [r["content_hash"] for r in calibration_records],
        "motor_calibration": motor_hash(calibration_records),
        "control_hz": cfg.rates.control_hz, "learning_filter": learning_filter,
        "trials": trials, "final_error": final, "stopped": stopped,
        "units": {"feedforward_n": "N", "control_hz": "Hz", "max_pct": "% of the peak",
                  "rms_pct": "% of the peak", "max_n": "N", "rms_n": "N"},
        "feedforward_n": np.asarray(feedforward_n, float),
    })
    rec["content_hash"] = content_hash(rec)
    return rec


def write(cfg: RigConfig, record: dict[str, Any]) -> Path:
    """A new record file in ``folder(cfg)`` (never overwrites)."""
    d = folder(cfg)
    d.mkdir(parents=True, exist_ok=True)
    stamp = _dt.datetime.fromisoformat(record["created"]).strftime("%Y%m%dT%H%M%S%fZ")
    path = d / f"{record['profile']['name']}-{stamp}-{record['content_hash'][7:15]}.json"
    if path.exists():
        raise InputError(f"{path}: a learned-feedforward record with this name already exists")
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(record, indent=1, allow_nan=False) + "\n")
    os.replace(tmp, path)
    return path


def read(path: Path) -> dict[str, Any]:
    """Read and verify one record (ValueError naming the file and the reason)."""
    try:
        rec = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: not a readable learned-feedforward record ({exc})") from None
    if not isinstance(rec, dict) or rec.get("format") != FORMAT:
        raise InputError(f"{path}: format: not a learned-feedforward record")
    if rec.get("content_hash") != content_hash(rec):
        raise InputError(f"{path}: content_hash does not match: the file was altered")
    return rec


def find(cfg: RigConfig, profile: profiles.Profile,
         calibration_records: list[dict[str, Any]]) -> tuple[dict[str, Any], Path] | None:
    """The newest valid record for this profile, rig, loop rate and motor calibration."""
    d = folder(cfg)
    if not d.is_dir():
        return None
    want = (profile_hash(profile), rig_identity(cfg), float(cfg.rates.control_hz),
            motor_hash(calibration_records))
    best: tuple[dict[str, Any], Path] | None = None
    for path in sorted(d.glob("*.json")):
        try:
            rec = read(path)
        except ValueError as exc:
            warnings.warn(f"skipping {exc}", stacklevel=2)
            continue
        have = (rec["profile"]["content_hash"], rec["rig"], float(rec["control_hz"]),
                rec.get("motor_calibration"))
        if have == want and (best is None or rec["created"] > best[0]["created"]):
            best = (rec, path)
    return best


def demand_source(record: dict[str, Any]) -> tuple[Callable[[profiles.Profile, float], float],
                                                   dict[str, Any]]:
    """The loop's feedforward from a record's table (0 before the start and after the end)."""
    u = np.asarray(record["feedforward_n"], float)
    hz = float(record["control_hz"])

    def table(profile: profiles.Profile, t: float) -> float:
        j = int(round(t * hz))
        return float(u[j]) if 0 <= j < u.size else 0.0

    return table, {"kind": "learned", "lead_s": 0.0, "record": record["content_hash"],
                   "created": record["created"], "trials": len(record["trials"]),
                   "final_max_error_pct": record["final_error"].get("max_pct")}
