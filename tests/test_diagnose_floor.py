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
from pathlib import Path

import numpy as np
import pytest

from rig.analysis import diagnose as dg
from rig.analysis import fit as ft
from rig.analysis import measurement as ms
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
