"""Issue 39: ``min_gain`` is asked of the held-out error above its noise floor.

A candidate must remove at least ``min_gain`` (20 %) of the held-out error the model so
far leaves. Asked of the whole error, that rule refuses a true second effect whenever the
first leaves little more than the floor: on the wide benchmark's development seed 616
(the drive's lag and a string of 1.05e5 N/m hidden, five base parameters off, three
blows), the drive removed 99.9 % and the string then 17.5 % of what was left, most of what
stood above the floor, at p = 1e-14; it was refused for the 20 %. The floor
(``search.floor_ms``) is what the held-out residual holds when the model is right: the
output noise and the input force's noise through the model."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rig.analysis import diagnose as dg
from rig.analysis import fit as ft
from rig.analysis import measurement as ms
from rig.analysis import remainder as rm
from rig.analysis import synth
from rig.analysis.diagnose import search
from rig.analysis.diagnose.search import channel_floor, floor_ms
from rig.inputs import profiles
from rig.model.action import ActionModel

ROOT = Path(__file__).parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import diagnose_wide as wide  # noqa: E402

SEED = 616  # a development seed of benchmarks/diagnose_wide.py (0-999), never a reserved one


def test_the_floor_is_what_the_right_model_leaves(tmp_path: Path) -> None:
    """The truth's own held-out mean square, channel by channel, against the floor computed
    for it: output noise plus the input force's noise through it (an independent answer:
    the synthesized run's noise, seen through the residual of the model that made it)."""
    truth = ActionModel(effects=["compliant_string"])
    path = tmp_path / "run.h5"
    synth.synth(truth, [profiles.load(ROOT / "profiles" / "forte.yaml")] * 2, path, seed=3,
                duration=0.15)
    meas = ms.load(path)
    data = ft.Data.build(meas, "force", 0.15, None, align_s=5e-4)  # as diagnose builds it
    model = ft.rebuild(truth, rate=meas[0].rate)
    _, test_m = ft.split_masks(data)
    test = data.subset(test_m)
    preds = test.simulate(model)
    got = test.channel_ms(preds)
    floor, _ = channel_floor(model, test, test.residuals(preds))
    assert floor is not None and set(floor) == set(got)
    # one realization of correlated noise: a channel's mean square spreads widely about its
    # floor (here 0.61-1.82), the channels' mean less
    ratios = {c: got[c][0] / floor[c] for c in got}
    assert all(0.25 < r < 4.0 for r in ratios.values()), ratios
    whole = np.mean([got[c][0] for c in got]) / np.mean([floor[c] for c in got])
    assert 0.5 < whole < 1.5, (whole, ratios)
    # the output noise alone is a small part of it: the input's noise moves the blow
    out_only = floor_ms(test, test.noise_vector()[None, :])
    assert all(out_only[c] < 0.5 * floor[c] for c in floor), (out_only, floor)
    # and the base model, which lacks the string, stands far above it
    base = ft.rebuild(ActionModel(), rate=meas[0].rate)
    above = test.channel_ms(test.simulate(base))
    assert np.mean([above[c][0] for c in above]) > 10 * np.mean(list(floor.values()))


@pytest.mark.slow
def test_a_second_effect_near_the_floor_is_judged_on_what_stands_above_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    d = wide.draw(SEED)
    assert set(d.hidden) == {"drive_dynamics", "compliant_string"} and d.user is None
    # the split the seed was measured with: every other blow in the order recorded (since
    # then the blows are ranked by force, fit.held_out_trials, and this seed's string
    # removes 27 % of the whole held-out error, over min_gain, with no floor needed)
    monkeypatch.setattr(ft, "held_out_trials", lambda data: [
        i for i, g in enumerate(ft.blows(data.measurements)) if g % 2 == 1])
    # and the one-at-a-time start scan it was measured with: with the joint starts
    # (search.CANDIDATE_SOBOL) round 1 fits the drive closer and the string then removes
    # 23 % of the whole held-out error, over min_gain without the floor (the same set)
    monkeypatch.setattr(search, "CANDIDATE_SOBOL", 0)
    path = tmp_path / "run.h5"
    wide.synth_run(d, d.blows, path, SEED)
    diag = dg.diagnose(ActionModel(), ms.load(path), duration=d.window, jobs=2,
                       candidates=["drive_dynamics", "compliant_string", "flexible_shank",
                                   "backcheck_law"])
    assert diag.chosen_names == ["drive_dynamics", "compliant_string"]
    string = diag.chosen[1]
    # less than min_gain of the whole held-out error, more of what stood above the floor
    assert string.removal < diag.min_gain <= string.floor_removal, (
        string.removal, string.floor_removal)
    assert string.as_dict()["floor_removal"] == string.floor_removal


def _rippled(meas: list[ms.Measurement], amp: float) -> list[ms.Measurement]:
    """``meas`` with a 20 ms sine of ``amp`` rad (one period, 0.10-0.12 s, as the hammer
    nears the string) added to the second trial's hammer angle: a local misfit no model of
    the action makes."""
    second = meas[1]
    t = second.time
    sel = (t > 0.10) & (t < 0.12)
    hammer = second.channels["hammer_angle"].copy()
    hammer[sel] += amp * np.sin(2 * np.pi * (t[sel] - 0.10) / 0.02)
    return [meas[0], replace(second, channels={**second.channels, "hammer_angle": hammer})]


def test_the_search_asks_the_floor_test_the_verdict_gives(tmp_path: Path) -> None:
    """``channel_floor`` with the trials: the p the verdict's "What it leaves" gives
    (remainder.remainder: the whole and each channel in each phase, Bonferroni), which a
    local misfit in a quiet channel cannot hide from; the whole alone loses it in the
    other channels' floor (the pair step asks this p: issue 39, wide seed 1248). On the
    right model's own noise neither says more than noise."""
    truth = ActionModel()
    path = tmp_path / "run.h5"
    synth.synth(truth, [profiles.load(ROOT / "profiles" / "forte.yaml")] * 2, path, seed=3,
                duration=0.15)
    meas = ms.load(path)
    model = ft.rebuild(truth, rate=meas[0].rate)
    got = {}
    for amp in (0.0, 1.5e-3):
        trials = _rippled(meas, amp)
        data = ft.Data.build(trials, "force", 0.15, None, align_s=5e-4)
        test = data.subset(ft.split_masks(data)[1])
        resid = test.residuals(test.simulate(model))
        _, whole = channel_floor(model, test, resid)
        floor, places = channel_floor(model, test, resid, trials, align_s=5e-4)
        left = rm.remainder(model, test, trials, of="truth", align_s=5e-4)
        assert left is not None and floor is not None
        got[amp] = whole, places, left.p
    assert got[0.0][0] > 0.05 and got[0.0][1] > 0.05, got  # noise is noise to both
    whole, places, verdict = got[1.5e-3]
    assert whole > 0.05, got  # lost in the whole
    assert places < 1e-4, got  # found where it is
    assert verdict < 1e-4, got  # and the verdict says the same


def test_a_residual_the_verdict_finds_above_the_floor_opens_the_pair_step(
        tmp_path: Path) -> None:
    """The same ripple in a diagnosis: no candidate explains it, the verdict finds it above
    the floor, and so does the gate of the pair step, which then tries the pair (before,
    the gate asked the whole alone, p = 0.45, and no pair was tried)."""
    path = tmp_path / "run.h5"
    synth.synth(ActionModel(), [profiles.load(ROOT / "profiles" / "forte.yaml")] * 2, path,
                seed=3, duration=0.15)
    trials = _rippled(ms.load(path), 1.5e-3)
    diag = dg.diagnose(ActionModel(), trials, duration=0.15, jobs=1,
                       candidates=["compliant_string", "drive_dynamics"])
    report = "\n".join(diag.report_lines())
    assert diag.chosen_names == [], report
    assert diag.remainder is not None and diag.remainder.significant, report
    assert any("no effect alone was significant and the residual stood above its noise "
               "floor" in n for n in diag.notes), report
