"""Bridge channels on the SCXI-1520 through nidaqmx: shared by the load cell and gauge."""

from __future__ import annotations

from typing import Any


def add_ni_bridge_channel(task: Any, physical_channel: str, name: str, range_mv_per_v: float,
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


def ni_null_and_shunt(task: Any, name: str, shunt_resistor_ohm: float | None,
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
