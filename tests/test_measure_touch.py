"""`rig measure touch` (issue 40): slow force ramps through the torque loop on the simulated
rig find where the key starts down and back up; the figures agree with `rig touch` of the
same model within the spread the measurement reports; the record is written and later runs
embed it; bad input is one line, exit 2, nothing written."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from rig.calibration import records
from rig.calibration import touch as ct
from rig.cli import app
from rig.inputs import config
from rig.inputs.params import Parameters
from rig.model import touch
from rig.model.action import ActionModel
from rig.recordings import runfile
from rig.services import calibrate as cal_svc
from rig.services import measure_touch as svc
from rig.services import run as run_svc
from rig.sim_backend.simrig import sim_parameters

ROOT = Path(__file__).resolve().parents[1]
MASSES = [0, 1, 2, 3, 4, 5, 4, 3, 2, 1, 0]
# the presses of the test: from under the model's balance force at rest (36 g) to over it,
# back to under its force at the pressed stop (29 g); 16.5 s of profile a trial
RAMPS = ct.Ramps(from_g=30.0, to_g=42.0, low_g=24.0, rate_g_s=2.0)


def sim(tmp_path: Path, friction: str = "regularised") -> config.RigConfig:
    """The simulated rig on the base model (the one `rig touch` measures), lock-step."""
    return config.from_mapping({
        "name": "touch", "backend": "sim", "data_folder": str(tmp_path),
        "drive": {"port": "sim", "poll_period_s": 0.01},
        "sim": {"realtime": False, "effects": [], "friction": friction},
        "loop": {"rest_s": 0.2},
        "channels": {"strain_gauge": {"enabled": False}}})


def calibrated(tmp_path: Path) -> config.RigConfig:
    cfg = sim(tmp_path)
    cal_svc.calibrate_loadcell(cfg, MASSES)
    return cfg


def test_a_trial_is_one_profile_of_slow_ramps() -> None:
    r = ct.Ramps(from_g=25, to_g=70, low_g=10, rate_g_s=2)
    knots = r.knots()
    assert [round(ct.grams(f), 9) for _, f in knots] == [0, 25, 70, 70, 10]
    # up at 2 g/s (22.5 s), held 1 s, down at 2 g/s (30 s)
    assert np.diff([t for t, _ in knots]) == pytest.approx([0.5, 22.5, 1.0, 30.0])
    assert r.segments() == {"down": (0.5, 23.0), "up": (24.0, 54.0)}


def test_presses_follow_one_another_each_let_go_to_no_force() -> None:
    r = ct.Ramps(from_g=25, to_g=70, low_g=10, rate_g_s=2)
    points, period = r.presses(2, let_go_s=0.3, gap_s=0.5)
    end = r.knots()[-1][0]
    assert period == pytest.approx(end + 0.5)
    t = [p[0] for p in points]
    assert np.all(np.diff(t) >= 0)
    assert points[6] == [period, 0.0] and points[5] == [pytest.approx(end + 0.3), 0.0]
    assert points[-1] == [2 * period, 0.0] and len(points) == 2 * 6 + 1
    assert points[8][1] == pytest.approx(ct.newtons(70)) and points[8][0] == pytest.approx(
        period + r.knots()[2][0])


def synthetic_ramp() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time s, dip m, force N): the dip creeps linearly (felt), then the key goes at
    t = 3.0 s with a parabola, on 0.5 um counts; the force rises 0.02 N/s with noise."""
    rng = np.random.default_rng(0)
    t = np.arange(0, 6, 5e-4)
    dip = 1e-6 * t + np.where(t > 3.0, 2e-3 * (t - 3.0) ** 2, 0.0)
    dip = np.round(dip / 5e-7) * 5e-7
    return t, dip, 0.3 + 0.02 * t + rng.normal(0, 0.2, t.size)


def test_the_start_is_where_the_dip_leaves_its_elastic_trend() -> None:
    """A synthetic ramp: the dip creeps linearly (felt), then the key goes at t = 3.0 s with
    a parabola; the force rises 0.02 N/s with noise. The start is found within the
    encoder's tolerance of 3.0 s and its force from the fitted ramp."""
    t, dip, force = synthetic_ramp()
    s = ct.find_start(t, dip, force, (0.0, 6.0), +1, ct.Ramps(), 5e-7, "synthetic")
    # 10 counts (5 um) off the trend: (t - 3)^2 = 2.5e-3 -> 0.05 s after the start
    assert s.time_s == pytest.approx(3.05, abs=0.002)
    assert s.force_n == pytest.approx(0.3 + 0.02 * 3.05, abs=3e-3)
    # the return: the same mirrored
    s_up = ct.find_start(t, 8e-3 - dip, force, (0.0, 6.0), -1, ct.Ramps(), 5e-7, "synthetic")
    assert s_up.time_s == pytest.approx(s.time_s, abs=1e-9)
    # no start: the key never went the threshold
    with pytest.raises(ValueError, match="did not go down by 0.25 mm"):
        ct.find_start(t, 1e-6 * t, force, (0.0, 6.0), +1, ct.Ramps(), 5e-7, "synthetic")


def test_the_travel_rule_reads_the_force_where_the_key_has_gone_the_threshold() -> None:
    """The synthetic ramp above: the key has gone 0.25 mm from where it stood at the ramp's
    start when 2e-3 (t - 3)^2 + 1e-6 t = 2.5e-4, t = 3.3512 s (3.3515 s on the 0.5 um
    counts); the travel rule's weight is the fitted ramp's force there, the onset rule's at
    3.05 s."""
    t, dip, force = synthetic_ramp()
    s = ct.find_start(t, dip, force, (0.0, 6.0), +1, ct.Ramps(), 5e-7, "synthetic")
    assert s.ref_dip_m == 0.0
    assert s.went_s == pytest.approx(3.3515, abs=2e-4)
    assert s.went_dip_m - s.ref_dip_m > 0.25e-3
    assert s.weight_n("travel") == s.went_force_n == pytest.approx(0.3 + 0.02 * 3.3515,
                                                                   abs=3e-3)
    assert s.weight_n("onset") == s.force_n
    # a trial's figures follow the rule
    up = ct.find_start(t, 8e-3 - dip, force, (0.0, 6.0), -1, ct.Ramps(), 5e-7, "synthetic")
    for rule, key in (("travel", "went_force_n"), ("onset", "force_n")):
        m = ct.summarise(ct.Ramps(rule=rule), [{"down": s, "up": up}] * 2)
        assert m.per_trial_g()["down_weight"] == [ct.grams(getattr(s, key))] * 2
        assert m.raw_points()[0]["down"]["force_n"] == getattr(s, key)
    with pytest.raises(ValueError, match="auto is resolved by the rig"):
        ct.analyse([], ct.Ramps(), 5e-7)


def test_auto_takes_onset_only_on_the_simulated_regularised_action(tmp_path: Path) -> None:
    cfg = sim(tmp_path)
    assert svc.resolve_rule(cfg, "auto") == "onset"
    assert svc.resolve_rule(cfg, "travel") == "travel"
    stick = sim(tmp_path, "stick")
    assert svc.resolve_rule(stick, "auto") == "travel"
    assert svc.resolve_rule(stick, "onset") == "onset"


@pytest.mark.parametrize("ramps, words", [
    (ct.Ramps(rule="start"), "--rule: expected one of auto, travel, onset, got 'start'"),
    (ct.Ramps(condition=-1), "--condition: expected 0 or more presses, got -1"),
    (ct.Ramps(from_g=40, to_g=30), "--from, --to, --low: expected low < from < to"),
    (ct.Ramps(rate_g_s=0), "--rate: expected a positive number, got 0"),
    (ct.Ramps(to_g=6000), "--to: 6000 g (58.840 N) is over the rig's limits.max_force_n"),
    (ct.Ramps(threshold_mm=8), "--threshold: expected at most 5 mm"),
])
def test_bad_presses_are_refused(ramps: ct.Ramps, words: str) -> None:
    with pytest.raises(ValueError, match=words.replace("(", r"\(").replace(")", r"\)")):
        ramps.check(50.0)


def test_cli_refuses_bad_input_in_one_line(tmp_path: Path) -> None:
    rig_yaml = tmp_path / "rig.yaml"
    rig_yaml.write_text(sim(tmp_path).to_yaml())
    runner = CliRunner()
    for args, words in ((["--trials", "1"], "--trials: expected at least 2"),
                        (["--from", "80"], "--from, --to, --low: expected low < from < to"),
                        ([], "calibration: the load cell has no calibration record")):
        res = runner.invoke(app, ["measure", "touch", "--rig", str(rig_yaml), *args])
        assert res.exit_code == 2, res.output
        lines = [ln for ln in res.output.splitlines() if ln.startswith("error")]
        assert len(lines) == 1 and words in lines[0], res.output
    assert not list(tmp_path.glob("*.h5")) and not (tmp_path / "calibrations").exists()


def test_cli_refuses_a_bad_model_before_any_press(tmp_path: Path) -> None:
    """`--model` is read before the rig is touched: a bad file is one line naming it, exit
    2, no press run and nothing written."""
    rig_yaml = tmp_path / "rig.yaml"
    rig_yaml.write_text(sim(tmp_path).to_yaml())
    bad = tmp_path / "heavy.yaml"
    bad.write_text("parameters:\n  bodies:\n    hammer_head: {mass: heavy}\n")
    res = CliRunner().invoke(app, ["measure", "touch", "--rig", str(rig_yaml),
                                   "--model", str(bad)])
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.output.splitlines() if ln.startswith("error")]
    assert len(lines) == 1 and "heavy.yaml" in lines[0] and "mass" in lines[0], res.output
    assert not list(tmp_path.glob("*.h5")) and not (tmp_path / "calibrations").exists()


@pytest.mark.parametrize(("args", "field"), [
    (["--presses", "-1"], "--presses"),
    (["--presses", "2", "--to", "1e6"], "--to"),
    (["--presses", "2", "--from", "50", "--to", "40"], "--from"),
    (["--presses", "2", "--rate", "0"], "--rate"),
    (["--presses", "2", "--rig", "missing-rig.yaml"], "missing-rig.yaml"),
    (["--rate", "5"], "--rate"),            # press settings without --presses: no presses
    (["--rig", "rig.yaml"], "--rig"),
    (["--from", "20", "--condition", "0"], "--from")])
def test_rig_touch_refuses_presses_it_cannot_make_in_one_line(tmp_path: Path, args: list[str],
                                                               field: str) -> None:
    """`rig touch --presses`' settings are checked as `rig measure touch` checks them, before
    the model is solved: one line naming the option, exit 2, and no plot written."""
    page = tmp_path / "touch.html"
    res = CliRunner().invoke(app, ["touch", *args, "--plot", str(page)])
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error") and field in lines[0], res.output
    assert not page.exists()


def test_the_presses_are_summed_up_with_where_each_key_stopped() -> None:
    """``returns_summary``: the mean and 2 sd of the up-weights, and each press's stop named
    from the stroke stops whose contact is closed (the drop screw, the front punching), its
    jack's distance off the whippen stop (contact 5 open; 0 when closed)."""
    def ret(up: float, pen: dict[int, float]) -> dict:
        return {"up_weight": up, "stop_dip_m": 8e-3, "penetration_m": pen}

    out = svc.returns_summary([ret(19.0, {11: 1e-5, 2: -1e-3, 5: -7e-4}),
                               ret(21.0, {11: -1e-4, 2: 2e-5, 5: -2.3e-3}),
                               ret(20.0, {11: -1e-4, 2: -1e-4, 5: 1e-6})])
    assert out["up_weight_g"] == pytest.approx(20.0)
    assert out["spread_g"] == pytest.approx(2.0)  # 2 x sd(19, 21, 20) = 2 x 1
    assert out["stops"] == [touch.STROKE_STOPS[11], touch.STROKE_STOPS[2], "no stop"]
    assert out["jack_off_stop_m"] == pytest.approx([7e-4, 2.3e-3, 0.0])
    assert svc.returns_summary([ret(19.0, {11: 1e-5})])["spread_g"] == 0.0


def test_an_existing_out_is_refused_without_force(tmp_path: Path) -> None:
    cfg = calibrated(tmp_path)
    out = tmp_path / "mine.h5"
    out.write_bytes(b"the user's")
    with pytest.raises(ValueError, match="--out: .*mine.h5 exists; use --force"):
        svc.measure_touch(cfg, RAMPS, trials=3, out=out)
    assert out.read_bytes() == b"the user's"
    assert not list((tmp_path / "calibrations").glob("touch-*.json"))


def _schema(name: str) -> dict:
    """docs/json.md's schema ``name``."""
    text = (ROOT / "docs" / "json.md").read_text()
    schemas = [json.loads(b) for b in re.findall(r"^```json\n(.*?)^```", text, re.S | re.M)]
    return next(s for s in schemas if s["$id"] == name)


def validate_document(doc: dict) -> None:
    """``doc`` against docs/json.md's rig.measure-touch/1 schema."""
    jsonschema = pytest.importorskip("jsonschema")
    jsonschema.validate(doc, _schema("rig.measure-touch/1"))


@pytest.fixture(scope="module")
def measured(tmp_path_factory: pytest.TempPathFactory):  # noqa: ANN201
    tmp = tmp_path_factory.mktemp("touch")
    cfg = calibrated(tmp)
    result, record, run_file = svc.measure_touch(cfg, RAMPS, trials=3, out=tmp / "touch.h5")
    return cfg, result, record, run_file


@pytest.fixture(scope="module")
def static() -> tuple[ActionModel, touch.Touch]:
    model = ActionModel()
    return model, touch.measure(model)


def _frictionless_at(model: ActionModel, res: touch.Touch, dip: float) -> float:
    """The model's frictionless static key force (N) with the key front at ``dip``."""
    st = touch._Statics(model)
    y, f = st.rest, 0.0
    for d in res.dip_m:  # along the path to the last point, then to the dip
        y, f, _ = st.solve(float(d), y, f, st.frictionless)
    y, f, _ = st.solve(float(dip), y, f, st.frictionless)
    return float(f)


@pytest.mark.slow
def test_the_simulated_rig_agrees_with_rig_touch_within_its_spread(measured, static) -> None:
    """On the simulated rig (the shipped model, its regularised friction laws) the key
    starts down at the frictionless force of the stroke's first point and back up at the
    frictionless force where it was pressed: those laws carry no force at zero speed, so a
    slow ramp lets the key creep off wherever the friction-free balance lets it. Both
    within the spread the measurement reports (2 sd of 3 trials)."""
    _, result, _, _ = measured
    model, res = static
    f = result.figures
    dw_ref = touch.grams(float(res.frictionless_n[0]))
    up_dip = float(np.mean([tr["up"].dip_m for tr in result.trials]))
    assert res.dip_m[-1] < up_dip < res.dip_m[-1] + touch.STEP_M  # pressed at the stroke's end
    uw_ref = touch.grams(_frictionless_at(model, res, up_dip))
    assert 0 < f["down_weight"]["spread_g"] < 1.0 and 0 < f["up_weight"]["spread_g"] < 1.0
    assert abs(f["down_weight"]["mean_g"] - dw_ref) <= f["down_weight"]["spread_g"]
    assert abs(f["up_weight"]["mean_g"] - uw_ref) <= f["up_weight"]["spread_g"]
    balance = (dw_ref + uw_ref) / 2
    assert abs(f["balance_weight"]["mean_g"] - balance) <= max(f["balance_weight"]["spread_g"],
                                                             f["down_weight"]["spread_g"])
    # and far from the stick-friction figures of the same stroke ends (the rig's action
    # sticks; the simulated one creeps)
    assert touch.grams(float(res.down_n[0])) - f["down_weight"]["mean_g"] > 10
    assert f["up_weight"]["mean_g"] - touch.grams(float(res.up_n[-1])) > 5


@pytest.mark.slow
def test_the_record_is_written_and_later_runs_embed_it(measured, tmp_path: Path) -> None:
    cfg, result, record, run_file = measured
    rec = records.read(record)
    assert rec["sensor"] == "touch" and rec["rig"] == records.rig_identity(cfg)
    assert rec["fit"]["down_weight"]["mean_g"] == pytest.approx(
        result.figures["down_weight"]["mean_g"])
    assert rec["uncertainty"]["up_weight"] == {"spread_g": result.figures["up_weight"][
        "spread_g"], "k": 2.0}
    assert 0 < rec["uncertainty"]["load_cell_zero_g"] < 1.0  # the load cell's zero (k = 2)
    assert len(rec["raw_points"]) == 3 and rec["run_file"] == str(run_file)
    assert runfile.read(run_file).status == "complete"
    # the newest touch record is embedded in the next run's metadata
    prof = tmp_path / "short.yaml"
    prof.write_text("name: short\nsegments:\n  - {hold: 0.01}\n  - {ramp: 0.05, to: 1}\n"
                    "  - {ramp: 0.05, to: 0}\n")
    rep = run_svc.run(prof, cfg, out=tmp_path / "next.h5")
    meta = runfile.read(rep.path).metadata
    assert meta["touch_record"]["content_hash"] == rec["content_hash"]
    # the summary in grams with newtons beside
    lines = svc.summary(result)
    dw = result.figures["down_weight"]
    assert lines[0].split()[:6] == ["down_weight", f"{dw['mean_g']:.2f}", "g", "+-",
                                     f"{dw['spread_g']:.2f}", f"({dw['mean_n']:.4f}"]
    doc = json.loads(json.dumps(svc.document(result, record, run_file)))
    assert doc["record"] == str(record)
    validate_document(doc)


# the sticking simulated rig's presses: from under where the key starts to creep (about 44 g)
# to over where it runs away (53.5 g), back to under its up force at the stop (20 g); 30.5 s
STICK_RAMPS = ct.Ramps(from_g=44.0, to_g=58.0, low_g=14.0, rate_g_s=2.0)


@pytest.fixture(scope="module")
def stuck(tmp_path_factory: pytest.TempPathFactory):  # noqa: ANN201
    """`rig measure touch` on the simulated rig with ``sim.friction: stick`` (one conditioning
    press, 3 trials, the travel rule by auto) and `rig touch` of the same model."""
    tmp = tmp_path_factory.mktemp("stick")
    cfg = sim(tmp, "stick")
    cal_svc.calibrate_loadcell(cfg, MASSES)
    result, record, run_file = svc.measure_touch(cfg, STICK_RAMPS, trials=3,
                                                 out=tmp / "stick.h5")
    return result, record, run_file, touch.measure(ActionModel(sim_parameters(cfg)))


@pytest.mark.slow
def test_the_sticking_rig_weighs_every_worked_press_alike_by_the_travel_rule(stuck) -> None:
    """On the sticking simulated rig (auto: the travel rule) the conditioning press is run
    and left out, and the recorded presses agree with each other: spread under 1.5 g for
    the down- and up-weight. The press from the assembled rest (the conditioning one) goes
    down over 3 g higher than the worked ones, so recording it -- the rule before this one
    -- would break that. The onset rule on the same presses reads the start of the creep
    off the pressed stop, over 10 g above `rig touch`'s up force at the stroke's end; the
    travel rule reads within 2 g of it."""
    result, record, run_file, res = stuck
    ref = res.from_rest()
    assert ref["down_dip_m"] == pytest.approx(0.25e-3) and 7e-3 < ref["up_dip_m"] < 8e-3
    assert result.ramps.rule == "travel" and result.ramps.condition == 1
    run = runfile.read(run_file)
    assert len(run.trials) == 4 and len(result.trials) == 3
    f = result.figures
    for name in ("down_weight", "up_weight"):
        assert 0 < f[name]["spread_g"] < 1.5, (name, f[name])
    count = svc.count_m(sim(Path("."), "stick"))
    first = ct.analyse([run.trials[0].channels], result.ramps, count).trials[0]
    assert ct.grams(first["down"].went_force_n) - f["down_weight"]["mean_g"] > 3
    onset_up = np.mean([ct.grams(tr["up"].force_n) for tr in result.trials])
    assert onset_up - ref["up_weight"] > 10
    assert abs(f["up_weight"]["mean_g"] - ref["up_weight"]) < 2
    rec = records.read(record)
    assert rec["checks"]["rule"] == "travel" and rec["checks"]["conditioning_presses"] == 1
    assert rec["raw_points"][0]["down"]["force_n"] == result.trials[0]["down"].went_force_n


@pytest.mark.slow
def test_the_sticking_rig_measures_the_worked_keys_down_weight_within_its_spread(stuck) -> None:
    """The acceptance criterion, down: the sticking simulated rig's down-weight (travel rule,
    after the conditioning press) within the spread the measurement reports of `rig touch`'s
    worked key (``Touch.worked_key``: a press from the rest a press and its return leave,
    the force where the key has gone 0.25 mm from that rest). The press from the assembled
    rest (``Touch.from_rest``) is over 2 g further off: the worked key is lighter."""
    result, _, _, res = stuck
    ref, first = res.worked_key(), res.from_rest()
    f = result.figures["down_weight"]
    assert abs(f["mean_g"] - ref["down_weight"]) <= f["spread_g"], (f, ref)
    assert abs(f["mean_g"] - first["down_weight"]) - abs(f["mean_g"] - ref["down_weight"]) > 2


@pytest.mark.slow
def test_the_sticking_rig_measures_what_rig_touch_of_its_model_prints_within_its_spread(
        stuck, tmp_path: Path) -> None:
    """The acceptance criterion through the command line: the sticking simulated rig's
    down- and up-weight each within the spread the measurement reports of what `rig touch`
    of the same model prints -- the worked key's down-weight, and the up-weight of `rig touch
    --presses 3` with the measurement's ramps and rig (``svc.model_returns``: the same force
    profile in time, the conditioning press first, every friction element sticking; then the
    force lowered quasi-statically from where each recorded press holds the key at its stop,
    the force where it has come 0.25 mm up). The rig's key runs down to the drop screw with
    momentum and stays there with the jack off its whippen stop; the quasi-static worked key
    pushes the jack back onto it (docs/touch.md, "The up-weight after a press in time")."""
    result, _, _, _ = stuck
    rig_yaml = tmp_path / "stick-rig.yaml"
    rig_yaml.write_text(sim(tmp_path, "stick").to_yaml())
    model = tmp_path / "base.yaml"
    model.write_text("effects: []\n")
    r = STICK_RAMPS
    args = ["touch", "--model", str(model), "--presses", "3", "--rig", str(rig_yaml),
            "--from", f"{r.from_g:g}", "--to", f"{r.to_g:g}", "--low", f"{r.low_g:g}",
            "--rate", f"{r.rate_g_s:g}"]
    res = CliRunner().invoke(app, [*args, "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    jsonschema = pytest.importorskip("jsonschema")
    jsonschema.validate(doc, _schema("rig.touch/1"))
    p = doc["presses"]
    assert p["presses"] == 3 and p["conditioning_presses"] == 1 and len(p["per_press_g"]) == 3
    assert p["rest_s"] == 0.2 and p["rig"].startswith(str(rig_yaml))
    # each at the drop screw, the jack off its whippen stop
    assert p["stops"] == [touch.STROKE_STOPS[11]] * 3, p
    assert min(p["jack_off_stop_m"]) > 0.3e-3 and all(7.9e-3 < d < 8.3e-3
                                                       for d in p["stop_dip_m"]), p
    for name, model_g in (("down_weight", doc["worked"]["down_weight"]),
                          ("up_weight", p["up_weight_g"])):
        f = result.figures[name]
        assert abs(f["mean_g"] - model_g) <= f["spread_g"], (name, f, model_g)
    # the quasi-static worked key's up-weight (the jack pushed back onto its stop) is heavier
    assert doc["worked"]["up_weight"] - p["up_weight_g"] > 0.5
    text = CliRunner().invoke(app, args)
    assert text.exit_code == 0, text.output
    assert f"after 3 presses in time: up-weight {p['up_weight_g']:.2f} g" in text.stdout


@pytest.mark.slow
def test_the_presses_are_compared_with_a_model_and_a_heavier_hammer_is_told(stuck) -> None:
    """`rig measure touch --model` (``svc.compare_model``): the sticking rig's presses
    against the base model -- the action the rig plays -- agree within the measured spread
    for both weights, the down-weight being `rig touch`'s worked key; against a model
    whose hammer head is 25 % heavier, the measured down-weight is below the model's by
    more than the spread, and the lines say so."""
    result, _, _, res = stuck
    cfg = sim(Path("."), "stick")
    same = svc.compare_model(ActionModel(), cfg, result)
    assert same["down_weight"]["model_g"] == pytest.approx(res.worked_key()["down_weight"],
                                                           abs=0.05)
    for name in ("down_weight", "up_weight"):
        c = same[name]
        assert c["measured_g"] == result.figures[name]["mean_g"]
        assert c["measured_minus_model_g"] == pytest.approx(c["measured_g"] - c["model_g"])
        assert c["within_spread"], same
    assert len(same["up_weight"]["model_per_trial_g"]) == len(result.trials)
    heavy = Parameters.default()
    heavy.update({"bodies.hammer_head.mass": 0.00792 * 1.25}, source="test")
    other = svc.compare_model(ActionModel(heavy), cfg, result)
    d = other["down_weight"]
    assert d["model_g"] > same["down_weight"]["model_g"] + 2 * d["spread_g"]
    assert d["measured_minus_model_g"] < -d["spread_g"] and not d["within_spread"]
    lines = svc.comparison_lines(other, Path("heavy.yaml"))
    assert lines[0] == "against the model heavy.yaml:"
    assert lines[1].split()[:4] == ["down_weight", "model", f"{d['model_g']:.2f}", "g,"]
    assert "beyond the measured spread" in lines[1]
    doc = json.loads(json.dumps(svc.document(result, Path("r.json"), Path("r.h5"), other)))
    validate_document(doc)
