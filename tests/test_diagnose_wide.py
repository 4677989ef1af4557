"""The wide diagnosis benchmark (issue 39): its draws stay in their documented ranges and
are the same for a seed every time; the user effects it hides outside the library load,
change a blow measurably and are never candidates; its scorer scores hand-made diagnoses
as the issue's acceptance list says; the written-model check tells better from worse; one
seed end to end (slow)."""

from __future__ import annotations

import json
import math
import sys
import tempfile
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest

from rig.analysis import diagnose as dg
from rig.analysis import fit as ft
from rig.analysis import measurement as ms
from rig.analysis import synth
from rig.analysis.diagnose import search
from rig.inputs import profiles
from rig.model.action import ActionModel
from rig.model.effects import BUILTIN

ROOT = Path(__file__).parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import diagnose_wide as wide  # noqa: E402
from user_effects.outside import FAMILY  # noqa: E402

DEV = range(0, 300)  # development seeds only: the reserved ones are not drawn here
FORTE = ROOT / "profiles" / "forte.yaml"


def test_draws_are_deterministic_per_seed() -> None:
    for seed in (0, 7, 123, 999):
        assert asdict(wide.draw(seed)) == asdict(wide.draw(seed))
    assert asdict(wide.draw(1)) != asdict(wide.draw(2))


def _blow_in_range(b: wide.Blow) -> None:
    t = [p[0] for p in b.points]
    f = [p[1] for p in b.points]
    assert t[:2] == [0.0, 0.02] and f[:2] == [0.0, 0.0] and f[-1] == 0.0
    assert all(b > a for a, b in zip(t[1:], t[2:], strict=False)), b
    if b.kind == "piano":
        assert 1.5 <= b.peak <= 5.0
    elif b.kind == "held":
        assert 5.0 <= b.peak <= 40.0
        assert 0.15 <= t[3] - t[2] <= 0.3  # its hold
    else:
        assert b.kind in ("staccato", "repeated") and 8.0 <= b.peak <= 40.0
    if b.kind == "staccato":
        assert t[3] - t[2] <= 0.03
    if b.kind == "repeated":
        assert f[4] == f[5] and 0.1 * f[3] <= f[4] <= 0.5 * f[3]  # the partial release
        assert f[6] == f[7] >= 8.0


def test_draws_stay_in_their_documented_ranges() -> None:
    pool = set(wide.library_pool())
    assert "fingertip" not in pool and "key_liftoff" in pool
    kinds, n_hidden, windows, users, based = set(), [], [], 0, 0
    for seed in DEV:
        d = wide.draw(seed)
        assert 2 <= len(d.blows) <= 3 and len(d.held_out) == wide.HELD_OUT_BLOWS
        for b in d.blows + d.held_out:
            _blow_in_range(b)
            kinds.add(b.kind)
        assert d.window is None or 0.1 <= d.window <= 0.4
        windows.append(d.window)
        assert 0.5 <= d.noise <= 2.5
        assert set(d.hidden) <= pool and len(d.hidden) <= 3
        assert not {"key_liftoff", "key_encoder_misread"} <= set(d.hidden)
        n_hidden.append(len(d.hidden))
        for name, values in d.hidden.items():
            specs = {p.name: p for p in BUILTIN[name].parameters}
            assert set(values) == {p for p, s in specs.items() if s.fitted}
            for p, v in values.items():
                s = specs[p]
                assert s.bounds[0] <= v <= s.bounds[1]
                if name == "load_cell_filter":
                    assert 40.0 <= v <= 250.0 and d.filter_hz == v
                elif s.off is not None and s.off != 0:
                    assert 0.4 <= v / s.off <= 0.75 or 1.35 <= v / s.off <= 2.5, (name, p)
                elif s.default > 0:
                    assert s.default / 3 * (1 - 1e-12) <= v <= s.default * 3 * (1 + 1e-12)
                else:
                    assert 0.05 * s.bounds[1] <= v <= 0.3 * s.bounds[1]
        if "load_cell_filter" not in d.hidden:
            assert d.filter_hz is None
        if d.base:
            based += 1
            assert 2 <= len(d.base) <= 5 and set(d.base) <= set(wide.BASE_PARAMS)
            assert all(0.01 <= abs(f - 1) <= 0.06 for f in d.base.values())
        if d.user is not None:
            users += 1
            _, _, lo, hi = FAMILY[d.user[0]]
            assert lo <= d.user[1] <= hi
    n = len(DEV)
    assert kinds == set(wide.BLOW_KINDS)
    assert set(n_hidden) == {0, 1, 2, 3}
    # the shares the docstring states, within what 300 draws allow (binomial, > 4 sigma)
    assert abs(based / n - wide.P_BASE_OFF) < 0.1
    assert abs(users / n - wide.P_USER) < 0.1
    assert abs(sum(w is None for w in windows) / n - wide.P_DEFAULT_WINDOW) < 0.1


def test_base_offsets_reach_the_truth_model() -> None:
    d = next(wide.draw(s) for s in DEV if wide.draw(s).base)
    truth = wide.truth_model(d)
    base = ActionModel()
    for name, factor in d.base.items():
        for path in wide.BASE_PARAMS[name]:
            assert truth.params.get(path) == pytest.approx(base.params.get(path) * factor)


def test_reserved_seeds_get_a_banner() -> None:
    assert wide.reserved_banner(range(0, 1000)) == ""
    assert "RESERVED seeds 1000-1399, 5000-5199" in wide.reserved_banner(range(990, 1001))
    assert "(1 of them here)" in wide.reserved_banner(range(990, 1001))
    assert wide.reserved_banner(range(1400, 5000)) == ""
    assert wide.reserved_banner(range(5200, 5300)) == ""
    assert "RESERVED" in wide.reserved_banner([1250])
    assert "RESERVED" in wide.reserved_banner([1150])
    assert "(2 of them here)" in wide.reserved_banner([4999, 5000, 5199, 5200])


@pytest.fixture(scope="module")
def angle_noise() -> float:
    """The simulated rig's noise on the key and hammer angles (rad), from a synthesized
    run (ft.Data's noise estimate)."""
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "base.h5"
        synth.synth(ActionModel(), [profiles.load(FORTE)], run, seed=1, duration=0.15)
        data = ft.Data.build(ms.load(run), "force", 0.15, None)
    return max(data.noise[0]["key_angle"], data.noise[0]["hammer_angle"])


@pytest.mark.parametrize("name", sorted(FAMILY))
def test_user_effects_load_act_and_are_not_candidates(name: str, angle_noise: float) -> None:
    cls, par, lo, _ = FAMILY[name]
    spec = f"{ROOT / 'tests' / 'user_effects' / 'outside.py'}:{cls.__name__}"
    model = ActionModel(effects=[{spec: {par: lo}}])  # as a user names it, from its file
    assert model.effect_names == [name] and model.effects[0].values[par] == lo
    prof = profiles.load(FORTE)
    res, ref = model.simulate(prof, 0.15), ActionModel().simulate(prof, 0.15)
    assert res.success, res.message
    moved = max(float(np.max(np.abs(res.channels[c] - ref.channels[c])))
                for c in ("key_angle", "hammer_angle"))
    assert moved > 5 * angle_noise, f"{name} at {lo}: {moved:.2g} rad"  # even at its least
    assert name not in BUILTIN
    assert name not in {c.name for c in dg.candidates_for(ActionModel())}


def _draw(hidden: dict, base: dict | None = None, user: tuple | None = None) -> wide.Draw:
    blow = wide.Blow("held", [(0.0, 0.0), (0.02, 0.0), (0.1, 20.0), (0.3, 20.0)])
    return wide.Draw(0, [blow, blow], [blow, blow], 0.15, 1.0, hidden,
                     hidden.get("load_cell_filter", {}).get("cutoff"), base or {}, user)


def test_scorer_exact_set_and_top1() -> None:
    d = _draw({"key_liftoff": {"damping": 50.0, "pin_friction": 0.5},
               "compliant_string": {"stiffness": 3e4}})
    s = wide.score(d, ["compliant_string", "key_liftoff"], {}, {})
    assert s.exact and s.top1 and s.alarm is None and s.outside_credit is None
    s = wide.score(d, ["key_liftoff"], {}, {})
    assert not s.exact and s.top1 and s.misses == ["missed compliant_string"]
    s = wide.score(d, ["felt_hysteresis", "key_liftoff", "compliant_string"], {}, {})
    assert not s.exact and not s.top1 and s.misses == ["extra felt_hysteresis"]
    assert not wide.score(d, [], {}, {}).top1
    # the issue's simplest case: lift-off hidden, the encoder misread (which implies it) named
    one = _draw({"key_liftoff": {"damping": 50.0, "pin_friction": 0.0}})
    s = wide.score(one, ["key_encoder_misread"], {}, {})
    assert not s.exact and not s.top1 and s.misses == ["extra key_encoder_misread"]
    # the misread hidden: named with or without the lift-off it implies, it is exact
    mis = _draw({"key_encoder_misread": {"sensitivity": 60.0}})
    assert wide.score(mis, ["key_encoder_misread"], {}, {}).exact
    assert wide.score(mis, ["key_liftoff", "key_encoder_misread"], {}, {}).exact
    assert not wide.score(mis, ["key_liftoff"], {}, {}).exact


def test_scorer_counts_an_exact_trade_the_diagnosis_states() -> None:
    d = _draw({"drive_dynamics": {"delay": 0.008, "bandwidth": 60.0},
               "load_cell_filter": {"cutoff": 120.0}})
    s = wide.score(d, ["drive_dynamics"], {}, {}, ["load_cell_filter"])
    assert not s.exact and s.exact_stated and s.misses == ["missed load_cell_filter"]
    assert not wide.score(d, ["drive_dynamics"], {}, {}).exact_stated  # no trade stated
    assert wide.score(d, ["drive_dynamics", "load_cell_filter"], {}, {}).exact_stated
    # the drive alone hidden: right with or without the stated trade
    lone = _draw({"drive_dynamics": {"delay": 0.008, "bandwidth": 60.0}})
    s = wide.score(lone, ["drive_dynamics"], {}, {}, ["load_cell_filter"])
    assert s.exact and s.exact_stated
    # a stated trade does not excuse another miss
    three = _draw({"drive_dynamics": {"delay": 0.008, "bandwidth": 60.0},
                   "load_cell_filter": {"cutoff": 120.0},
                   "compliant_string": {"stiffness": 3e4}})
    assert not wide.score(three, ["drive_dynamics"], {}, {}, ["load_cell_filter"]).exact_stated
    scores = [wide.score(d, ["drive_dynamics"], {}, {}, ["load_cell_filter"]),
              wide.score(three, ["drive_dynamics"], {}, {}, ["load_cell_filter"])]
    got = wide.summarize(scores)
    assert got["exact"] == (0, 2) and got["exact_stated"] == (1, 2)
    assert ("exact up to an exact trade the diagnosis states (Diagnosis.trades): 1/2"
            in wide.table(got))


def test_scorer_base_parameters_are_nuisance_unless_named_wrongly() -> None:
    d = _draw({}, base={"bodies.hammer_head.mass": 1.05, "springs.jack_torque": 0.98})
    s = wide.score(d, [], {}, {})
    assert s.exact and s.alarm is False and s.top1 is None
    s = wide.score(d, ["base:bodies.hammer_head.mass"], {}, {})
    assert s.exact and s.alarm is False
    s = wide.score(d, ["bodies.key.mass"], {}, {})  # a parameter that is not off
    assert not s.exact and s.alarm is True and s.misses == ["extra bodies.key.mass"]
    s = wide.score(d, ["drive_dynamics"], {}, {})
    assert not s.exact and s.alarm is True
    # a right base claim first counts for top-1 where an effect is hidden
    h = _draw({"flexible_shank": {"E": 2e10, "damping_ratio": 0.01}},
              base={"bodies.hammer_head.mass": 1.05})
    assert wide.score(h, ["hammer_head.mass", "flexible_shank"], {}, {}).top1


def test_scorer_outside_library_credit() -> None:
    d = _draw({}, user=("key_front_friction", 0.5))
    s = wide.score(d, ["felt_hysteresis", "drive_dynamics"], {}, {})
    assert s.outside_credit and not s.exact and s.alarm is None and s.user == \
        "key_front_friction"
    s = wide.score(d, [], {}, {})
    assert s.outside_credit is False and s.exact
    both = _draw({"compliant_string": {"stiffness": 3e4}}, user=("hammer_air_drag", 1e-5))
    assert wide.score(both, ["compliant_string"], {}, {}).outside_credit is False
    assert wide.score(both, ["compliant_string", "backcheck_law"], {}, {}).outside_credit


def test_scorer_coverage() -> None:
    d = _draw({"key_liftoff": {"damping": 50.0, "pin_friction": 0.5},
               "load_cell_filter": {"cutoff": 120.0}})
    values = {"key_liftoff.damping": 53.0, "key_liftoff.pin_friction": 0.9,
              "load_cell_filter.cutoff": 500.0}
    sigma = {"key_liftoff.damping": 2.0, "key_liftoff.pin_friction": 0.1,
             "load_cell_filter.cutoff": 1.0}
    s = wide.score(d, ["key_liftoff", "load_cell_filter"], values, sigma)
    # damping within 1.96 sigma, pin friction 4 sigma off; the sensor-side filter not
    # counted (the synthesized rig's filter is not the effect's model)
    assert (s.covered, s.checked) == (1, 2)
    # an effect chosen wrongly has no truth to cover
    s = wide.score(d, ["compliant_string"], {"compliant_string.stiffness": 1e4},
                   {"compliant_string.stiffness": 1.0})
    assert (s.covered, s.checked) == (0, 0)
    # a missing sigma does not cover
    s = wide.score(d, ["key_liftoff"], {"key_liftoff.damping": 50.0}, {})
    assert (s.covered, s.checked) == (0, 1)


def test_summary_counts_each_figure_over_the_seeds_it_applies_to() -> None:
    lift = _draw({"key_liftoff": {"damping": 50.0, "pin_friction": 0.5}})
    none = _draw({})
    user = _draw({}, user=("key_lead_mass", 0.01))
    scores = [wide.score(lift, ["key_liftoff"], {"key_liftoff.damping": 50.5},
                         {"key_liftoff.damping": 1.0}),
              wide.score(lift, ["key_encoder_misread"], {}, {}),
              wide.score(none, ["drive_dynamics"], {}, {}),
              wide.score(none, [], {}, {}),
              wide.score(user, ["felt_hysteresis"], {}, {})]
    for s, sec, worse in zip(scores, (10.0, 30.0, 20.0, 50.0, 40.0),
                             (False, True, None, None, None), strict=True):
        s.seconds, s.written_worse = sec, worse
    got = wide.summarize(scores)
    assert got["exact"] == (2, 5) and got["top1"] == (1, 2)
    assert got["false_alarm"] == (1, 2) and got["outside_credit"] == (1, 1)
    assert got["cover95"] == (1, 1) and got["written_worse"] == (1, 2)
    assert got["median_s"] == 30.0
    assert got["exact_by_hidden"] == {"0": (1, 3), "1": (1, 2), "2": (0, 0), "3": (0, 0)}
    assert got["exact_where_shown"] == (0, 0)
    scores[0].shown, scores[1].shown = True, True
    got = wide.summarize(scores)
    assert got["exact_where_shown"] == (1, 2)
    lines = wide.table(got)
    assert any(line.startswith("exact") and "2/5" in line and "0.40" in line
               for line in lines)
    assert lines[-1] == "exact by hidden library effects: 0: 1/3, 1: 1/2, 2: 0/0, 3: 0/0"
    assert lines[-2] == ("exact where the run shows the hidden set on both sides (oracle): 1/2 "
                         "(of 2 seeds with a hidden library effect)")
    assert got["shown_calibrated"] is None  # no seed has the calibrated oracle (older files)
    # the first lost by the calibration, the second shown only once calibrated
    scores[1].shown = False
    scores[0].shown_calibrated, scores[1].shown_calibrated = False, True
    got = wide.summarize(scores)
    assert got["shown_calibrated"] == (1, 1)
    assert wide.table(got)[-2] == ("shown with the base calibrated jointly on the training "
                                   "trials (oracle): 1 of 2 (1 not shown uncalibrated)")
    assert got["timing_flags"] is None  # no seed has the timing verdict (older files)
    # the timing verdict on the chosen sets: silent on the exact one, speaking against one
    # of the two wrong ones (nothing chosen: no verdict on a set)
    scores[0].timing, scores[1].timing, scores[2].timing = "", "timing of x: ...", ""
    got = wide.summarize(scores)
    assert got["timing_flags"] == ((0, 1), (1, 2))
    assert wide.table(got)[-2] == ("the timing verdict speaks against the chosen set: 0/1 "
                                   "exact sets, 1/2 others")


def test_written_model_check_tells_better_from_worse(tmp_path: Path) -> None:
    truth = ActionModel(effects=[{"compliant_string": {"stiffness": 2e4}}])
    blows = [profiles.load(FORTE),
             profiles.from_points([[0, 0], [0.02, 0], [0.08, 20], [0.3, 20]], name="20 N")]
    synth.synth(truth, blows, tmp_path / "held.h5", seed=4, duration=0.12)
    meas = ms.load(tmp_path / "held.h5")
    removal, p = wide.written_vs_base(truth, ActionModel(), meas, 0.12)
    assert removal > 0.5 and p > 0.5  # the truth is better than the base: not worse
    removal, p = wide.written_vs_base(ActionModel(), truth, meas, 0.12)
    assert removal < -1.0 and p < 1e-3  # the base written over the truth: worse


def test_the_oracle_says_whether_the_held_out_trials_show_the_hidden_set(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # a soft string hidden; the weaker blow is the held-out one (fit.split_masks):
    # a 20 N blow strikes the string hard, a 1.5 N piano blow never reaches it
    strong = wide.Blow("held", [(0.0, 0.0), (0.02, 0.0), (0.1, 20.0), (0.3, 20.0)])
    piano = wide.Blow("piano", [(0.0, 0.0), (0.02, 0.0), (0.1, 1.5), (0.3, 1.5)])
    string = {"compliant_string": {"stiffness": 2e4}}

    def oracle(blows: list[wide.Blow], hidden: dict, calibrate: bool = False
               ) -> tuple[bool | None, str]:
        d = wide.Draw(0, blows, blows, 0.15, 1.0, hidden, None, {}, None)
        path = tmp_path / f"run{len(list(tmp_path.iterdir()))}.h5"
        wide.synth_run(d, d.blows, path, 3)
        return wide.oracle_shown(d, ms.load(path), calibrate=calibrate)

    shown, why = oracle([strong, strong], string)
    assert shown is True and "removes" in why and "training trials too" in why, why
    # the base calibrated jointly on the training blow for both models: still shown
    shown, why = oracle([strong, strong], string, calibrate=True)
    assert shown is True and "training trials too" in why, why
    shown, why = oracle([strong, piano], string)
    assert shown is False and "of the held-out error" in why and "needs >= 20 %" in why, why
    # the strong blow is fitted on wherever it comes in the run (fit.held_out_trials)
    shown, why = oracle([piano, strong], string)
    assert shown is False and "of the held-out error" in why, why
    # held out the other way round (the split forced): the held-out blow shows it, the
    # training one cannot
    monkeypatch.setattr(ft, "held_out_trials", lambda data: [1])
    shown, why = oracle([piano, strong], string)
    assert shown is False and "of the training error" in why, why
    monkeypatch.undo()
    # a pair whose second effect the held-out trial does not need: not shown
    pair = {**string, "drive_dynamics": {"delay": 1e-5, "bandwidth": 1000.0}}
    shown, why = oracle([strong, strong], pair)
    assert shown is False and "without drive_dynamics" in why, why
    assert oracle([strong, strong], {}) == (None, "")


def test_the_oracle_does_not_count_a_pair_that_trades_exactly_as_shown(
        tmp_path: Path) -> None:
    # the drive's dead time (8 ms) and a 100 Hz load-cell filter, whose advance (4.2 ms)
    # the drive's delay absorbs: at the true values the drive without the filter is far
    # off, refitted it does as well, so the pair is not shown (the drive alone is)
    strong = wide.Blow("held", [(0.0, 0.0), (0.02, 0.0), (0.1, 20.0), (0.3, 20.0)])
    lags = {"drive_dynamics": {"delay": 0.008, "bandwidth": 60.0},
            "load_cell_filter": {"cutoff": 100.0}}

    def oracle(hidden: dict, filter_hz: float | None) -> tuple[bool | None, str]:
        d = wide.Draw(0, [strong, strong], [], 0.15, 1.0, hidden, filter_hz, {}, None)
        path = tmp_path / f"run{len(list(tmp_path.iterdir()))}.h5"
        wide.synth_run(d, d.blows, path, 5)
        return wide.oracle_shown(d, ms.load(path))

    shown, why = oracle(lags, 100.0)
    assert shown is False and "without load_cell_filter, the others refitted" in why, why
    shown, why = oracle({"drive_dynamics": lags["drive_dynamics"]}, None)
    assert shown is True, why


@pytest.mark.slow
def test_a_back_check_shown_by_a_strong_blow_is_fitted_on_it(tmp_path: Path) -> None:
    # a back check off its thesis values (development seed 603's), two 2.6 N piano blows
    # first and a 32 N held blow last: the strong blow is fitted on and the piano blows
    # are held out (fit.held_out_trials), and the back check fitted on the strong blow
    # predicts the piano blows. Fitted on the piano blows (the run's first blow, held out
    # before the blows were ranked by force), it predicted the strong blow worse than the
    # base model and nothing was chosen.
    piano = wide.Blow("piano", [(0.0, 0.0), (0.02, 0.0), (0.12, 2.65), (0.34, 2.65),
                                (0.44, 0.0)])
    held = wide.Blow("held", [(0.0, 0.0), (0.02, 0.0), (0.1, 31.9), (0.3, 31.9),
                              (0.36, 0.0)])
    check = {"backcheck_law": {"stiffness_scale": 0.68, "friction": 0.75, "damping": 1.05}}
    d = wide.Draw(0, [piano, piano, held], [], 0.215, 1.08, check, None, {}, None)
    wide.synth_run(d, d.blows, tmp_path / "run.h5", 603)
    meas = ms.load(tmp_path / "run.h5")
    diag = dg.diagnose(ActionModel(), meas, duration=d.window, jobs=1,
                       candidates=["backcheck_law", "felt_hysteresis", "flexible_shank"])
    assert diag.held_out_trials == [0, 1]
    assert diag.chosen_names == ["backcheck_law"], diag.verdict()
    final = diag.final
    assert final is not None
    assert abs(final.values["backcheck_law.friction"] - 0.75) < 3 * final.sigma[
        "backcheck_law.friction"], final.value_text()


def test_the_joint_calibration_finds_a_heavier_hammer_head(tmp_path: Path) -> None:
    # two 20 N blows of an action whose hammer head is 8 % heavier than the thesis's,
    # nothing hidden: the base-parameter scales fitted jointly find the mass within 2 %
    # and leave the other scales near 1, and the calibrated model fits better
    strong = wide.Blow("held", [(0.0, 0.0), (0.02, 0.0), (0.1, 20.0), (0.3, 20.0)])
    d = wide.Draw(0, [strong, strong], [], 0.15, 1.0, {}, None,
                  {"bodies.hammer_head.mass": 1.08}, None)
    wide.synth_run(d, d.blows, tmp_path / "run.h5", 3)
    data = ft.Data.build(ms.load(tmp_path / "run.h5"), "force", d.window, None, align_s=5e-4)
    base = ft.rebuild(ActionModel(), rate=data.measurements[0].rate)
    model, scales = wide.calibrate_base(base, data)
    assert abs(scales["base:bodies.hammer_head.mass"] - 1.08) < 0.02, scales
    ms0 = np.mean(data.residuals(data.simulate(base)) ** 2)
    ms1 = np.mean(data.residuals(data.simulate(model)) ** 2)
    assert ms1 < 0.2 * ms0, (ms0, ms1)


def test_the_oracle_counts_what_calibration_gains_and_loses() -> None:
    shown, not_shown, nothing = (True, "a"), (False, "b"), (None, "")
    line = wide.oracle_table([(shown, shown), (not_shown, shown), (not_shown, shown),
                              (shown, not_shown), (nothing, nothing)])
    assert line == ("seeds with a hidden library effect: 4; shown: 2; shown with the base "
                    "calibrated jointly: 3 (gained 2, lost 1)")


@pytest.mark.slow
def test_one_seed_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "wide.json"
    wide.main(["--first-seed", "5", "--seeds", "1", "--jobs", "1", "--json", str(out)])
    printed = capsys.readouterr().out
    assert printed.startswith("seed 5: ") and "median_s" in printed
    (rec,) = json.loads(out.read_text())["seeds"]
    assert rec["draw"] == json.loads(json.dumps(asdict(wide.draw(5))))
    s = rec["score"]
    assert s["seed"] == 5 and s["hidden"] == [] and s["user"] is None
    assert s["alarm"] == bool(s["chosen"]) and math.isfinite(s["seconds"])
    assert (s["written_worse"] is None) == (not s["chosen"])


@pytest.mark.slow
def test_the_oracles_alone_print_per_seed_and_count(capsys: pytest.CaptureFixture[str]
                                                    ) -> None:
    # development seed 180: a back check hidden, no base offsets, three strong repeated
    # blows (docs/performance.md: shown both ways)
    wide.main(["--first-seed", "180", "--seeds", "1", "--oracle-only"])
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("seed 180: backcheck_law"), lines
    assert lines[1].startswith("  oracle: shown: the true set removes"), lines
    assert lines[2].startswith("  calibrated: shown: the true set removes"), lines
    assert lines[3] == ("seeds with a hidden library effect: 1; shown: 1; shown with the base "
                        "calibrated jointly: 1 (gained 0, lost 0)"), lines


@pytest.mark.slow
def test_the_back_checks_friction_scan_finds_its_narrow_well(tmp_path: Path) -> None:
    # development seed 1538's run: a back check (friction 0.248, stiffness scale 2.02) and
    # the load cell's filter (45.9 Hz) hidden, two held blows. With the filter at its truth,
    # the back check fitted from a 4-point scan of each parameter, the stiffness first,
    # went to a scale of 9.8 and a friction of 0.95, 15 times the truth's training cost:
    # the friction's well is a few hundredths wide. Its SCAN points, scanned first
    # (fit.scan_order), land in it: within 3 times the truth's cost after the 10
    # evaluations (1.6 times with the damping scanned linearly, whose scan then kept the
    # default 2.45 s/m; 2.1 times with it scanned over decades, from 2.85 s/m: truth 1.34).
    from rig.model.effects import BACKCHECK_FRICTION_SCAN

    d = wide.draw(1538)
    assert sorted(d.hidden) == ["backcheck_law", "load_cell_filter"] and d.user is None
    wide.synth_run(d, d.blows, tmp_path / "run.h5", 1538)
    data = ft.Data.build(ms.load(tmp_path / "run.h5"), "force", d.window, None, align_s=5e-4)
    train = data.subset(ft.split_masks(data)[0])
    model = ft.rebuild(ActionModel(), rate=data.measurements[0].rate)
    law = BUILTIN["backcheck_law"]
    filt = BUILTIN["load_cell_filter"](**d.hidden["load_cell_filter"])
    targets = [ft.target(model, f"backcheck_law.{k}", [filt, law()])
               for k in ("stiffness_scale", "friction", "damping")]
    assert [t.scan for t in targets] == [0, BACKCHECK_FRICTION_SCAN, 0]
    truth = d.hidden["backcheck_law"]
    c_truth = float(np.mean(train.residuals(train.simulate(ft.rebuild(
        model, [filt, law(**truth)], rate=train.measurements[0].rate))) ** 2))
    res = ft.fit(model, train, targets, [filt, law], jobs=1, max_nfev=10, scan=4)
    assert abs(res.values["backcheck_law.friction"] - truth["friction"]) < 0.03, res.values
    assert res.cost < 3 * c_truth, (res.cost, c_truth)
    coarse = ft.fit(model, train, [replace(t, scan=0) for t in targets], [filt, law], jobs=1,
                    max_nfev=10, scan=4)
    assert coarse.cost > 5 * c_truth, (coarse.values, coarse.cost, c_truth)


@pytest.mark.slow
def test_the_back_checks_damping_is_fitted_over_decades(tmp_path: Path) -> None:
    # development seed 1591's run: a back check alone hidden (stiffness scale 2.06,
    # friction 0.197, damping 1.12 s/m), no base offsets, a repeated blow trained on and a
    # staccato held out. The round's fit (a 4-point scan, 16 joint starts, two least-squares
    # runs of 10 evaluations) with the damping linear across 0-50 s/m went to 49 s/m, and
    # the held-out error stayed 15 times the truth's; fitted in log(damping + shift) it
    # stays in the truth's basin.
    d = wide.draw(1591)
    assert list(d.hidden) == ["backcheck_law"] and not d.base and d.user is None
    wide.synth_run(d, d.blows, tmp_path / "run.h5", 1591)
    data = ft.Data.build(ms.load(tmp_path / "run.h5"), "force", d.window, None, align_s=5e-4)
    train_m, test_m = ft.split_masks(data)
    train, test = data.subset(train_m), data.subset(test_m)
    rate = data.measurements[0].rate
    model = ft.rebuild(ActionModel(), rate=rate)
    law = BUILTIN["backcheck_law"]
    targets = [ft.target(model, f"backcheck_law.{k}", [law()])
               for k in ("stiffness_scale", "friction", "damping")]
    assert targets[2].log and targets[2].shift > 0

    def held_out(values: dict[str, float]) -> float:
        own = {k.split(".")[1]: v for k, v in values.items()}
        return float(np.mean(test.residuals(test.simulate(ft.rebuild(
            model, [law(**own)], rate=rate))) ** 2))

    def round_fit(tt: list[ft.Target]) -> ft.FitResult:
        return ft.fit(model, train, tt, [law], jobs=1, max_nfev=10, scan=4,
                      starts=ft.sobol_starts(tt, search.CANDIDATE_SOBOL),
                      multistart=search.CANDIDATE_STARTS)

    truth = held_out({f"backcheck_law.{k}": v for k, v in d.hidden["backcheck_law"].items()})
    res = round_fit(targets)
    assert res.values["backcheck_law.damping"] < 10, res.values
    assert held_out(res.values) < 3 * truth, (res.values, truth)
    linear = round_fit([replace(t, shift=0.0) for t in targets])
    assert linear.values["backcheck_law.damping"] > 30, linear.values
    assert held_out(linear.values) > 8 * truth, (linear.values, truth)


@pytest.mark.slow
def test_the_shank_start_scan_finds_the_ringing_modes_basin(tmp_path: Path) -> None:
    # development seed 619's run: a flexible shank hidden (E = 8.23e9 Pa), base parameters
    # a few per cent off, its repeated and held blows (those diagnose fits on). The strain's
    # ring-down makes the training cost ripple in E (basins ~10 % wide); a round's fit (the
    # diagnosis's 10 evaluations from its start scan) from the 4-point scan's best start,
    # 1.0e10, stopped in the next basin, 9.4e9, and the shank then predicted the held-out
    # blow worse than the rigid one. The shank's E is scanned at SHANK_E_SCAN points.
    d = wide.draw(619)
    assert list(d.hidden) == ["flexible_shank"] and d.user is None
    d = replace(d, blows=d.blows[:2])
    wide.synth_run(d, d.blows, tmp_path / "run.h5", 619)
    data = ft.Data.build(ms.load(tmp_path / "run.h5"), "force", d.window, None, align_s=5e-4)
    model = ft.rebuild(ActionModel(), rate=data.measurements[0].rate)
    shank = BUILTIN["flexible_shank"]
    specs = ["flexible_shank.E", "flexible_shank.damping_ratio"]
    res = ft.fit(model, data, specs, [shank], jobs=1, max_nfev=10, scan=4)
    truth = d.hidden["flexible_shank"]["E"]
    assert abs(res.values["flexible_shank.E"] / truth - 1) < 0.04, res.values
