"""rig touch (issue 40): touch weights at the key front against independent answers."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rig.errors import InputError
from rig.inputs.params import Parameters
from rig.model import kernel as k
from rig.model import touch
from rig.model.action import ActionModel

ROOT = Path(__file__).resolve().parents[1]
FRICTION_OFF = {**{f"contacts.{i}.A": 0.0 for i in (1, 4, 7, 10)},
                **{f"joint_friction.{j}.E": 0.0
                   for j in ("key", "whippen", "jack", "repetition", "hammer")}}


def model_with(overrides: dict[str, object]) -> ActionModel:
    params = Parameters.default()
    params.update(overrides, source="test")
    return ActionModel(params)


@pytest.fixture(scope="module")
def base() -> touch.Touch:
    return touch.measure(ActionModel())


@pytest.fixture(scope="module")
def frictionless() -> tuple[ActionModel, touch.Touch]:
    m = model_with(FRICTION_OFF)
    return m, touch.measure(m)


def _elastic_energy(model: ActionModel, y: np.ndarray) -> float:
    """Every contact's stored energy, the integral of its elastic law a x^3 + b x^2 + c x."""
    co = np.zeros((k.N_CONTACT_OUT, 1, model.packed.n_contacts))
    k.sample_outputs(model.packed.arrays, model.workspace(), y[None, :], np.zeros(1),
                     model._head_pt, model._gauge, np.zeros((k.N_X, 1)), co)
    cl = model.packed.arrays.cl
    total = 0.0
    for i, x in enumerate(co[k.O_PEN, 0]):
        if x > 0:
            total += cl[i, k.L_A] * x**4 / 4 + cl[i, k.L_B] * x**3 / 3 + cl[i, k.L_C] * x**2 / 2
    return total


def _potential(model: ActionModel, y: np.ndarray) -> float:
    """Gravity (the kernel's energy function), the springs (from the parameter file: the
    jack's constant torque, the repetition spring) and the felts (J)."""
    tree = model.params.tree
    pot = model.energy(np.r_[y[: k.NQ], np.zeros(k.NQ)])[1]
    sign = tree["springs_sign"]["jack"]
    pot -= sign * tree["springs"]["jack_torque"] * y[k.QJ]
    rep = tree["springs"]["repetition"]
    theta0 = rep["theta0"] + tree["repetition_spring"]["regulation"]
    pot += 0.5 * rep["k"] * (y[k.QR] - theta0) ** 2
    return pot + _elastic_energy(model, y)


def _path(model: ActionModel, result: touch.Touch) -> list[np.ndarray]:
    st = touch._Statics(model)
    y, f, out = st.rest, 0.0, []
    for d in result.dip_m:
        y, f, _ = st.solve(float(d), y, f, st.frictionless)
        out.append(y.copy())
    return out


def test_frictionless_action_balances_by_virtual_work(frictionless):
    """Without friction DW == UW == balance weight, and the key force at each dip is the
    potential energy's slope along the press (F d(dip) = dV), computed independently."""
    model, res = frictionless
    assert res.figures["friction"] == pytest.approx(0.0, abs=1e-6)
    assert res.figures["down_weight"] == pytest.approx(res.figures["up_weight"], abs=1e-6)
    np.testing.assert_allclose(res.down_n, res.up_n, atol=1e-9)
    np.testing.assert_allclose(res.down_n, res.frictionless_n, atol=1e-9)
    path = _path(model, res)
    pot = np.array([_potential(model, y) for y in path])
    slope = (pot[2:] - pot[:-2]) / (res.dip_m[2:] - res.dip_m[:-2])
    np.testing.assert_allclose(res.frictionless_n[1:-1], slope, rtol=3e-3)
    mid = int(np.argmin(np.abs(res.dip_m - res.method["mid_stroke_dip_m"])))
    assert res.figures["balance_weight"] == pytest.approx(touch.grams(res.frictionless_n[mid]))
    # over the whole stroke: the largest and the smallest frictionless force
    assert res.figures["down_weight_stroke"] == pytest.approx(
        touch.grams(res.frictionless_n.max()))
    assert res.figures["up_weight_stroke"] == pytest.approx(touch.grams(res.frictionless_n.min()))


def test_key_pin_friction_alone_adds_its_torque_over_the_front_arm_exactly():
    """An exact answer by hand: with friction at the key's balance pin only (E) the key
    front, held at each dip, turns the key to the same angle as without friction, so the
    rest of the action takes the same state and the key force changes by the pin's torque
    over the key front's horizontal arm at that angle, r = cos(th) px - sin(th) py: up by
    E / r on the way down, down by E / r on the way up, at every dip (the first step from
    rest included, where the back felt and the hammer rail let go)."""
    e_key = 0.0122
    model = model_with({**FRICTION_OFF, "joint_friction.key.E": e_key})
    res = touch.measure(model)
    px, py = model.params.tree["key_input"]["point"]
    th = np.array([y[k.QK] for y in _path(model, res)])
    arm = np.cos(th) * px - np.sin(th) * py
    np.testing.assert_allclose(res.down_n - res.frictionless_n, e_key / arm, rtol=1e-6)
    np.testing.assert_allclose(res.frictionless_n - res.up_n, e_key / arm, rtol=1e-6)
    assert res.figures["friction"] == pytest.approx(touch.grams(e_key / arm[
        int(np.argmin(np.abs(res.dip_m - res.method["mid_stroke_dip_m"])))]), rel=1e-6)


def test_key_front_lead_moves_balance_by_its_moment(base):
    """10 g of lead on the line from the balance pin to the key front, halfway out: every
    weight (friction included) drops by 10 g x 1/2 (its moment over the front's arm)."""
    p = Parameters.default()
    key = p.tree["bodies"]["key"]
    m, (cx, cy) = key["mass"], key["com"]
    lead, s = 0.010, 0.5
    px, py = p.tree["key_input"]["point"]
    at = (s * px, s * py)
    p.set("bodies.key.mass", m + lead)
    p.set("bodies.key.com", [(m * cx + lead * at[0]) / (m + lead),
                             (m * cy + lead * at[1]) / (m + lead)])
    leaded = touch.measure(ActionModel(p))
    g = p.tree["gravity"]
    expected = lead * s * g / touch.G0 * 1e3  # grams-force
    for name in ("down_weight", "up_weight", "balance_weight", "down_weight_stroke",
                 "up_weight_stroke"):
        assert base.figures[name] - leaded.figures[name] == pytest.approx(expected, abs=0.03)
    assert leaded.figures["friction"] == pytest.approx(base.figures["friction"], abs=0.03)
    assert leaded.figures["front_weight"] - base.figures["front_weight"] == pytest.approx(
        expected, abs=1e-3)
    assert leaded.figures["inertia_mass"] > base.figures["inertia_mass"]


def test_key_inertia_is_felt_through_the_front_arm_squared(base):
    """More moment of inertia of the key (statics unchanged): the mass felt at the key front
    grows by it over the key front's arm squared (the arm at rest; 0.5 % shorter than
    mid-stroke's)."""
    added = 1e-3  # kg m^2
    heavier = touch.measure(model_with({"bodies.key.inertia": 2.75e-3 + added}))
    assert heavier.figures["down_weight"] == pytest.approx(base.figures["down_weight"])
    assert heavier.figures["inertia_mass"] - base.figures["inertia_mass"] == pytest.approx(
        added / base.key_front_radius_m**2 * 1e3, rel=0.01)
    # the force that accelerates the key front at a (on top of the static one): the key's
    # added inertia needs added x a / r^2 more (r the front's arm), by hand
    a = 10.0
    assert touch.acceleration_force(heavier, a) - touch.acceleration_force(base, a) == \
        pytest.approx(added * a / base.key_front_radius_m**2, rel=0.01)
    assert touch.acceleration_force(base, a) == pytest.approx(
        base.figures["inertia_mass"] / 1e3 * a)


def test_the_slow_press_plot_is_a_page_of_the_stroke_and_is_not_overwritten(tmp_path, base):
    """rig touch --plot: one Plotly figure of the down, up and frictionless force (grams)
    against the dip (mm); an existing file is kept unless --force."""
    import re

    from rig.services import touch as svc

    out = tmp_path / "touch.html"
    svc.write_plot(base, out, "base model", force=False)
    text = out.read_text()
    assert text.startswith("<!DOCTYPE html>") and "data-figures='1'" in text
    call = re.search(r'Plotly\.newPlot\(\s*"touch-stroke",\s*(\[.*?\]),\s*\{', text, re.S)
    assert call is not None
    traces = {t["name"]: t for t in json.loads(call.group(1))}
    assert set(traces) == {"down press", "up press", "frictionless"}
    for name, force in (("down press", base.down_n), ("up press", base.up_n),
                        ("frictionless", base.frictionless_n)):
        np.testing.assert_allclose(_plotted(traces[name]["x"]), base.dip_m * 1e3)
        np.testing.assert_allclose(_plotted(traces[name]["y"]),
                                   [touch.grams(f) for f in force])
    with pytest.raises(InputError, match="exists"):
        svc.write_plot(base, out, "again", force=False)
    assert out.read_text() == text
    svc.write_plot(base, out, "again", force=True)
    assert "again" in out.read_text()


def _plotted(values: object) -> np.ndarray:
    """A Plotly trace's array: a list, or a typed array ({"dtype", "bdata"} in base64)."""
    import base64

    if isinstance(values, dict):
        return np.frombuffer(base64.b64decode(values["bdata"]), dtype=values["dtype"])
    return np.asarray(values, dtype=float)


def test_heavier_hammer_raises_weights_by_the_geometry(frictionless, base):
    """1 g more hammer head: the frictionless key force rises by 1 g x the head's rise per
    key-front dip (read from the path's kinematics), and the down-weight by more (friction
    grows with the load it carries)."""
    model, res = frictionless
    extra = 0.001
    heavier = model_with({**FRICTION_OFF, "bodies.hammer_head.mass": 0.00792 + extra})
    res2 = touch.measure(heavier)
    path = _path(model, res)
    ws = model.workspace()
    cx, cy = model.params.tree["bodies"]["hammer_head"]["com"]

    def head_com(y: np.ndarray) -> np.ndarray:
        a = model.packed.arrays
        k.kinematics(y[: k.NQ], y[k.NQ : k.NY], a.sp, a.sec_xi, ws.org, ws.phi, ws.w, ws.vO,
                     ws.JO, ws.Jp, ws.aO, ws.al, ws.cs)
        c, s = ws.cs[k.F_HEAD]
        return np.array([ws.org[k.F_HEAD, 0] + c * cx - s * cy,
                         ws.org[k.F_HEAD, 1] + s * cx + c * cy])

    i = int(np.argmin(np.abs(res.dip_m - res.method["mid_stroke_dip_m"])))  # mid-stroke
    velocity = (head_com(path[i + 1]) - head_com(path[i - 1])) / (
        res.dip_m[i + 1] - res.dip_m[i - 1])  # per unit key-front dip
    ratio = velocity[1]
    # the added mass moves with the head's centre: the mass felt at the key front grows by
    # it times the square of the head's speed per key-front speed
    assert res2.figures["inertia_mass"] - res.figures["inertia_mass"] == pytest.approx(
        extra * 1e3 * velocity @ velocity, rel=0.02)
    assert 3 < ratio < 8  # the head rises several times faster than the key front dips
    g = model.params.tree["gravity"]
    assert res2.frictionless_n[i] - res.frictionless_n[i] == pytest.approx(
        extra * g * ratio, rel=0.01)
    assert res2.figures["down_weight"] - res.figures["down_weight"] == pytest.approx(
        touch.grams(extra * g * ratio), rel=0.01)
    assert res2.figures["strike_weight"] > res.figures["strike_weight"]
    assert res2.figures["hammer_mass"] == pytest.approx(res.figures["hammer_mass"] + 1.0)
    # with friction: the down-weight rises by more than the frictionless share
    with_friction = touch.measure(model_with({"bodies.hammer_head.mass": 0.00792 + extra}))
    rise = with_friction.figures["down_weight"] - base.figures["down_weight"]
    assert rise > touch.grams(extra * g * ratio)
    assert with_friction.figures["up_weight"] > base.figures["up_weight"]


def test_friction_shares_add_up_to_the_friction_of_the_down_press(base):
    """The friction each joint and contact dissipates per key-front travel (a power balance)
    adds up to what the down press needs over the frictionless force."""
    total = sum(base.friction_shares_g.values())
    mid = int(np.argmin(np.abs(base.dip_m - base.method["mid_stroke_dip_m"])))
    assert total == pytest.approx(touch.grams(base.down_n[mid] - base.frictionless_n[mid]),
                                  rel=0.02)
    assert base.friction_shares_g["key pin"] == pytest.approx(
        touch.grams(0.0122 / base.key_front_radius_m), rel=0.02)


def test_static_figures_follow_their_definitions(base):
    p = Parameters.default().tree
    key = p["bodies"]["key"]
    # front weight: the key alone, its weight's moment about the pin over the front's arm
    th = ActionModel().rest_state()[k.QK]
    cx, cy = key["com"]
    arm = cx * math.cos(th) - cy * math.sin(th)
    assert base.figures["front_weight"] == pytest.approx(
        key["mass"] * p["gravity"] * arm / base.key_front_radius_m / touch.G0 * 1e3, rel=1e-4)
    hammer = sum(p["bodies"][b]["mass"] for b in ("hammer_base", "hammer_shank", "hammer_head"))
    assert base.figures["hammer_mass"] == pytest.approx(hammer * 1e3)
    # the capstan sits about half as far from the pin as the key front
    assert base.figures["key_ratio"] == pytest.approx(0.1176 / 0.2278, rel=0.03)
    assert base.figures["balance_weight"] == pytest.approx(
        (base.figures["down_weight"] + base.figures["up_weight"]) / 2)
    assert base.figures["down_weight"] > base.figures["balance_weight"] > \
        base.figures["up_weight"] > 0


def test_models_with_effect_states_are_refused():
    with pytest.raises(InputError, match="fingertip"):
        touch.measure(ActionModel(effects=["fingertip"]))


def _rig(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "rig", *args], capture_output=True, text=True,
                          timeout=600, cwd=cwd, env={**os.environ, "PYTHONPATH": str(ROOT)})


@pytest.mark.slow
def test_cli_prints_and_emits_json(tmp_path, base):
    out = _rig("touch", "--json")
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout)
    assert doc["schema"] == "rig.touch/1"
    jsonschema = pytest.importorskip("jsonschema")
    import re

    text = (ROOT / "docs" / "json.md").read_text()
    schemas = [json.loads(b) for b in re.findall(r"^```json\n(.*?)^```", text, re.S | re.M)]
    jsonschema.validate(doc, next(s for s in schemas if s["$id"] == "rig.touch/1"))
    assert doc["figures"]["down_weight"]["value"] == pytest.approx(base.figures["down_weight"])
    assert doc["figures"]["down_weight"]["newtons"] == pytest.approx(base.newtons["down_weight"])
    worked = base.worked_key()
    assert doc["worked"]["down_weight"] == pytest.approx(worked["down_weight"])
    assert doc["worked"]["up_weight"] == pytest.approx(worked["up_weight"])
    page = tmp_path / "touch.html"
    text = _rig("touch", "--plot", str(page), "--accel", "5")
    assert text.returncode == 0, text.stderr
    assert any(ln.startswith("down_weight") for ln in text.stdout.splitlines())
    assert f"worked key: down {worked['down_weight']:.2f} g" in text.stdout
    push = base.figures["inertia_mass"] / 1e3 * 5  # N: the mass felt x 5 m/s^2
    assert f"5 m/s^2 at the key front needs {push:.3f} N" in text.stdout
    assert doc["acceleration"]["force_N"] == pytest.approx(base.figures["inertia_mass"] / 100)
    assert page.read_text().startswith("<!DOCTYPE html>")
    again = _rig("touch", "--plot", str(page))
    assert again.returncode == 2 and "exists" in again.stderr
    assert len(again.stderr.strip().splitlines()) == 1
    bad = tmp_path / "m.yaml"
    bad.write_text("parameters: {contacts: {1: {A: oops}}}\n")
    refused = _rig("touch", "--model", str(bad))
    assert refused.returncode == 2
    assert str(bad.name) in refused.stderr and len(refused.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_sweep_reports_touch_and_a_heavier_hammer_raises_it():
    """rig sweep --touch: each row's model gives its touch weights beside the blow's metrics;
    a heavier hammer head raises the down- and up-weight and the strike weight."""
    from rig.analysis import sweep as sw
    from rig.inputs import profiles

    axes = [sw.Axis.parse("bodies.hammer_head.mass=0.007:0.009")]
    study = sw.action_study(ActionModel(), profiles.load(ROOT / "profiles" / "forte.yaml"),
                            axes, duration=0.02, touch=True)
    names = [m.name for m in study.metrics]
    assert names[-len(sw.TOUCH_METRICS):] == [m.name for m in sw.TOUCH_METRICS]
    light = dict(zip(names, study.fn(study.shared, np.array([0.007])), strict=True))
    heavy = dict(zip(names, study.fn(study.shared, np.array([0.009])), strict=True))
    for name in ("down_weight_g", "up_weight_g", "balance_weight_g", "strike_weight_g"):
        assert heavy[name] > light[name] + 0.5, name
    assert heavy["front_weight_g"] == pytest.approx(light["front_weight_g"])
    # the row's figures are rig touch's of the same model
    m = ActionModel(Parameters.default().set("bodies.hammer_head.mass", 0.009))
    assert heavy["down_weight_g"] == pytest.approx(touch.measure(m).figures["down_weight"])
    # without --touch the study is as before
    plain = sw.action_study(ActionModel(), profiles.load(ROOT / "profiles" / "forte.yaml"),
                            axes, duration=0.02)
    assert [m.name for m in plain.metrics] == [m.name for m in sw.ACTION_METRICS]


@pytest.mark.slow
def test_slow_force_ramp_starts_the_key_near_the_static_down_weight():
    """The dynamic answer: a slow force ramp (0 -> 70 g in 4 s) on the model whose friction
    thresholds are lowered so that its regularised laws act nearly as Coulomb friction at
    creep speeds. The key front is 0.25 mm down (the stroke's first point) at a force near
    the static down force there, and closer to it the lower the thresholds."""
    from rig.inputs import profiles

    ramp = profiles.from_points([[0.0, 0.0], [4.0, 0.070 * touch.G0]], name="ramp")
    gaps = []
    shipped = touch.measure(ActionModel()).figures["down_weight_stroke"]
    for vt, wt in ((5e-4, 5e-3), (1e-4, 1e-3)):
        p = Parameters.default()
        for c in (1, 4, 7, 10):
            p.set(f"friction_threshold.contact_vt.{c}", vt)
        for j in ("key", "whippen", "jack", "repetition", "hammer"):
            p.set(f"friction_threshold.joint_wt.{j}", wt)
        model = ActionModel(p)
        static = touch.measure(model)
        # the static figures are the sliding limit: the thresholds do not move them
        assert static.figures["down_weight_stroke"] == pytest.approx(shipped, abs=0.05)
        res = model.simulate(ramp)
        i = int(np.argmax(res.channels["key_dip"] > static.dip_m[0]))
        gaps.append(static.down_n[0] - res.channels["force"][i])
    # closer the lower the thresholds: under the static force at 100x, 0.3 g over it at
    # 500x (the dynamic law keeps Eq. 3.6's static hump B1 at creep speeds; the static
    # solve takes the kinetic A)
    assert 0 < abs(gaps[1]) < gaps[0]
    assert touch.grams(abs(gaps[1])) < 2.0


def _dissipated(model: ActionModel, st: touch._Statics, y: np.ndarray, force: float) -> float:
    """Energy (J) the friction of every contact and pin dissipates in the press's step that
    ends at y (its speeds are the step's increments over touch.STEP_S): force x slip."""
    co = np.zeros((k.N_CONTACT_OUT, 1, model.packed.n_contacts))
    k.sample_outputs(st.sliding, model.workspace(), y[None, :], np.array([force]),
                     model._head_pt, model._gauge, np.zeros((k.N_X, 1)), co)
    out = float(np.sum(np.abs(co[k.O_FT, 0] * co[k.O_SLIP, 0])))
    jf = st.sliding.jf
    for j, c in enumerate(k.JOINT_COORD):
        if model.active[c]:
            w = y[k.NQ + c]
            out += abs(k.joint_torque(w, jf[j, 0], 0.0, 0.0, jf[j, 3]) * w)
    return out * touch.STEP_S


@pytest.mark.parametrize("regulation", [0.0, -0.172])
def test_the_presses_balance_work_potential_and_friction(regulation):
    """Virtual work with friction, step by step along both presses: the key force's work
    over each step equals the rise of the potential energy (gravity, springs, felts:
    written out in this file) plus what every contact's and pin's friction dissipates
    (force x slip, from the kernel's outputs). On the thesis's spring preload and on the
    regulated one, where on the return the knuckle's friction drags the jack off its
    whippen stop (contact 5 opens): the friction then turns with the slip it makes."""
    model = model_with({"repetition_spring.regulation": regulation})
    res = touch.measure(model)
    st = touch._Statics(model)
    if regulation:
        assert "up press, contact 5" in res.method["contacts_changed"]
    assert res.method["worst_residual"] < touch.FORCE_TOL
    presses = (("down", res.down_states[:-1], res.down_n, res.dip_m),
               ("up", res.up_states[::-1], res.up_n[::-1], res.dip_m[::-1]))
    for way, states, forces, dips in presses:
        work = (forces[1:] + forces[:-1]) / 2 * np.diff(dips)
        rise = np.diff([_potential(model, y) for y in states])
        lost = [_dissipated(model, st, y, f) for y, f in zip(states, forces, strict=True)]
        lost = (np.array(lost[1:]) + np.array(lost[:-1])) / 2
        # each step within 0.5 % but where a joint or contact changes between sticking and
        # sliding in it (its dissipation is then no straight line); the stroke within 1 %
        err = (work - rise - lost) / lost
        assert np.median(np.abs(err)) < 5e-3, way
        assert np.sum(work - rise - lost) == pytest.approx(0.0, abs=1e-2 * np.sum(lost)), way


@pytest.mark.slow
def test_flexible_shank_statics_match_the_rigid_ones(base):
    """The shank's bending coordinates enter the solve (their own scale); statically they bend
    by micrometres, so the weights are the rigid model's."""
    flex = touch.measure(ActionModel(effects=["flexible_shank"]))
    for name in ("down_weight", "up_weight", "down_weight_stroke", "up_weight_stroke"):
        assert flex.figures[name] == pytest.approx(base.figures[name], abs=0.05), name
    for name in ("down_weight", "up_weight"):  # the worked key's too (47.01 / 47.04 g down)
        assert flex.worked_key()[name] == pytest.approx(base.worked_key()[name], abs=0.05), name
    assert flex.stroke_end == base.stroke_end
    # the shank's mass is in its Gauss points now: density x area x length
    assert flex.figures["hammer_mass"] == pytest.approx(base.figures["hammer_mass"], abs=0.01)


def _sticking_model() -> ActionModel:
    """The base model with Dahl's sticking law at every pin and contact with friction (the
    simulated rig's ``sim.friction: stick``, rig.sim_backend.simrig.sim_parameters)."""
    from rig.inputs import config
    from rig.sim_backend.simrig import sim_parameters

    cfg = config.from_mapping({"name": "stick", "backend": "sim", "data_folder": ".",
                               "drive": {"port": "sim"},
                               "sim": {"effects": [], "friction": "stick"}})
    return ActionModel(sim_parameters(cfg), output_rate=2000.0)


@pytest.mark.slow
def test_a_worked_key_weighs_what_the_sticking_simulation_measures_after_a_press():
    """The worked key (a press from the rest its first press and return leave, friction
    carried over) against an independent answer: the sticking model simulated in time
    (Dahl's law, no quasi-static solve) under three slow force presses, 44 -> 58 -> 14 g at 2
    g/s, let go to 0 g between them. The simulated key goes 0.25 mm down from where it
    stood at 44 g at 51.9 g on its first press and near 47 g on the next two; the worked
    key's down-weight agrees with those two within 0.5 g and lies over 3 g under the press
    from the assembled rest (so the test tells the two apart); its rest (no force, the jack
    left off its stop) is the simulated key's rest after a press within 5 um."""
    from rig.calibration import touch as ct
    from rig.inputs import profiles

    model = _sticking_model()
    res = touch.measure(model)
    worked, first = res.worked_key(), res.from_rest()
    ramps = ct.Ramps(from_g=44.0, to_g=58.0, low_g=14.0, rate_g_s=2.0)
    knots = ramps.knots()
    period = knots[-1][0] + 0.5  # back to 0 g in 0.3 s, 0.2 s at rest
    points = []
    for i in range(3):
        points += [[i * period + t, f] for t, f in knots]
        points.append([i * period + knots[-1][0] + 0.3, 0.0])
    points.append([3 * period, 0.0])
    sim = model.simulate(profiles.from_points(points, name="presses", description="",
                                              source="test", force_limit=50.0,
                                              max_duration=1e3))
    assert sim.success, sim.message
    t, dip = sim.time, sim.channels["key_dip"]
    force = np.interp(t, [p[0] for p in points], [p[1] for p in points])
    downs, rests = [], []
    for i in range(3):
        on = (t >= i * period) & (t < (i + 1) * period)
        start = ct.find_start(t[on] - i * period, dip[on], force[on],
                              ramps.segments()["down"], +1, ramps, 5e-7, f"press {i}")
        downs.append(ct.grams(start.went_force_n))
        rests.append(float(np.interp((i + 1) * period - 0.01, t, dip)))
    assert downs[0] - first["down_weight"] > 0  # the assembled key: the first press's
    assert abs(downs[0] - first["down_weight"]) < 2.5
    for d in downs[1:]:
        assert abs(d - worked["down_weight"]) < 0.5, (downs, worked)
    assert first["down_weight"] - worked["down_weight"] > 3
    # both rest lower than the assembled key (27-29 um simulated, the key having run back
    # onto its back felt; 43 um let go quasi-statically)
    assert min(rests) > 10e-6 and worked["rest_dip_m"] > 10e-6, (rests, worked)
    assert max(abs(r - worked["rest_dip_m"]) for r in rests) < 20e-6, (rests, worked)


def test_a_worked_key_without_an_answer_leaves_the_other_figures(monkeypatch, base):
    """Where the worked key's press finds no equilibrium, measure keeps the first press's
    figures and says why (method.worked_key_failed), and worked_key() refuses."""
    def no_answer(*args, **kwargs):
        raise InputError("model: worked down press at 0.29 mm of key-front dip: no answer")

    monkeypatch.setattr(touch, "_worked", no_answer)
    res = touch.measure(ActionModel())
    assert res.figures == base.figures and not res.worked
    assert "worked down press" in res.method["worked_key_failed"]
    assert "worked" not in res.to_json()
    with pytest.raises(ValueError, match="not computed"):
        res.worked_key()


def test_a_return_from_the_stop_starts_where_a_press_in_time_left_the_key():
    """``stop_returns``: the shipped model pressed in time (every friction sticking) from
    rest by 0 -> 44 g in 0.5 s and 2 g/s to 58 g, held 1 s: the key runs through let-off
    down to the front punching (contact 2, 9.9 mm) with the jack tripped off its whippen
    stop (contact 5 open over 2 mm), and the force lowered slowly from there lets it come
    0.25 mm up at 22.6 g: under the force held, over the worked key's 20.0 g. The same
    model, its friction laws already Dahl's, gives the same returns; a time outside the
    profile is refused."""
    g = 9.80665e-3
    t = np.array([0.0, 0.5, 7.5, 8.5])
    f = np.array([0.0, 44.0, 58.0, 58.0]) * g
    model = ActionModel()
    (r,) = touch.stop_returns(model, t, f, [8.5])
    assert r["held_n"] == pytest.approx(58 * g)
    assert r["penetration_m"][2] > 0 and r["penetration_m"][5] < -2e-3, r
    assert r["up_dip_m"] == pytest.approx(r["stop_dip_m"] - touch.FIRST_M)
    assert 9.5e-3 < r["stop_dip_m"] < 10.5e-3
    assert r["up_weight"] == pytest.approx(22.6, abs=0.3)
    assert r["up_n"] == pytest.approx(r["up_weight"] * g)
    stuck = ActionModel(touch.sticking_parameters(model.params))
    (again,) = touch.stop_returns(stuck, t, f, [8.5])
    assert again["up_weight"] == pytest.approx(r["up_weight"], abs=1e-9)
    with pytest.raises(InputError, match="at_s"):
        touch.stop_returns(model, t, f, [9.0])


@pytest.mark.slow
def test_the_return_from_the_stop_weighs_what_the_simulations_ramp_down_reads():
    """``stop_returns`` against an independent reading: the sticking model simulated in time
    under three presses 44 -> 58 -> 14 g at 2 g/s, let go to 0 g between them, comes up by
    the travel rule on its ramps down (22.30, 19.12, 18.63 g); the quasi-static returns from
    the ends of the same holds agree within 0.3 g each, the first from the front punching,
    the two later ones from the drop screw with the jack off its whippen stop."""
    from rig.calibration import touch as ct
    from rig.inputs import profiles

    model = _sticking_model()
    ramps = ct.Ramps(from_g=44.0, to_g=58.0, low_g=14.0, rate_g_s=2.0)
    knots = ramps.knots()
    points, period = ramps.presses(3)
    pts = np.array(points)
    sim = model.simulate(profiles.from_points(points, name="presses", description="",
                                              source="test", force_limit=50.0,
                                              max_duration=1e3))
    assert sim.success, sim.message
    t, dip = sim.time, sim.channels["key_dip"]
    force = np.interp(t, pts[:, 0], pts[:, 1])
    returns = touch.stop_returns(model, pts[:, 0], pts[:, 1],
                                 [i * period + knots[3][0] for i in range(3)])
    for i, r in enumerate(returns):
        on = (t >= i * period) & (t < (i + 1) * period)
        up = ct.find_start(t[on] - i * period, dip[on], force[on], ramps.segments()["up"], -1,
                           ramps, 5e-7, f"press {i}")
        assert abs(r["up_weight"] - ct.grams(up.went_force_n)) < 0.3, (i, r, up)
        assert r["stop_dip_m"] == pytest.approx(up.ref_dip_m, abs=2e-5)
    assert returns[0]["penetration_m"][2] > 0
    for r in returns[1:]:
        assert r["penetration_m"][11] > 0 and r["penetration_m"][5] < -0.3e-3, r
