"""Issue 39: a diagnosis that holds on data it never saw; each failure class with a small,
fixed seed.

- An effect that switches on another (the key encoder's misread switches on lift-off) is
  named instead of it only when the held-out data show what it adds, not when it merely
  removes a share of a residual that is within the noise.
- Held-out data are another blow than the training one when the run has several.
- The model as it would be written is checked on the held-out data; worse than the base
  there, it is neither claimed nor written.
- Physics outside the library (friction at the key front) is credited to no library
  effect when the held-out blow differs from the training one.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
import yaml

from rig.analysis import diagnose as dg
from rig.analysis import fit as ft
from rig.analysis import measurement as ms
from rig.analysis import synth
from rig.analysis.diagnose.check import written_removal, written_values
from rig.errors import InputError
from rig.inputs import profiles
from rig.model.action import ActionModel
from rig.model.effects import BUILTIN, make

ROOT = Path(__file__).parents[1]
FORTE = ROOT / "profiles" / "forte.yaml"
PIANO = ROOT / "profiles" / "piano.yaml"


def _cand(name: str, removal: float) -> dg.Candidate:
    return dg.Candidate(name, "", {}, {}, {}, removal, {}, 10.0, True)


def test_an_implying_effect_must_beat_the_one_it_implies_on_the_held_out_test() -> None:
    """The public case's numbers: lift-off alone removes 99.3 %, the misread (lift-off plus
    a false rotation) 99.5 %, 27 % of what lift-off leaves -- above ``min_gain``, but the
    held-out test of the misread against lift-off alone gives p = 0.19: the simpler
    explanation goes first. With a small p the misread keeps its place."""
    implies = {"key_encoder_misread": ("key_liftoff",)}
    asked: list[tuple[str, str]] = []

    def p_of(p: float):  # noqa: ANN202 - a test double of search.held_out_p
        def better(a: dg.Candidate, b: dg.Candidate) -> float:
            asked.append((a.name, b.name))
            return p
        return better

    cands = [_cand("key_encoder_misread", 0.99519), _cand("key_liftoff", 0.99340),
             _cand("backcheck_law", 0.084)]
    out = dg.rank(cands, implies, 0.2, p_of(0.19), 0.05 / 8)
    assert [c.name for c in out] == ["key_liftoff", "key_encoder_misread", "backcheck_law"]
    assert asked == [("key_encoder_misread", "key_liftoff")]
    assert "could be noise (held-out p = 0.19 > 0.0063)" in out[1].note
    cands = [_cand("key_encoder_misread", 0.99519), _cand("key_liftoff", 0.99340)]
    out = dg.rank(cands, implies, 0.2, p_of(1e-6), 0.05 / 8)
    assert [c.name for c in out] == ["key_encoder_misread", "key_liftoff"]
    assert "could be noise" not in out[0].note
    # below min_gain the test is not asked: the tie goes to the simpler one as before
    asked.clear()
    cands = [_cand("key_encoder_misread", 0.4965), _cand("key_liftoff", 0.4960)]
    out = dg.rank(cands, implies, 0.2, p_of(0.0), 0.05)
    assert [c.name for c in out] == ["key_liftoff", "key_encoder_misread"] and not asked


@pytest.mark.slow
def test_the_public_liftoff_case_names_liftoff_alone(tmp_path: Path) -> None:
    """`rig synth --model truth.yaml --profile profiles/forte.yaml` with
    `effects: [key_liftoff]` (seed 0, the profile's duration), then diagnose against
    `effects: []`: lift-off alone, not the key encoder's misread (which it named before,
    sensitivity -0.54 rad/m, a sensor fault that is not there)."""
    path = tmp_path / "data.h5"
    synth.synth(ActionModel(effects=["key_liftoff"]), [profiles.load(FORTE)], path, seed=0)
    d = dg.diagnose(ActionModel(), ms.load(path), jobs=2)
    assert d.chosen_names == ["key_liftoff"], "\n".join(d.report_lines())
    f = d.final
    assert f is not None
    assert abs(f.values["key_liftoff.damping"] - 100.0) <= 1.96 * f.sigma["key_liftoff.damping"]


def _blow_meas(peak: float, label: str) -> ms.Measurement:
    rate = 2000.0
    t = np.arange(0, 0.6, 1 / rate)
    f = np.interp(t, [0, 0.02, 0.1, 0.3, 0.34, 0.6], [0, 0, peak, peak, 0, 0])
    f = f + 0.05 * np.random.default_rng(len(label)).standard_normal(t.size)
    return ms.Measurement(t, {"time": t, "force": f, "hammer_angle": 0 * t},
                          {"force": "N", "hammer_angle": "rad"}, label=label)


def test_held_out_trials_are_another_blow_when_the_run_has_several() -> None:
    """Two repeats each of a 30 N and a 1.2 N blow: the blows are told apart by their force
    (peak and impulse), and the held-out trials are the other blow's, not repeats of the
    training blow; the strongest blow is fitted on whatever its place in the run, and a
    held-out blow lies between fitted ones where there are three; one blow repeated:
    alternate trials as before."""
    meas = [_blow_meas(30, "f0"), _blow_meas(30, "f1"), _blow_meas(1.2, "p0"),
            _blow_meas(1.2, "p1")]
    assert ft.blows(meas) == [0, 0, 1, 1]
    data = ft.Data.build(meas, "force", 0.3, ["hammer_angle"])
    assert ft.held_out_trials(data) == [2, 3]
    train, test = ft.split_masks(data)
    assert [bool(m.all()) for m in train] == [True, True, False, False]
    assert [bool(m.all()) for m in test] == [False, False, True, True]
    # the gentle blow first: still the strong one fitted on
    first_gentle = [meas[2], meas[3], meas[0], meas[1]]
    assert ft.held_out_trials(ft.Data.build(first_gentle, "force", 0.3,
                                            ["hammer_angle"])) == [0, 1]
    # three blows, interleaved: ranked by force, every other one held out, so the 18 N
    # blow between the 30 N and the 1.2 N ones is held out (fitted on both ends)
    meas2 = [meas[0], meas[2], meas[1], meas[3], _blow_meas(18, "m")]
    assert ft.blows(meas2) == [0, 1, 0, 1, 2]
    assert ft.held_out_trials(ft.Data.build(meas2, "force", 0.3, ["hammer_angle"])) == [4]
    meas3 = [_blow_meas(1.2, "p"), _blow_meas(18, "m"), _blow_meas(30, "f")]
    assert ft.held_out_trials(ft.Data.build(meas3, "force", 0.3, ["hammer_angle"])) == [1]
    # whatever order the trials were recorded in, the same blows are held out
    for order in itertools.permutations(range(5)):
        shuffled = [meas2[i] for i in order]
        held = ft.held_out_trials(ft.Data.build(shuffled, "force", 0.3, ["hammer_angle"]))
        assert {shuffled[i].label for i in held} == {"m"}, order
    # one blow repeated: alternate trials
    same = [_blow_meas(30, f"f{i}") for i in range(4)]
    assert ft.held_out_trials(ft.Data.build(same, "force", 0.3, ["hammer_angle"])) == [1, 3]


@pytest.fixture(scope="module")
def forte_and_piano(tmp_path_factory: pytest.TempPathFactory) -> list[ms.Measurement]:
    """The base model's own blows, forte then piano (0.15 s, seed 5)."""
    path = tmp_path_factory.mktemp("fp") / "fp.h5"
    synth.synth(ActionModel(), [profiles.load(FORTE), profiles.load(PIANO)], path, seed=5,
                duration=0.15)
    return ms.load(path)


def test_a_written_model_worse_than_the_base_on_held_out_blows_is_measured_so(
        forte_and_piano: list[ms.Measurement], tmp_path: Path) -> None:
    """``check.written_removal`` scores the set at its values as written (rounded to their
    uncertainty) on the held-out blow: lift-off with a stiff pin friction (10 N) on data
    with no lift-off predicts the piano blow worse than the base model; at its off values
    (no friction, the data's own damping) it changes almost nothing."""
    data = ft.Data.build(forte_and_piano, "force", 0.15, None)
    train_m, test_m = ft.split_masks(data)
    test = data.subset(test_m)
    base = ft.rebuild(ActionModel(), rate=forte_and_piano[0].rate)
    base_ms = {c: v[0] for c, v in test.channel_ms(test.simulate(base)).items()}
    by_name = {"key_liftoff": BUILTIN["key_liftoff"]}

    def cand(friction: float, sigma: float) -> dg.Candidate:
        vals = {"key_liftoff.damping": 100.0, "key_liftoff.pin_friction": friction}
        return dg.Candidate("key_liftoff", "", vals, {k: sigma for k in vals}, {}, 0.5, {},
                            10.0, True, effects=("key_liftoff",))

    bad = written_removal(cand(10.0, 0.01), base, by_name, test, base_ms)
    assert bad is not None and bad < -0.5
    # the values checked are those write_model writes
    c = cand(9.7312, 0.04)
    out = dg.write_model(None, c, tmp_path / "w.yaml")
    effects = yaml.safe_load(out.read_text())["effects"]
    assert {f"key_liftoff.{k}": v for k, v in effects[-1]["key_liftoff"].items()} \
        == written_values(c)
    assert written_values(c)["key_liftoff.pin_friction"] != c.values["key_liftoff.pin_friction"]


def test_a_written_set_worse_on_one_trial_of_the_run_is_found(tmp_path: Path) -> None:
    """``check.worse_trial``: a string of 2e4 N/m hidden, a 20 N blow (fitted on) and a
    1.5 N piano blow that never reaches the string (held out). The string at its true
    stiffness, or stiffer (nearer the base), predicts no trial worse than the base model; a
    string four times too soft makes the 20 N blow worse, significantly, and leaves the
    piano blow as it was."""
    from rig.analysis.diagnose.check import worse_trial

    strong = profiles.from_points([[0, 0], [0.02, 0], [0.1, 20], [0.3, 20]], name="20 N")
    piano = profiles.from_points([[0, 0], [0.02, 0], [0.1, 1.5], [0.3, 1.5]], name="piano")
    path = tmp_path / "string.h5"
    synth.synth(ActionModel(effects=[{"compliant_string": {"stiffness": 2e4}}]),
                [strong, piano], path, seed=5, duration=0.15)
    meas = ms.load(path)
    data = ft.Data.build(meas, "force", 0.15, None, align_s=5e-4)
    assert ft.held_out_trials(data) == [1]
    base = ft.rebuild(ActionModel(), rate=meas[0].rate)
    by_name = {"compliant_string": BUILTIN["compliant_string"]}

    def string(stiffness: float) -> dg.Candidate:
        v = {"compliant_string.stiffness": stiffness}
        return dg.Candidate("compliant_string", "", v, {k: 1e-9 for k in v}, {}, 0.5, {},
                            10.0, True, effects=("compliant_string",))

    assert worse_trial(string(2e4), base, by_name, data, [1], 0.05) is None
    assert worse_trial(string(1e5), base, by_name, data, [1], 0.05) is None
    bad = worse_trial(string(5e3), base, by_name, data, [1], 0.05)
    assert bad is not None and bad.index == 0 and not bad.held_out, bad
    assert bad.label == meas[0].label and bad.removal < -0.3 and bad.p_value < 1e-6, bad


@pytest.mark.slow
def test_a_chosen_set_worse_on_held_out_blows_is_not_claimed_nor_written(tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A set whose final values (after the final refits: here forced to a drive delay of
    30 ms, as a final refit landing in a wrong basin would) predict the held-out blow worse
    than the base model: the diagnosis withdraws it (nothing chosen, the verdict says so)
    and ``write_model`` refuses. The data hold a drive of 3 ms, 120 Hz (a forte and a 24 N
    blow, 0.15 s, seed 5), which the round finds; unpatched, it is chosen."""
    path = tmp_path / "drive.h5"
    softer = profiles.from_points([[0, 0], [0.02, 0], [0.1, 24], [0.3, 24]], name="24 N")
    synth.synth(ActionModel(effects=[{"drive_dynamics": {"delay": 0.003, "bandwidth": 120}}]),
                [profiles.load(FORTE), softer], path, seed=5, duration=0.15)
    meas = ms.load(path)
    real = dg._add_input_noise

    def bad_final(final: dg.Candidate, *a: object, **k: object) -> None:
        real(final, *a, **k)  # type: ignore[arg-type]
        final.values["drive_dynamics.delay"] = 0.03

    monkeypatch.setattr(dg, "_add_input_noise", bad_final)
    monkeypatch.setattr(dg, "VALLEY_STARTS", ())  # no restarts: quicker, same first round
    d = dg.diagnose(ActionModel(), meas, duration=0.15, candidates=["drive_dynamics"], jobs=2)
    text = "\n".join(d.report_lines())
    assert [c.name for c in d.withdrawn] == ["drive_dynamics"], text
    assert d.chosen_names == [] and d.best is None, text
    assert d.written_removal is not None and d.written_removal < 0, text
    assert d.verdict().startswith("no effect is claimed: drive_dynamics"), text
    with pytest.raises(InputError, match="nothing to write"):
        dg.write_model(None, d, tmp_path / "out.yaml")
    monkeypatch.setattr(dg, "_add_input_noise", real)
    d = dg.diagnose(ActionModel(), meas, duration=0.15, candidates=["drive_dynamics"], jobs=2)
    assert d.chosen_names == ["drive_dynamics"] and not d.withdrawn, "\n".join(d.report_lines())
    assert d.written_removal is not None and d.written_removal > 0.5
    assert d.worse_trial is None and d.as_dict()["worse_trial"] is None
    # better on the held-out blow, but one trial of the run (check.worse_trial, tested on
    # its own above) worse: withdrawn too, the verdict names the trial
    seen: list[list[int]] = []

    def one_worse(final: dg.Candidate, base: ActionModel, by_name: object, data: ft.Data,
                  held_out: list[int], alpha: float, noise: bool = True) -> dg.WorseTrial:
        seen.append(list(held_out))
        return dg.WorseTrial(0, data.measurements[0].label, -0.4, 1e-9, 0 in held_out)

    monkeypatch.setattr(dg, "worse_trial", one_worse)
    d = dg.diagnose(ActionModel(), meas, duration=0.15, candidates=["drive_dynamics"], jobs=2)
    text = "\n".join(d.report_lines())
    assert seen == [[1]] and d.chosen_names == [] and d.written_removal is not None \
        and d.written_removal > 0.5, text
    assert [c.name for c in d.withdrawn] == ["drive_dynamics"], text
    assert d.verdict().startswith("no effect is claimed: drive_dynamics"), text
    assert f"predicts {meas[0].label} (a training trial) worse than the base model (40 % " \
        "more error there, p = 1e-09" in d.verdict(), text
    assert d.as_dict()["worse_trial"] == {"index": 0, "label": meas[0].label, "removal": -0.4,
                                          "p_value": 1e-9, "held_out": False}
    with pytest.raises(InputError, match="nothing to write"):
        dg.write_model(None, d, tmp_path / "out.yaml")


FRICTION = '''
import numpy as np
from rig.model.effects import Effect, EffectParameter, Signature


class KeyFrontFriction(Effect):
    name = "key_front_friction"
    summary = "Coulomb friction at the key front (a rubbing guide pin)"
    parameters = (EffectParameter("force", "N", 0.5, (0.0, 5.0), True, "friction force"),)
    signature = Signature(("key_angle", "key_dip"), ("key descent",), "shape")

    def generalized_force(self, t, q, qd):
        f = np.zeros(9)
        f[0] = -self.values["force"] * 0.2278 * np.tanh(qd[0] / 0.05)  # key top at 0.2278 m
        return f
'''


@pytest.mark.slow
def test_friction_outside_the_library_is_credited_to_no_library_effect(tmp_path: Path) -> None:
    """Physics outside the library: 0.5 N of Coulomb friction at the key front (a user
    effect, not a candidate), a forte and a piano blow (0.3 s, seed 7), the piano blow held
    out. No library effect is claimed (a drive's lag or the felt's hysteresis take some of
    a friction's delay on one blow, not on the other); the verdict says the residual stands
    above its floor, where, and to write the physics as a user effect. (On a forte and a
    24 N blow, whose frictional delays are alike, drive_dynamics is still claimed: issue
    39, not done.)"""
    (tmp_path / "friction.py").write_text(FRICTION)
    eff = make(f"{tmp_path / 'friction.py'}:KeyFrontFriction", tmp_path)
    path = tmp_path / "friction.h5"
    synth.synth(ActionModel(effects=[eff]), [profiles.load(FORTE), profiles.load(PIANO)],
                path, seed=7, duration=0.3)
    d = dg.diagnose(ActionModel(), ms.load(path), duration=0.3, jobs=2)
    text = "\n".join(d.report_lines())
    assert d.chosen_names == [] and d.best is None, text
    assert d.verdict().startswith("no library effect explains the residual"), text
    assert "user effect" in d.verdict()
