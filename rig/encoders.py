"""Quadrature encoders on the PCI-6602: counts (x4 decoded) -> rad or m.

value = initial_value + sign * counts * si_per_count. Rotary scales: 163,840
and 327,680 counts/rev; linear scale: 0.5 um/count (thesis Section 2.3).
The counters are read in ticks so the run file keeps the raw counts.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rig.config import Encoder


def to_si(counts: np.ndarray | float, si_per_count: float, offset: float, sign: int = 1) -> Any:
    """Counts -> rad (angular) or m (linear)."""
    return offset + sign * np.asarray(counts, dtype=float) * si_per_count


def to_counts(value: np.ndarray | float, si_per_count: float, offset: float) -> Any:
    """rad or m -> whole counts from ``offset`` (the value at count 0): what the counter reads."""
    return np.floor((np.asarray(value, dtype=float) - offset) / si_per_count + 0.5)


def add_ni_channel(task: Any, enc: Encoder, name: str) -> None:
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
