"""Issue 39: the held-out test both ways (``core.diagnose``'s contract). With several blows
the usual side (the strongest blow fitted on, the others scored) is searched at
``USUAL_SHARE`` of the level; only when it chooses nothing is the swapped side searched, at
the rest; the swapped side's choice is taken only when its first effect, alone in the
usual side's first round, passes every check there but the level. One blow: one search at
the whole level.

The contract is tested on real synthesized runs with ``_one_way`` replaced by a recorder
(the selector's logic), and the swapped split and the whole path end to end (slow) on a
key lift-off that the usual side's level misses (wide benchmark development seed 1586)."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import pytest

from rig.analysis import diagnose as dg
from rig.analysis import measurement as ms
from rig.analysis import synth
from rig.analysis.diagnose.results import Candidate, Diagnosis
from rig.inputs import profiles
from rig.model.action import ActionModel

ROOT = Path(__file__).parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import diagnose_wide as wide  # noqa: E402

FORTE = ROOT / "profiles" / "forte.yaml"
PIANO = [(0.0, 0.0), (0.02, 0.0), (0.07, 3.0), (0.1, 3.0), (0.13, 0.0)]


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[ms.Measurement]]:
    """Two real runs of the base model: a forte and a piano blow (two blows), and the
    forte blow twice (one blow repeated)."""
    tmp = tmp_path_factory.mktemp("two_ways")
    forte = profiles.load(FORTE)
    piano = profiles.from_points([list(p) for p in PIANO], name="piano")
    out = {}
    for name, blows in (("two", [forte, piano]), ("one", [forte, forte])):
        synth.synth(ActionModel(), blows, tmp / f"{name}.h5", seed=3, duration=0.12)
        out[name] = ms.load(tmp / f"{name}.h5")
    return out


def _candidate(name: str, *, floor_removal: float, p: float, chosen: bool = False
               ) -> Candidate:
    return Candidate(name, "", {f"{name}.damping": 80.0}, {f"{name}.damping": 5.0},
                     {f"{name}.damping": "N s/m"}, floor_removal, {}, 12.0, chosen,
                     p_value=p, train_gain=0.5, floor_removal=floor_removal,
                     effects=(name,) if chosen else ())


def _diagnosis(split: str, candidates: list[Candidate], chosen: list[Candidate],
               wall: float) -> Diagnosis:
    return Diagnosis(None, [], {}, candidates, split, 0.2, 3.0,  # type: ignore[arg-type]
                     wall_s=wall, notes=[f"{split}'s own note"], chosen=chosen)


class Recorder:
    """``_one_way`` replaced: the level and side of each call, and a prepared answer."""

    def __init__(self, usual: Diagnosis, other: Diagnosis) -> None:
        self.answers = {False: usual, True: other}
        self.calls: list[tuple[float, bool]] = []

    def __call__(self, base: ActionModel, meas: Any, *, alpha: float, swapped: bool = False,
                 **kw: Any) -> Diagnosis:
        self.calls.append((alpha, swapped))
        return self.answers[swapped]


def _sides(usual_first: Candidate, usual_chosen: list[Candidate],
           other_chosen: list[Candidate], another_passes: bool = True) -> Recorder:
    """The two sides' answers; with ``another_passes`` the usual side's first round holds
    a second candidate that passes every check but the level (so the swapped side is
    searched whatever ``usual_first`` is)."""
    more = [_candidate("felt_hysteresis", floor_removal=0.5, p=0.2)] if another_passes else []
    return Recorder(_diagnosis("usual", [usual_first, *more], usual_chosen, 30.0),
                    _diagnosis("swapped", [], other_chosen, 20.0))


def _two_blows(rec: Recorder, runs: dict[str, list[ms.Measurement]],
               monkeypatch: pytest.MonkeyPatch) -> Diagnosis:
    """``diagnose`` on the two-blow run at alpha 0.05, the sides answered by ``rec``."""
    monkeypatch.setattr(dg, "_one_way", rec)
    return dg.diagnose(ActionModel(), runs["two"], alpha=0.05)


def test_one_blow_repeated_gets_one_search_at_the_whole_level(
        runs: dict[str, list[ms.Measurement]], monkeypatch: pytest.MonkeyPatch) -> None:
    rec = _sides(_candidate("key_liftoff", floor_removal=0.7, p=0.09), [], [])
    monkeypatch.setattr(dg, "_one_way", rec)
    diag = dg.diagnose(ActionModel(), runs["one"], alpha=0.05)
    assert rec.calls == [(0.05, False)]
    assert diag is rec.answers[False]


def test_a_choice_on_the_usual_side_stands_alone(
        runs: dict[str, list[ms.Measurement]], monkeypatch: pytest.MonkeyPatch) -> None:
    lift = _candidate("key_liftoff", floor_removal=0.7, p=1e-6, chosen=True)
    rec = _sides(lift, [lift], [_candidate("drive_dynamics", floor_removal=0.9, p=0.0,
                                           chosen=True)])
    diag = _two_blows(rec, runs, monkeypatch)
    assert rec.calls == [(pytest.approx(dg.USUAL_SHARE * 0.05), False)]
    assert diag.chosen_names == ["key_liftoff"]


def test_a_set_the_usual_side_withdrew_is_not_searched_again(
        runs: dict[str, list[ms.Measurement]], monkeypatch: pytest.MonkeyPatch) -> None:
    lift = _candidate("key_liftoff", floor_removal=0.7, p=1e-6, chosen=True)
    rec = _sides(lift, [], [_candidate("key_liftoff", floor_removal=0.9, p=0.0, chosen=True)])
    rec.answers[False].withdrawn = [lift]  # its written model failed the held-out check
    diag = _two_blows(rec, runs, monkeypatch)
    assert len(rec.calls) == 1 and diag.chosen == [] and diag.withdrawn == [lift]


def test_the_swapped_side_lends_the_level_when_the_usual_side_fails_only_the_level(
        runs: dict[str, list[ms.Measurement]], monkeypatch: pytest.MonkeyPatch) -> None:
    # lift-off removes 70 % of the usual side's error above its floor at p = 0.09: every
    # check but the level passes there
    rec = _sides(_candidate("key_liftoff", floor_removal=0.7, p=0.09), [],
                 [_candidate("key_liftoff", floor_removal=0.95, p=1e-9, chosen=True)])
    diag = _two_blows(rec, runs, monkeypatch)
    assert rec.calls == [(pytest.approx(0.04), False), (pytest.approx(0.01), True)]
    assert diag.chosen_names == ["key_liftoff"] and diag.split == "swapped"
    assert diag.wall_s == 50.0  # both sides' time
    assert diag.notes[0].startswith("two ways: the usual side (usual; at 0.8 of the level, "
                                    "0.04) chose nothing; key_liftoff alone there passes")
    assert "removes 70 % of its held-out error, p = 0.09" in diag.notes[0]
    assert diag.notes[1] == "swapped's own note"


def test_the_swapped_side_does_not_lend_the_size(
        runs: dict[str, list[ms.Measurement]], monkeypatch: pytest.MonkeyPatch) -> None:
    # 16 % of the usual side's error above its floor: short of min_gain (20 %) whatever
    # the level; the usual side's empty result stands, saying what the other side chose
    rec = _sides(_candidate("backcheck_law", floor_removal=0.16, p=0.2), [],
                 [_candidate("backcheck_law", floor_removal=0.6, p=1e-5, chosen=True)])
    diag = _two_blows(rec, runs, monkeypatch)
    assert len(rec.calls) == 2
    assert diag.chosen == [] and diag.split == "usual" and diag.wall_s == 50.0
    assert diag.notes[-1] == (
        "the held-out test the other way round (swapped; at 0.2 of the level, 0.01) chose "
        "backcheck_law; not taken: on the usual side (at 0.8 of the level, 0.04) "
        "backcheck_law alone removes less than 20 % of the held-out error above its noise "
        "floor")


def test_an_effect_that_makes_the_usual_side_worse_is_not_taken(
        runs: dict[str, list[ms.Measurement]], monkeypatch: pytest.MonkeyPatch) -> None:
    # development seed 1628 (a back check and a string beside friction at the key front,
    # outside the library): the swapped side's pair step chose the drive and the back
    # check; the drive alone on the usual side made the held-out error 12 % worse at
    # p = 0.67, where judge's size check fails without a reason of its own
    drive = _candidate("drive_dynamics", floor_removal=-0.126, p=0.67)
    drive.removal = -0.124
    rec = _sides(drive, [], [_candidate("drive_dynamics", floor_removal=0.36, p=0.00028,
                                        chosen=True)])
    diag = _two_blows(rec, runs, monkeypatch)
    assert diag.chosen == [] and diag.split == "usual"
    assert diag.notes[-1].endswith("drive_dynamics alone makes the held-out error worse "
                                   "(-12 % removed)")


def test_each_effect_of_a_pair_must_hold_alone_on_the_usual_side(
        runs: dict[str, list[ms.Measurement]], monkeypatch: pytest.MonkeyPatch) -> None:
    pair = _candidate("backcheck_law", floor_removal=0.5, p=1e-6, chosen=True)
    pair.partner, pair.effects = "drive_dynamics", ("drive_dynamics", "backcheck_law")
    rec = Recorder(_diagnosis("usual", [_candidate("backcheck_law", floor_removal=0.3, p=0.1),
                                        _candidate("drive_dynamics", floor_removal=0.05,
                                                   p=0.3)], [], 30.0),
                   _diagnosis("swapped", [], [pair], 20.0))
    diag = _two_blows(rec, runs, monkeypatch)
    assert diag.chosen == []
    assert "chose drive_dynamics + backcheck_law; not taken: " in diag.notes[-1]
    assert diag.notes[-1].endswith("drive_dynamics alone removes less than 20 % of the "
                                   "held-out error above its noise floor")
    rec.answers[False].candidates[1].floor_removal = 0.25  # now both hold alone
    diag = dg.diagnose(ActionModel(), runs["two"], alpha=0.05)
    assert diag.chosen_names == ["drive_dynamics", "backcheck_law"]
    assert "backcheck_law alone there passes every check but the level" in diag.notes[0]
    assert "; drive_dynamics alone there passes every check but the level" in diag.notes[0]


def test_an_effect_the_usual_side_never_fitted_is_not_taken(
        runs: dict[str, list[ms.Measurement]], monkeypatch: pytest.MonkeyPatch) -> None:
    rec = _sides(_candidate("key_liftoff", floor_removal=0.7, p=0.09), [],
                 [_candidate("string_compliance", floor_removal=0.6, p=1e-5, chosen=True)])
    diag = _two_blows(rec, runs, monkeypatch)
    assert diag.chosen == []
    assert diag.notes[-1].endswith("string_compliance alone was not fitted there")


def test_an_effect_whose_fit_failed_on_the_usual_side_is_not_taken(
        runs: dict[str, list[ms.Measurement]], monkeypatch: pytest.MonkeyPatch) -> None:
    failed = _candidate("key_liftoff", floor_removal=math.nan, p=1.0)
    failed.error = "simulation failed at t = 0.05 s"
    rec = _sides(failed, [], [_candidate("key_liftoff", floor_removal=0.9, p=0.0,
                                         chosen=True)])
    diag = _two_blows(rec, runs, monkeypatch)
    assert diag.chosen == []
    assert diag.notes[-1].endswith("key_liftoff alone could not be fitted there (simulation "
                                   "failed at t = 0.05 s)")


def test_the_swapped_side_is_not_searched_when_nothing_could_be_taken(
        runs: dict[str, list[ms.Measurement]], monkeypatch: pytest.MonkeyPatch) -> None:
    # no candidate of the usual side's first round passes every check but the level: a
    # swapped choice would be refused whatever it is, so the run is diagnosed once
    rec = _sides(_candidate("key_liftoff", floor_removal=0.1, p=0.5), [],
                 [_candidate("key_liftoff", floor_removal=0.9, p=0.0, chosen=True)],
                 another_passes=False)
    diag = _two_blows(rec, runs, monkeypatch)
    assert rec.calls == [(pytest.approx(0.04), False)]
    assert diag.chosen == [] and diag.split == "usual" and diag.wall_s == 30.0
    assert diag.notes[-1] == (
        "the held-out test the other way round was not run: no candidate alone on the usual "
        "side (at 0.8 of the level, 0.04) passes every check but the level, so nothing it "
        "chose could be taken")


def test_nothing_either_way_says_so(
        runs: dict[str, list[ms.Measurement]], monkeypatch: pytest.MonkeyPatch) -> None:
    rec = _sides(_candidate("key_liftoff", floor_removal=0.7, p=0.09), [], [])
    diag = _two_blows(rec, runs, monkeypatch)
    assert diag.chosen == [] and diag.split == "usual"
    assert diag.notes[-1] == ("the held-out test the other way round (swapped; at 0.2 of the "
                              "level, 0.01, the usual side having 0.8 of it, 0.04) chose "
                              "nothing either")
    assert rec.answers[False].notes == ["usual's own note"]  # the side's own is not changed


def test_the_confirmation_is_judged_on_a_copy(
        runs: dict[str, list[ms.Measurement]], monkeypatch: pytest.MonkeyPatch) -> None:
    first = _candidate("key_liftoff", floor_removal=0.7, p=0.09)
    first.why_not = "held-out improvement could be noise (p = 0.09 > 0.0057)"
    rec = _sides(first, [], [_candidate("key_liftoff", floor_removal=0.9, p=0.0,
                                        chosen=True)])
    monkeypatch.setattr(dg, "_one_way", rec)
    dg.diagnose(ActionModel(), runs["two"], alpha=0.05)
    # the usual side's first round still says why it was not significant at its level
    assert not first.significant and first.why_not.startswith("held-out improvement")


def test_the_swapped_split_exchanges_the_trials(runs: dict[str, list[ms.Measurement]]
                                                ) -> None:
    kw: dict[str, Any] = dict(
        input="force", duration=0.1, channels=None, candidates=["drive_dynamics"],
        extra=(), max_nfev=2, scan=1, min_gain=0.2, min_noise_gain=3.0, label="model",
        align_s=5e-4, single=True, max_effects=1, z_off=1.96, backward=False,
        held_out_test="noise", final_nfev=2, weights="none", progress=None,
        base_params=False, jobs=1)
    usual = dg._one_way(ActionModel(), runs["two"], alpha=0.04, **kw)
    other = dg._one_way(ActionModel(), runs["two"], alpha=0.01, swapped=True, **kw)
    assert usual.held_out_trials == [1] and other.held_out_trials == [0]
    assert usual.split == "2 trials: fit on even, score on odd"
    assert other.split == ("2 trials of 2 blows: fit on trials [1], score on trials [0] "
                           "(other blows; the sides swapped: the strongest blow scored)")
    (u,), (o,) = usual.candidates, other.candidates
    assert math.isfinite(u.p_value) and math.isfinite(o.p_value)
    # each side's base error is its own held-out trials' (the forte blow against the piano)
    assert usual.base_error != other.base_error


@pytest.mark.slow
def test_a_key_liftoff_the_usual_level_misses_is_found_with_the_sides_swapped(
        tmp_path: Path) -> None:
    # wide benchmark development seed 1586: key lift-off (86.7 N s/m, 1.0 N pin friction)
    # beside four base parameters a few per cent off, noise x1.32, a repeated 32 N, a
    # 2.6 N piano and an 11 N staccato blow. Fitted on the repeated and piano blows and
    # scored on the staccato one, lift-off alone removed 67 % of the held-out error at
    # p = 0.092, short of the round's level; fitted on the staccato blow and scored on the
    # others, its p was 0 (measured, issue 39)
    d = wide.draw(1586)
    assert sorted(d.hidden) == ["key_liftoff"] and d.user is None and d.filter_hz is None
    wide.synth_run(d, d.blows, tmp_path / "run.h5", 1586)
    meas = ms.load(tmp_path / "run.h5")
    diag = dg.diagnose(ActionModel(), meas, duration=d.window, jobs=1)
    assert diag.chosen_names == ["key_liftoff"], diag.verdict()
    assert diag.held_out_trials == [0, 1] and "the sides swapped" in diag.split
    assert diag.notes[0].startswith("two ways: the usual side (3 trials of 3 blows: fit on "
                                    "trials [0, 1], score on trials [2] (other blows)")
    final = diag.final
    assert final is not None
    truth = d.hidden["key_liftoff"]["pin_friction"]
    assert abs(final.values["key_liftoff.pin_friction"] - truth) < 3 * final.sigma[
        "key_liftoff.pin_friction"], final.value_text()
