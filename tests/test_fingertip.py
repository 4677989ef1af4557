"""The fingertip pulp (thesis Sections 3.8, 4.3) and the motion profiles that drive it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from rig.analysis import diagnose as dg
from rig.cli import app
from rig.inputs import profiles
from rig.inputs.params import Parameters
from rig.model.action import ActionModel
from rig.model.fingertip import Fingertip, constant_speed_force, kelvin_force
from rig.recordings import runfile

ROOT = Path(__file__).parents[1]
PRESS = ROOT / "profiles" / "fingertip-press.yaml"
SHIPPED = dict(Parameters.default().get("fingertip_kelvin_model"))


def test_the_effect_uses_the_shipped_parameters() -> None:
    e = Fingertip()
    ActionModel(effects=[e])
    assert e.values == pytest.approx(SHIPPED)


def test_section_4_3_thresholds_for_a_1_6_mm_indentation() -> None:
    """Fig. 4.15: ~1.9 N at 0.2 mm/s and ~5.3 N at 80 mm/s, from the model alone."""
    slow = constant_speed_force(0.2, 1.6, SHIPPED)
    fast = constant_speed_force(80.0, 1.6, SHIPPED)
    assert slow == pytest.approx(1.9, abs=0.1)
    assert fast == pytest.approx(5.3, abs=0.15)
    # the exact limits of Eq. 3.12-3.13 bracket them: the parallel spring alone when the
    # damper has all the time it needs, Eq. 3.14 (X2 = X) when it has none
    v = SHIPPED
    x = 1.6
    static = v["a1"] * math.exp(v["b1"] * x) * x
    instant = static + v["a2"] * math.exp(v["b2"] * x) * x
    assert constant_speed_force(2e-4, x, v) == pytest.approx(static, rel=1e-3)
    assert constant_speed_force(1e6, x, v) == pytest.approx(instant, rel=1e-3)
    assert static < slow < fast < instant
    # below 0.2 mm/s the force hardly changes any more (the slow threshold holds) ...
    assert slow - constant_speed_force(0.02, x, v) < 0.05 * slow
    # ... but above 80 mm/s the model keeps stiffening toward Eq. 3.14 (7.9 N): the
    # thesis's fast "threshold" is where Pawluk's data end, not a saturation of the model
    assert constant_speed_force(800.0, x, v) > 1.3 * fast
    assert kelvin_force(0.0, 0.0, v["a1"], v["a2"], v["b1"], v["b2"]) == 0.0


@pytest.fixture(scope="module")
def press() -> tuple[ActionModel, object]:
    model = ActionModel(effects=["fingertip"])
    prof = profiles.load(PRESS, kinds=profiles.KINDS)
    return model, model.simulate(prof)


def test_a_motion_profile_presses_the_key_through_the_pulp(press) -> None:
    model, res = press
    assert res.success, res.message
    ch = res.channels
    f, dip, ind = ch["force"], ch["key_dip"], ch["fingertip_indentation"]
    disp = ch["fingertip_displacement"]
    prof = profiles.load(PRESS, kinds=profiles.KINDS)
    assert disp == pytest.approx(prof.at(res.time), abs=1e-12)
    # the hammer strikes and the key bottoms under the finger
    assert {"strike", "key_bottom", "check"} <= set(res.events)
    assert dip.max() == pytest.approx(0.0105, abs=0.001)
    # while pressing, the force is Eq. 3.13 at the pulp's indentation (bone - key top)
    touching = f > 0
    assert touching.sum() > 0.3 * f.size
    assert ind[touching] == pytest.approx((disp - dip)[touching], abs=1e-9)
    x1 = ch["fingertip_damper_extension"] * 1e3
    x = ind * 1e3
    v = SHIPPED
    expect = v["a1"] * np.exp(v["b1"] * x) * x + v["a2"] * np.exp(v["b2"] * (x - x1)) * (x - x1)
    assert f[touching] == pytest.approx(expect[touching], rel=1e-9)
    # the pulp never pulls: no force once the bone withdraws above the pulp's surface
    assert f.min() == 0.0
    lifted = res.time > 0.21
    assert np.all(f[lifted] == 0.0)
    assert np.all(disp[lifted] - dip[lifted] < ind[lifted])  # the key top left the pulp
    # the pulp recovers only through its own damper: its surface stays indented a little
    assert 0.0 < ind[-1] < 0.2e-3


def test_the_pulp_creeps_along_eq_3_10_while_the_bone_holds(press) -> None:
    """Bone held at 13 mm, key bottomed: the damper creeps, C1 dX1/dt = K2 X2 (Eq. 3.10),
    so X1 rises and the force falls."""
    _, res = press
    ch = res.channels
    hold = (res.time > 0.09) & (res.time < 0.17)
    t = res.time[hold]
    x1 = ch["fingertip_damper_extension"][hold] * 1e3
    x2 = ch["fingertip_indentation"][hold] * 1e3 - x1
    v = SHIPPED
    rate = v["a2"] * np.exp(v["b2"] * x2) * x2 / (v["a3"] * np.exp(v["b3"] * x1))  # mm/s
    assert np.gradient(x1, t)[1:-1] == pytest.approx(rate[1:-1], rel=0.02)
    assert np.all(np.diff(x1) > 0)
    # 22.7 -> 22.3 N in the 80 ms (-1.9 %; -3.1 %, 21.6 -> 20.9 N, with the thesis's
    # repetition-spring preload, docs/model.md; more, before the back check held the
    # hammer: the hammer creeping off the check unloaded the key as well)
    assert ch["force"][hold][-1] < 0.99 * ch["force"][hold][0]


def test_motion_profiles_are_refused_where_a_force_is_needed(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="kind: motion: this command needs a force profile"):
        profiles.load(PRESS)
    bad = tmp_path / "bad.yaml"
    bad.write_text("kind: motion\npoints: [[0, 0], [0.05, 12]]\n")
    with pytest.raises(ValueError, match=r"bad.yaml: points\[1\] displacement: .*metres"):
        profiles.load(bad, kinds=profiles.KINDS)
    bad.write_text("kind: position\npoints: [[0, 0], [0.05, 0.01]]\n")
    with pytest.raises(ValueError, match="bad.yaml: kind: expected one of force, motion"):
        profiles.load(bad, kinds=profiles.KINDS)
    with pytest.raises(ValueError, match="needs the fingertip effect"):
        ActionModel().simulate(profiles.load(PRESS, kinds=profiles.KINDS), 0.01)
    runner = CliRunner()
    r = runner.invoke(app, ["run", str(PRESS), "--out", str(tmp_path / "x.h5")])
    assert r.exit_code == 2 and "kind: motion" in r.output
    assert not (tmp_path / "x.h5").exists()


def test_rig_simulate_plays_a_motion_profile(tmp_path: Path) -> None:
    out = tmp_path / "press.h5"
    r = CliRunner().invoke(app, ["simulate", str(PRESS), "-e", "fingertip", "--out", str(out),
                                 "--duration", "0.08"])
    assert r.exit_code == 0, r.output
    run = runfile.read(out)
    tr = run.trials[0]
    assert tr.units["fingertip_displacement"] == "m" and tr.units["force"] == "N"
    assert tr.channels["force"].max() > 10.0
    assert run.metadata["profile"]["kind"] == "motion"


def test_a_force_profile_leaves_the_fingertip_idle() -> None:
    forte = profiles.load(ROOT / "profiles" / "forte.yaml")
    a = ActionModel().simulate(forte, 0.06)
    b = ActionModel(effects=["fingertip"]).simulate(forte, 0.06)
    assert b.channels["key_dip"] == pytest.approx(a.channels["key_dip"], abs=2e-6)
    assert "fingertip" not in [c.name for c in dg.candidates_for(ActionModel())]
