"""Issue 39: two hidden effects that each make the fit worse alone and explain the
residual together. A forward search one effect at a time never takes the first step;
when no effect alone is significant and the residual stands above its noise floor,
``diagnose`` fits every pair of the remaining candidates together, judges them at the
level over the number of pairs, and takes the best whose two effects are both needed."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rig.analysis import diagnose as dg
from rig.analysis import measurement as ms
from rig.analysis import synth
from rig.analysis.diagnose import search as se
from rig.analysis.diagnose.results import Candidate
from rig.inputs import profiles
from rig.model.action import ActionModel
from rig.model.effects import BUILTIN

# a held blow, a lighter held blow, a piano one (forces N at times s)
BLOWS = (((0.0, 0.0), (0.02, 0.0), (0.115, 32.5), (0.311, 32.5), (0.355, 0.0), (0.505, 0.0)),
         ((0.0, 0.0), (0.02, 0.0), (0.093, 20.2), (0.320, 20.2), (0.385, 0.0), (0.535, 0.0)),
         ((0.0, 0.0), (0.02, 0.0), (0.094, 3.9), (0.335, 3.9), (0.423, 0.0), (0.623, 0.0)))
TRUTH = {"felt_hysteresis": {"ratio": 0.505}, "compliant_string": {"stiffness": 59500.0}}


def test_pairs_leave_out_an_effect_with_the_one_it_switches_on() -> None:
    lib = [BUILTIN[n] for n in ("key_liftoff", "key_encoder_misread", "compliant_string")]
    got = {(a.name, b.name) for a, b in se.pairs_of(lib)}
    assert got == {("key_liftoff", "compliant_string"),
                   ("key_encoder_misread", "compliant_string")}


def test_the_step_of_a_pair_names_both_effects() -> None:
    c = Candidate("compliant_string", "", {}, {}, {}, 0.9, {}, 10.0, True,
                  partner="felt_hysteresis")
    assert c.added == "felt_hysteresis + compliant_string (together)"
    assert c.as_dict()["partner"] == "felt_hysteresis"
    assert Candidate("x", "", {}, {}, {}, 0.0, {}, 0.0, False).added == "x"


def test_the_floor_test_says_noise_is_noise_and_a_miss_is_not() -> None:
    """``above_floor`` on a model's own noise (no input response: output noise only)."""
    from rig.analysis import fit as ft

    class Flat:  # the part of ft.Data above_floor reads
        input = "none"
        def noise_vector(self) -> np.ndarray:
            return np.full(4000, 0.01)

    rng = np.random.default_rng(3)
    noise = 0.01 * rng.standard_normal(4000)
    data = Flat()
    assert not se.above_floor(ActionModel(), data, noise, 0.05)  # type: ignore[arg-type]
    assert se.above_floor(ActionModel(), data, noise + 0.004, 0.05)  # type: ignore[arg-type]
    assert ft.input_noise_responses(ActionModel(), data) is None  # type: ignore[arg-type]


@pytest.mark.slow
def test_a_pair_neither_of_which_helps_alone_is_found_together(tmp_path: Path) -> None:
    truth = ActionModel(effects=[{n: dict(v)} for n, v in TRUTH.items()])
    profs = [profiles.from_points([list(p) for p in b], name=f"blow {i}")
             for i, b in enumerate(BLOWS)]
    run = tmp_path / "pair.h5"
    synth.synth(truth, profs, run, seed=51, noise_scale=1.6)
    meas = ms.load(run)
    names = ["felt_hysteresis", "compliant_string", "backcheck_law", "drive_dynamics"]
    diag = dg.diagnose(ActionModel(), meas, candidates=names, jobs=2)
    report = "\n".join(diag.report_lines())
    alone = {c.name: c for c in diag.candidates}
    assert not alone["felt_hysteresis"].significant, report
    assert not alone["compliant_string"].significant, report
    assert sorted(diag.chosen_names) == sorted(TRUTH), report
    step = diag.chosen[0]
    assert {step.name, step.partner} == set(TRUTH), report
    assert "together" in report and "needs both" in report, report
    f = diag.final
    assert f is not None
    ratio, s = f.values["felt_hysteresis.ratio"], f.sigma["felt_hysteresis.ratio"]
    assert abs(ratio - TRUTH["felt_hysteresis"]["ratio"]) <= 1.96 * s, report
