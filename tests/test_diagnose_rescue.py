"""Issue 39, fits that find the right basin: an effect a pair round shows to be enough
alone is fitted alone from there.

A round fits each candidate from a start scan over its own parameters, one at a time; an
effect whose parameters trade with each other (the shank's modulus and damping ratio) can
end in a wrong basin there. The pair round fits two effects jointly from a scan over both,
and can find the basin; when the pair is then refused because its partner is not needed
(the set refitted without it does as well), the effect it kept, refitted from there, is
judged alone (``search.rescued``).

The failure class, on the wide benchmark's development seed 619: a flexible shank alone
hidden (E = 8.2e9 Pa), four base parameters off, 0.38 s windows, noise x 1.43. Round 1
fitted the shank at E = 2.1e10 Pa with the damping ratio at 0.20 (8 % more held-out
error than the base); shank + lift-off removed 85 %, the shank refitted without lift-off
did as well (p = 0.99), the pair was refused, and nothing was chosen while the shank alone
at its true values removes 97.6 % of the held-out error.

Since the shank's modulus is scanned at 48 points (``effects.SHANK_E_SCAN``, session 35),
round 1 finds that basin itself on this run (tests/test_diagnose_wide.py,
``test_the_shank_start_scan_finds_the_ringing_modes_basin``); the test scans E at the
round's own 4 points, as when the rescue was measured, so that the path it tests is
taken."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import pytest

from rig.analysis import diagnose as dg
from rig.analysis import measurement as ms
from rig.model.action import ActionModel
from rig.model.effects import BUILTIN

ROOT = Path(__file__).parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import diagnose_wide as wide  # noqa: E402

SEED = 619  # a development seed of benchmarks/diagnose_wide.py (0-999), never a reserved one


@pytest.mark.slow
def test_an_effect_a_refused_pair_kept_is_fitted_alone_from_there(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    shank = BUILTIN["flexible_shank"]  # the forked workers inherit the coarse scan
    monkeypatch.setattr(shank, "parameters", tuple(replace(p, scan=0) for p in shank.parameters))
    d = wide.draw(SEED)
    assert list(d.hidden) == ["flexible_shank"] and d.user is None and len(d.base) == 4
    path = tmp_path / "run.h5"
    wide.synth_run(d, d.blows, path, SEED)
    # the candidates the failure involves: the pair round then has three pairs to fit
    diag = dg.diagnose(ActionModel(), ms.load(path), duration=d.window, jobs=2,
                       candidates=["flexible_shank", "key_liftoff", "backcheck_law"])
    first = {c.name: c for c in diag.candidates}
    assert not first["flexible_shank"].significant  # round 1 alone: the wrong basin
    assert diag.chosen_names == ["flexible_shank"]
    said = [n for n in diag.notes if n.startswith("round 1:")]
    assert said and "flexible_shank alone, fitted from where the pair's refit without its " \
        "partner ended, removes" in said[0], said
    e, sd = diag.final.values["flexible_shank.E"], diag.final.sigma["flexible_shank.E"]
    truth = d.hidden["flexible_shank"]["E"]
    assert abs(e - truth) <= 1.96 * sd + 0.05 * truth, (e, sd, truth)
    assert diag.written_removal is not None and diag.written_removal > 0.8
