"""Load-cell feedback in the 500 Hz loop: a PI controller on the force error.

Switched on in the rig config: ``loop.controller: rig.control.feedback:LoadCellPI``
(the loop's Controller hook, rig.controller). Each cycle

    demand = feedforward + Kp e + I,   I += Ki e dt,   e = feedforward_target - measured

where the target is the profile at the cycle's time: the loop sets ``target_n`` each
cycle (without it, the feedforward delayed by the drive's lag, ``lead`` cycles, which
for the advanced profile is the same). With a learned feedforward the PI so compares
the load cell with the profile, not with the learned table (which differs from the
profile by design): the PI then only corrects what the table did not learn, and the
learning (rig.control.ilc) inverts the closed loop (``lifted``).

Design from the identified drive model (Eq. D.1, thesis single model, K = 0.9322
N/N, ~8 ms lag incl. the load cell's filter): the loop's dead time is the lag plus
one 2 ms cycle, ~10 ms. An integral crossover at wc = 1 / (4 x 10 ms) = 25 rad/s
(4 Hz) keeps >= 60 deg phase margin against that dead time: Ki = wc / K;
Kp = 0.2 / K keeps the proportional loop gain far below the 1 / (K x lag x wc)
where the lag would make it ring. Anti-windup: the integral stops growing while the
demand would leave [0, limits.max_force_n] (conditional integration) and is clamped
to +-``integral_limit_n``; the loop's motor_torque.Limiter still applies after it.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from rig.control.ilc import DEFAULT_GAIN_K
from rig.errors import InputError


class LoadCellPI:
    """PI on the load-cell error with anti-windup; a Controller for ``loop.controller``."""

    name = "load_cell_pi"

    def __init__(self, gain_k: float = DEFAULT_GAIN_K, dead_time_s: float = 0.010,
                 control_hz: float = 500.0, lead: int = 4, max_force_n: float = 60.0,
                 integral_limit_n: float = 5.0) -> None:
        if not gain_k > 0 or not dead_time_s > 0:
            raise InputError(f"LoadCellPI: expected K > 0 and dead time > 0, got {gain_k}, "
                             f"{dead_time_s}")
        wc = 1.0 / (4.0 * dead_time_s)
        self.ki = wc / gain_k
        self.kp = 0.2 / gain_k
        self.dt = 1.0 / control_hz
        self.lead = lead
        self.max_force_n = max_force_n
        self.integral_limit_n = integral_limit_n
        self.target_n: float | None = None   # the profile now, set by the loop each cycle
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
