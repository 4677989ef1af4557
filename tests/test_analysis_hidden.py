"""Hidden-effect tests (issue 6): data synthesized with an effect the analysis is not told of.

For every effect in the library: a truth model with the effect (its fitted parameters moved
off their defaults, so the fit has to find them) makes a measurement-like run through the
simulated rig's drive and sensor models (noise, quantization), two trials at two force
levels; ``diagnose`` of the base model must rank that effect first, significantly, and the
model with it added and fitted must halve the held-out error on the channels the effect
touches. The load cell's filter is hidden the physical way: the sensor model filters the
force (4-pole Butterworth) and the truth has no effect. Without a hidden effect no candidate
is significant. A novel effect defined only here (an encoder mount that rings after the
strike) is explained by no library effect; diagnose points at its channel and phase, and
adding it as a user plug-in makes the error fall in ``compare``.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from rig.analysis import compare as cp
from rig.analysis import diagnose as dg
from rig.analysis import measurement as ms
from rig.analysis import synth
from rig.inputs import profiles
from rig.model.action import ActionModel, SimResult
from rig.model.effects import BUILTIN, Effect, EffectParameter, EffectState, Signature

DURATION = 0.15   # holds let-off, strike, string contact and the back check's catch
SENSOR_SIDE = {"load_cell_filter"}  # hidden in the sensor chain rather than in the truth


def truth_values(cls: type[Effect]) -> dict[str, float]:
    """Fitted parameters moved off their defaults (x1.5, or 10 % of the way to the upper
    bound), so the hidden effect differs from the candidate's starting point."""
    out = {}
    for p in cls.parameters:
        if not p.fitted:
            continue
        lo, hi = p.bounds
        v = p.default * 1.5 if p.default > 0 and p.default * 1.5 <= hi else \
            p.default + 0.1 * (hi - p.default)
        out[p.name] = v
    return out


def blows() -> list[profiles.Profile]:
    forte = profiles.load(Path(__file__).parents[1] / "profiles" / "forte.yaml")
    softer = profiles.from_points([[0, 0], [0.02, 0], [0.1, 24], [0.3, 24]], name="24 N")
    return [forte, softer]


def make_run(path: Path, truth: ActionModel, filtered: bool, seed: int = 3) -> list:
    synth.synth(truth, blows(), path, seed=seed, duration=DURATION,
                load_cell_filter=filtered)
    return ms.load(path)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(n for n, c in BUILTIN.items() if c.diagnosable))
def test_hidden_effect_is_found_and_fitted(name: str, tmp_path: Path) -> None:
    cls = BUILTIN[name]
    if name in SENSOR_SIDE:
        truth, filtered = ActionModel(), True
    else:
        truth, filtered = ActionModel(effects=[{name: truth_values(cls)}]), False
    meas = make_run(tmp_path / "hidden.h5", truth, filtered)
    diag = dg.diagnose(ActionModel(), meas, duration=DURATION, jobs=2)
    ranked = [c.name for c in diag.candidates]
    assert diag.best is not None, "\n".join(diag.report_lines())
    assert ranked[0] == name, "\n".join(diag.report_lines())
    touched = [c for c in cls.signature.channels if c in diag.base_error] or list(
        diag.base_error)
    assert diag.removal_on(diag.candidates[0], touched) >= 0.5, "\n".join(
        diag.report_lines())


@pytest.mark.slow
def test_no_hidden_effect_no_significant_candidate(tmp_path: Path) -> None:
    meas = make_run(tmp_path / "plain.h5", ActionModel(), False)
    diag = dg.diagnose(ActionModel(), meas, duration=DURATION, jobs=2)
    assert diag.best is None, "\n".join(diag.report_lines())
    # nothing is missing: the base model's held-out residual is within its noise floor
    assert diag.remainder is not None and not diag.remainder.significant, diag.verdict()
    assert diag.verdict().startswith("no missing effect can be shown"), diag.verdict()


class MountRinging(Effect):
    """Novel (test-only): the whippen encoder's mount rings after the strike."""

    name = "mount_ringing"
    summary = "the whippen encoder's read head rings on its bracket after the strike"
    parameters = (
        EffectParameter("amplitude", "rad", 1.5e-3, (0.0, 0.01), True, "ringing amplitude"),
        EffectParameter("frequency", "Hz", 150.0, (50.0, 500.0), False, "ringing frequency"),
        EffectParameter("decay", "s", 0.03, (0.001, 0.2), False, "decay time"),
    )
    signature = Signature(("whippen_angle",), ("flight back to the check", "check"),
                          "oscillation", 150.0, "the whippen reading rings after the strike")

    def measure(self, result: SimResult) -> None:
        pen = result.contact("contact_penetration", 12)
        hit = np.flatnonzero(pen > 0)
        if not hit.size:
            return
        t0 = result.time[hit[0]]
        t = np.clip(result.time - t0, 0.0, None)
        ring = self.values["amplitude"] * np.sin(2 * math.pi * self.values["frequency"] * t) \
            * np.exp(-t / self.values["decay"])
        result.channels["whippen_angle"] = result.channels["whippen_angle"] + ring


@pytest.mark.slow
def test_novel_effect_not_in_library(tmp_path: Path) -> None:
    truth = ActionModel(effects=[MountRinging()])
    meas = make_run(tmp_path / "novel.h5", truth, False)
    diag = dg.diagnose(ActionModel(), meas, duration=DURATION, jobs=2)
    assert diag.best is None, "\n".join(diag.report_lines())
    top = diag.signatures[0]
    assert top.channel == "whippen_angle", "\n".join(diag.report_lines())
    assert top.phase in ("flight back to the check", "check"), "\n".join(diag.report_lines())
    assert top.kind == "oscillation" and abs(top.frequency_hz - 150.0) < 25.0, top.text()
    assert "whippen_angle" in diag.verdict()
    assert diag.verdict().startswith("no library effect explains"), diag.verdict()
    assert "base parameters a few per cent off" in diag.verdict(), diag.verdict()
    assert diag.remainder is not None and diag.remainder.significant, diag.verdict()
    assert diag.remainder.places[0].signature.channel == "whippen_angle", diag.verdict()
    # the same effect as a user plug-in (this file, named by path) makes the error fall
    plugin = ActionModel.from_yaml(None, effects=[f"{__file__}:MountRinging"])
    comp = cp.compare(meas[0], [("base", ActionModel()), ("with plug-in", plugin)],
                      duration=DURATION)
    before, after = (m.errors["whippen_angle"].nrms for m in comp.models)
    assert after < 0.8 * before, cp.table(comp)  # what is left is the force noise's floor
    # Not asserted: the share removed in the ringing's own phase. With the faithful drive it
    # ranged 0.10-0.91 (after/before) over noise seeds 1-6 (0.09-1.16 with the old drive):
    # the force noise, not the ringing, sets that phase's error at this window, and a 150 Hz
    # component of 0.53 mrad remains there with the plug-in at seed 3 (0.69 mrad without).


@pytest.mark.slow
def test_physics_outside_the_library_beside_a_library_effect_is_named_as_left(
        tmp_path: Path) -> None:
    """Real data bring a library effect and physics no library has at once: the string is
    chosen, and what it leaves is said to stand above the noise floor where the novel
    ringing is (the whippen, at its frequency); with the ringing as a user plug-in beside
    the string, what is left falls to the floor."""
    truth = ActionModel(effects=[{"compliant_string": truth_values(
        BUILTIN["compliant_string"])}, MountRinging()])
    meas = make_run(tmp_path / "both.h5", truth, False)
    diag = dg.diagnose(ActionModel(), meas, duration=DURATION, jobs=2)
    report = "\n".join(diag.report_lines())
    assert diag.chosen_names == ["compliant_string"], report
    left = diag.remainder
    assert left is not None and left.significant and left.of == "compliant_string", report
    top = left.places[0].signature  # (its kind may read "lag": the channel's lag share
    assert top.channel == "whippen_angle", report  # is taken over the whole trial)
    assert abs(top.frequency_hz - 150.0) < 25.0, report
    assert max(left.channels, key=lambda c: left.channels[c]) == "whippen_angle", report
    assert "stands above the noise floor" in diag.verdict(), report
    assert "no further library candidate" in diag.verdict(), report
    # the truth's own model leaves only noise: the test does not call a right model short
    from rig.analysis import fit as ft
    from rig.analysis import remainder as rm

    data = ft.Data.build(meas, "force", DURATION, None, align_s=5e-4)
    test = data.subset(ft.split_masks(data)[1])
    right = rm.remainder(ft.rebuild(truth, rate=meas[0].rate), test, meas, of="truth")
    assert right is not None and not right.significant, (right.ratio, right.p)


# -- issue 13: pairs found jointly, a user effect with its own coordinate ---------------
# backcheck_law + drive_dynamics was a known limitation from issue 13 to 39: the drive
# removes 99 %, and in round 2 the back check removed 58 % of the training error (the forte)
# but only 14 % of the held-out error (the 24 N blow, which shows it less) at p = 6e-4,
# refused under the 20 % asked of the whole held-out error; min_gain is now asked of the
# error above the noise floor (search.channel_floor), and it is found
PAIRS = [("compliant_string", "load_cell_filter"), ("flexible_shank", "key_liftoff"),
         ("key_liftoff", "load_cell_filter"), ("backcheck_law", "drive_dynamics")]


def truth_and_filter(names: tuple[str, ...]) -> tuple[ActionModel, bool]:
    effects = [{n: truth_values(BUILTIN[n])} for n in names if n not in SENSOR_SIDE]
    return ActionModel(effects=effects), any(n in SENSOR_SIDE for n in names)


@pytest.mark.slow
@pytest.mark.parametrize("pair", PAIRS, ids=lambda p: "+".join(p))
def test_hidden_pair_is_found_jointly(pair: tuple[str, str], tmp_path: Path) -> None:
    truth, filtered = truth_and_filter(pair)
    meas = make_run(tmp_path / "pair.h5", truth, filtered, seed=5)
    diag = dg.diagnose(ActionModel(), meas, duration=DURATION, jobs=2)
    report = "\n".join(diag.report_lines())
    assert sorted(diag.chosen_names) == sorted(pair), report
    assert not re.search(r"\bnan\b", report, re.I), report
    out = dg.write_model(None, diag, tmp_path / "found.yaml")
    written = ActionModel.from_yaml(out)
    assert sorted(written.effect_names) == sorted(pair)


class KeyBedCushion(Effect):
    """Novel (test-only) with its own coordinate: the keybed's cloth punching is a mass
    on a spring under the key front that the key presses once it is down."""

    name = "keybed_cushion"
    summary = "a sprung cloth cushion under the key front with its own motion"
    parameters = (
        EffectParameter("k", "N m/rad", 40.0, (0.0, 400.0), True, "cushion stiffness"),
        EffectParameter("tau", "s", 0.005, (1e-4, 0.1), True, "cushion relaxation time"),
    )
    states = (EffectState("set", "rad", atol=1e-9),)

    def generalized_force(self, t: float, q: np.ndarray, qd: np.ndarray,
                          z: np.ndarray) -> np.ndarray:
        f = np.zeros(9)
        f[0] = -self.values["k"] * (q[0] - z[0])  # on the key's angle
        return f

    def state_derivative(self, t: float, q: np.ndarray, qd: np.ndarray,
                         z: np.ndarray) -> np.ndarray:
        return np.array([(q[0] - z[0]) / self.values["tau"]])


@pytest.mark.slow
def test_user_effect_with_own_coordinate_found_written_refitted_and_cuts_the_error(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from typer.testing import CliRunner

    from rig.cli import app

    monkeypatch.chdir(tmp_path)
    ref = f"{__file__}:KeyBedCushion"
    truth = ActionModel.from_yaml(None, effects=[ref])
    truth.effects[0].set("k", 80.0)
    meas = make_run(tmp_path / "cushion.h5", truth, False)
    runner = CliRunner()
    r = runner.invoke(app, ["diagnose", "cushion.h5", "--duration", str(DURATION),
                            "--extra", ref, "--jobs", "2", "--write", "found.yaml"])
    assert r.exit_code == 0, r.output
    assert "scipy-LSODA" in r.output and "keybed_cushion" in r.output
    assert "not evaluated" not in r.output, r.output
    found = ActionModel.from_yaml(tmp_path / "found.yaml")
    assert "keybed_cushion" in found.effect_names, r.output
    r = runner.invoke(app, ["fit", "cushion.h5", "--model", "found.yaml", "--param",
                            "keybed_cushion.k", "--duration", str(DURATION), "--jobs", "1",
                            "--max-nfev", "6", "--write", "refit.yaml"])
    assert r.exit_code == 0, r.output
    refit = ActionModel.from_yaml(tmp_path / "refit.yaml")
    k = dict(zip(refit.effect_names, refit.effects, strict=True))["keybed_cushion"].values["k"]
    assert abs(k - 80.0) < 0.3 * 80.0
    comp = cp.compare(meas[0], [("base", ActionModel()), ("refit", refit)], duration=DURATION)
    assert comp.models[1].mean_nrms() < 0.5 * comp.models[0].mean_nrms(), cp.table(comp)


@pytest.mark.slow
def test_a_correlated_valley_is_searched_and_its_minima_widen_the_interval(
        tmp_path: Path, monkeypatch) -> None:
    """The drive's delay and bandwidth trade off (only their total lag is pinned down): the
    final set is refitted from other starts along its valley and scored along it, said in a
    note; the stated uncertainties never shrink, and the values move only to a restart's
    minimum with less training error, said in a note, whose interval spans the first's.
    Without the starts, the same diagnosis gives the curvature uncertainties alone."""
    truth = ActionModel(effects=[{"drive_dynamics": truth_values(BUILTIN["drive_dynamics"])}])
    meas = make_run(tmp_path / "run.h5", truth, False, seed=102)

    def run() -> dg.Diagnosis:
        return dg.diagnose(ActionModel(), meas, duration=DURATION, candidates=["drive_dynamics"],
                           jobs=1)

    with_valley = run()
    monkeypatch.setattr(dg, "VALLEY_STARTS", ())
    without = run()
    assert with_valley.chosen_names == without.chosen_names == ["drive_dynamics"]
    a, b = with_valley.final, without.final
    assert a is not None and b is not None
    moved = [n for n in with_valley.notes if n.startswith("refitted from other starts")
             and not n.endswith("the first fit stays")]  # (a cheaper minimum refused)
    if a.values != b.values:
        # a restart found a minimum with less training error that is not the input
        # noise's (weighted, seed 102: 4.78 ms, 838 Hz against the first fit's 3.92 ms,
        # 199 Hz): the values move only with a note that says so, and the interval
        # then spans the first fit's values too
        assert moved, with_valley.notes
        for k in a.values:
            assert abs(a.values[k] - b.values[k]) <= 1.96 * a.sigma[k], (k, a.values, a.sigma)
    else:
        assert not moved
        assert all(a.sigma[k] >= b.sigma[k] for k in a.values)
    assert any(n.startswith("valley of drive_dynamics.delay and drive_dynamics.bandwidth")
               for n in with_valley.notes)
    assert not any(n.startswith("valley") for n in without.notes)
    # seed 102: other minima (about 1.5 ms, 73 Hz against 3.6 ms, 153 Hz) and values
    # along the valley as good on the held-out trial; the interval spans them, and covers
    # the truth (3 ms, 120 Hz)
    note = next(n for n in with_valley.notes if n.startswith("valley"))
    assert "least-squares minima" in note
    assert a.sigma["drive_dynamics.delay"] > 1.5 * b.sigma["drive_dynamics.delay"]
    for k, v in truth_values(BUILTIN["drive_dynamics"]).items():
        assert abs(a.values[f"drive_dynamics.{k}"] - v) <= 1.96 * a.sigma[f"drive_dynamics.{k}"]


@pytest.mark.slow
def test_a_drives_interval_spans_its_valley_when_the_input_noise_favours_one_end(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A drive of 3.57 ms, 148 Hz under a noisy force (the varied suite's seed 101: blows
    of 30.7 and 16.8 N, noise x 1.41, 0.146 s): the lower-bandwidth end of the valley (about
    1 ms, 55 Hz) fits the noisy force better on both trials for the noise alone. Its
    interval must still cover the truth: the valley is searched from across the drive's
    bounds, and its held-out test draws the input's noise. With the HAC test instead (no
    noise draws), the same diagnosis excluded the truth (42-58 Hz)."""
    truth_v = {"delay": 0.0035713, "bandwidth": 148.22}
    truth = ActionModel(effects=[{"drive_dynamics": truth_v}])

    def blow(peak: float, t: list[float], name: str) -> profiles.Profile:
        return profiles.from_points(list(zip(t, [0, 0, peak, peak, 0, 0], strict=True)),
                                    name=name)

    path = tmp_path / "drive.h5"
    synth.synth(truth, [blow(30.749, [0, 0.02, 0.0933, 0.2708, 0.3108, 0.4308], "A"),
                        blow(16.773, [0, 0.02, 0.0978, 0.2899, 0.3282, 0.4482], "B")],
                path, seed=101, duration=0.1459, noise_scale=1.409)
    meas = ms.load(path)

    def run() -> dg.Candidate:
        d = dg.diagnose(ActionModel(), meas, duration=0.1459, candidates=["drive_dynamics"],
                        jobs=1)
        assert d.chosen_names == ["drive_dynamics"], "\n".join(d.report_lines())
        assert d.final is not None
        return d.final

    def covered(c: dg.Candidate) -> dict[str, bool]:
        return {k: abs(c.values[f"drive_dynamics.{k}"] - v)
                <= 1.96 * c.sigma[f"drive_dynamics.{k}"] for k, v in truth_v.items()}

    assert all(covered(run()).values())
    monkeypatch.setattr(dg, "VALLEY_NOISE_DRAWS", 0)   # the HAC test along the valley
    assert not all(covered(run()).values())


def test_box_starts_span_the_bounds_of_what_moves_the_input_only() -> None:
    base = ActionModel()
    by_name = {n: BUILTIN[n] for n in ("drive_dynamics", "compliant_string")}
    vals = {"drive_dynamics.delay": 0.001, "drive_dynamics.bandwidth": 60.0,
            "compliant_string.stiffness": 3e4}
    c = dg.Candidate("compliant_string", "", dict(vals), {k: 1.0 for k in vals}, {}, 0.5, {},
                     10.0, True, effects=("drive_dynamics", "compliant_string"))
    add = [BUILTIN["drive_dynamics"](delay=0.001, bandwidth=60.0),
           BUILTIN["compliant_string"](stiffness=3e4)]
    targets = [dg.ft.target(base, k, add) for k in vals]
    starts = dg._box_starts(c, targets, by_name)
    assert len(starts) == dg.BOX_STARTS_PER_PARAM * 2
    assert all(s["compliant_string.stiffness"] == 3e4 for s in starts)  # not moved
    for k in ("drive_dynamics.delay", "drive_dynamics.bandwidth"):
        tg = targets[list(vals).index(k)]
        u = sorted((tg.to_u(s[k]) - tg.u_bounds[0]) / (tg.u_bounds[1] - tg.u_bounds[0])
                   for s in starts)
        assert len(set(u)) == len(u) and u[0] < 0.3 and u[-1] > 0.6, (k, u)  # spread
    string_only = dg.Candidate("compliant_string", "", {"compliant_string.stiffness": 3e4},
                               {"compliant_string.stiffness": 1.0}, {}, 0.5, {}, 10.0, True,
                               effects=("compliant_string",))
    assert dg._box_starts(string_only, targets[2:], by_name) == []


def test_a_drives_own_pair_is_walked_along_its_valley_whatever_its_correlation() -> None:
    """``_valleys`` walks (move one, refit the other) every pair of an effect that delays or
    filters the input, and other pairs only when strongly correlated: the drive's delay and
    bandwidth trade off along a curve whose correlation at one of its minima was 0.74."""
    by_name = {n: BUILTIN[n] for n in ("drive_dynamics", "flexible_shank")}
    vals = {"drive_dynamics.delay": 4e-5, "drive_dynamics.bandwidth": 47.0,
            "flexible_shank.E": 1.5e10, "flexible_shank.damping_ratio": 0.015}
    corr = {("drive_dynamics.delay", "drive_dynamics.bandwidth"): 0.74,
            ("drive_dynamics.delay", "flexible_shank.E"): 0.95,
            ("flexible_shank.E", "flexible_shank.damping_ratio"): 0.82}
    c = dg.Candidate("flexible_shank", "", dict(vals), {k: 1.0 for k in vals}, {}, 0.5, {},
                     10.0, True, corr=corr, effects=("drive_dynamics", "flexible_shank"))
    pairs = dg._valley_pairs(c, by_name)
    assert sorted(pairs) == sorted([("drive_dynamics.delay", "drive_dynamics.bandwidth"),
                                    ("drive_dynamics.delay", "flexible_shank.E")])
    shank = dg.Candidate("flexible_shank", "", {k: v for k, v in vals.items() if "shank" in k},
                         {}, {}, 0.5, {}, 10.0, True, corr={}, effects=("flexible_shank",))
    assert dg._valley_pairs(shank, by_name) == []


def _scored(base: ActionModel, by_name: dict, train: dg.ft.Data, test: dg.ft.Data,
            vals: dict[str, float], names: tuple[str, ...]) -> dg.Candidate:
    """The set ``names`` at ``vals`` as a chosen step, scored on ``test``."""
    add = [by_name[n](**{k.split(".")[1]: v for k, v in vals.items()
                         if k.startswith(n + ".")}) for n in names]
    model = dg.ft.rebuild(base, add, vals, [dg.ft.target(base, k, add) for k in vals],
                          test.measurements[0].rate)
    preds = test.simulate(model)
    ms_ = test.channel_ms(preds)
    return dg.Candidate(names[-1], "", dict(vals), {k: 0.01 * abs(v) for k, v in
                                                     vals.items()}, {}, 0.5, {}, 10.0,
                        True, {k: v[0] for k, v in ms_.items()}, effects=names,
                        train_cost=float(np.mean(train.residuals(train.simulate(model))
                                                 ** 2)),
                        test_noise={k: v[1] for k, v in ms_.items()},
                        test_resid=test.residuals(preds))


@pytest.mark.slow
def test_a_newcomer_credited_with_the_sets_own_refit_is_not_named(tmp_path: Path) -> None:
    """A round refits the effects already chosen with each newcomer; when that refit alone
    makes the gain (the set so far was fitted short of its minimum), the newcomer is not
    needed: without it, at the values fitted with it, the held-out error is as small.
    ``_without_newcomer`` refuses it and hands back the set at those values; a newcomer the
    data need (a back check in the truth) passes. ``_unneeded`` does the same for every
    effect of the final set."""
    truth = ActionModel(effects=[{"compliant_string": {"stiffness": 3e4}},
                                 {"backcheck_law": {"stiffness_scale": 0.5}}])
    meas = make_run(tmp_path / "set.h5", truth, False, seed=11)
    data = dg.ft.Data.build(meas, "force", DURATION, None)
    train_m, test_m = dg.ft.split_masks(data)
    train, test = data.subset(train_m), data.subset(test_m)
    base = dg.ft.rebuild(ActionModel(), rate=meas[0].rate)
    by_name = {n: BUILTIN[n] for n in ("compliant_string", "backcheck_law")}

    def scored(vals: dict[str, float], names: tuple[str, ...]) -> dg.Candidate:
        return _scored(base, by_name, train, test, vals, names)

    current = scored({"compliant_string.stiffness": 1.5e4}, ("compliant_string",))
    state = dg.State([BUILTIN["compliant_string"](stiffness=1.5e4)], current.test_resid,
                     {}, current.train_cost, dg.ft.input_noise_responses(
                         dg.ft.rebuild(base, [BUILTIN["compliant_string"](stiffness=1.5e4)],
                                       rate=meas[0].rate), test))
    check_off = {"backcheck_law.stiffness_scale": 1.0, "backcheck_law.friction": 0.434,
                 "backcheck_law.damping": 2.446}
    idle = scored({"compliant_string.stiffness": 3e4, **check_off},
                  ("compliant_string", "backcheck_law"))
    alt = dg._without_newcomer(idle, current, base, by_name, train, test, state, 0.01)
    assert alt is not None and not idle.significant and "the gain is theirs" in idle.why_not
    assert alt.values == {"compliant_string.stiffness": 3e4}
    assert alt.train_cost < current.train_cost and alt.effects == ("compliant_string",)
    needed = scored({"compliant_string.stiffness": 3e4, **check_off,
                     "backcheck_law.stiffness_scale": 0.5}, ("compliant_string", "backcheck_law"))
    assert dg._without_newcomer(needed, current, base, by_name, train, test, state,
                                0.01) is None and needed.significant
    # the final set: an effect whose values went back to off is dropped, a needed one kept
    drop = dg._unneeded([current, idle], base, by_name, train, test, 0.05, True)
    assert drop is not None and drop[0] == "backcheck_law" and drop[1] > 0.05
    assert not drop[3]  # found at the final values, before any refit
    assert [c.name for c in drop[2]] == ["compliant_string"]
    assert drop[2][0].effects == ("compliant_string",)
    assert drop[2][0].values == {"compliant_string.stiffness": 3e4}
    assert dg._unneeded([current, needed], base, by_name, train, test, 0.05, True) is None


@pytest.mark.slow
@pytest.mark.parametrize("net_delay_ms", [4.0, -2.0])
def test_a_lag_the_drive_takes_back_when_refitted_is_dropped(net_delay_ms: float,
                                                             tmp_path: Path) -> None:
    """The final set's pruning refits the others without an effect (``_unneeded``): two
    lags of the input trade, and at a drive + filter pair's values the drive alone is far
    off, yet refitted alone it does as well when the truth is the drive alone (the pair
    here is exactly the truth: the filter's advance added to the drive's dead time). A
    filter the drive cannot replace (the truth's net dead time negative: the drive's delay
    is >= 0) stays."""
    per_hz = BUILTIN["load_cell_filter"].GROUP_DELAY_RAD / (2 * math.pi)  # advance x cutoff
    delay = max(net_delay_ms * 1e-3, 0.0)
    # the filter's advance: a 100 Hz filter's beside a drive-only truth, else the part of
    # the truth's (negative) net dead time the drive's delay cannot give
    advance = per_hz / 100.0 if net_delay_ms > 0 else delay - net_delay_ms * 1e-3
    cutoff = per_hz / advance
    hidden = [{"drive_dynamics": {"delay": delay, "bandwidth": 70.0}}]
    if net_delay_ms < 0:
        hidden.append({"load_cell_filter": {"cutoff": cutoff}})
    meas = make_run(tmp_path / "lag.h5", ActionModel(effects=hidden), False)
    data = dg.ft.Data.build(meas, "force", DURATION, None)
    train_m, test_m = dg.ft.split_masks(data)
    train, test = data.subset(train_m), data.subset(test_m)
    base = dg.ft.rebuild(ActionModel(), rate=meas[0].rate)
    by_name = {n: BUILTIN[n] for n in ("drive_dynamics", "load_cell_filter")}
    drive = {"drive_dynamics.delay": delay, "drive_dynamics.bandwidth": 70.0}
    if net_delay_ms > 0:  # the same net lag, the drive's dead time lengthened by the advance
        drive["drive_dynamics.delay"] = delay + advance
    first = _scored(base, by_name, train, test, drive, ("drive_dynamics",))
    pair = _scored(base, by_name, train, test, {**drive, "load_cell_filter.cutoff": cutoff},
                   ("drive_dynamics", "load_cell_filter"))
    held = dg._unneeded([first, pair], base, by_name, train, test, 0.05, True, refit_nfev=0)
    assert held is None  # at the pair's values both look needed
    drop = dg._unneeded([first, pair], base, by_name, train, test, 0.05, True)
    if net_delay_ms < 0:
        assert drop is None
        return
    assert drop is not None and drop[0] == "load_cell_filter" and drop[3], drop
    reduced = drop[2][-1]
    assert reduced.effects == ("drive_dynamics",)
    # refitted back to the truth's lag: the dead time and the second-order lag's low-
    # frequency group delay (2 zeta / omega_n) trade along a valley, their sum is fixed
    # (to within the whole-trial alignment, +-0.5 ms)

    def lag(v: dict[str, float]) -> float:
        return v["drive_dynamics.delay"] + 2 * 0.7 / (2 * math.pi * v[
            "drive_dynamics.bandwidth"])

    assert abs(lag(reduced.values) - lag({"drive_dynamics.delay": delay,
                                          "drive_dynamics.bandwidth": 70.0})) < 5e-4


@pytest.mark.slow
def test_a_drives_interval_reaches_along_its_curved_valley(tmp_path: Path) -> None:
    """The shank and the drive hidden together (fixed suite, seed 105): the final fit ends at
    the valley's low-bandwidth end (about 0.04 ms, 47 Hz; the drive's two parameters
    correlated 0.74 there), the fits from across the box stop on ripples of the cost far
    from it, and the truth (3 ms, 120 Hz) is as good on the held-out trial (HAC p = 0.26).
    Walked along the curve, moving the delay and refitting the bandwidth from its last
    refit, the interval covers the truth; with only the correlated pairs walked it spanned
    0-0.53 ms, 42-52 Hz."""
    hidden = ["flexible_shank", "drive_dynamics"]
    tv = {n: truth_values(BUILTIN[n]) for n in hidden}
    meas = make_run(tmp_path / "pair.h5", ActionModel(effects=[{n: tv[n]} for n in hidden]),
                    False, seed=105)
    d = dg.diagnose(ActionModel(), meas, duration=DURATION,
                    candidates=["flexible_shank", "drive_dynamics"], jobs=1)
    assert sorted(d.chosen_names) == sorted(hidden), "\n".join(d.report_lines())
    assert d.final is not None
    for k, v in tv["drive_dynamics"].items():
        key = f"drive_dynamics.{k}"
        assert abs(d.final.values[key] - v) <= 1.96 * d.final.sigma[key], (
            key, d.final.values[key], d.final.sigma[key], v)


@pytest.mark.slow
def test_a_fit_stopped_on_a_shelf_is_restarted(tmp_path: Path) -> None:
    """A least-squares fit can stop on a shelf of the cost (measured: felt_hysteresis' ratio
    at 0.33 with truth 0.458, +- 0.004, 30 sigma off). ``_restarts`` refits the final set
    from other starts and keeps the minimum the training data favour, first in its list."""
    true_ratio = 0.45
    truth = ActionModel(effects=[{"felt_hysteresis": {"ratio": true_ratio}}])
    meas = make_run(tmp_path / "felt.h5", truth, False, seed=7)
    data = dg.ft.Data.build(meas, "force", DURATION, None)
    train_m, test_m = dg.ft.split_masks(data)
    train, test = data.subset(train_m), data.subset(test_m)
    by_name = {"felt_hysteresis": BUILTIN["felt_hysteresis"]}
    stuck = dg.Candidate("felt_hysteresis", "", {"felt_hysteresis.ratio": 0.2},
                         {"felt_hysteresis.ratio": 0.001}, {}, 0.5, {}, 10.0, True,
                         effects=("felt_hysteresis",))
    base = dg.ft.rebuild(ActionModel(), rate=meas[0].rate)
    minima, note = dg._restarts(stuck, base, by_name, train, test, 40)
    assert note and "other starts" in note[0], note
    v = stuck.values["felt_hysteresis.ratio"]
    assert abs(v - true_ratio) < 0.05, (v, note)
    assert minima[0][1] == stuck.values and minima[0][0] == min(m[0] for m in minima)
    assert stuck.sigma["felt_hysteresis.ratio"] != 0.001  # the new minimum's own
