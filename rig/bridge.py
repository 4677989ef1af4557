"""Bridge channels on the SCXI-1520 through nidaqmx: shared by the load cell and gauge."""

from __future__ import annotations

from typing import Any


def add_ni_bridge_channel(task: Any, physical_channel: str, name: str, range_mv_per_v: float,
                          quarter: bool, excitation_volts: float, resistance_ohm: float) -> None:
    """Add a V/V bridge channel (full or quarter bridge, internal excitation) to a task."""
    from nidaqmx.constants import BridgeConfiguration, BridgeUnits, ExcitationSource

    r = range_mv_per_v * 1e-3
    config = BridgeConfiguration.QUARTER_BRIDGE if quarter else BridgeConfiguration.FULL_BRIDGE
    task.ai_channels.add_ai_bridge_chan(
        physical_channel, name_to_assign_to_channel=name, min_val=-r, max_val=r,
        units=BridgeUnits.VOLTS_PER_VOLT, bridge_config=config,
        voltage_excit_source=ExcitationSource.INTERNAL, voltage_excit_val=excitation_volts,
        nominal_bridge_resistance=resistance_ohm)


def ni_null_and_shunt(task: Any, name: str, shunt_resistor_ohm: float,
                      resistance_ohm: float) -> None:
    """Offset nulling, then shunt calibration; nidaqmx's bridge_resistance defaults to 120
    ohm, so the bridge's own resistance is always passed."""
    task.perform_bridge_offset_nulling_cal(channel=name)
    task.perform_bridge_shunt_cal(channel=name, shunt_resistor_value=shunt_resistor_ohm,
                                  bridge_resistance=resistance_ohm)
