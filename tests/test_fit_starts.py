"""Issue 39: fits that find the right basin need starts spread over the bounds jointly, not
only one parameter at a time (``fit.sobol_starts``), and least squares from more than the
single best of them (``fit(multistart=...)``, ``fit.distinct_starts``).

The case that asked for it (wide benchmark development seed 1515: the drive's lag and a
back check hidden, repeated and staccato blows): round 1 fitted the drive alone at 10.6 ms
and 559 Hz (truth 6.1 ms, 46 Hz), the back check then found no basin beside it from the
one-at-a-time scan, and the diagnosis named the drive alone. With a candidate's starts
spread jointly over its own bounds and two least-squares runs, round 1 fitted the drive at
8.4 ms and 91 Hz, and the back check was found beside it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rig.analysis import fit as ft
from rig.analysis import measurement as ms
from rig.analysis import synth
from rig.analysis.diagnose import search
from rig.errors import InputError
from rig.inputs import profiles
from rig.model.action import ActionModel
from rig.model.effects import BUILTIN

ROOT = Path(__file__).resolve().parents[1]
K = "compliant_string.stiffness"


@pytest.fixture(scope="module")
def string_data(tmp_path_factory: pytest.TempPathFactory) -> ft.Data:
    truth = ActionModel(effects=[{"compliant_string": {"stiffness": 3.0e4}}])
    path = tmp_path_factory.mktemp("string") / "d.h5"
    synth.synth(truth, [profiles.load(ROOT / "profiles" / "forte.yaml")], path, seed=4,
                duration=0.08)
    meas = ms.load(path)
    return ft.Data.build(meas, "force", 0.08, None)


def test_sobol_starts_fill_each_targets_range_in_fitted_coordinates() -> None:
    base = ActionModel()
    law = BUILTIN["backcheck_law"]
    targets = [ft.target(base, f"backcheck_law.{p}", [law()])
               for p in ("stiffness_scale", "friction", "damping")]
    assert targets[0].log and not targets[1].log  # 0.05-20: log-spaced; 0-1.5: linear
    starts = ft.sobol_starts(targets, 16)
    assert len(starts) == 16
    for t in targets:
        lo, hi = t.u_bounds
        q = np.array([(t.to_u(s[t.label]) - lo) / (hi - lo) for s in starts])
        assert np.all((q >= 0) & (q <= 1))
        # a base-2 Sobol set of 16: one point in each sixteenth of every coordinate
        assert sorted(np.minimum((q * 16).astype(int), 15)) == list(range(16))
    assert ft.sobol_starts(targets, 16) == starts  # one fixed sequence: reproducible
    assert ft.sobol_starts([], 16) == []


def test_a_damping_from_zero_is_fitted_and_scanned_over_decades() -> None:
    # a damping's bounds start at 0 and its default lies in the bottom twentieth of them:
    # scanned linearly, 4 points at 1/8, 3/8, 5/8, 7/8 of the back check's 0-50 s/m are
    # 6.25-43.75 s/m, none near its default 2.446 or below it (development seed 1591's
    # truth: 1.12 s/m). Fitted in log(v + shift), the shift LOG_SHIFT of the default, the
    # same scan spans 0.04-19 s/m, and 0 stays inside the bounds.
    from rig.model.effects import LOG_SHIFT

    base = ActionModel()
    law = BUILTIN["backcheck_law"]
    t = ft.target(base, "backcheck_law.damping", [law()])
    assert t.lo == 0.0 and t.log and t.shift == pytest.approx(LOG_SHIFT * 2.446)
    lo, hi = t.u_bounds
    assert np.isfinite(lo) and np.isfinite(hi)
    assert t.from_u(lo) == pytest.approx(0.0, abs=1e-12) and t.from_u(hi) == pytest.approx(50)
    for v in (0.0, 0.01, 1.0, 2.446, 30.0):
        assert t.from_u(t.to_u(v)) == pytest.approx(v, abs=1e-12)
    h = 1e-6  # dv/du, which the uncertainties use, is the coordinate's own derivative
    assert t.dv_du(1.5) == pytest.approx((t.from_u(t.to_u(1.5) + h) - 1.5) / h, rel=1e-4)
    scan = [t.from_u(lo + q * (hi - lo)) for q in (np.arange(4) + 0.5) / 4]
    assert scan[0] < 2.446 / 10 and scan[1] < 2.446 < scan[2] and scan[3] < 25, scan
    # a user's damping of 0 is a valid value to start from, and bounds given away from 0
    # keep the plain rule
    z = ft.target(base, "backcheck_law.damping", [law(damping=0.0)])
    assert z.value == 0.0 and z.from_u(z.to_u(0.0)) == pytest.approx(0.0, abs=1e-12)
    assert z.from_u(z.to_u(3.0)) == pytest.approx(3.0)
    g = ft.target(base, "backcheck_law.damping=0.5:40", [law()])
    assert g.shift == 0.0 and g.log and g.to_u(2.446) == 0.0
    # a parameter without the flag keeps the plain rule
    assert ft.target(base, "backcheck_law.friction", [law()]).shift == 0.0
    assert not ft.target(base, "backcheck_law.friction", [law()]).log
    # the shank's damping ratio and the balance rail's damping keep the linear scan: on
    # development seed 1583 (the shank and the drive's lag) the shank's ratio scanned over
    # decades sent the fit to another basin of E (docs/performance.md)
    assert [(e, p.name) for e, c in BUILTIN.items() for p in c.parameters if p.log] == [
        ("backcheck_law", "damping")]


def test_distinct_starts_are_the_cheapest_that_differ() -> None:
    span = np.array([1.0, 1.0])
    tried = [(3.0, np.array([0.9, 0.9])), (1.0, np.array([0.0, 0.0])),
             (1.5, np.array([0.05, 0.02])), (2.0, np.array([0.5, 0.0]))]
    got = ft.distinct_starts(tried, span, 2)
    # the second cheapest is a near copy of the cheapest (within a tenth of the span)
    assert [list(u) for u in got] == [[0.0, 0.0], [0.5, 0.0]]
    assert len(ft.distinct_starts(tried, span, 1)) == 1
    assert len(ft.distinct_starts(tried, span, 10)) == 3


def test_a_given_start_is_costed_and_taken_when_it_is_the_lowest(string_data: ft.Data
                                                                  ) -> None:
    base = ft.rebuild(ActionModel(), rate=string_data.measurements[0].rate)
    law = BUILTIN["compliant_string"]
    res = ft.fit(base, string_data, [K], [law], jobs=1, max_nfev=0,
                 starts=[{K: 3.05e4}, {K: 3.0e6}])
    assert res.values[K] == pytest.approx(3.05e4)
    assert len(res.history) == 3  # the start itself and the two given
    with pytest.raises(InputError, match="starts"):
        ft.fit(base, string_data, [K], [law], jobs=1, max_nfev=0,
               starts=[{"compliant_string.nothing": 1.0}])


def test_multistart_runs_from_each_distinct_start_and_keeps_the_lowest(
        string_data: ft.Data) -> None:
    base = ft.rebuild(ActionModel(), rate=string_data.measurements[0].rate)
    law = BUILTIN["compliant_string"]
    far = [{K: 3.0e6}]
    one = ft.fit(base, string_data, [K], [law], jobs=1, max_nfev=6, starts=far)
    two = ft.fit(base, string_data, [K], [law], jobs=1, max_nfev=6, starts=far,
                 multistart=2)
    assert two.cost <= one.cost
    assert two.nfev > one.nfev  # a second run, counted
    assert two.values[K] == pytest.approx(3.0e4, rel=0.05)


def test_a_candidate_with_two_or_more_parameters_gets_joint_starts(
        string_data: ft.Data, monkeypatch: pytest.MonkeyPatch) -> None:
    """evaluate_candidate passes CANDIDATE_SOBOL joint starts and CANDIDATE_STARTS runs to
    the fit for a newcomer with 2+ fitted parameters, none for one with a single one."""
    seen: list[tuple[int, int]] = []
    real = ft.fit

    def spy(*a, **k):  # type: ignore[no-untyped-def]
        seen.append((len(k.get("starts", ())), k.get("multistart", 1)))
        return real(*a, **{**k, "max_nfev": 1})

    monkeypatch.setattr(ft, "fit", spy)
    base = ft.rebuild(ActionModel(), rate=string_data.measurements[0].rate)
    train, test = (string_data.subset(m) for m in ft.split_masks(string_data))
    r0 = test.residuals(test.simulate(base))
    state = search.State([], r0, test.channel_ms(test.simulate(base)),
                         float(np.mean(train.residuals(train.simulate(base)) ** 2)))
    for name in ("backcheck_law", "compliant_string"):
        search.evaluate_candidate(BUILTIN[name], base, train, test, state, 1, 0.2, 3.0,
                                  scan=1)
    assert seen == [(search.CANDIDATE_SOBOL, search.CANDIDATE_STARTS), (0, 1)]
