"""The key-top load cell: full bridge read as V/V, converted to newtons.

force_n = (ratio_v_per_v - offset) / sensitivity, with the sensitivity in
(V/V) per N. The nominal sensitivity is the rated output over full scale
(Sensotec Model 13: 2 mV/V at 111 N); calibration (issue 5) replaces it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rig.config import LoadCell


def nominal_sensitivity(cfg: LoadCell) -> float:
    """(V/V) per N from the data sheet."""
    return cfg.rated_output_mv_per_v * 1e-3 / cfg.full_scale_n


def to_newtons(ratio: np.ndarray | float, sensitivity: float, offset: float) -> Any:
    """Bridge ratio (V/V) -> force on the key top (N)."""
    return (np.asarray(ratio, dtype=float) - offset) / sensitivity


def add_ni_channel(task: Any, cfg: LoadCell, name: str = "load_cell") -> None:
    """Add the load cell to an nidaqmx task as a full-bridge V/V channel."""
    from nidaqmx.constants import BridgeConfiguration, BridgeUnits, ExcitationSource

    r = cfg.input_range_mv_per_v * 1e-3
    task.ai_channels.add_ai_bridge_chan(
        cfg.physical_channel, name_to_assign_to_channel=name, min_val=-r, max_val=r,
        units=BridgeUnits.VOLTS_PER_VOLT, bridge_config=BridgeConfiguration.FULL_BRIDGE,
        voltage_excit_source=ExcitationSource.INTERNAL, voltage_excit_val=cfg.excitation_volts,
        nominal_bridge_resistance=cfg.bridge_resistance_ohm)


def ni_calibrate(task: Any, cfg: LoadCell, name: str = "load_cell",
                 shunt_resistor_ohm: float = 100000.0) -> None:
    """Offset nulling then shunt calibration on the SCXI-1520 (key unloaded)."""
    task.perform_bridge_offset_nulling_cal(channel=name)
    task.perform_bridge_shunt_cal(channel=name, shunt_resistor_value=shunt_resistor_ohm,
                                  bridge_resistance=cfg.bridge_resistance_ohm)
