"""Calibration records in use, and raw -> SI conversion of acquired blocks.

Which calibration applies to each sensor is asked in one place,
``rig.calibration.records.lookup`` (the newest valid record per sensor, else the
data sheet's nominal one from ``nominal`` here, marked ``nominal: true``). Conventions:

    load_cell      sensitivity (V/V)/N,      offset V/V     force = (r - offset) / sensitivity
    strain_gauge   sensitivity = gage factor, offset V/V    NI quarter-bridge-I formula
    <encoder>      sensitivity rad|m per count (signed), offset rad|m at count 0
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from rig import encoders, loadcell, strain
from rig.config import RigConfig
from rig.errors import InputError


@dataclass(frozen=True)
class CalRecord:
    """One sensor's calibration as used for a run."""

    sensor: str
    nominal: bool
    sensitivity: float
    offset: float
    raw_units: str
    units: str
    source: str = "data sheet"
    record_file: str = ""  # the stored record (rig.calibration.records) it came from, if any

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def nominal(cfg: RigConfig) -> dict[str, CalRecord]:
    """Data-sheet calibrations of every sensor of the rig."""
    ch = cfg.channels
    recs = {"load_cell": CalRecord("load_cell", True, loadcell.nominal_sensitivity(ch.load_cell),
                                   0.0, "V/V", "N")}
    if ch.strain_gauge.enabled:
        recs["strain_gauge"] = CalRecord("strain_gauge", True, ch.strain_gauge.gage_factor, 0.0,
                                         "V/V", "m/m")
    for name, enc in ch.encoders.items():
        recs[name] = CalRecord(name, True, enc.sign * enc.si_per_count, enc.initial_value,
                               "counts", enc.units)
    return recs


RAW_UNITS = {"sample": "1", "load_cell_ratio": "V/V", "strain_ratio": "V/V"}


def raw_names(cfg: RigConfig) -> list[str]:
    """Raw channel names in the order of a block's columns."""
    names = ["sample", "load_cell_ratio"]
    if cfg.channels.strain_gauge.enabled:
        names.append("strain_ratio")
    names += [f"{n}_counts" for n in cfg.channels.encoders]
    return names


def channel_units(cfg: RigConfig) -> dict[str, str]:
    """Units of every channel a measured run stores (raw and calibrated)."""
    u = {"time": "s", **RAW_UNITS, "force": "N"}
    if cfg.channels.strain_gauge.enabled:
        u["shank_strain"] = "m/m"
    for n, enc in cfg.channels.encoders.items():
        u[f"{n}_counts"] = "counts"
        u[enc.channel_name] = enc.units
    return {k: v for k, v in u.items() if k != "strain_ratio" or "shank_strain" in u}


# the 500 Hz loop's records in a run file (section "commands")
COMMAND_UNITS = {
    "time": "s", "tick": "1", "target": "N", "feedforward": "N", "demand": "N", "volts": "V",
    "limited": "1", "measured_force": "N", "lateness": "s", "missed": "1",
}
COMMAND_DOCS = {
    "time": "trial time of the loop tick (0 = profile start)",
    "tick": "index of the 500 Hz tick on the rig's clock",
    "target": "profile force at this time",
    "feedforward": "open-loop demand: the profile advance_s ahead, or with a motor "
                   "calibration its inverse force map of the profile lag_s ahead "
                   "(metadata run.compensation)",
    "demand": "force demanded after the controller and the limits",
    "volts": "analog output to the drive",
    "limited": "1 where a force or rate limit changed the demand",
    "measured_force": "latest load-cell force the controller saw",
    "lateness": "time from the tick to the loop's wake-up",
    "missed": "ticks missed before this one (the output was held)",
}
CHANNEL_DOCS = {
    "time": "trial time (0 = profile start), sample / rate",
    "sample": "sample counter since the acquisition started (proves no gap)",
    "load_cell_ratio": "load-cell bridge output, raw",
    "strain_ratio": "strain-gauge quarter bridge output, raw",
    "force": "force on the key top from the load cell (calibration in metadata)",
    "shank_strain": "hammer-shank strain at the gauge, + = tension",
}


def channel_docs(cfg: RigConfig) -> dict[str, str]:
    """Description of every channel a measured (or synthetic) run stores. Encoder angles are
    the record's offset (the body's angle at count 0, i.e. at the acquisition start, in the
    model's ground frame; nominal: channels.encoders.<name>.initial_value, 0 by default)
    plus the counted motion."""
    docs = dict(CHANNEL_DOCS)
    for n, enc in cfg.channels.encoders.items():
        docs[f"{n}_counts"] = f"{n} encoder counts (x4) since the acquisition start, on the " \
                              f"{enc.body}"
        start = ("motion from the pose at the acquisition start" if enc.initial_value == 0
                 else f"{enc.initial_value:g} {enc.units} at the acquisition start + motion")
        docs[enc.channel_name] = (f"{enc.body} from the {n} encoder: calibration offset + "
                                  f"counted motion (nominal: {start})")
    return docs


def convert(block: np.ndarray, cfg: RigConfig, cals: dict[str, CalRecord],
            t0_sample: int = 0) -> dict[str, np.ndarray]:
    """A raw block (rows of ``raw_names``) -> named raw and SI channels, with time (s)."""
    names = raw_names(cfg)
    if block.ndim != 2 or block.shape[1] != len(names):
        raise InputError(f"block: expected rows of {len(names)} columns {names}, got "
                         f"shape {block.shape}")
    cols = {n: block[:, i] for i, n in enumerate(names)}
    out: dict[str, np.ndarray] = {
        "time": (cols["sample"] - t0_sample) / cfg.rates.acquisition_hz, **cols}
    lc = cals["load_cell"]
    out["force"] = loadcell.to_newtons(cols["load_cell_ratio"], lc.sensitivity, lc.offset)
    if "strain_ratio" in cols:
        sg = cals["strain_gauge"]
        g = cfg.channels.strain_gauge
        out["shank_strain"] = strain.to_strain(cols["strain_ratio"], sg.sensitivity, sg.offset,
                                               g.lead_wire_resistance_ohm,
                                               g.nominal_resistance_ohm)
    for n, enc in cfg.channels.encoders.items():
        rec = cals[n]
        out[enc.channel_name] = encoders.to_si(cols[f"{n}_counts"], rec.sensitivity, rec.offset)
    return out
