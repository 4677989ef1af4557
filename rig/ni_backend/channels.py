"""The sensors' NI channel set-up (nidaqmx): bridge channels on the SCXI-1520 (the load cell
and the strain gauge; offset nulling and shunt calibration) and the encoders' counters on
the PCI-6602. Each kind of sensor of the sensor table (rig.sensors.table, ``Sensor.kind``)
has its DAQmx channel in ``NI_CHANNELS``; ``channel(cfg, sensor)`` is a sensor's."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from rig.errors import InputError
from rig.inputs.config import Encoder, LoadCell, RigConfig, StrainGauge
from rig.sensors.table import Sensor


def add_bridge_channel(task: Any, physical_channel: str, name: str, range_mv_per_v: float,
                          quarter: bool, excitation_volts: float, resistance_ohm: float,
                          lowpass_hz: float | None) -> None:
    """Add a V/V bridge channel (full or quarter bridge, internal excitation) to a task, with
    the SCXI-1520's 4-pole lowpass on at ``lowpass_hz`` (None: off)."""
    from nidaqmx.constants import BridgeConfiguration, BridgeUnits, ExcitationSource

    r = range_mv_per_v * 1e-3
    config = BridgeConfiguration.QUARTER_BRIDGE if quarter else BridgeConfiguration.FULL_BRIDGE
    chan = task.ai_channels.add_ai_bridge_chan(
        physical_channel, name_to_assign_to_channel=name, min_val=-r, max_val=r,
        units=BridgeUnits.VOLTS_PER_VOLT, bridge_config=config,
        voltage_excit_source=ExcitationSource.INTERNAL, voltage_excit_val=excitation_volts,
        nominal_bridge_resistance=resistance_ohm)
    chan.ai_lowpass_enable = lowpass_hz is not None
    if lowpass_hz is not None:
        chan.ai_lowpass_cutoff_freq = float(lowpass_hz)


def null_and_shunt(task: Any, name: str, shunt_resistor_ohm: float | None,
                      resistance_ohm: float) -> float | None:
    """Offset nulling, then (with a resistor) NI's shunt calibration; nidaqmx's
    bridge_resistance defaults to 120 ohm, so the bridge's own resistance is always passed.
    Returns the driver's gain adjustment (None without a shunt step)."""
    task.perform_bridge_offset_nulling_cal(channel=name)
    if shunt_resistor_ohm is None:
        return None
    task.perform_bridge_shunt_cal(channel=name, shunt_resistor_value=float(shunt_resistor_ohm),
                                  bridge_resistance=resistance_ohm)
    return float(task.ai_channels[name].ai_bridge_shunt_cal_gain_adjust)


def add_load_cell(task: Any, cfg: LoadCell, name: str = "load_cell") -> None:
    """Add the load cell to an nidaqmx task as a full-bridge V/V channel."""
    add_bridge_channel(task, cfg.physical_channel, name, cfg.input_range_mv_per_v,
                       False, cfg.excitation_volts, cfg.bridge_resistance_ohm, cfg.lowpass_hz)


def calibrate_load_cell(task: Any, cfg: LoadCell, name: str = "load_cell",
                 shunt_resistor_ohm: float | None = None) -> float | None:
    """Offset nulling, then (with a resistor) shunt calibration on the SCXI-1520 (key
    unloaded); the driver's gain adjustment, if any."""
    return null_and_shunt(task, name, shunt_resistor_ohm, cfg.bridge_resistance_ohm)


def add_strain_gauge(task: Any, cfg: StrainGauge, name: str = "strain_gauge") -> None:
    """Add the gauge to an nidaqmx task as a quarter-bridge V/V channel (350 ohm)."""
    add_bridge_channel(task, cfg.physical_channel, name, cfg.input_range_mv_per_v,
                       True, cfg.excitation_volts, cfg.nominal_resistance_ohm, cfg.lowpass_hz)


def calibrate_strain_gauge(task: Any, cfg: StrainGauge, name: str = "strain_gauge",
                 shunt_resistor_ohm: float | None = None) -> float | None:
    """Offset nulling, then (with the calibration record's resistor) shunt calibration;
    bridge_resistance is the gauge's (NI defaults to 120). The driver's gain adjustment."""
    return null_and_shunt(task, name, shunt_resistor_ohm, cfg.nominal_resistance_ohm)


def add_encoder(task: Any, enc: Encoder, name: str) -> None:
    """Add the encoder to a counter task, counting ticks with x4 decoding."""
    from nidaqmx.constants import AngleUnits, EncoderType, LengthUnits

    if enc.kind == "angular":
        assert enc.counts_per_rev is not None
        task.ci_channels.add_ci_ang_encoder_chan(
            enc.counter, name_to_assign_to_channel=name, decoding_type=EncoderType.X_4,
            units=AngleUnits.TICKS, pulses_per_rev=int(round(enc.counts_per_rev / 4)),
            initial_angle=0.0)
    else:
        assert enc.metres_per_count is not None
        task.ci_channels.add_ci_lin_encoder_chan(
            enc.counter, name_to_assign_to_channel=name, decoding_type=EncoderType.X_4,
            units=LengthUnits.TICKS, dist_per_pulse=enc.metres_per_count * 4, initial_pos=0.0)


@dataclass(frozen=True)
class NiChannel:
    """A sensor's DAQmx channel: ``add(task)`` adds it under the sensor's name; ``counter``:
    False, a channel of the shared analog-input task (the bridges'); True, a counter task
    of its own on the analog-input sample clock."""

    add: Callable[[Any], None]
    counter: bool = False


def _load_cell(cfg: RigConfig, s: Sensor) -> NiChannel:
    return NiChannel(functools.partial(add_load_cell, cfg=cfg.channels.load_cell))


def _strain_gauge(cfg: RigConfig, s: Sensor) -> NiChannel:
    return NiChannel(functools.partial(add_strain_gauge, cfg=cfg.channels.strain_gauge))


def _encoder(cfg: RigConfig, s: Sensor) -> NiChannel:
    return NiChannel(functools.partial(add_encoder, enc=cfg.channels.encoders[s.name],
                                       name=s.name), counter=True)


# each kind of sensor in the sensor table -> its DAQmx channel (docs/architecture.md,
# "Add a sensor")
NI_CHANNELS: dict[str, Callable[[RigConfig, Sensor], NiChannel]] = {
    "load_cell": _load_cell, "strain_gauge": _strain_gauge, "encoder": _encoder}


def channel(cfg: RigConfig, sensor: Sensor) -> NiChannel:
    """``sensor``'s DAQmx channel (its kind's entry in ``NI_CHANNELS``)."""
    how = NI_CHANNELS.get(sensor.kind)
    if how is None:
        raise InputError(f"channels: sensor {sensor.name!r} (kind {sensor.kind!r}) has no NI "
                         f"channel set-up (NI_CHANNELS in rig/ni_backend/channels.py)")
    return how(cfg, sensor)
