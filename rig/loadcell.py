"""The key-top load cell: full bridge read as V/V, converted to newtons.

force_n = (ratio_v_per_v - offset) / sensitivity, with the sensitivity in
(V/V) per N. The nominal sensitivity is the rated output over full scale
(Sensotec Model 13: 2 mV/V at 111 N); calibration replaces it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rig.inputs.config import LoadCell


def nominal_sensitivity(cfg: LoadCell) -> float:
    """(V/V) per N from the data sheet."""
    return cfg.rated_output_mv_per_v * 1e-3 / cfg.full_scale_n


def to_newtons(ratio: np.ndarray | float, sensitivity: float, offset: float) -> Any:
    """Bridge ratio (V/V) -> force on the key top (N)."""
    return (np.asarray(ratio, dtype=float) - offset) / sensitivity


def to_ratio(force_n: np.ndarray | float, sensitivity: float, offset: float) -> Any:
    """Force on the key top (N) -> bridge ratio (V/V): the inverse of ``to_newtons``."""
    return offset + sensitivity * np.asarray(force_n, dtype=float)
