"""Whole blows: rest state, events, strike, stepping, integrators."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rig.model import kernel as k
from rig.model.action import ANGLE_CHANNELS, EVENT_ORDER, ActionModel
from rig.model.integrators import DormandPrince, ScipyIntegrator

# action-geometry.md, "Rest-state check": penetration (mm) at the Table 3.2 angles
GEOMETRY_GAPS_MM = {1: 0.14, 2: -9.39, 3: -0.03, 4: -2.54, 5: 0.13, 6: 0.20, 7: -0.06, 8: -8.36,
                    9: -7.09, 10: 0.03, 11: -6.70, 12: -48.73, 13: -0.22, 14: 0.15}
TABLE_3_2 = {"theta_k": 0.032, "theta_w": 0.025, "theta_j": 0.337, "theta_r": 0.377,
             "theta_h": 0.293}


def penetrations_mm(model: ActionModel, y: np.ndarray) -> dict[int, float]:
    res = model.result_from_samples(np.zeros(1), y[None, :], np.zeros(1))
    return {cid: 1e3 * res.contact("contact_penetration", cid)[0] for cid in GEOMETRY_GAPS_MM}


def test_table_3_2_angles_reproduce_the_geometry_gaps():
    model = ActionModel(effects=["key_liftoff"])  # contact 14 exists only with lift-off
    y = model._table_state()
    y[k.QYK] = 0.0  # the pivot height y0 already equals Table 3.2's Y_k
    gaps = dict(GEOMETRY_GAPS_MM)
    assert model.balance_rail is not None
    gaps[14] += 1e3 * model.balance_rail["offset_m"]  # the rail is placed by the rest rule
    for cid, pen in penetrations_mm(model, y).items():
        assert pen == pytest.approx(gaps[cid], abs=0.05), f"contact {cid}"


@pytest.mark.parametrize("effects", [[], ["key_liftoff"]], ids=["revolute key", "key lift-off"])
def test_rest_state_matches_table_3_2_and_the_rest_gaps(effects):
    model = ActionModel(effects=effects)
    y = model.rest_state()
    for name, value in TABLE_3_2.items():
        i = ("theta_k", "y_k", "theta_w", "theta_j", "theta_r", "theta_h").index(name)
        assert y[i] == pytest.approx(value, abs=0.004), name
    for cid, pen in penetrations_mm(model, y).items():
        if cid == 14 and not effects:
            continue
        assert pen == pytest.approx(GEOMETRY_GAPS_MM[cid], abs=0.5), f"contact {cid}"
    assert np.abs(model.accelerations(y)).max() < 1e-6  # a true equilibrium


def test_forte_events_in_physical_order(forte_rigid):
    ev = forte_rigid.events
    assert all(math.isfinite(ev[name]) for name in EVENT_ORDER), ev
    assert ev["key_starts"] < ev["toe_meets_button"] < ev["let_off"] < ev["strike"]
    assert ev["strike"] < ev["string_release"] < ev["check"]
    assert ev["key_bottom"] < ev["key_release"]
    assert ev["string_release"] - ev["strike"] < 0.004  # the hammer rebounds within a few ms


def keytop_speed(res) -> float:
    """Largest downward speed (m/s) of the key top (Pk2)."""
    return float(np.gradient(res.channels["key_dip"], res.time).max())


def energy_gained_and_work(model, res) -> tuple[float, float]:
    """(kinetic + gravitational energy gained since rest, work of the key force), J, at the
    last sample before the strike (rigid model: the angles and their rates are the state)."""
    i = int(np.searchsorted(res.time, res.events["strike"], side="right")) - 1
    y = np.zeros(k.NY)
    for name, qi in ANGLE_CHANNELS.items():
        y[qi] = res.channels[name][i]
        y[k.NQ + qi] = res.channels[name.replace("_angle", "_angular_velocity")][i]
    gained = sum(model.energy(y)) - sum(model.energy(model.rest_state()[: k.NY]))
    work = float(np.trapezoid(res.channels["force"][: i + 1], res.channels["key_dip"][: i + 1]))
    return gained, work


def test_forte_strike(rigid_model, forte_rigid, piano_rigid):
    assert forte_rigid.success and piano_rigid.success
    assert forte_rigid.contact("contact_penetration", 12).max() < 2e-3  # felt sinks < 2 mm
    v_forte, v_piano = forte_rigid.strike_speed, piano_rigid.strike_speed
    assert 0.0 < v_piano < v_forte  # both reach the string, the harder blow faster
    for res in (forte_rigid, piano_rigid):
        # the action multiplies the key's speed (the head rises ~48 mm as the key dips ~10) ...
        assert res.strike_speed > keytop_speed(res)
        # ... but cannot give the hammer more energy than the key force has put in
        gained, work = energy_gained_and_work(rigid_model, res)
        assert 0.0 < gained < work
    # the head reaches the string from about 48 mm below: the key dips about 10 mm
    assert forte_rigid.channels["key_dip"].max() == pytest.approx(0.0105, abs=0.0015)


# thesis Section 5.2: piano blows 0-5 N moving the key at 0-250 mm/s, forte 0-30 N
PIANO_MAX_FORCE, PIANO_MAX_KEY_SPEED, FORTE_MAX_FORCE = 5.0, 0.25, 30.0


def test_shipped_blows_in_the_thesis_ranges(forte, piano, forte_rigid, piano_rigid):
    assert piano.peak <= PIANO_MAX_FORCE and forte.peak <= FORTE_MAX_FORCE
    assert keytop_speed(piano_rigid) <= PIANO_MAX_KEY_SPEED
    assert keytop_speed(forte_rigid) > PIANO_MAX_KEY_SPEED  # beyond the piano range


def test_stepping_in_2ms_pieces_gives_the_same_blow(rigid_model, forte, forte_rigid):
    stepper = rigid_model.stepper()
    for t in np.arange(0.002, forte.duration + 1e-9, 0.002):
        stepper.advance(float(t), float(forte.at(t - 0.002)), float(forte.at(t)))
    stepped = stepper.result()
    assert stepped.success
    for name in EVENT_ORDER:
        assert stepped.events[name] == pytest.approx(forte_rigid.events[name], abs=5e-5), name
    assert stepped.strike_speed == pytest.approx(forte_rigid.strike_speed, rel=1e-3)
    np.testing.assert_allclose(stepped.channels["hammer_angle"],
                               forte_rigid.channels["hammer_angle"], atol=2e-4)


@pytest.mark.slow
def test_dopri_agrees_with_scipy_bdf(forte, forte_rigid):
    ref = ActionModel(integrator=ScipyIntegrator("BDF", rtol=1e-8)).simulate(forte)
    assert ref.success
    assert forte_rigid.events["strike"] == pytest.approx(ref.events["strike"], abs=1e-4)
    assert forte_rigid.strike_speed == pytest.approx(ref.strike_speed, rel=0.01)
    for name in EVENT_ORDER:
        assert forte_rigid.events[name] == pytest.approx(ref.events[name], abs=3e-4), name


def test_a_failed_integration_returns_status_and_message(forte):
    model = ActionModel(integrator=DormandPrince(max_step=1e-3))
    model.integrator.max_steps = 50
    res = model.simulate(forte)
    assert not res.success
    assert res.status == -3 and "too many steps" in res.message
    assert res.time[-1] < forte.duration  # what was computed is kept
    with pytest.raises(RuntimeError):
        model.stepper().advance(0.1, 0.0)  # a fresh stepper works ...
        st = model.stepper()
        st.status = -3
        st.advance(0.2, 0.0)  # ... a failed one refuses to go on


def test_bad_arguments_are_refused(rigid_model):
    with pytest.raises(ValueError, match="t_end"):
        rigid_model.stepper().advance(0.0, 1.0)
    with pytest.raises(ValueError, match="f_start"):
        rigid_model.stepper().advance(0.01, float("nan"))
    with pytest.raises(ValueError, match="rtol"):
        DormandPrince(rtol=2.0)
    with pytest.raises(ValueError, match="effects"):
        ActionModel(effects=["key_liftoff", "key_liftoff"])
