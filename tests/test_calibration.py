"""Calibration (issue 5): recovery of the simulated sensors' truth, refusals, records,
lookup for runs, the motor map, the encoder check, the NI calls and the CLI."""

from __future__ import annotations

import datetime as dt
import json
import warnings
from pathlib import Path
from unittest import mock

import nidaqmx
import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from rig import calrecords, config, profiles, runfile
from rig.calibration import encoders, motor, records
from rig.calibration import loadcell as lc
from rig.calibration import strain as sg
from rig.calibration.bench import NiBench, SimBench
from rig.calibration.settings import CalibrationSettings
from rig.cli import app
from rig.services import calibrate as svc

ROOT = Path(__file__).resolve().parents[1]
MASSES = [0, 1, 2, 3, 4, 5, 4, 3, 2, 1, 0]
TIGHT = CalibrationSettings(load_cell={"gravity_rel_halfwidth": 1e-5},
                            strain_gauge={"gage_factor_rel_halfwidth": 0.0,
                                          "shunt_rel_halfwidth": 1e-4,
                                          "gauge_resistance_rel_halfwidth": 1e-4,
                                          "tolerance": 0.1})


def sim(tmp_path: Path, seed: int = 4) -> config.RigConfig:
    return config.from_mapping({"name": "test", "backend": "sim", "drive": {"port": "sim"},
                                "sim": {"realtime": False, "seed": seed},
                                "loop": {"rest_s": 0.1}, "data_folder": str(tmp_path)})


def with_cal(cfg: config.RigConfig, **settings) -> config.RigConfig:
    return config.from_mapping({**cfg.model_dump(mode="json"), "calibration": settings})


def test_rig_config_carries_calibration_settings(tmp_path: Path) -> None:
    cfg = with_cal(sim(tmp_path), max_age_days=7, required=["load_cell"],
                   load_cell={"min_points": 6})
    assert isinstance(cfg.calibration, CalibrationSettings)
    assert cfg.calibration.max_age_days == 7 and cfg.calibration.load_cell.min_points == 6
    assert config.from_mapping(yaml.safe_load(cfg.to_yaml())) == cfg  # YAML round trip
    assert config.builtin_sim().calibration == CalibrationSettings()
    for bad, words in (({"max_age_days": 0}, "calibration.max_age_days: Input should be "
                                             "greater than 0"),
                       ({"motor": {"step_hold_s": "long"}}, "calibration.motor.step_hold_s: "),
                       ({"shunt": 1}, "calibration.shunt: unknown field")):
        with pytest.raises(ValueError, match="^rig config: " + words) as exc:
            with_cal(sim(tmp_path), **bad)
        assert "\n" not in str(exc.value)


@pytest.mark.parametrize("seed", range(6))
def test_loadcell_recovers_true_sensitivity_and_offset(tmp_path: Path, seed: int) -> None:
    cfg = sim(tmp_path, seed)
    bench = SimBench(cfg)
    pts = svc.loadcell_points(cfg, bench, MASSES)
    r = lc.analyse(pts, cfg, TIGHT.load_cell)
    truth = bench.truth()["load_cell"]
    u = r.uncertainty
    assert abs(r.fit["sensitivity"] - truth["sensitivity"]) <= u["sensitivity_v_per_v_per_n"]
    assert abs(r.fit["offset"] - truth["offset"]) <= u["offset_v_per_v"]
    # the truth differs from nominal by far more than the uncertainty: the test can fail
    nom = calrecords.nominal(cfg)["load_cell"].sensitivity
    assert abs(nom - truth["sensitivity"]) > 3 * u["sensitivity_v_per_v_per_n"]
    assert r.figures["hysteresis_pct_fs"] < 0.5 and r.figures["nonlinearity_pct_fs"] < 0.5


def test_loadcell_default_budget_polynomial_and_repeatability(tmp_path: Path) -> None:
    cfg = sim(tmp_path)
    bench = SimBench(cfg)
    two_cycles = MASSES + [1, 2, 3, 4, 5, 4, 3, 2, 1, 0]
    r = lc.analyse(svc.loadcell_points(cfg, bench, two_cycles), cfg,
                   CalibrationSettings().load_cell, degree=2)
    assert r.fit["model"] == "polynomial degree 2"
    assert len(r.fit["coefficients_n_per_mv_per_v_power"]) == 3
    assert r.figures["nonrepeatability_pct_fs"] is not None
    assert r.figures["nonrepeatability_pct_fs"] < 0.1
    # 0.3 % for g dominates the default budget: U(scale) ~ 2 * 0.003 / sqrt(3)
    assert r.uncertainty["sensitivity_relative"] == pytest.approx(2 * 0.003 / 3 ** 0.5, rel=0.05)
    assert len(r.fit["residuals_n"]) == len(two_cycles)


def _refused(tmp_path: Path, fn, match: str) -> None:
    folder = tmp_path / "recs"
    with pytest.raises(ValueError, match=match):
        fn(folder)
    assert not folder.exists() or not list(folder.iterdir())


def test_bad_loadcell_data_is_refused_and_nothing_written(tmp_path: Path) -> None:
    cfg = sim(tmp_path)
    _refused(tmp_path, lambda f: svc.calibrate_loadcell(cfg, [0, 1, 2, 1, 0], folder=f),
             r"too few: 3 distinct masses")
    _refused(tmp_path, lambda f: svc.calibrate_loadcell(cfg, [0, 1, 2, 3, 4, 5], folder=f),
             "no unloading points")
    _refused(tmp_path, lambda f: svc.calibrate_loadcell(
        cfg, [0, 4, 8, 12, 16, 20, 10, 0], folder=f), r"points\[6\] \(20 kg\).*saturated")
    readings = [0.0, 0.17e-3, 0.35e-3, 0.33e-3, 0.69e-3, 0.87e-3, 0.52e-3, 0.17e-3, 0.0]
    _refused(tmp_path, lambda f: svc.calibrate_loadcell(cfg, [0, 1, 2, 3, 4, 5, 3, 1, 0],
                                                        readings, folder=f),
             r"points\[4\] \(3 kg, load\): non-monotonic reading")
    with pytest.raises(ValueError, match=r"mass: expected a number in kg, got 'two'"):
        lc.parse_mass("two")
    csv = tmp_path / "p.csv"
    csv.write_text("mass_kg\n0\n1\nabc\n")
    with pytest.raises(ValueError, match=r"row 3 mass_kg: expected a number in kg, got 'abc'"):
        lc.read_csv(csv)


def test_record_file_hash_and_newest_valid(tmp_path: Path) -> None:
    cfg = sim(tmp_path)
    _, p1 = svc.calibrate_loadcell(cfg, MASSES, operator="ana", identifier="SN 123")
    _, p2 = svc.calibrate_loadcell(cfg, MASSES, operator="bo")
    rec = records.read(p2)
    for key in ("sensor", "identifier", "created", "operator", "raw_points", "fit",
                "uncertainty", "software_version", "content_hash"):
        assert key in rec
    assert records.read(p1)["identifier"] == "SN 123"
    assert rec["units"]["sensitivity"] == "(V/V)/N"
    found = records.newest_valid(tmp_path / "calibrations", "load_cell", cfg)
    assert found is not None and found[1] == p2
    # another simulated seed is another rig
    assert records.newest_valid(tmp_path / "calibrations", "load_cell", sim(tmp_path, 9)) is None
    # tampering invalidates a record: the older one is used, with a warning
    data = json.loads(p2.read_text())
    data["fit"]["sensitivity"] *= 1.01
    p2.write_text(json.dumps(data))
    with pytest.warns(records.CalibrationAgeWarning, match="content_hash does not match"):
        found = records.newest_valid(tmp_path / "calibrations", "load_cell", cfg)
    assert found is not None and found[1] == p1


def test_strain_recovers_true_gauge_factor_and_offset(tmp_path: Path) -> None:
    # k = 2 covers ~95 %: over 8 seeds x 2 parameters expect most within U, all within 1.5 U
    z = []
    for seed in range(8):
        cfg = sim(tmp_path, seed)
        bench = SimBench(cfg)
        r = sg.calibrate(cfg, bench, TIGHT.strain_gauge)
        truth = bench.truth()["strain_gauge"]
        z.append(abs(r.fit["sensitivity"] - truth["sensitivity"]) / r.uncertainty["sensitivity"])
        z.append(abs(r.fit["offset"] - truth["offset"]) / r.uncertainty["offset_v_per_v"])
        assert abs(2.0 - truth["sensitivity"]) > r.uncertainty["sensitivity"]
        assert r.fit["gain_adjustment"] == pytest.approx(2.0 / truth["sensitivity"], rel=1e-3)
    assert sum(v <= 1 for v in z) >= 14 and max(z) < 1.5, z


def test_strain_shunt_out_of_tolerance_is_refused(tmp_path: Path) -> None:
    cfg = sim(tmp_path)
    # the operator fitted a 50 kohm shunt but the procedure assumes 100 kohm
    bench = SimBench(cfg)
    real_shunt = bench.shunt
    bench.shunt = lambda sensor, on, r: real_shunt(sensor, on, 50000.0)  # type: ignore
    _refused(tmp_path, lambda f: svc.calibrate_strain(cfg, bench=bench, folder=f),
             r"shunt step: out of tolerance")


def test_lookup_sim_nominal_then_new_records(tmp_path: Path) -> None:
    cfg = sim(tmp_path)
    cals = calrecords.lookup(cfg)
    assert all(r.nominal for r in cals.values())
    _, path = svc.calibrate_loadcell(cfg, MASSES)
    cals = calrecords.lookup(cfg)
    assert not cals["load_cell"].nominal and path.name in cals["load_cell"].source
    assert cals["strain_gauge"].nominal
    assert records.embedded(cals, cfg)[0]["content_hash"] in cals["load_cell"].source


def test_lookup_warns_on_old_records_and_refuses_ni_without_them(tmp_path: Path) -> None:
    cfg = sim(tmp_path)
    svc.calibrate_loadcell(cfg, MASSES)
    later = dt.datetime.now(dt.UTC) + dt.timedelta(days=31)
    with pytest.warns(records.CalibrationAgeWarning, match="days old"):
        records.records_for_run(cfg, now=later)
    ni = config.from_mapping({"backend": "ni", "drive": {"port": "/dev/ttyS0"},
                              "data_folder": str(tmp_path / "ni")})
    with pytest.raises(records.MissingCalibration, match="no valid record for load_cell, "
                                                         "strain_gauge"):
        calrecords.lookup(ni)
    raw = calrecords.lookup(with_cal(ni, use_raw_units=True))
    assert raw["load_cell"].nominal and "use_raw_units" in raw["load_cell"].source


@pytest.mark.slow
def test_run_embeds_the_records_it_used(tmp_path: Path) -> None:
    from rig.services import run as run_svc

    cfg = sim(tmp_path)
    rep = run_svc.run(ROOT / "profiles" / "piano.yaml", cfg, out=tmp_path / "a.h5")
    cals = runfile.read(rep.path).metadata["calibrations"]
    assert all(c["nominal"] for c in cals)
    _, path = svc.calibrate_loadcell(cfg, MASSES)
    rep = run_svc.run(ROOT / "profiles" / "piano.yaml", cfg, out=tmp_path / "b.h5")
    meta = runfile.read(rep.path).metadata
    cals = {c["sensor"]: c for c in meta["calibrations"]}
    assert not cals["load_cell"]["nominal"] and path.name in cals["load_cell"]["source"]
    # the full record is embedded, not only a pointer: it verifies and equals the file
    [full] = meta["calibration_records"]
    assert full == records.read(path) and full["content_hash"] == records.content_hash(full)
    assert full["raw_points"] and full["uncertainty"]


def test_loop_feedforward_uses_the_motor_calibration_when_there_is_one(tmp_path: Path) -> None:
    from rig.services import run as run_svc

    cfg = sim(tmp_path)
    forte = profiles.load(ROOT / "profiles" / "forte.yaml")
    ff, what = run_svc.demand_source(cfg, records.embedded(calrecords.lookup(cfg), cfg))
    assert what["kind"] == "advance" and what["lead_s"] == 0.008
    assert ff(forte, 0.05) == pytest.approx(float(forte.at(0.058)))
    result, path, _ = svc.calibrate_motor(cfg)
    full = records.embedded(calrecords.lookup(cfg), cfg)
    assert [r["sensor"] for r in full] == ["motor"]
    ff, what = run_svc.demand_source(cfg, full)
    comp = result.compensation
    assert what["kind"] == "motor calibration" and what["record"] == records.read(path)[
        "content_hash"]
    assert what["lead_s"] == pytest.approx(comp.lag_s) and comp.lag_s != 0.008
    for t in (-0.05, 0.01, 0.05, 0.09):
        assert ff(forte, t) == pytest.approx(comp.demand_at(forte, t))
    # the inverse map asks for more than the profile where the motor gives less (gain < 1)
    assert ff(forte, 0.07) > float(forte.at(0.07 + comp.lag_s)) > 0


@pytest.mark.slow
def test_motor_calibration_reduces_the_runs_tracking_error(tmp_path: Path) -> None:
    """Through `rig run` (lock-step): no advance, the default 8 ms advance, then after
    `rig calibrate motor` -- the compensated run tracks the forte profile best."""
    from rig.services import run as run_svc

    forte = ROOT / "profiles" / "forte.yaml"
    cfg = sim(tmp_path)
    none = run_svc.run(forte, config.from_mapping({**cfg.model_dump(mode="json"),
                                                    "loop": {"rest_s": 0.1, "advance_s": 0}}),
                       out=tmp_path / "none.h5")
    adv = run_svc.run(forte, cfg, out=tmp_path / "adv.h5")
    svc.calibrate_motor(cfg)
    comp = run_svc.run(forte, cfg, out=tmp_path / "comp.h5")
    kinds = [runfile.read(r.path).metadata["run"]["compensation"]["kind"]
             for r in (none, adv, comp)]
    assert kinds == ["advance", "advance", "motor calibration"]
    e = [run_svc.tracking_error(r.path)["max_error_pct"] for r in (none, adv, comp)]
    assert e[2] < e[1] < e[0], e


def test_motor_map_lag_and_forte_tracking(tmp_path: Path) -> None:
    cfg = sim(tmp_path)
    result, path, track = svc.calibrate_motor(cfg)
    fit = result.fit
    assert 0.004 < fit["lag_s"] < 0.03
    # the simulated drive's settled gain on rising demands is 0.9267 (Appendix D)
    assert fit["sensitivity"] == pytest.approx(0.9267, abs=0.02)
    assert track["compensated"]["max_error_pct"] < track["uncompensated"]["max_error_pct"]
    assert track["compensated"]["max_error_pct"] < \
        track["uncompensated_shift_8ms"]["max_error_pct"]
    comp = motor.compensation_for(cfg)
    assert comp.lag_s == pytest.approx(fit["lag_s"])
    assert float(comp.forward(comp.demand(20.0))) == pytest.approx(20.0)
    forte = profiles.load(ROOT / "profiles" / "forte.yaml")
    assert comp.demand_at(forte, 0.05) == pytest.approx(
        float(comp.demand(forte.at(0.05 + comp.lag_s))))
    assert records.read(path)["tracking"]["compensated"] == track["compensated"]


def test_motor_refuses_a_dead_drive(tmp_path: Path) -> None:
    cfg = sim(tmp_path)
    s = CalibrationSettings().motor
    demand, segs = motor.sequence(cfg, s)
    with pytest.raises(ValueError, match="does not rise with the demand"):
        motor.analyse(cfg, demand, segs, np.random.default_rng(0).normal(
            0, 0.2, demand.size * 4), s)


@pytest.mark.slow
def test_encoder_check_passes_and_catches_bad_config(tmp_path: Path) -> None:
    cfg = sim(tmp_path)
    bench = SimBench(cfg)
    ok = encoders.check(cfg, bench)
    assert ok.passed, ok.failures()
    assert ok.results["key"]["measured_extreme"] == pytest.approx(0.0103, abs=0.001)
    data = cfg.model_dump()
    data["channels"]["encoders"]["whippen"]["counts_per_rev"] = 163840
    data["channels"]["encoders"]["hammer"]["sign"] = -1
    bad = config.from_mapping(data)
    res = encoders.check(bad, SimBench(cfg))
    fails = " ".join(res.failures())
    assert "whippen: resolution" in fails and "hammer: counts in the wrong direction" in fails


# ---- NI through autospecs of nidaqmx's real classes ----
REAL_TASK = nidaqmx.Task


def _ni_task(*args, **kwargs):
    from nidaqmx.task import InStream, Timing
    from nidaqmx.task.channels import AIChannel
    from nidaqmx.task.collections import AIChannelCollection

    t = mock.create_autospec(REAL_TASK, instance=True)
    t.ai_channels = mock.create_autospec(AIChannelCollection, instance=True)
    chan = mock.create_autospec(AIChannel, instance=True)
    t.ai_channels.__getitem__.return_value = chan
    t.timing = mock.create_autospec(Timing, instance=True)
    t.in_stream = mock.create_autospec(InStream, instance=True)
    return t


def test_ni_strain_calibration_calls(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(nidaqmx, "Task", _ni_task)
    ni = config.from_mapping({"backend": "ni", "drive": {"port": "/dev/ttyS0"},
                              "data_folder": str(tmp_path)})
    bench = NiBench(ni)
    task = bench._task("strain_gauge")
    chan = task.ai_channels["strain_gauge"]
    rest, e_eq = 1e-5, -350 / (2 * 100350)
    shunted = rest - 2 * e_eq / (4 + 2 * 2 * e_eq)        # GF 2, no lead: the exact step
    rng = np.random.default_rng(1)
    state = {"on": False}

    def read(number_of_samples_per_channel, timeout):
        base = shunted if state["on"] else rest
        return (base + rng.normal(0, 1e-7, number_of_samples_per_channel)).tolist()

    task.read.side_effect = read
    type(chan).ai_bridge_shunt_cal_enable = mock.PropertyMock(
        side_effect=lambda v=None: state.update(on=v))
    chan.ai_bridge_shunt_cal_gain_adjust = 1.0004
    result, path = svc.calibrate_strain(ni, bench=bench)
    task.perform_bridge_offset_nulling_cal.assert_called_once_with(channel="strain_gauge")
    task.perform_bridge_shunt_cal.assert_called_once_with(
        channel="strain_gauge", shunt_resistor_value=100000.0, bridge_resistance=350.0)
    kw = task.ai_channels.add_ai_bridge_chan.call_args.kwargs
    assert kw["nominal_bridge_resistance"] == 350.0
    assert result.fit["gain_adjustment"] == pytest.approx(1.0, abs=1e-3)
    assert result.fit["driver_gain_adjustment"] == 1.0004 and result.checks["driver_agrees"]
    assert records.read(path)["rig"]["backend"] == "ni"


@pytest.mark.hardware
def test_ni_loadcell_reads_on_real_cards(tmp_path: Path) -> None:
    try:
        nidaqmx.Task("rig-probe").close()
    except nidaqmx.errors.Error as exc:
        pytest.skip(f"needs NI-DAQmx and the rig's cards ({type(exc).__name__})")
    ni = config.from_mapping({"backend": "ni", "drive": {"port": "/dev/ttyS0"}})
    bench = NiBench(ni)
    try:
        r = bench.read_bridge("load_cell", 0.2)
    finally:
        bench.close()
    assert r.size == 400 and np.all(np.abs(r) < 3e-3)


# ---- CLI ----
def test_cli_loadcell_csv_interactive_and_text_mass(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    csv = tmp_path / "points.csv"
    csv.write_text("mass_kg\n" + "\n".join(str(m) for m in MASSES) + "\n")
    res = runner.invoke(app, ["calibrate", "loadcell", "--points", str(csv), "--records",
                              "recs", "--operator", "ana"])
    assert res.exit_code == 0, res.output
    assert "hysteresis" in res.output and "wrote recs/load_cell-" in res.output
    csv.write_text("mass_kg\n0\nten\n")
    res = runner.invoke(app, ["calibrate", "loadcell", "--points", str(csv), "--records",
                              "bad"])
    assert res.exit_code == 2 and "got 'ten'" in res.output and not Path("bad").exists()
    typed = "\n".join(["0", "1", "lots", "2", "3", "4", "5", "3", "1", "0", ""]) + "\n"
    res = runner.invoke(app, ["calibrate", "loadcell", "--records", "inter"], input=typed)
    assert res.exit_code == 0, res.output
    assert "refused: points[3] mass: expected a number in kg, got 'lots'" in res.output
    assert len(list(Path("inter").glob("load_cell-*.json"))) == 1
    res = runner.invoke(app, ["calibrate", "strain", "--records", "recs"])
    assert res.exit_code == 0 and "gain adjustment" in res.output
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cals = calrecords.lookup(config.builtin_sim())
    assert cals["load_cell"].nominal  # records went to --records, not the default folder
