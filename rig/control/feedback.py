"""Load-cell feedback in the 500 Hz loop: a PI controller on the force error.

Switched on in the rig config: ``loop.controller: rig.control.feedback:LoadCellPI``
(the loop's Controller hook, rig.services.run). Each cycle

    demand = feedforward + Kp e + I,   I += Ki e dt,   e = feedforward_target - measured

where the target is the profile at the cycle's time (the loop passes the advanced
feedforward; the PI compares the load cell with the feedforward delayed by the
drive's lag, ``lead`` cycles, so the open-loop lag compensation is not fought).

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
        self.reset()

    def reset(self) -> None:
        self.integral = 0.0
        self._ff: deque[float] = deque([0.0] * (self.lead + 1), maxlen=self.lead + 1)

    def __call__(self, t: float, feedforward_n: float, measured_n: float) -> float:
        self._ff.append(feedforward_n)
        target = self._ff[0]   # the feedforward `lead` cycles ago: what the force should be now
        e = target - measured_n
        out = feedforward_n + self.kp * e + self.integral
        inside = 0.0 <= out <= self.max_force_n
        if inside or (out > self.max_force_n and e < 0) or (out < 0 and e > 0):
            self.integral = min(self.integral_limit_n, max(-self.integral_limit_n,
                                                           self.integral + self.ki * e * self.dt))
        return out
