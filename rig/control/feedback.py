"""Load-cell feedback in the 500 Hz loop: a PI controller on the force error.

Switched on in the rig config: ``loop.controller: rig.control.feedback:LoadCellPI``
(the loop's Controller hook, rig.loop.hook). Each cycle

    demand = feedforward + Kp e + I,   I += Ki e dt,   e = feedforward_target - measured

where the target is the profile at the cycle's time: the loop sets ``target_n`` each
cycle (without it, the feedforward delayed by the drive's lag, ``lead`` cycles, which
for the advanced profile is the same). With a learned feedforward the PI so compares
the load cell with the profile, not with the learned table (which differs from the
profile by design): the PI then only corrects what the table did not learn, and the
learning (rig.control.ilc) inverts the closed loop (``lifted``).

Design from the identified drive model: the motor calibration record's (``rig
calibrate motor``: K its ``sensitivity``, its ``lag_s``) when the run uses one
(``design_from``, called by ``rig run`` and ``--learn``), else the thesis's (Eq.
D.1, single model, K = 0.9322 N/N, ~8 ms lag incl. the load cell's filter): the
loop's dead time is the lag plus one cycle (2 ms), ~10 ms. An integral crossover
at wc = 1 / (4 x 10 ms) = 25 rad/s (4 Hz) keeps >= 60 deg phase margin against
that dead time: Ki = wc / K; Kp = 0.2 / K keeps the proportional loop gain far
below the 1 / (K x lag x wc) where the lag would make it ring. Anti-windup: the
integral stops growing while the demand would leave [0, limits.max_force_n]
(conditional integration) and is clamped to +-``integral_limit_n``; the loop's
motor_torque.Limiter still applies after it.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

from rig.control.ilc import DEFAULT_GAIN_K
from rig.errors import InputError

THESIS_LAG_S = 0.008           # the thesis's drive lag incl. the load cell's filter (Eq. D.1)
THESIS_DEAD_TIME_S = 0.010     # that lag + one 2 ms cycle
THESIS_DESIGN = "thesis single model (Eq. D.1), 10 ms dead time"


class LoadCellPI:
    """PI on the load-cell error with anti-windup; a Controller for ``loop.controller``."""

    name = "load_cell_pi"

    def __init__(self, gain_k: float = DEFAULT_GAIN_K, dead_time_s: float = THESIS_DEAD_TIME_S,
                 control_hz: float = 500.0, lead: int = 4, max_force_n: float = 60.0,
                 integral_limit_n: float = 5.0) -> None:
        self.integral_limit_n = integral_limit_n
        self.target_n: float | None = None   # the profile now, set by the loop each cycle
        self._design(gain_k, dead_time_s, control_hz, lead, max_force_n,
                     THESIS_DESIGN if (gain_k, dead_time_s) == (DEFAULT_GAIN_K,
                                                                THESIS_DEAD_TIME_S) else "given")
        self.reset()

    def _design(self, gain_k: float, dead_time_s: float, control_hz: float, lead: int,
                max_force_n: float, source: str) -> None:
        if not gain_k > 0 or not dead_time_s > 0:
            raise InputError(f"LoadCellPI: expected K > 0 and dead time > 0, got {gain_k}, "
                             f"{dead_time_s}")
        wc = 1.0 / (4.0 * dead_time_s)
        self.ki = wc / gain_k
        self.kp = 0.2 / gain_k
        self.dt = 1.0 / control_hz
        self.lead = lead
        self.max_force_n = max_force_n
        self.design = {"source": source, "gain_k": gain_k, "dead_time_s": dead_time_s,
                       "kp": self.kp, "ki_per_s": self.ki, "lead_cycles": float(lead),
                       "max_force_n": max_force_n}

    def design_from(self, motor_record: dict[str, Any] | None, control_hz: float,
                    max_force_n: float) -> None:
        """Design for the run: from the motor calibration record in use (K = its
        ``fit.sensitivity``, dead time = its ``fit.lag_s`` + one cycle, lead = the lag in
        cycles), else the thesis's model at this rate; the limits' maximum force."""
        if motor_record is None:
            self._design(DEFAULT_GAIN_K, THESIS_DEAD_TIME_S, control_hz,
                         int(round(THESIS_LAG_S * control_hz)), max_force_n, THESIS_DESIGN)
        else:
            fit = motor_record["fit"]
            k, lag = float(fit["sensitivity"]), float(fit["lag_s"])
            self._design(k, lag + 1.0 / control_hz, control_hz, int(round(lag * control_hz)),
                         max_force_n, f"motor calibration {motor_record.get('content_hash', '?')}")
        self.reset()

    def reset(self) -> None:
        self.integral = 0.0
        self.integrating: list[bool] = []   # per cycle since reset: did the integral move?
        self._ff: deque[float] = deque([0.0] * (self.lead + 1), maxlen=self.lead + 1)

    def __call__(self, t: float, feedforward_n: float, measured_n: float) -> float:
        self._ff.append(feedforward_n)
        # the profile now (the loop sets target_n), else the feedforward `lead` cycles ago
        target = self.target_n if self.target_n is not None else self._ff[0]
        e = target - measured_n
        out = feedforward_n + self.kp * e + self.integral
        inside = 0.0 <= out <= self.max_force_n
        moved = False
        if inside or (out > self.max_force_n and e < 0) or (out < 0 and e > 0):
            raw = self.integral + self.ki * e * self.dt
            self.integral = min(self.integral_limit_n, max(-self.integral_limit_n, raw))
            moved = self.integral == raw
        self.integrating.append(moved)
        return out

    def lifted(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The PI over a trial of n cycles as d = F u - C y + (terms without u or y):
        C = Kp I + Ki dt (strictly lower ones, the columns of the cycles the anti-windup
        held the integral in the last trial played or simulated zeroed); F = I with the
        profile as target, else I + C S (S the lead-cycle delay of the feedforward).
        What the learning update needs to invert the closed loop (rig.control.plant)."""
        mask = (np.asarray(self.integrating[:n], float) if len(self.integrating) >= n
                else np.ones(n))   # the cycles whose error the integral took in (anti-windup)
        C = self.kp * np.eye(n) + self.ki * self.dt * np.tril(np.ones((n, n)), -1) * mask
        if self.target_n is not None:
            return np.eye(n), C
        return np.eye(n) + C @ np.eye(n, k=-self.lead), C
