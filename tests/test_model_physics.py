"""Physics of the action model checked against independent answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rig.inputs.params import Parameters
from rig.model import kernel as k
from rig.model.action import ActionModel
from rig.model.integrators import DormandPrince, RungeKutta4, ScipyIntegrator

G = 9.81
JOINTS = ("key", "whippen", "jack", "repetition", "hammer")


def conservative_params() -> Parameters:
    """No contacts, no pin friction, no springs, no shank damping: gravity and inertia remain."""
    p = Parameters.default()
    p.set("hammer_shank_damping.ratio", 0.0)
    for c in p.tree["contacts"]:
        for coef in ("a", "b", "c"):
            p.set(f"contacts.{c['id']}.{coef}", 0.0)
    for j in JOINTS:
        p.set(f"joint_friction.{j}.E", 0.0)
    p.set("springs.jack_torque", 0.0)
    p.set("springs.repetition.k", 0.0)
    return p


INTEGRATORS = [
    pytest.param(lambda: DormandPrince(rtol=1e-10, max_step=1e-3), id="dopri54"),
    pytest.param(lambda: RungeKutta4(step=1e-5), id="rk4"),
    pytest.param(lambda: ScipyIntegrator("LSODA", rtol=1e-10, max_step=1e-3), id="scipy-LSODA",
                 marks=pytest.mark.slow),  # plain-Python right-hand side: seconds
]


def run(model: ActionModel, y0: np.ndarray, t1: float, n_out: int = 50) -> np.ndarray:
    out_t = np.linspace(0.0, t1, n_out)
    adv = model.integrator.advance(model.packed.arrays, model.workspace(), y0, 0.0, t1, 1e-5,
                                   np.zeros(1), np.zeros(1), out_t, model.atol * 1e-3)
    assert adv.success, adv.message
    return adv.out


@pytest.mark.parametrize("make", INTEGRATORS)
def test_free_swinging_bodies_keep_their_energy(make):
    model = ActionModel(conservative_params(), effects=["flexible_shank"], integrator=make())
    y0 = model._table_state()
    y0[k.NQ + k.QK] = 0.5  # rad/s
    y0[k.NQ + k.QW] = -3.0
    y0[k.NQ + k.QH] = 8.0
    out = run(model, y0, 0.1)
    e = np.array([sum(model.energy(row)) for row in out])
    kinetic = np.array([model.energy(row)[0] for row in out])
    assert kinetic.max() - kinetic.min() > 1e-4, "the bodies must actually exchange energy"
    assert np.abs(e - e[0]).max() < 1e-6 * kinetic.max()


@pytest.mark.parametrize("make", INTEGRATORS)
def test_key_on_its_slider_falls_freely(make):
    """With lift-off on and no contacts, the key pivot falls as y = y0 - g t^2 / 2."""
    model = ActionModel(conservative_params(), effects=["key_liftoff"], integrator=make())
    y0 = model._table_state()
    out = run(model, y0, 0.05)
    t = np.linspace(0.0, 0.05, 50)
    np.testing.assert_allclose(out[:, k.QYK], -0.5 * G * t**2, atol=1e-9)
    np.testing.assert_allclose(out[:, k.QK], y0[k.QK], atol=1e-9)


def test_normal_force_law():
    a, b, c, d = 1.26e10, 3.26e7, 7.92e3, 1.877
    for x, xd in [(1e-4, 0.0), (3e-4, 0.2), (2e-4, -0.3)]:
        expected = (a * x**3 + b * x**2 + c * x) * (1 + d * xd)
        assert k.normal_force(x, xd, a, b, c, d) == pytest.approx(expected, rel=1e-12)
    assert k.normal_force(-1e-4, 1.0, a, b, c, d) == 0.0  # apart: no force
    assert k.normal_force(1e-4, -1.0, a, b, c, d) == 0.0  # separating fast: never pulls


def test_friction_law_is_odd_and_tends_to_the_kinetic_coefficient():
    mu = [k.friction_coefficient(s, 0.434, 1.78, 1.0, 0.05) for s in (-10.0, -0.01, 0.01, 10.0)]
    assert mu[0] == pytest.approx(-mu[3]) and mu[1] == pytest.approx(-mu[2])
    assert mu[3] == pytest.approx(0.434, rel=1e-3)
    peak = max(k.friction_coefficient(s, 0.434, 1.78, 1.0, 0.05) for s in np.linspace(0, .2, 400))
    assert peak > 0.434  # the static peak of Eq. 3.6 with B1 > 0


def test_string_contact_force_from_independent_geometry():
    """Turn the hammer until its felt sinks 0.5 mm into the string; check pen and force."""
    p = Parameters.default()
    model = ActionModel(p)
    pts = p.tree["points"]
    pg3 = np.array(pts["ground"]["Pg3"]["at"])
    felt = np.array(pts["hammer_head"]["Phh3"]["at"]) + np.array([-0.1275, 0.0])
    radius = pts["hammer_head"]["Phh3"]["radius"]
    string_y = pts["ground"]["Pg9"]["at"][1]

    def top(th: float) -> float:
        c, s = math.cos(th), math.sin(th)
        return pg3[1] + s * felt[0] + c * felt[1] + radius

    th = -0.07
    for _ in range(50):  # Newton on the felt top reaching 0.5 mm above the string line
        th -= (top(th) - string_y - 5e-4) / ((top(th + 1e-7) - top(th)) / 1e-7)
    y = model._table_state()
    y[k.QH] = th
    res = model.result_from_samples(np.zeros(1), y[None, :], np.zeros(1))
    pen = res.contact("contact_penetration", 12)[0]
    c12 = next(c for c in p.tree["contacts"] if c["id"] == 12)
    assert pen == pytest.approx(5e-4, abs=1e-9)
    expected = c12["a"] * pen**3 + c12["b"] * pen**2 + c12["c"] * pen
    assert res.contact("contact_force", 12)[0] == pytest.approx(expected, rel=1e-9)
    assert res.contact("contact_force", 8)[0] == 0.0  # let-off button far away: no force


def test_rest_state_is_a_torque_balance(rigid_model):
    """At rest the hammer's gravity moment about its pivot equals the knuckle contacts' moment."""
    y = rigid_model.rest_state()
    res = rigid_model.result_from_samples(np.zeros(1), y[None, :], np.zeros(1))
    p = rigid_model.params.tree
    pg3 = np.array(p["points"]["ground"]["Pg3"]["at"])
    th = y[k.QH]
    rot = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
    moment = 0.0
    b = p["bodies"]
    for name, offset in (("hammer_base", (0.0, 0.0)), ("hammer_shank", (-0.1275, 0.0)),
                         ("hammer_head", (-0.1275, 0.0))):
        com = rot @ (np.array(b[name]["com"]) + offset)
        moment += com[0] * (-b[name]["mass"] * G)
    # contacts 7 and 10 push the knuckle (body 2 of the pair): recompute their lines of action
    for cid in (7, 10, 13):
        fn = res.contact("contact_force", cid)[0]
        if fn == 0.0:
            continue
        px = res.contact("contact_point_x", cid)[0]
        moment += _contact_moment(rigid_model, y, cid, fn, px, pg3)
    assert abs(moment) < 1e-7
    assert np.abs(rigid_model.accelerations(y)).max() < 1e-6


def _contact_moment(model, y, cid, fn, px, pivot):
    """Moment about the pivot of contact cid's normal force, from its geometry in the kernel."""
    ws = model.workspace()
    q, qd = y[: k.NQ], y[k.NQ :]
    org, phi, w, vO, JO, Jp, aO, al, cs = ws[:9]
    arrays = model.packed.arrays
    k.kinematics(q, qd, arrays.sp, arrays.sec_xi, org, phi, w, vO, JO, Jp, aO, al, cs)
    i = model.packed.contact_ids.index(cid)
    f1, f2, pen, nx, ny, cx, cy = k.contact_geometry(arrays.cf, i, org, phi, cs)
    assert cx == pytest.approx(px)
    sign = 1.0 if f2 in (k.F_HAMMER, k.F_HEAD) else -1.0
    fx, fy = sign * fn * nx, sign * fn * ny
    return (cx - pivot[0]) * fy - (cy - pivot[1]) * fx
