"""Units a map may name, converted to SI (the run file's units)."""

from __future__ import annotations

import math

# name -> (SI units, factor to SI)
UNITS: dict[str, tuple[str, float]] = {
    "m": ("m", 1.0), "mm": ("m", 1e-3), "um": ("m", 1e-6), "in": ("m", 0.0254),
    "rad": ("rad", 1.0), "deg": ("rad", math.pi / 180.0),
    "N": ("N", 1.0), "mN": ("N", 1e-3), "kN": ("N", 1e3),
    "m/m": ("m/m", 1.0), "ustrain": ("m/m", 1e-6),
    "m/s": ("m/s", 1.0), "mm/s": ("m/s", 1e-3),
    "rad/s": ("rad/s", 1.0), "deg/s": ("rad/s", math.pi / 180.0),
    "s": ("s", 1.0), "ms": ("s", 1e-3), "us": ("s", 1e-6),
    "V": ("V", 1.0), "mV": ("V", 1e-3), "V/V": ("V/V", 1.0), "mV/V": ("V/V", 1e-3),
    "1": ("1", 1.0), "counts": ("counts", 1.0),
}
LENGTH = "m"
