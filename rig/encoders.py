"""Quadrature encoders on the PCI-6602: counts (x4 decoded) -> rad or m.

value = initial_value + sign * counts * si_per_count. Rotary scales: 163,840
and 327,680 counts/rev; linear scale: 0.5 um/count (thesis Section 2.3).
The counters are read in ticks so the run file keeps the raw counts.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def to_si(counts: np.ndarray | float, si_per_count: float, offset: float, sign: int = 1) -> Any:
    """Counts -> rad (angular) or m (linear)."""
    return offset + sign * np.asarray(counts, dtype=float) * si_per_count


def to_counts(value: np.ndarray | float, si_per_count: float, offset: float) -> Any:
    """rad or m -> whole counts from ``offset`` (the value at count 0): what the counter reads."""
    return np.floor((np.asarray(value, dtype=float) - offset) / si_per_count + 0.5)
