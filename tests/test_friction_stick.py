"""Dahl's friction law (issue 40): the model option that makes the action stick as a real one
does (every pin and contact with friction a bristle law with one coefficient), the simulated
rig's ``sim.friction: stick``. Off by default: the bristle coordinates are frozen."""

from __future__ import annotations

import numpy as np
import pytest

from rig.calibration import touch as ct
from rig.errors import InputError
from rig.inputs import config, profiles
from rig.inputs.params import Parameters
from rig.model import kernel as k
from rig.model import touch
from rig.model.action import ActionModel
from rig.sim_backend.simrig import sim_parameters

PINS = ("key", "whippen", "jack", "repetition", "hammer")


def _rig(friction: str) -> config.RigConfig:
    return config.from_mapping({"backend": "sim", "sim": {"effects": [], "friction": friction},
                                "channels": {"strain_gauge": {"enabled": False}}})


def _hold(model: ActionModel, grams: float) -> np.ndarray:
    """The key dip (m) 2, 3 and 4 s after a weight was put on the key front (in 0.5 s)."""
    g = ct.newtons(grams)
    prof = profiles.from_points([[0.0, 0.0], [0.5, g], [4.5, g]], name="hold")
    res = model.simulate(prof)
    assert res.success
    return np.array([res.at("key_dip", t) for t in (2.5, 3.5, 4.5)])


def _holds(dip: np.ndarray) -> bool:
    """Still: under 0.2 um in the last second, and settling (less than the second before)."""
    return abs(dip[2] - dip[1]) < 0.2e-6 and abs(dip[2] - dip[1]) <= abs(dip[1] - dip[0])


def test_off_by_default_the_bristles_are_frozen() -> None:
    model = ActionModel()
    assert [c for c in model.coordinates if c.startswith("z_")] == ["z_b"]  # the back check's
    stick = ActionModel(sim_parameters(_rig("stick")))
    moving = [c for c in stick.coordinates if c.startswith("z_")]
    assert moving == ["z_b", "z_key", "z_whippen", "z_jack", "z_repetition", "z_hammer",
                      "z_c2", "z_c3", "z_c4"]
    assert ActionModel(sim_parameters(_rig("regularised"))).coordinates == model.coordinates
    # rig touch takes every law as Coulomb's: the same figures with the option on (within
    # 0.01 g: the rest pose it starts from settles, sticking, micrometres elsewhere)
    assert touch.measure(stick).figures["down_weight"] == pytest.approx(
        touch.measure(model).figures["down_weight"], abs=0.01)


def test_a_weight_between_up_and_down_weight_holds_the_key_still() -> None:
    """40 g on the key front (between the shipped model's UW and DW): the regularised laws
    let the key creep down (they carry no force at zero speed), Dahl's law holds it."""
    creep = _hold(ActionModel(), 40.0)
    assert creep[2] > 5e-3  # run down to its stop
    held = _hold(ActionModel(sim_parameters(_rig("stick"))), 40.0)
    assert _holds(held)
    assert held[2] < 0.1e-3  # on its felts


def test_the_key_pin_holds_below_its_coulomb_torque_and_slides_above() -> None:
    """With friction at the key's balance pin only, on Dahl's law: a weight 0.5 g under rig
    touch's static down force at the stroke's first point (the frictionless force plus the
    pin's torque over the front's arm) holds the key; 0.5 g over it takes the key down."""
    p = Parameters.default()
    for c in (1, 7, 10):
        p.set(f"contacts.{c}.A", 0.0)
    p.set("friction_law.contact.4", "smoothed")
    for pin in PINS[1:]:
        p.set(f"joint_friction.{pin}.E", 0.0)
    p.set("friction_law.joint.key", "dahl")
    model = ActionModel(p)
    assert [c for c in model.coordinates if c.startswith("z_")] == ["z_key"]
    static = touch.grams(float(touch.measure(model).down_n[0]))
    under = _hold(model, static - 0.5)
    assert _holds(under) and under[2] < 0.1e-3
    over = _hold(model, static + 0.5)
    assert over[2] > 5e-3


def test_bad_friction_laws_are_refused_in_one_line() -> None:
    with pytest.raises(InputError, match=r"friction_law\.joint\.key: expected one of"):
        ActionModel(Parameters.default().set("friction_law.joint.key", "sticky"))
    with pytest.raises(InputError, match=r"friction_law\.dahl\.presliding_angle: expected a "
                                         r"positive value"):
        ActionModel(Parameters.default().set("friction_law.joint.key", "dahl")
                    .set("friction_law.dahl.presliding_angle", 0.0))
    with pytest.raises(InputError, match=r"sim\.friction"):
        _rig("sticky")
    assert k.NQ == 18 and len(k.QZ_CONTACT) == 4


def test_the_simulated_rig_builds_its_action_with_the_setting() -> None:
    from rig.sim_backend.simrig import SimRig

    assert "z_key" in SimRig(_rig("stick")).model.coordinates
    assert "z_key" not in SimRig(_rig("regularised")).model.coordinates
