"""Issue 39: an effect a later round added is claimed only if the diagnosis's test, with
its two sides swapped, needs it (``check.swapped_p``): the final set with and without it
refitted on the held-out trials, scored on the training trials.

The run: the drive's lag alone (6.4 ms, 59 Hz), a held 27 N blow fitted on and a staccato
12 N blow held out (wide benchmark development seed 729). The held blow's slow ramp fixes
the drive's whole lag but not how it splits between its dead time and its second-order
lag; the training fit lands at 5.4 ms and 47 Hz, whose misfit on the staccato blow a back
check (and a compliant string) then "removes". Fitted on the staccato blow, the drive
alone leaves the held blow nothing for the back check to do."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.analysis import fit as ft
from rig.analysis import measurement as ms
from rig.analysis import synth
from rig.analysis.diagnose.check import swapped_p
from rig.analysis.diagnose.results import Candidate
from rig.inputs import profiles
from rig.model.action import ActionModel
from rig.model.effects import BUILTIN

DRIVE, BACKCHECK = BUILTIN["drive_dynamics"], BUILTIN["backcheck_law"]
BY_NAME = {"drive_dynamics": DRIVE, "backcheck_law": BACKCHECK}
HELD = [(0.0, 0.0), (0.02, 0.0), (0.109561, 27.057455), (0.303256, 27.057455),
        (0.359604, 0.0), (0.509604, 0.0)]
STACCATO = [(0.0, 0.0), (0.02, 0.0), (0.054999, 11.736339), (0.055735, 11.736339),
            (0.076982, 0.0), (0.326982, 0.0)]
WINDOW = 0.34790353
TRUE_DRIVE = {"delay": 0.006365864, "bandwidth": 59.311364}


def _run(truth: ActionModel, path: Path) -> list[ms.Measurement]:
    blows = [profiles.from_points([list(p) for p in HELD], name="held 0"),
             profiles.from_points([list(p) for p in STACCATO], name="staccato 1")]
    synth.synth(truth, blows, path, seed=729, duration=WINDOW, noise_scale=0.79513057)
    return ms.load(path)


def _sides(meas: list[ms.Measurement]) -> tuple[ActionModel, ft.Data, ft.Data]:
    """The base model and the diagnosis's own split (held blow fitted on, staccato held
    out), without the whole-blow alignment, as diagnose fits a set with a lag."""
    data = ft.Data.build(meas, "force", WINDOW, None, align_s=0.0)
    train_m, test_m = ft.split_masks(data)
    return (ft.rebuild(ActionModel(), rate=meas[0].rate), data.subset(train_m),
            data.subset(test_m))


def _final(values: dict[str, float]) -> Candidate:
    names = tuple(dict.fromkeys(k.split(".")[0] for k in values))
    return Candidate(names[-1], "", values, {}, {k: "" for k in values}, 0.0, {}, 0.0, True,
                     effects=names)


def test_a_back_check_fitted_to_the_drives_training_misfit_is_not_needed_swapped(
        tmp_path: Path) -> None:
    meas = _run(ActionModel(effects=[DRIVE(**TRUE_DRIVE)]), tmp_path / "drive.h5")
    base, train, test = _sides(meas)
    assert ft.held_out_trials(ft.Data.build(meas, "force", WINDOW, None)) == [1]
    # the set the diagnosis had before this check (its values after the final restarts)
    final = _final({"drive_dynamics.delay": 0.0054006, "drive_dynamics.bandwidth": 47.489,
                    "backcheck_law.stiffness_scale": 0.88619,
                    "backcheck_law.friction": 0.51349, "backcheck_law.damping": 1.8775})
    p = swapped_p(final, "backcheck_law", base, BY_NAME, train, test, True)
    assert p is not None and p > 0.05, p


def test_a_true_back_check_is_needed_swapped(tmp_path: Path) -> None:
    """A mild back check (the noise-model test alone gives p = 0.06 here: the drive
    refitted without it passes more of the force's noise; the HAC test, 0.0007)."""
    back = {"stiffness_scale": 1.2, "friction": 0.3, "damping": 1.0}
    meas = _run(ActionModel(effects=[DRIVE(**TRUE_DRIVE), BACKCHECK(**back)]),
                tmp_path / "both.h5")
    base, train, test = _sides(meas)
    final = _final({**{f"drive_dynamics.{k}": v for k, v in TRUE_DRIVE.items()},
                    **{f"backcheck_law.{k}": v for k, v in back.items()}})
    p = swapped_p(final, "backcheck_law", base, BY_NAME, train, test, True)
    assert p is not None and p < 0.01, p


def test_an_effect_outside_the_set_is_not_asked(tmp_path: Path) -> None:
    meas = _run(ActionModel(), tmp_path / "none.h5")
    base, train, test = _sides(meas)
    final = _final({"drive_dynamics.delay": 0.001, "drive_dynamics.bandwidth": 80.0})
    assert swapped_p(final, "backcheck_law", base, BY_NAME, train, test, True) is None


@pytest.mark.slow
def test_diagnose_does_not_claim_what_the_drives_training_misfit_left(
        tmp_path: Path) -> None:
    """The whole diagnosis on the drive's run above: a back check the pair round fits to
    what the drive's training values leave on the held-out blow is not claimed; the drive
    alone is. Before the back check's friction was scanned densely (session 41), the pair
    round chose back check + compliant string (71 % of the held-out error left by the
    drive, p = 0.0002) and the swapped test withdrew it at the end; since then the round
    fits the back check elsewhere (45.5 % of that error) and its own check refuses it: the
    drive refitted beside it does as well without it (p = 0.064). Since its damping is
    fitted over decades (session 42), no candidate beside the drive is significant in the
    second round, and there is nothing to refuse. Any of the three will do, and one of them
    must be there."""
    from rig.analysis import diagnose as dg

    meas = _run(ActionModel(effects=[DRIVE(**TRUE_DRIVE)]), tmp_path / "drive.h5")
    d = dg.diagnose(ActionModel(), meas, duration=WINDOW, jobs=2)
    text = "\n".join(d.report_lines())
    assert d.chosen_names == ["drive_dynamics"], text
    swapped = [n for n in d.notes if " not claimed: the set fitted on the held-out trials "
               "does as well without it on the training trials" in n]
    in_round = [n for n in d.notes if "backcheck_law alone from there" in n
                and "do as well without it on the held-out data" in n
                and "the gain is theirs" in n]
    none_after = "no further library candidate removes a significant share" in text
    assert swapped or in_round or none_after, text
