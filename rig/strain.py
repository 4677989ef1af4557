"""The hammer-shank strain gauge: quarter bridge (type I), 350 ohm, read as V/V.

NI's quarter-bridge-I conversion, with Vr the change of bridge ratio from the
unstrained value:  strain = -4 Vr / (GF (1 + 2 Vr)) * (1 + RL / Rg).
``sensitivity`` below is the gage factor in use and ``offset`` the unstrained
ratio (V/V); calibration replaces the nominal values.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rig.errors import InputError


def to_strain(ratio: np.ndarray | float, gage_factor: float, offset: float,
              lead_wire_ohm: float = 0.0, gauge_ohm: float = 350.0) -> Any:
    """Bridge ratio (V/V) -> strain (m/m), + = tension."""
    vr = np.asarray(ratio, dtype=float) - offset
    return -4.0 * vr / (gage_factor * (1.0 + 2.0 * vr)) * (1.0 + lead_wire_ohm / gauge_ohm)


def to_ratio(strain: np.ndarray | float, gage_factor: float, offset: float,
             lead_wire_ohm: float = 0.0, gauge_ohm: float = 350.0) -> Any:
    """Strain (m/m) -> bridge ratio (V/V): the inverse of ``to_strain``."""
    e = np.asarray(strain, dtype=float) / (1.0 + lead_wire_ohm / gauge_ohm)
    return offset - gage_factor * e / (4.0 + 2.0 * gage_factor * e)


def shunt_equivalent_strain(gauge_ohm: float, gage_factor: float, shunt_ohm: float) -> float:
    """Equivalent strain (m/m) of a shunt across a quarter-bridge gauge: -Rg/(GF (Rg + Rs))."""
    for name, v in (("gauge_ohm", gauge_ohm), ("gage_factor", gage_factor),
                    ("shunt_ohm", shunt_ohm)):
        if not v > 0:
            raise InputError(f"{name}: expected a positive value, got {v}")
    return -gauge_ohm / (gage_factor * (gauge_ohm + shunt_ohm))
