"""Force demand -> drive volts: scaling, safety limits, the lag-compensating advance;
the drive's process model (thesis Eq. D.1), the one definition that the learner's planning
(rig.control.plant) and the simulated drive (rig.sim_backend.drive_model) share: its
coefficients (``ProcessModel``, ``thesis_process`` in the thesis's time unit
``THESIS_TIME_UNIT_S``), its rising- and falling-demand models (``RiseFall``,
``thesis_models``), discretised for a held demand (``process_discrete``).

The motor presses the key top through a 0.1 m arm, so force and torque are
interchangeable (thesis Section 2.8): torque = force * arm; the drive turns
volts into current, the motor current into torque.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Self

import numpy as np

from rig.errors import InputError
from rig.inputs.config import DriveOutput, DriveScaling, Limits
from rig.inputs.params import THESIS_TIME_UNIT_S, Parameters
from rig.inputs.profiles import Profile


@dataclass(frozen=True)
class TorqueScaling:
    """Demanded key force (N) <-> analog-output volts."""

    volts_per_newton: float
    min_volts: float
    max_volts: float

    @classmethod
    def from_config(cls, scaling: DriveScaling, output: DriveOutput) -> TorqueScaling:
        return cls(scaling.volts_per_newton, output.min_volts, output.max_volts)

    def volts(self, force_n: float) -> float:
        """Volts for a force, clipped to the output's range."""
        return min(self.max_volts, max(self.min_volts, force_n * self.volts_per_newton))

    def force(self, volts: float | np.ndarray) -> float | np.ndarray:
        return volts / self.volts_per_newton


class Limiter:
    """Clamps each demand to [0, max_force] and its change per cycle to max_rate * dt."""

    def __init__(self, limits: Limits, dt: float) -> None:
        if not dt > 0:
            raise InputError(f"dt: expected a positive cycle time in s, got {dt}")
        self.max_force = limits.max_force_n
        self.max_step = limits.max_rate_n_per_s * dt
        self.last = 0.0

    def reset(self, value: float = 0.0) -> None:
        self.last = value

    def __call__(self, demand: float) -> tuple[float, bool]:
        """The limited demand (N) and whether a limit acted."""
        if not math.isfinite(demand):
            raise InputError(f"demand: expected a finite force in N, got {demand}")
        v = min(self.max_force, max(0.0, demand))
        v = min(self.last + self.max_step, max(self.last - self.max_step, v))
        self.last = v
        return v, abs(v - demand) > 1e-12


def check_profile(profile: Profile, limits: Limits, advance_s: float = 0.0) -> None:
    """Refuse (ValueError naming the point) a profile that exceeds the force or rate limit."""
    over = np.flatnonzero(profile.force > limits.max_force_n)
    if over.size:
        i = int(over[0])
        raise InputError(f"{profile.source}: points[{i}] force: {profile.force[i]:g} N is above "
                         f"the rig's limits.max_force_n of {limits.max_force_n:g} N")
    rates = np.abs(np.diff(profile.force) / np.diff(profile.time))
    fast = np.flatnonzero(rates > limits.max_rate_n_per_s * (1 + 1e-9))
    if fast.size:
        i = int(fast[0]) + 1
        raise InputError(f"{profile.source}: points[{i}]: {rates[i - 1]:g} N/s is faster than the "
                         f"rig's limits.max_rate_n_per_s of {limits.max_rate_n_per_s:g} N/s")
    if advance_s < 0:
        raise InputError(f"advance_s: expected >= 0 s, got {advance_s}")


def feedforward(profile: Profile, t: float, advance_s: float) -> float:
    """The open-loop demand at trial time t: the profile advance_s ahead (0 before the start)."""
    return float(profile.at(t + advance_s)) if t + advance_s >= 0 else 0.0


# The thesis's process models (Appendix D), by their name under the parameters' actuator:
# the single model (Eq. D.1 for every demand) and the rising- and falling-demand models
SINGLE_MODEL = "process_model_all"
RISING_MODEL = "process_model_increasing"
FALLING_MODEL = "process_model_decreasing"


def process_coefficients(Tw: float, zeta: float, Tp3: float) -> tuple[float, float, float]:
    """a3, a2, a1 of Eq. D.1, a3 y''' + a2 y'' + a1 y' + y = K u (Tw, Tp3 in s)."""
    return (Tw * Tw * Tp3, Tw * Tw + 2 * zeta * Tw * Tp3, 2 * zeta * Tw + Tp3)


def _in_seconds(m: Mapping[str, float], time_unit_s: float) -> tuple[float, float, float, float]:
    return (float(m["K"]), float(m["Tw"]) * time_unit_s, float(m["zeta"]),
            float(m["Tp3"]) * time_unit_s)


def thesis_process(params: Parameters, name: str = SINGLE_MODEL,
                   time_unit_s: float = THESIS_TIME_UNIT_S) -> tuple[float, float, float, float]:
    """(K, Tw, zeta, Tp3) of Eq. D.1, Tw and Tp3 in s, from the parameters'
    ``actuator.<name>`` (Tw, Tp3 in ``time_unit_s``, the thesis's 2 ms loop periods)."""
    return _in_seconds(params.get(f"actuator.{name}"), time_unit_s)


@dataclass(frozen=True)
class ProcessModel:
    """Eq. D.1: K (N/N), Tw (s), zeta, Tp3 (s)."""

    K: float
    Tw: float
    zeta: float
    Tp3: float

    def __post_init__(self) -> None:
        if not (self.K > 0 and self.Tw > 0 and self.zeta > 0 and self.Tp3 > 0):
            raise InputError(f"process model: expected K, Tw, zeta, Tp3 > 0, got {self}")

    def discrete(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(A, B) for the state [y, y', y''] and a demand held for dt (zero-order hold)."""
        return _discrete(self, dt)

    def exact_discrete(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``discrete`` computed (matrix exponential), not cached."""
        return process_discrete(self.K, self.Tw, self.zeta, self.Tp3, dt)

    @classmethod
    def from_thesis(cls, m: Mapping[str, float], time_unit_s: float = THESIS_TIME_UNIT_S
                    ) -> ProcessModel:
        """From the thesis's K, Tw, zeta, Tp3 (Tw, Tp3 in ``time_unit_s``)."""
        return cls(*_in_seconds(m, time_unit_s))


@functools.lru_cache(maxsize=64)
def _discrete(model: ProcessModel, dt: float) -> tuple[np.ndarray, np.ndarray]:
    A, B = model.exact_discrete(dt)
    A.setflags(write=False)
    B.setflags(write=False)
    return A, B


@dataclass(frozen=True)
class RiseFall:
    """A rising- and a falling-demand process model (the same one for a linear drive).
    A demand is played with the rising model after it rose, with the falling model after
    it fell, else as before (the state, force and its derivatives, carries over)."""

    name: str
    rise: ProcessModel
    fall: ProcessModel

    def scaled(self, gain: float) -> Self:
        """The same drive with both models' K multiplied by ``gain``."""
        if gain == 1.0:
            return self
        rise = dataclasses.replace(self.rise, K=self.rise.K * gain)
        fall = rise if self.fall == self.rise else dataclasses.replace(self.fall,
                                                                      K=self.fall.K * gain)
        return dataclasses.replace(self, rise=rise, fall=fall)

    def modes(self, d: np.ndarray) -> np.ndarray:
        """True where cycle j's demand is played with the rising model."""
        return self._modes(np.asarray(d, float))

    def _modes(self, d: np.ndarray) -> np.ndarray:
        rising = np.empty(d.size, bool)
        state, last = True, 0.0
        for j, x in enumerate(d):
            if x > last:
                state = True
            elif x < last:
                state = False
            rising[j], last = state, float(x)
        return rising


def thesis_models(params: Parameters | None = None,
                  time_unit_s: float = THESIS_TIME_UNIT_S) -> tuple[RiseFall, RiseFall]:
    """The thesis's single model and its rising/falling pair (Appendix D)."""
    p = params or Parameters.default()
    single = ProcessModel.from_thesis(p.get(f"actuator.{SINGLE_MODEL}"), time_unit_s)
    return (RiseFall("thesis single model", single, single),
            RiseFall("thesis rise/fall models",
                     ProcessModel.from_thesis(p.get(f"actuator.{RISING_MODEL}"), time_unit_s),
                     ProcessModel.from_thesis(p.get(f"actuator.{FALLING_MODEL}"), time_unit_s)))


def zoh(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact discretisation of x' = A x + B u for u held over dt (matrix exponential)."""
    from scipy.linalg import expm

    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = A * dt
    M[:n, n] = B * dt
    E = expm(M)
    return E[:n, :n], E[:n, n]


def process_discrete(K: float, Tw: float, zeta: float, Tp3: float,
                     dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of Eq. D.1 K / ((1 + 2 zeta Tw s + (Tw s)^2)(1 + Tp3 s)) for a demand held
    over dt; state [y, y', y''] (continuous across a switch between models), output y."""
    a3, a2, a1 = process_coefficients(Tw, zeta, Tp3)
    A = np.array([[0, 1, 0], [0, 0, 1], [-1 / a3, -a1 / a3, -a2 / a3]])
    B = np.array([0, 0, K / a3])
    return zoh(A, B, dt)
