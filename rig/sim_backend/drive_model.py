"""The drive and motor: demand force -> force on the key (thesis Appendix D).

G(s) = K / ((1 + 2 zeta Tw s + (Tw s)^2)(1 + Tp3 s)), identified from load-cell
data. Tw and Tp3 are given without units; read as 2 ms sample periods (the
500 Hz loop) the model lags a 30 ms ramp by ~7 ms and settles in ~28 ms, which
matches the thesis's ~8 ms and ~25 ms. With ``variant="rise_fall"`` the
increasing-demand model applies while the demand rises and the decreasing
one while it falls (the state carries over, so the output is continuous).

Discretised exactly (zero-order hold) at the acquisition step: the analog
output holds each demand until the next write.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.linalg import expm

from rig.params import Parameters


def _discrete(K: float, Tw: float, zeta: float, Tp3: float, dt: float) -> tuple[np.ndarray,
                                                                                 np.ndarray]:
    # a3 x''' + a2 x'' + a1 x' + x = K u, output x (continuous across variant switches)
    a3 = Tw * Tw * Tp3
    a2 = Tw * Tw + 2 * zeta * Tw * Tp3
    a1 = 2 * zeta * Tw + Tp3
    A = np.array([[0, 1, 0], [0, 0, 1], [-1 / a3, -a1 / a3, -a2 / a3]])
    B = np.array([0, 0, K / a3])
    M = np.zeros((4, 4))
    M[:3, :3] = A * dt
    M[:3, 3] = B * dt
    E = expm(M)
    return E[:3, :3], E[:3, 3]


class DriveModel:
    """Third-order process model with rise/fall variants, stepped at a fixed dt."""

    def __init__(self, dt: float, variant: str = "rise_fall", time_unit_s: float = 0.002,
                 params: Parameters | None = None) -> None:
        if variant not in ("rise_fall", "all"):
            raise ValueError(f"variant: expected 'rise_fall' or 'all', got {variant!r}")
        if not dt > 0:
            raise ValueError(f"dt: expected a positive step in s, got {dt}")
        p = params or Parameters.default()

        def disc(name: str) -> tuple[np.ndarray, np.ndarray]:
            m: Mapping[str, float] = p.get(f"actuator.{name}")
            return _discrete(m["K"], m["Tw"] * time_unit_s, m["zeta"], m["Tp3"] * time_unit_s, dt)

        if variant == "all":
            both = disc("process_model_all")
            self._rise = self._fall = both
        else:
            self._rise = disc("process_model_increasing")
            self._fall = disc("process_model_decreasing")
        self.dt = dt
        self.x = np.zeros(3)
        self._last_u = 0.0
        self._rising = True

    def reset(self) -> None:
        self.x[:] = 0.0
        self._last_u = 0.0
        self._rising = True

    @property
    def output(self) -> float:
        return float(self.x[0])

    def step(self, u: float, n: int) -> np.ndarray:
        """Hold demand u (N) for n steps; the force (N) at the end of each step."""
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
