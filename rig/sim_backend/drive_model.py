"""The drive and motor: demand force -> force on the key (thesis Section 2.8, Appendix D).

The thesis identified G(s) = K / ((1 + 2 zeta Tw s + (Tw s)^2)(1 + Tp3 s)) (Eq. D.1)
with MATLAB's process models from the 10 N step responses of Fig. D.1, which
the load cell recorded *through* the signal conditioner's 100 Hz hardware
filter (Fig. D.3; D.2 calls it a model of "motor + amplifier + load cell", and
Appendix D notes that the 8 ms latency "is not due to the motor inductance
only"). So G is the demand -> *recorded* force, filter included.

**The filter is counted once, in this model**: the simulated load cell does not
filter again (``sim.load_cell_filter_hz`` is null by default). The other
split -- a plant before the filter, then the filter in the load cell -- is not
what the thesis identified and cannot be recovered from it: a third-order plant
fitted so that plant x filter matches G misses G's 10 N step by up to 9 % of
the step, and the exact inverse (G / filter, made proper by four poles at
2 kHz) asks the motor for 45 % of the step within 0.2 ms (measured with
``python benchmarks/fidelity_drive.py --split``; docs/running.md, "The
simulated drive"). The price: the simulated key feels the force as the load
cell reports it, not ~4 ms earlier as on the real rig (the recorded force does
not lag the key force; ``rig synth --load-cell-filter`` adds that lag on the
sensor side when a test needs it).

Units of Tw and Tp3: the thesis prints them without units. Read as 2 ms sample
periods (the 500 Hz loop, ``sim.process_time_unit_s``), the single model lags a
ramp by (2 zeta Tw + Tp3) x 2 ms = 6.86 ms (plus 1 ms for the 500 Hz hold), is
best aligned with the forte demand by a 7.9 ms shift, and settles to 2 % of a
10 N step in ~28 ms: the thesis's ~8 ms (with the filter) and ~25 ms. Read as
milliseconds it would lag 3.4 ms and settle in 14 ms, half the measured figures
although the filter is already inside G.

Variants (``sim.drive_model``):

* ``single`` (default): Eq. D.1 with the single model's parameters
  (``actuator.process_model_all``), the model the thesis found as good as any.
* ``asymmetric``: the increasing-demand model while the demand rises, the
  decreasing-demand model while it falls (Figs. D.11-D.16; the state carries
  over, so the force is continuous). The thesis calls the falling branch's
  prediction "discouraging" and found no gain over the single model; it is
  here for robustness tests (a drive much slower on release).
* ``step_size``: the single model whose first-order (current) stage cannot
  change faster than a 10 N step makes it change (K x 10 N / Tp3 = 2.0 kN/s):
  steps up to 10 N (the size G was identified on) respond exactly as
  ``single``; larger steps rise and fall slew-limited, so the response's
  shape changes with the step's size, as Fig. D.2 shows for the real drive.
  The thesis gives no parameters for Fig. D.2; the slew limit is this
  module's assumption (an amplifier saturating against the motor's
  inductance), chosen so that the identified 10 N steps are untouched.
  Ramps as steep as a forte blow (375 N/s) are untouched too.

Discretised exactly (zero-order hold) at the acquisition step for the linear
variants: the analog output holds each demand until the next write.
"""

from __future__ import annotations

import math

import numpy as np

from rig.errors import InputError
from rig.inputs.params import THESIS_TIME_UNIT_S, Parameters
from rig.motor_torque import (
    FALLING_MODEL,
    RISING_MODEL,
    SINGLE_MODEL,
    process_coefficients,
    process_discrete,
    thesis_process,
    zoh,
)

VARIANTS = ("single", "asymmetric", "step_size")
STEP_SIZE_REFERENCE_N = 10.0   # the step size of Fig. D.1 that Eq. D.1 was identified on
_SUBSTEPS = 20                 # sub-steps per sample for the slew-limited variant


def ramp_lag_s(K: float, Tw: float, zeta: float, Tp3: float) -> float:
    """Steady lag (s) of the continuous model behind a ramp, its output divided by K:
    a1 = 2 zeta Tw + Tp3 (Tw, Tp3 in s). The exact answer the tests check against."""
    return process_coefficients(Tw, zeta, Tp3)[2]


class DriveResponse:
    """Eq. D.1 (filter included) in one of ``VARIANTS``, stepped at a fixed dt (s)."""

    def __init__(self, dt: float, variant: str = "single",
                 time_unit_s: float = THESIS_TIME_UNIT_S,
                 params: Parameters | None = None) -> None:
        if variant not in VARIANTS:
            raise InputError(f"variant: expected one of {', '.join(VARIANTS)}, got {variant!r}")
        if not dt > 0:
            raise InputError(f"dt: expected a positive step in s, got {dt}")
        if not time_unit_s > 0:
            raise InputError(f"time_unit_s: expected a positive unit in s, got {time_unit_s}")
        p = params or Parameters.default()

        def coeffs(name: str) -> tuple[float, float, float, float]:
            return thesis_process(p, name, time_unit_s)

        self.variant = variant
        self.dt = dt
        single = coeffs(SINGLE_MODEL)
        self.gain = single[0]
        if variant == "asymmetric":
            self._rise = process_discrete(*coeffs(RISING_MODEL), dt)
            self._fall = process_discrete(*coeffs(FALLING_MODEL), dt)
        else:
            self._rise = self._fall = process_discrete(*single, dt)
        if variant == "step_size":
            K, Tw, zeta, Tp3 = single
            self._tp3 = Tp3
            self.slew_n_per_s = K * STEP_SIZE_REFERENCE_N / Tp3
            h = dt / _SUBSTEPS
            # second-order stage Tw^2 y'' + 2 zeta Tw y' + y = c, driven by the current stage c
            A2 = np.array([[0.0, 1.0], [-1 / (Tw * Tw), -2 * zeta / Tw]])
            B2 = np.array([0.0, 1 / (Tw * Tw)])
            self._A2, self._B2 = zoh(A2, B2, h)
            self._decay = math.exp(-h / Tp3)
            self._h = h
        self.x = np.zeros(3)
        self._last_u = 0.0
        self._rising = True

    def reset(self) -> None:
        self.x[:] = 0.0
        self._last_u = 0.0
        self._rising = True

    @property
    def output(self) -> float:
        """The force (N) now."""
        return float(self.x[0])

    def step(self, u: float, n: int) -> np.ndarray:
        """Hold demand u (N) for n steps; the force (N) at the end of each step."""
        if self.variant == "step_size":
            return self._step_slew(u, n)
        if u > self._last_u:
            self._rising = True
        elif u < self._last_u:
            self._rising = False
        self._last_u = u
        Ad, Bd = self._rise if self._rising else self._fall
        out = np.empty(n)
        for i in range(n):
            self.x = Ad @ self.x + Bd * u
            out[i] = self.x[0]
        return out

    def _step_slew(self, u: float, n: int) -> np.ndarray:
        # state here: [y, y', c] with c the current stage (N), c' = (K u - c) / Tp3 limited
        # to +-slew; exact first-order decay per sub-step, then clipped
        lim = self.slew_n_per_s * self._h
        target = self.gain * u
        out = np.empty(n)
        y = self.x[:2].copy()
        c = float(self.x[2])
        for i in range(n):
            for _ in range(_SUBSTEPS):
                c_new = target + (c - target) * self._decay
                c_new = min(max(c_new, c - lim), c + lim)
                # the second-order stage sees the sub-step's mean current
                y = self._A2 @ y + self._B2 * (0.5 * (c + c_new))
                c = c_new
            out[i] = y[0]
        self.x[:2] = y
        self.x[2] = c
        self._last_u = u
        return out
