"""The fingertip pulp between the finger's last bone and the key (thesis Sections 3.8, 4.3).

The thesis's nonlinear Kelvin model (Fig. 3.12): a spring K = a1 exp(b1 X) in
parallel with a damper C1 = a3 exp(b3 X1) in series with a spring
K2 = a2 exp(b2 X2), X = X1 + X2 the indentation of the pulp:

    X1 = X - X2                                                       (3.9)
    C1 dX1/dt = K2 X2                                                 (3.10)
    F = K X + K2 X2                                                   (3.11)
    dX2/dt = dX/dt - a2 exp(b2 X2) X2 / (a3 exp(b3 (X - X2)))         (3.12)
    F = a1 exp(b1 X) X + a2 exp(b2 X2) X2                             (3.13)

with the shipped parameters (``fingertip_kelvin_model``; N, mm, s as the thesis
gives them; the code converts at the boundary, SI inside).

With the ``fingertip`` effect, a ``kind: motion`` profile gives the downward
displacement d(t) of the fingertip's last bone from where the pulp just touches
the key top at rest; the indentation is X = d - key_dip, and F pushes the key
top straight down where the motor's force would (the point Pk2).

Unloading, where the thesis's model does not hold (Section 3.8: "the
mechanical properties of the fingertip during the unloading phase cannot be
simulated with this model"): Eq. 3.12 integrated while X falls lets the series
spring keep its stretch (the damper holds it), so Eq. 3.13 would give a force
at zero indentation, and once X2 < 0 a pull. The code therefore
(1) never lets the pulp pull the key: the force on the key is max(0, Eq. 3.13);
(2) gives the free pulp its own surface: when Eq. 3.13 would not push, the
key top has left the pulp, whose indentation is then where Eq. 3.13 is zero
for the current damper extension X1 (the state), and X1 creeps back through
the same damper (Eq. 3.10); the key touches again when it reaches that surface
(a recovery of seconds near rest: the thesis's elements run backwards, not a
measured recovery).
Both are this code's assumptions, not the thesis's; the loading branch is
exactly Eq. 3.12-3.13.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from rig.errors import InputError
from rig.model.effects import BUILTIN, Effect, EffectParameter, EffectState, Signature

if TYPE_CHECKING:
    from rig.inputs import profiles
    from rig.model.action import ActionModel, SimResult

MM = 1e-3  # m per mm


def kelvin_force(x_mm: float, x2_mm: float, a1: float, a2: float, b1: float,
                 b2: float) -> float:
    """Eq. 3.13: the pulp's force (N) at indentation X and series-spring extension X2 (mm)."""
    return a1 * math.exp(b1 * x_mm) * x_mm + a2 * math.exp(b2 * x2_mm) * x2_mm


def series_rate(x_mm: float, xdot_mm_s: float, x2_mm: float, a2: float, a3: float,
                b2: float, b3: float) -> float:
    """Eq. 3.12: dX2/dt (mm/s)."""
    return xdot_mm_s - a2 * math.exp(b2 * x2_mm) * x2_mm / (a3 * math.exp(b3 * (x_mm - x2_mm)))


def constant_speed_force(speed_mm_s: float, depth_mm: float, values: dict[str, float]) -> float:
    """The pulp's force (N) after indenting at constant speed from rest to ``depth_mm``:
    Eq. 3.12 integrated (LSODA, tight tolerances) and Eq. 3.13 at the end (Fig. 4.15)."""
    if not speed_mm_s > 0 or not depth_mm > 0:
        raise InputError("speed_mm_s, depth_mm: expected positive numbers")
    v = values
    from scipy.integrate import solve_ivp  # (lazy: rig simulate does not need scipy's ODEs)

    sol = solve_ivp(lambda t, y: [series_rate(speed_mm_s * t, speed_mm_s, y[0], v["a2"],
                                              v["a3"], v["b2"], v["b3"])],
                    (0.0, depth_mm / speed_mm_s), [0.0], method="LSODA", rtol=1e-10,
                    atol=1e-12)
    if not sol.success:
        raise RuntimeError(f"the pulp's integration failed: {sol.message}")
    return kelvin_force(depth_mm, float(sol.y[0, -1]), v["a1"], v["a2"], v["b1"], v["b2"])


class Fingertip(Effect):
    """The key pressed through the fingertip pulp by a displacement of the finger's last bone."""

    name = "fingertip"
    summary = ("The key is driven through the thesis's nonlinear Kelvin model of the fingertip "
               "pulp (Section 3.8, Eq. 3.9-3.13) from a displacement profile of the finger's "
               "last bone (profile kind: motion); the pulp never pulls the key and leaves it when "
               "its force would reach zero (unloading: docs/effects.md). Adds "
               "fingertip_displacement and fingertip_indentation; under a force profile it "
               "does nothing.")
    parameters = (
        EffectParameter("a1", "N/mm", 0.0178, (1e-5, 10.0), False, "parallel spring scale",
                        "fingertip_kelvin_model.a1"),
        EffectParameter("a2", "N/mm", 0.0518, (1e-5, 10.0), False, "series spring scale",
                        "fingertip_kelvin_model.a2"),
        EffectParameter("a3", "N s/mm", 0.0889, (1e-5, 10.0), False, "damper scale",
                        "fingertip_kelvin_model.a3"),
        EffectParameter("b1", "1/mm", 2.6177, (0.0, 20.0), False, "parallel spring exponent",
                        "fingertip_kelvin_model.b1"),
        EffectParameter("b2", "1/mm", 2.6788, (0.0, 20.0), False, "series spring exponent",
                        "fingertip_kelvin_model.b2"),
        EffectParameter("b3", "1/mm", 0.6919, (0.0, 20.0), False, "damper exponent",
                        "fingertip_kelvin_model.b3"),
    )
    signature = Signature(
        ("force", "key_dip"), ("key descent",), "shape", None,
        "with a motion input, the key force follows the pulp's rate-dependent stiffness: "
        "stiffer the faster the finger moves (1.9 N at 0.2 mm/s, 5.3 N at 80 mm/s for "
        "1.6 mm)")
    states = (EffectState("damper_extension", "m", atol=1e-10),)
    diagnosable = False  # an input model: the rig presses with force, nothing to diagnose

    def __init__(self, **values: float) -> None:
        super().__init__(**values)
        self._motion: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._key: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)

    # -- the motion input ----------------------------------------------------------------
    def drive_by_motion(self, model: ActionModel, profile: profiles.Profile | None) -> None:
        """Follow ``profile`` (kind motion; None: no finger on the key) in ``model``."""
        if profile is None:
            self._motion = None
            return
        from rig.model import kernel as k

        self._motion = None  # the rest state is found without the finger (pulp relaxed)
        rest = model.keytop_rest()
        sp = model.packed.arrays.sp
        t = np.asarray(profile.time, float)
        d = np.asarray(profile.force, float)
        slope = np.diff(d) / np.diff(t)
        self._key = (float(sp[k.S_KEYPX]), float(sp[k.S_KEYPY]), float(sp[k.S_PIVY0]), rest)
        self._motion = (t, d, slope)

    def _bone(self, t: float) -> tuple[float, float]:
        assert self._motion is not None
        tt, d, slope = self._motion
        i = int(np.searchsorted(tt, t, side="right")) - 1
        if i < 0 or i >= slope.size:
            return float(np.interp(t, tt, d)), 0.0
        return float(d[i] + slope[i] * (t - tt[i])), float(slope[i])

    def _indentation(self, t: float, q: np.ndarray, qd: np.ndarray) -> tuple[float, float,
                                                                              float]:
        """X (m), dX/dt (m/s) and d(key-top height)/d(theta_k) (m/rad)."""
        from rig.model import kernel as k

        px, py, y0, rest = self._key
        c, s = math.cos(q[k.QK]), math.sin(q[k.QK])
        top = y0 + q[k.QYK] + s * px + c * py
        lever = c * px - s * py
        top_rate = qd[k.QYK] + lever * qd[k.QK]
        d, dd = self._bone(t)
        return d - (rest - top), dd + top_rate, lever

    def _pulp(self, x_geom_m: float, x1_m: float) -> tuple[float, float, float]:
        """Indentation X (mm), series extension X2 (mm) and force (N) of the pulp whose
        damper is extended by X1 when the key top is at geometric indentation X_geom."""
        v = self.values
        x1 = x1_m / MM
        x = x_geom_m / MM
        f = kelvin_force(x, x - x1, v["a1"], v["a2"], v["b1"], v["b2"])
        if f > 0.0:
            return x, x - x1, f
        # off the key: the free pulp's surface, where Eq. 3.13 gives no force
        if x1 == 0.0:
            return 0.0, 0.0, 0.0
        from scipy.optimize import brentq  # (lazy: only a fingertip blow needs it)

        lo, hi = min(0.0, x1), max(0.0, x1)
        xf = brentq(lambda y: kelvin_force(y, y - x1, v["a1"], v["a2"], v["b1"], v["b2"]),
                    lo, hi, xtol=1e-12)
        return xf, xf - x1, 0.0

    # -- hooks ---------------------------------------------------------------------------
    def generalized_force(self, t: float, q: np.ndarray, qd: np.ndarray,
                          *z: np.ndarray) -> np.ndarray | None:
        if self._motion is None:
            return None
        from rig.model import kernel as k

        x, _, lever = self._indentation(t, q, qd)
        f = self._pulp(x, float(z[0][0]))[2]
        out = np.zeros(k.NQ_MECH)
        out[k.QK] = -f * lever   # straight down at the key top
        out[k.QYK] = -f
        return out

    def state_derivative(self, t: float, q: np.ndarray, qd: np.ndarray,
                         z: np.ndarray) -> np.ndarray:
        """dX1/dt = K2 X2 / C1 (Eq. 3.10; Eq. 3.12 is its difference from dX/dt)."""
        if self._motion is None:
            return np.zeros(1)
        x, _, _ = self._indentation(t, q, qd)
        v = self.values
        x1 = float(z[0]) / MM
        xp, x2, _ = self._pulp(x, float(z[0]))
        rate = v["a2"] * math.exp(v["b2"] * x2) * x2 / (v["a3"] * math.exp(v["b3"] * x1))
        return np.array([rate * MM])

    def add_channels(self, result: SimResult) -> None:
        if self._motion is None:
            return
        q_all = result_states(result)
        if q_all is None:
            return
        from rig.model import kernel as k

        n = result.time.size
        disp, ind, force = np.zeros(n), np.zeros(n), np.zeros(n)
        x1 = result.channels["fingertip_damper_extension"]
        for i in range(n):
            q, qd = q_all[i, : k.NQ], q_all[i, k.NQ : 2 * k.NQ]
            x, _, _ = self._indentation(float(result.time[i]), q, qd)
            xp, _, f = self._pulp(x, float(x1[i]))
            disp[i] = self._bone(float(result.time[i]))[0]
            ind[i] = xp * MM
            force[i] = f
        result.channels["force"] = force
        result.channels["fingertip_displacement"] = disp
        result.channels["fingertip_indentation"] = ind
        result.units.update(fingertip_displacement="m", fingertip_indentation="m")

    def describe(self) -> dict[str, Any]:
        out = super().describe()
        out["input"] = "motion" if self._motion is not None else "none"
        return out


BUILTIN[Fingertip.name] = Fingertip


def result_states(result: SimResult) -> np.ndarray | None:
    """The state rows (angles and rates) of a simulated result, rebuilt from its channels."""
    from rig.model import kernel as k
    from rig.model.vocabulary import ANGLE_CHANNELS

    ch = result.channels
    n = result.time.size
    y = np.zeros((n, 2 * k.NQ))
    for name, qi in ANGLE_CHANNELS.items():
        if name not in ch:
            return None
        y[:, qi] = ch[name]
        y[:, k.NQ + qi] = ch[name.replace("_angle", "_angular_velocity")]
    if "key_lift" in ch:
        y[:, k.QYK] = ch["key_lift"]
    return y
