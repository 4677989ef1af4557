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

from rig.calibration import encoders, motor, records
from rig.calibration import loadcell as lc
from rig.calibration import records as cal_records
from rig.calibration import strain as sg
from rig.calibration.settings import CalibrationSettings
from rig.cli import app
from rig.daq import DaqFault
from rig.inputs import config, profiles
from rig.ni_backend.bench import NiBench
from rig.recordings import runfile
from rig.sensors import table as sensor_table
from rig.services import calibrate as svc
from rig.sim_backend.bench import SimBench

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
    nom = sensor_table.nominal(cfg)["load_cell"].sensitivity
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
    with pytest.warns(records.InvalidRecordWarning, match="content_hash does not match"):
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
    cals = cal_records.lookup(cfg)
    assert all(r.nominal for r in cals.values())
    _, path = svc.calibrate_loadcell(cfg, MASSES)
    cals = cal_records.lookup(cfg)
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
        cal_records.lookup(ni)
    raw = cal_records.lookup(with_cal(ni, use_raw_units=True))
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
    from rig.calibration.motor import demand_source

    cfg = sim(tmp_path)
    forte = profiles.load(ROOT / "profiles" / "forte.yaml")
    ff, what = demand_source(cfg, records.embedded(cal_records.lookup(cfg), cfg))
    assert what["kind"] == "advance" and what["lead_s"] == 0.008
    assert ff(forte, 0.05) == pytest.approx(float(forte.at(0.058)))
    result, path, _ = svc.calibrate_motor(cfg)
    full = records.embedded(cal_records.lookup(cfg), cfg)
    assert [r["sensor"] for r in full] == ["motor"]
    ff, what = demand_source(cfg, full)
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
    # the simulated drive's settled gain is the single model's K = 0.9322 (Appendix D)
    assert fit["sensitivity"] == pytest.approx(0.9322, abs=0.02)
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
NI_TASKS: list[mock.MagicMock] = []


def _ni_task(*args, **kwargs):
    """An autospec of nidaqmx.Task with autospecs of its collections, timing, triggers and
    streams: a method or keyword nidaqmx does not have fails the test."""
    from nidaqmx.task import InStream, OutStream, Timing
    from nidaqmx.task.channels import AIChannel
    from nidaqmx.task.collections import (
        AIChannelCollection,
        AOChannelCollection,
        CIChannelCollection,
    )
    from nidaqmx.task.triggering import StartTrigger, Triggers

    t = mock.create_autospec(REAL_TASK, instance=True)
    t.ai_channels = mock.create_autospec(AIChannelCollection, instance=True)
    chan = mock.create_autospec(AIChannel, instance=True)
    t.ai_channels.__getitem__.return_value = chan
    t.ao_channels = mock.create_autospec(AOChannelCollection, instance=True)
    t.ci_channels = mock.create_autospec(CIChannelCollection, instance=True)
    t.timing = mock.create_autospec(Timing, instance=True)
    t.triggers = mock.create_autospec(Triggers, instance=True)
    t.triggers.start_trigger = mock.create_autospec(StartTrigger, instance=True)
    t.in_stream = mock.create_autospec(InStream, instance=True)
    t.out_stream = mock.create_autospec(OutStream, instance=True)
    t.name = args[0] if args else kwargs.get("new_task_name", "")
    NI_TASKS.append(t)
    return t


@pytest.fixture
def ni_tasks(monkeypatch) -> list[mock.MagicMock]:
    NI_TASKS.clear()
    monkeypatch.setattr(nidaqmx, "Task", _ni_task)
    return NI_TASKS


def _ni_named(name: str) -> list[mock.MagicMock]:
    return [t for t in NI_TASKS if t.name == name]


def _ni_cfg(tmp_path: Path, **kw) -> config.RigConfig:
    return config.from_mapping({"backend": "ni", "drive": {"port": "/dev/ttyS0"},
                                "data_folder": str(tmp_path), **kw})


def test_ni_strain_calibration_calls(tmp_path: Path, ni_tasks) -> None:
    from nidaqmx.constants import BridgeConfiguration, BridgeUnits, ExcitationSource, ShuntCalSelect

    ni = _ni_cfg(tmp_path)
    bench = NiBench(ni)
    task = bench._task("strain_gauge")
    chan = task.ai_channels["strain_gauge"]
    rest, e_eq = 1e-5, -350 / (2 * 100350)
    shunted = rest - 2 * e_eq / (4 + 2 * 2 * e_eq)        # GF 2, no lead: the exact step
    rng = np.random.default_rng(1)
    state = {"on": False}
    events: list[str] = []

    def read(number_of_samples_per_channel, timeout):
        events.append("read shunted" if state["on"] else "read rest")
        base = shunted if state["on"] else rest
        return (base + rng.normal(0, 1e-7, number_of_samples_per_channel)).tolist()

    task.read.side_effect = read
    task.perform_bridge_offset_nulling_cal.side_effect = lambda **kw: events.append("null")
    task.perform_bridge_shunt_cal.side_effect = lambda **kw: events.append("driver shunt cal")
    # properties of nidaqmx's AIChannel: a misspelt name would leave these untouched
    enable = mock.PropertyMock(side_effect=lambda v=None: state.update(on=v))
    select, resistance = mock.PropertyMock(), mock.PropertyMock()
    type(chan).ai_bridge_shunt_cal_enable = enable
    type(chan).ai_bridge_shunt_cal_select = select
    type(chan).ai_bridge_shunt_cal_shunt_cal_a_resistance = resistance
    chan.ai_bridge_shunt_cal_gain_adjust = 1.0004
    result, path = svc.calibrate_strain(ni, bench=bench)
    task.ai_channels.add_ai_bridge_chan.assert_called_once_with(
        "SC1Mod1/ai1", name_to_assign_to_channel="strain_gauge", min_val=-2e-3, max_val=2e-3,
        units=BridgeUnits.VOLTS_PER_VOLT, bridge_config=BridgeConfiguration.QUARTER_BRIDGE,
        voltage_excit_source=ExcitationSource.INTERNAL, voltage_excit_val=2.5,
        nominal_bridge_resistance=350.0)
    task.perform_bridge_offset_nulling_cal.assert_called_once_with(channel="strain_gauge")
    task.perform_bridge_shunt_cal.assert_called_once_with(
        channel="strain_gauge", shunt_resistor_value=100000.0, bridge_resistance=350.0)
    assert [c.args for c in enable.call_args_list] == [(False,), (True,), (False,)]
    select.assert_called_with(ShuntCalSelect.A)
    resistance.assert_called_with(100000.0)
    # nulling before the rest reading; NI's own shunt cal only after the shunt is released
    assert events[0] == "null" and events[-1] == "driver shunt cal"
    assert events.index("read shunted") > events.index("read rest")
    assert result.fit["offset"] == pytest.approx(rest, abs=1e-7)
    assert result.fit["gain_adjustment"] == pytest.approx(1.0, abs=1e-3)
    assert result.fit["driver_gain_adjustment"] == 1.0004 and result.checks["driver_agrees"]
    assert result.raw_points["nulling"] == {"hardware_nulling": True}
    assert records.read(path)["rig"]["backend"] == "ni"


def test_ni_loadcell_calibration_reads_the_bridge_task(tmp_path: Path, ni_tasks) -> None:
    """Known masses on NI: one full-bridge V/V task, a finite 2 kHz acquisition per point,
    read in 0.1 s chunks, started and stopped each time; the fit recovers the bridge."""
    from nidaqmx.constants import (
        AcquisitionType,
        BridgeConfiguration,
        BridgeUnits,
        ExcitationSource,
    )

    ni = _ni_cfg(tmp_path)
    bench = NiBench(ni)
    sens, offset, g = 1.9e-5, 4e-5, 9.80665
    state = {"mass": 0.0}
    bench.apply_mass = lambda m, gravity: state.update(mass=m)  # type: ignore[method-assign]
    rng = np.random.default_rng(2)
    task = bench._task("load_cell")
    task.read.side_effect = lambda number_of_samples_per_channel, timeout: (
        offset + sens * state["mass"] * g + rng.normal(0, 2e-8, number_of_samples_per_channel)
    ).tolist()
    result, path = svc.calibrate_loadcell(ni, MASSES, bench=bench)
    task.ai_channels.add_ai_bridge_chan.assert_called_once_with(
        "SC1Mod1/ai0", name_to_assign_to_channel="load_cell", min_val=-3e-3, max_val=3e-3,
        units=BridgeUnits.VOLTS_PER_VOLT, bridge_config=BridgeConfiguration.FULL_BRIDGE,
        voltage_excit_source=ExcitationSource.INTERNAL, voltage_excit_val=5.0,
        nominal_bridge_resistance=350.0)
    n = int(round(1.3 * 2000))     # settle 0.3 s + average 1 s
    assert task.timing.cfg_samp_clk_timing.call_args_list == \
        [mock.call(2000.0, sample_mode=AcquisitionType.FINITE, samps_per_chan=n)] * len(MASSES)
    assert task.start.call_count == task.stop.call_count == len(MASSES)
    assert task.read.call_args_list[0] == mock.call(number_of_samples_per_channel=200,
                                                    timeout=10.0)
    assert task.read.call_count == len(MASSES) * 13
    assert result.fit["sensitivity"] == pytest.approx(sens, rel=1e-4)
    assert result.fit["offset"] == pytest.approx(offset, abs=1e-8)
    assert len(_ni_named("rig-cal-load_cell")) == 1 and records.read(path)["sensor"] == \
        "load_cell"


VPN = config.DriveScaling().volts_per_newton


def _fake_drive(gain: float, delay_samples: int, sens: float, offset: float,
                seed: int = 3):
    """An ai.read for the load-cell task of the NI motor calibration: the force follows the
    waveform last written to the drive task (held 4 samples per period at 2 kHz), times
    ``gain``, ``delay_samples`` later; returned as bridge ratios (V/V)."""
    rng = np.random.default_rng(seed)

    def read(number_of_samples_per_channel, timeout):
        ao = _ni_named("rig-cal-drive")[-1]
        volts = np.asarray(ao.write.call_args.args[0], float)
        demand = np.repeat(volts[:-1] / VPN, 4)
        force = gain * np.r_[np.zeros(delay_samples), demand][:demand.size]
        assert number_of_samples_per_channel == force.size
        return (offset + sens * force + rng.normal(0, 1e-8, force.size)).tolist()

    return read


def _recording_tasks(monkeypatch, events: list[str]) -> None:
    """Like ni_tasks, and each task's start, write and close go to ``events`` in order."""

    def task(*args, **kwargs):
        t = _ni_task(*args, **kwargs)
        events.append(f"new {t.name}")
        t.start.side_effect = lambda: events.append(f"start {t.name}")
        t.close.side_effect = lambda: events.append(f"close {t.name}")
        t.write.side_effect = lambda data, **kw: events.append(f"write {t.name} {data!r}")
        return t

    monkeypatch.setattr(nidaqmx, "Task", task)


def test_ni_motor_waveform_triggers_the_load_cell(tmp_path: Path, ni_tasks,
                                                  monkeypatch) -> None:
    """drive_static on NI: a finite 500 Hz AO waveform on the drive card (the demand in
    volts, then 0 V); the load-cell task, 4 samples per period at 2 kHz, armed first and
    started by the AO start trigger over RTSI; its ratios come back unchanged."""
    from nidaqmx.constants import AcquisitionType

    events: list[str] = []
    _recording_tasks(monkeypatch, events)
    bench = NiBench(_ni_cfg(tmp_path))
    ai = bench._task("load_cell")
    ai.read.side_effect = _fake_drive(1.0, 0, 2e-5, 1e-5)
    demand = np.array([0.0, 5.0, 10.0, 10.0, 2.5])
    ratios = bench.drive_static(demand)
    [ao] = _ni_named("rig-cal-drive")
    ao.ao_channels.add_ao_voltage_chan.assert_called_once_with("Dev1/ao0", min_val=-10.0,
                                                               max_val=10.0)
    ao.timing.cfg_samp_clk_timing.assert_called_once_with(
        500.0, sample_mode=AcquisitionType.FINITE, samps_per_chan=demand.size + 1)
    assert ao.write.call_args.kwargs == {"auto_start": False}
    assert ao.write.call_args.args[0] == pytest.approx([*(demand * VPN), 0.0])
    ai.timing.cfg_samp_clk_timing.assert_called_once_with(
        2000.0, sample_mode=AcquisitionType.FINITE, samps_per_chan=demand.size * 4)
    ai.triggers.start_trigger.cfg_dig_edge_start_trig.assert_called_once_with(
        "/Dev1/ao/StartTrigger")
    assert ai.read.call_args == mock.call(number_of_samples_per_channel=20,
                                          timeout=pytest.approx(6 / 500 + 10))
    # the waveform is written, the AI task armed, then the AO task started (its trigger)
    assert [e.split(" [")[0] for e in events] == [
        "new rig-cal-load_cell", "new rig-cal-drive", "write rig-cal-drive",
        "start rig-cal-load_cell", "start rig-cal-drive", "close rig-cal-drive"]
    ao.wait_until_done.assert_called_once_with(timeout=10.0)
    ai.stop.assert_called_once_with()
    ai.triggers.start_trigger.disable_start_trig.assert_called_once_with()
    ao.close.assert_called_once_with()
    expected = 1e-5 + 2e-5 * np.repeat(demand, 4)
    assert ratios.shape == (20,) and ratios == pytest.approx(expected, abs=1e-7)
    # a volts_per_newton that would clip is clipped to the output's range
    big = np.array([0.0, 1e6])
    bench.drive_static(big)
    assert _ni_named("rig-cal-drive")[-1].write.call_args.args[0] == [0.0, 10.0, 0.0]


def test_ni_motor_failure_leaves_the_drive_at_zero(tmp_path: Path, ni_tasks,
                                                    monkeypatch) -> None:
    """An analog output holds its last value: if the load-cell read fails mid-waveform, the
    waveform task is stopped and closed, then a fresh on-demand task writes 0 V (it could
    not reserve the channel before); the DAQmx error comes back as a one-line fault."""
    events: list[str] = []
    _recording_tasks(monkeypatch, events)
    bench = NiBench(_ni_cfg(tmp_path))
    ai = bench._task("load_cell")
    ai.read.side_effect = nidaqmx.errors.DaqError("Some or all of the samples requested "
                                                  "have not yet been acquired.", -200284)
    with pytest.raises(DaqFault, match=r"^motor: .* failed \(DAQmx -200284\): Some or all "
                                       r"of the samples requested have not yet been "
                                       r"acquired\.$"):
        bench.drive_static(np.array([0.0, 20.0, 20.0]))
    [ao], [zero] = _ni_named("rig-cal-drive"), _ni_named("rig-cal-drive-zero")
    ao.stop.assert_called_once_with()
    zero.ao_channels.add_ao_voltage_chan.assert_called_once_with("Dev1/ao0", min_val=-10.0,
                                                                 max_val=10.0)
    zero.timing.cfg_samp_clk_timing.assert_not_called()       # on demand
    zero.write.assert_called_once_with(0.0, auto_start=True)
    assert events[-4:] == ["close rig-cal-drive", "new rig-cal-drive-zero",
                           "write rig-cal-drive-zero 0.0", "close rig-cal-drive-zero"]
    ai.stop.assert_called_once_with()
    ai.triggers.start_trigger.disable_start_trig.assert_called_once_with()
    # a waveform that played out ends at 0 V by itself: no extra task
    ai.read.side_effect = _fake_drive(1.0, 0, 2e-5, 0.0)
    bench.drive_static(np.array([0.0, 20.0, 20.0]))
    assert len(_ni_named("rig-cal-drive-zero")) == 1 and events[-1] == "close rig-cal-drive"


def test_ni_motor_calibration_recovers_the_drive(tmp_path: Path, ni_tasks) -> None:
    """`rig calibrate motor` on NI end to end: the ratios read back are converted with the
    load-cell record in use and the map, gain and lag of the (fake) drive come out."""
    ni = _ni_cfg(tmp_path, calibration={"use_raw_units": True})  # nominal load cell
    sens = 2e-3 / 111.0
    bench = NiBench(ni)
    ai = bench._task("load_cell")
    ai.read.side_effect = _fake_drive(0.9, 16, sens, 0.0)
    result, path, track = svc.calibrate_motor(ni, bench=bench)
    assert len(_ni_named("rig-cal-drive")) == 4   # the sequence, then three tracking runs
    assert result.fit["sensitivity"] == pytest.approx(0.9, rel=2e-3)
    assert result.fit["lag_s"] == pytest.approx(0.008, abs=2e-4)
    assert result.fit["map_force_n"] == pytest.approx(
        [0.9 * d for d in result.fit["map_demand_n"]], abs=0.02)
    # what is left is the 500 Hz hold of the demand (~1 N on forte's steepest rise)
    e = {k: v["max_error_pct"] for k, v in track.items()}
    assert e["compensated"] < 5 < e["uncompensated_shift_8ms"] < e["uncompensated"], e
    assert records.read(path)["rig"]["backend"] == "ni"


def test_ni_encoder_check_reads_the_counters(tmp_path: Path, ni_tasks, monkeypatch) -> None:
    """`rig check encoders` on NI: one counter task per encoder (x4, ticks), started and
    read on demand while the operator presses the key, at their own pace; it passes for a
    hand press slower and deeper than the motor's, and still catches a wrong sign."""
    import time as time_mod

    from nidaqmx.constants import AngleUnits, EncoderType, LengthUnits

    ni = _ni_cfg(tmp_path)
    hz = ni.rates.control_hz
    hand = encoders.press(ni, seconds=1.0, peak_n=4.5)       # a quicker hand than the motor
    model = encoders.model_press(ni, hand)
    n_reads = encoders.press(ni).size
    counts = {}
    for name, e in ni.channels.encoders.items():
        v = model["key_dip" if e.kind == "linear" else f"{e.body}_angle"][::4]
        v = np.r_[v, np.full(n_reads - v.size, v[-1])]
        counts[name] = np.round(v / e.si_per_count)
    sleeps: list[float] = []
    monkeypatch.setattr(time_mod, "sleep", sleeps.append)

    def counter_task(*args, **kwargs):
        t = _ni_task(*args, **kwargs)
        t.read.side_effect = iter(counts[t.name.removeprefix("rig-check-")].tolist())
        return t

    monkeypatch.setattr(nidaqmx, "Task", counter_task)
    res = encoders.check(ni, NiBench(ni))
    assert res.passed, res.failures()
    key, whippen, hammer = (_ni_named(f"rig-check-{n}")[0] for n in ("key", "whippen", "hammer"))
    key.ci_channels.add_ci_lin_encoder_chan.assert_called_once_with(
        "Dev3/ctr0", name_to_assign_to_channel="key", decoding_type=EncoderType.X_4,
        units=LengthUnits.TICKS, dist_per_pulse=pytest.approx(2e-6), initial_pos=0.0)
    whippen.ci_channels.add_ci_ang_encoder_chan.assert_called_once_with(
        "Dev3/ctr1", name_to_assign_to_channel="whippen", decoding_type=EncoderType.X_4,
        units=AngleUnits.TICKS, pulses_per_rev=81920, initial_angle=0.0)
    hammer.ci_channels.add_ci_ang_encoder_chan.assert_called_once_with(
        "Dev3/ctr2", name_to_assign_to_channel="hammer", decoding_type=EncoderType.X_4,
        units=AngleUnits.TICKS, pulses_per_rev=40960, initial_angle=0.0)
    for t in (key, whippen, hammer):
        t.timing.cfg_samp_clk_timing.assert_not_called()        # on-demand reads
        t.start.assert_called_once_with()
        assert t.read.call_args_list == [mock.call()] * n_reads
        t.close.assert_called_once_with()
    assert sleeps == [1.0 / hz] * n_reads
    assert res.results["key"]["measured_extreme"] == pytest.approx(counts["key"].max() * 0.5e-6)
    assert res.results["key"]["expected_extreme"] == pytest.approx(0.0103, abs=0.001)
    for name in ("whippen", "hammer"):     # slopes against key dip, by dip not by time
        assert res.results[name]["ratio_to_model"] == pytest.approx(1.0, abs=0.03)
    # the hammer's counter wired the other way round: the check says so
    NI_TASKS.clear()
    data = ni.model_dump()
    data["channels"]["encoders"]["hammer"]["sign"] = -1
    bad = config.from_mapping(data)
    fails = " ".join(encoders.check(bad, NiBench(bad)).failures())
    assert "hammer: counts in the wrong direction" in fails and "whippen" not in fails


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
        cals = cal_records.lookup(config.builtin_sim())
    assert cals["load_cell"].nominal  # records went to --records, not the default folder
