"""One trial of the loop against the simulated drive chain, without the action or processes.

The drive is a force source (the simulated key feels ``max(drive output, 0)``
whatever the action does), so the loop's tracking can be studied offline from
``rig.sim_backend.drive_model.DriveResponse`` and the load cell's noise alone, in
milliseconds instead of a real-time run: what tests and ``benchmarks/tracking.py``
use. Timing as in ``rig run``: at tick j (t_j = j / control_hz) the loop reads the
load cell's latest sample, then writes demand u_j, held until the next tick.
``jitter_s``: each write comes 0..jitter_s late (uniform, in 2 kHz samples);
``gain``: the drive's gain scaled by this (a drifting drive).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.inputs.config import Limits
from rig.motor_torque import Limiter
from rig.sim_backend.drive_model import DriveResponse


@dataclass
class TrialResult:
    measured: np.ndarray   # N, the load cell read at each tick (what the loop sees)
    key_force: np.ndarray  # N, the true force on the key at each tick
    demand: np.ndarray     # N, the limited demand written at each tick
    limited: int           # ticks where motor_torque.Limiter acted
    lateness: np.ndarray   # s, how late each write came (0..jitter_s), as the loop records


def play(u: np.ndarray, *, variant: str = "single", control_hz: float = 500.0,
         sample_hz: float = 2000.0, noise_n: float = 0.22, jitter_s: float = 0.0,
         gain: float = 1.0, limits: Limits | None = None, controller: object | None = None,
         reference: np.ndarray | None = None, rng: np.random.Generator | None = None
         ) -> TrialResult:
    """Play feedforward table ``u`` (N per tick) once; ``controller`` as in rig run's loop."""
    rng = rng or np.random.default_rng(0)
    spc = int(round(sample_hz / control_hz))
    drive = DriveResponse(1.0 / sample_hz, variant)
    lim = Limiter(limits or Limits(), 1.0 / control_hz)
    n = len(u)
    tail = spc * 4
    total = n * spc + tail
    delay = (rng.integers(0, int(round(jitter_s * sample_hz)) + 1, size=n) if jitter_s > 0
             else np.zeros(n, int))
    force = np.zeros(total + 1)   # force[s] = key force at sample s
    measured = np.empty(n)
    key = np.empty(n)
    demand = np.empty(n)
    limited = 0
    if controller is not None:
        controller.reset()  # type: ignore[attr-defined]
    s = 0
    last = 0.0
    for j in range(n):
        start = j * spc + int(delay[j])
        while s < start:   # the previous demand still holds
            force[s + 1] = max(gain * drive.step(last, 1)[0], 0.0)
            s += 1
        key[j] = force[s]
        measured[j] = force[s] + noise_n * rng.standard_normal()
        ff = float(u[j])
        if controller is not None:
            if reference is not None and hasattr(controller, "target_n"):
                controller.target_n = float(reference[j])   # as rig run's loop does
            ff = controller(j / control_hz, ff, measured[j])  # type: ignore[operator]
        last, hit = lim(float(ff))
        limited += int(hit)
        demand[j] = last
    return TrialResult(measured, key, demand, limited, delay / sample_hz)
