"""The measured-run schema: the rig's sensors, their run-file channels and calibrations.

One table, ``sensors(cfg)``, lists every sensor of a rig in the order of the card rows'
columns (after ``sample``): its raw column and SI channel with units and descriptions,
its data-sheet calibration, its raw -> SI conversion and its ``kind``, by which each
backend finds its own part: the NI channel set-up (rig.ni_backend.channels.NI_CHANNELS)
and the simulated chain, true value -> reading (rig.sim_backend.sensors.SIM_CHAINS). The
NI reader, the simulated rig, the acquisition process, `rig synth` and the calibration
bench all read it; adding a sensor is one entry in ``SENSOR_TABLE`` and its part in each
backend (docs/architecture.md, "Add a sensor").

Which calibration applies to each sensor is asked in one place,
``rig.calibration.records.lookup`` (the newest valid record per sensor, else the
data sheet's nominal one from ``nominal`` here, marked ``nominal: true``). Conventions:

    load_cell      sensitivity (V/V)/N,      offset V/V     force = (r - offset) / sensitivity
    strain_gauge   sensitivity = gage factor, offset V/V    NI quarter-bridge-I formula
    <encoder>      sensitivity rad|m per count (signed), offset rad|m at count 0
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from rig import encoders, loadcell, strain
from rig.errors import InputError
from rig.inputs.config import RigConfig


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


Convert = Callable[[np.ndarray, float, float], Any]  # (values, sensitivity, offset)


@dataclass(frozen=True)
class Sensor:
    """One sensor: a raw column of the card rows and the SI channel calibrated from it."""

    name: str                  # its calibration record's sensor name
    raw: str                   # raw column (card rows and run file)
    raw_units: str
    raw_doc: str
    channel: str               # calibrated (SI) channel
    units: str
    doc: str
    sensitivity: float         # data-sheet (nominal) calibration, in the conventions above
    offset: float
    to_si: Convert             # raw -> SI with a calibration (sensitivity, offset)
    to_raw: Convert            # SI -> raw: what the card reads of a true value
    kind: str                  # what the backends look its parts up by: its NI channel
                               # (rig.ni_backend.channels.NI_CHANNELS), its simulated chain
                               # (rig.sim_backend.sensors.SIM_CHAINS)


def _load_cell(cfg: RigConfig) -> list[Sensor]:
    lc = cfg.channels.load_cell
    return [Sensor(
        "load_cell", "load_cell_ratio", "V/V", "load-cell bridge output, raw",
        "force", "N", "force on the key top from the load cell (calibration in metadata)",
        loadcell.nominal_sensitivity(lc), 0.0, loadcell.to_newtons, loadcell.to_ratio,
        "load_cell")]


def _strain_gauge(cfg: RigConfig) -> list[Sensor]:
    g = cfg.channels.strain_gauge
    if not g.enabled:
        return []
    wires = {"lead_wire_ohm": g.lead_wire_resistance_ohm, "gauge_ohm": g.nominal_resistance_ohm}
    return [Sensor(
        "strain_gauge", "strain_ratio", "V/V", "strain-gauge quarter bridge output, raw",
        "shank_strain", "m/m", "hammer-shank strain at the gauge, + = tension",
        g.gage_factor, 0.0, functools.partial(strain.to_strain, **wires),
        functools.partial(strain.to_ratio, **wires), "strain_gauge")]


def _encoders(cfg: RigConfig) -> list[Sensor]:
    """Encoder angles are the record's offset (the body's angle at count 0, i.e. at the
    acquisition start, in the model's ground frame; nominal: channels.encoders.<name>.
    initial_value, 0 by default) plus the counted motion."""
    out = []
    for n, enc in cfg.channels.encoders.items():
        start = ("motion from the pose at the acquisition start" if enc.initial_value == 0
                 else f"{enc.initial_value:g} {enc.units} at the acquisition start + motion")
        out.append(Sensor(
            n, f"{n}_counts", "counts",
            f"{n} encoder counts (x4) since the acquisition start, on the {enc.body}",
            enc.channel_name, enc.units,
            f"{enc.body} from the {n} encoder: calibration offset + counted motion "
            f"(nominal: {start})",
            enc.sign * enc.si_per_count, enc.initial_value, encoders.to_si, encoders.to_counts,
            "encoder"))
    return out


# The rig's sensors, in the order of the card rows' columns: each entry gives the sensors
# of one kind that a rig configuration has (none when it is not fitted).
SensorKind = Callable[[RigConfig], list[Sensor]]
SENSOR_TABLE: list[SensorKind] = [_load_cell, _strain_gauge, _encoders]
FEEDBACK = "load_cell_ratio"  # the raw column the loop's force feedback reads
SAMPLE = "sample"             # the card rows' first column: the sample counter


def sensors(cfg: RigConfig) -> list[Sensor]:
    """Every sensor of the rig, in the order of the card rows' columns (after ``sample``)."""
    out = [s for kind in SENSOR_TABLE for s in kind(cfg)]
    names = [SAMPLE, "time"] + [n for s in out for n in (s.raw, s.channel)]
    if len(set(names)) != len(names):
        raise InputError(f"channels: two sensors write the same channel: {names}")
    if len({s.name for s in out}) != len(out):
        raise InputError(f"channels: two sensors have the same name: {[s.name for s in out]}")
    return out


def nominal(cfg: RigConfig) -> dict[str, CalRecord]:
    """Data-sheet calibrations of every sensor of the rig."""
    return {s.name: CalRecord(s.name, True, s.sensitivity, s.offset, s.raw_units, s.units)
            for s in sensors(cfg)}


def raw_names(cfg: RigConfig) -> list[str]:
    """Raw channel names in the order of a block's columns."""
    return [SAMPLE] + [s.raw for s in sensors(cfg)]


def column(cfg: RigConfig, raw: str) -> int:
    """The card rows' column holding raw channel ``raw``."""
    return raw_names(cfg).index(raw)


def channel_units(cfg: RigConfig) -> dict[str, str]:
    """Units of every channel a measured run stores (raw and calibrated)."""
    table = sensors(cfg)
    return {"time": "s", SAMPLE: "1", **{s.raw: s.raw_units for s in table},
            **{s.channel: s.units for s in table}}


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
    SAMPLE: "sample counter since the acquisition started (proves no gap)",
}


def channel_docs(cfg: RigConfig) -> dict[str, str]:
    """Description of every channel a measured (or synthetic) run stores."""
    table = sensors(cfg)
    return {**CHANNEL_DOCS, **{s.raw: s.raw_doc for s in table},
            **{s.channel: s.doc for s in table}}


def convert(block: np.ndarray, cfg: RigConfig, cals: dict[str, CalRecord],
            t0_sample: int = 0) -> dict[str, np.ndarray]:
    """A raw block (rows of ``raw_names``) -> named raw and SI channels, with time (s)."""
    table = sensors(cfg)
    names = [SAMPLE] + [s.raw for s in table]
    if block.ndim != 2 or block.shape[1] != len(names):
        raise InputError(f"block: expected rows of {len(names)} columns {names}, got "
                         f"shape {block.shape}")
    cols = {n: block[:, i] for i, n in enumerate(names)}
    out: dict[str, np.ndarray] = {
        "time": (cols[SAMPLE] - t0_sample) / cfg.rates.acquisition_hz, **cols}
    for s in table:
        rec = cals[s.name]
        out[s.channel] = s.to_si(cols[s.raw], rec.sensitivity, rec.offset)
    return out
