"""Display units for SI channel values (light: `rig info` uses it without the analysis stack)."""

from __future__ import annotations

DISPLAY = {"rad": (1e3, "mrad"), "m": (1e3, "mm"), "m/m": (1e6, "microstrain"),
           "N": (1.0, "N"), "m/s": (1.0, "m/s"), "rad/s": (1.0, "rad/s"), "s": (1e3, "ms")}


def scale(units: str) -> tuple[float, str]:
    """(factor, display units) for SI ``units``."""
    return DISPLAY.get(units, (1.0, units))
