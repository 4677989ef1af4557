"""The key-top load cell: full bridge read as V/V, converted to newtons.

force_n = (ratio_v_per_v - offset) / sensitivity, with the sensitivity in
(V/V) per N. The nominal sensitivity is the rated output over full scale
(Sensotec Model 13: 2 mV/V at 111 N); calibration replaces it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rig.bridge import add_ni_bridge_channel, ni_null_and_shunt
from rig.config import LoadCell


def nominal_sensitivity(cfg: LoadCell) -> float:
    """(V/V) per N from the data sheet."""
    return cfg.rated_output_mv_per_v * 1e-3 / cfg.full_scale_n


def to_newtons(ratio: np.ndarray | float, sensitivity: float, offset: float) -> Any:
    """Bridge ratio (V/V) -> force on the key top (N)."""
    return (np.asarray(ratio, dtype=float) - offset) / sensitivity


def to_ratio(force_n: np.ndarray | float, sensitivity: float, offset: float) -> Any:
    """Force on the key top (N) -> bridge ratio (V/V): the inverse of ``to_newtons``."""
    return offset + sensitivity * np.asarray(force_n, dtype=float)


def add_ni_channel(task: Any, cfg: LoadCell, name: str = "load_cell") -> None:
    """Add the load cell to an nidaqmx task as a full-bridge V/V channel."""
    add_ni_bridge_channel(task, cfg.physical_channel, name, cfg.input_range_mv_per_v,
                          False, cfg.excitation_volts, cfg.bridge_resistance_ohm, cfg.lowpass_hz)


def ni_calibrate(task: Any, cfg: LoadCell, name: str = "load_cell",
                 shunt_resistor_ohm: float | None = None) -> float | None:
    """Offset nulling, then (with a resistor) shunt calibration on the SCXI-1520 (key
    unloaded); the driver's gain adjustment, if any."""
    return ni_null_and_shunt(task, name, shunt_resistor_ohm, cfg.bridge_resistance_ohm)
