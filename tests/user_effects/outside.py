"""A family of user effects that no library effect models (issue 39).

Each is a plain ``rig.model.effects.Effect`` subclass with Python forces (docs/effects.md,
"Hooks"), so a model with one integrates with scipy-LSODA. ``benchmarks/diagnose_wide.py``
hides one of them in some seeds to see whether ``rig diagnose`` credits physics outside
the library to a library effect; they are never candidates there. Coordinates:
``q = [theta_k, y_k, theta_w, theta_j, theta_r, theta_h, u1, v1, v2]`` (docs/model.md).

- ``KeyFrontFriction``: Coulomb friction at the key front (the front guide pin rubbing its
  bushing), a force ``F`` against the key's motion at the front pin (0.2278 m from the
  balance point), smoothed over 5 mm/s of pin speed.
- ``KeyLeadMass``: an added body, a lead weight of mass ``m`` set in the key at 0.12 m
  from the balance point on a compliant mount (a second body on its own coordinate: its
  angle about the key's pivot, coupled to the key by a torsional spring-damper of natural
  frequency ``f`` and damping ratio 0.2).
- ``CompliantWhippenFlange``: a compliant pivot: the whippen flange's cloth bushing holds
  the whippen toward its rest angle with a torsional stiffness ``k`` and a damping of 2 %
  of critical for the whippen's inertia (a rigid revolute joint in the library's model).
- ``HammerAirDrag``: velocity-dependent damping, a torque ``-c w |w|`` on the hammer (air
  drag on the head; the library's joint friction is linear in the rate).

``FAMILY`` maps each name to its class and the range its value is drawn from.
"""

from __future__ import annotations

import math

import numpy as np

from rig.model.effects import Build, Effect, EffectParameter, EffectState, Signature

KEY_FRONT_ARM_M = 0.2278     # balance point to the key front pin (points.key.Pk2.at[0])
LEAD_ARM_M = 0.12            # balance point to the lead weight
PIN_SPEED_M_S = 0.005        # Coulomb friction smoothed over this pin speed


class KeyFrontFriction(Effect):
    name = "key_front_friction"
    summary = "Coulomb friction at the key's front guide pin"
    parameters = (EffectParameter("force", "N", 0.5, (0.0, 5.0), True,
                                  "friction force at the front pin"),)
    signature = Signature(("key_angle",), ("descent", "return"), "shape",
                          text="a slower key under a constant drag")

    def generalized_force(self, t: float, q: np.ndarray, qd: np.ndarray,
                          *z: np.ndarray) -> np.ndarray:
        f = np.zeros(9)
        v = KEY_FRONT_ARM_M * qd[0]
        f[0] = -self.values["force"] * KEY_FRONT_ARM_M * math.tanh(v / PIN_SPEED_M_S)
        return f


class KeyLeadMass(Effect):
    name = "key_lead_mass"
    summary = "a lead weight on a compliant mount in the key (an added body)"
    parameters = (EffectParameter("mass", "kg", 0.01, (0.0, 0.05), True, "lead mass"),
                  EffectParameter("frequency", "Hz", 150.0, (10.0, 2000.0), True,
                                  "the mount's natural frequency"))
    states = (EffectState("angle", "rad", atol=1e-10), EffectState("rate", "rad/s",
                                                                   atol=1e-8))
    signature = Signature(("key_angle", "force"), ("descent",), "oscillation",
                          text="a mount resonance and a heavier key")

    def _coupling(self) -> tuple[float, float, float]:
        inertia = self.values["mass"] * LEAD_ARM_M ** 2
        w = 2 * math.pi * self.values["frequency"]
        return inertia, inertia * w * w, 2 * 0.2 * inertia * w

    def _torque(self, q: np.ndarray, qd: np.ndarray, z: np.ndarray) -> float:
        _, k, c = self._coupling()
        return k * (z[0] - q[0]) + c * (z[1] - qd[0])  # on the key, from the lead

    def generalized_force(self, t: float, q: np.ndarray, qd: np.ndarray,
                          *z: np.ndarray) -> np.ndarray:
        f = np.zeros(9)
        f[0] = self._torque(q, qd, z[0])  # its weight reaches the key through the mount
        return f

    def state_derivative(self, t: float, q: np.ndarray, qd: np.ndarray,
                         z: np.ndarray) -> np.ndarray:
        inertia, _, _ = self._coupling()
        if inertia <= 0:
            return np.array([z[1], 0.0])
        # the lead's own weight, on the key's front side: it pulls the key front down
        weight = -self.values["mass"] * 9.81 * LEAD_ARM_M * math.cos(z[0])
        return np.array([z[1], (-self._torque(q, qd, z) + weight) / inertia])


class CompliantWhippenFlange(Effect):
    name = "compliant_whippen_flange"
    summary = "a compliant pivot: the whippen flange's bushing resists rotation"
    parameters = (EffectParameter("stiffness", "N m/rad", 0.05, (0.0, 5.0), True,
                                  "torsional stiffness of the bushing"),)
    signature = Signature(("key_angle", "hammer_angle"), ("descent",), "shape",
                          text="a stiffer action while the whippen turns")

    def apply(self, build: Build) -> None:
        self._rest = float(build.params.get("initial_state.theta_w"))
        inertia = float(build.params.get("bodies.whippen.inertia"))
        self._damping = 2 * 0.02 * math.sqrt(max(self.values["stiffness"], 0.0) * inertia)

    def generalized_force(self, t: float, q: np.ndarray, qd: np.ndarray,
                          *z: np.ndarray) -> np.ndarray:
        f = np.zeros(9)
        f[2] = -self.values["stiffness"] * (q[2] - self._rest) - self._damping * qd[2]
        return f


class HammerAirDrag(Effect):
    name = "hammer_air_drag"
    summary = "velocity-dependent (quadratic) damping of the hammer"
    parameters = (EffectParameter("coefficient", "N m s^2/rad^2", 2e-6, (0.0, 1e-3), True,
                                  "torque per squared hammer rate"),)
    signature = Signature(("hammer_angle",), ("free flight",), "shape",
                          text="a hammer that slows in flight, more at higher speed")

    def generalized_force(self, t: float, q: np.ndarray, qd: np.ndarray,
                          *z: np.ndarray) -> np.ndarray:
        f = np.zeros(9)
        f[5] = -self.values["coefficient"] * qd[5] * abs(qd[5])
        return f


# name -> (class, parameter, lower, upper): the value is drawn log-uniform in [lower, upper]
FAMILY: dict[str, tuple[type[Effect], str, float, float]] = {
    KeyFrontFriction.name: (KeyFrontFriction, "force", 0.2, 1.5),
    KeyLeadMass.name: (KeyLeadMass, "mass", 0.005, 0.03),
    CompliantWhippenFlange.name: (CompliantWhippenFlange, "stiffness", 0.02, 0.3),
    HammerAirDrag.name: (HammerAirDrag, "coefficient", 2e-6, 3e-5),
}
