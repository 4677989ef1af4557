"""Issue 11 (inputs): settings and files that could move the motor or blind the safety
monitor are refused with one line naming the file and field (exit 2 at the CLI, nothing
written); a run file that did not finish is flagged by compare, diagnose and fit."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from rig import motor_torque
from rig.analysis import measurement as ms
from rig.calibration.records import MissingCalibration, lookup
from rig.cli import app
from rig.errors import InputError
from rig.inputs import config, profiles
from rig.model.action import ActionModel
from rig.recordings import runfile

ROOT = Path(__file__).parents[1]
FORTE = ROOT / "profiles" / "forte.yaml"


def _one_error_line(result, *parts: str) -> str:
    assert result.exit_code == 2, result.output
    lines = [ln for ln in result.stderr.splitlines()  # progress lines ("rig: ...") aside
             if ln.strip() and not ln.startswith("rig: ")]
    assert len(lines) == 1, lines
    for p in parts:
        assert p in lines[0], lines[0]
    return lines[0]


# ---- rig config ----
UNSAFE = [
    # zero demand must write 0 V: the output range's clamps must contain 0, min < max
    ("channels: {drive_output: {min_volts: 2}}", "channels.drive_output.min_volts"),
    ("channels: {drive_output: {min_volts: 10, max_volts: -10}}", "channels.drive_output"),
    ("channels: {drive_output: {min_volts: -1, max_volts: -0.5}}",
     "channels.drive_output.max_volts"),
    ("channels: {drive_output: {max_volts: 12}}", "channels.drive_output.max_volts"),
    # a drive poll slower than 100 ms would see a drive fault too late
    ("drive: {poll_period_s: 1.0e+9}", "drive.poll_period_s"),
    ("drive: {poll_period_s: 0.2}", "drive.poll_period_s"),
    # strict numbers: no bool as a number, no text, no inf or nan, bounded
    ("rates: {control_hz: true}", "rates.control_hz"),
    ("rates: {control_hz: '500'}", "rates.control_hz"),
    ("rates: {control_hz: 1.0e+12, acquisition_hz: 2.0e+12}", "rates.control_hz"),
    ("acquisition: {buffer_s: .inf}", "acquisition.buffer_s"),
    ("acquisition: {buffer_s: 1.0e+30}", "acquisition.buffer_s"),
    ("acquisition: {start_timeout_s: .nan}", "acquisition.start_timeout_s"),
    ("loop: {rest_s: .inf}", "loop.rest_s"),
    ("loop: {rest_s: 1.0e+300}", "loop.rest_s"),
    ("drive: {timeout_s: 1.0e+9}", "drive.timeout_s"),
    ("limits: {max_rate_n_per_s: .inf}", "limits.max_rate_n_per_s"),
    ("limits: {max_profile_s: 0}", "limits.max_profile_s"),
    ("channels: {encoders: {key: {counter: c0, body: key, kind: linear, "
     "metres_per_count: 1.0e-6, sign: true}}}", "channels.encoders.key.sign"),
    # channels that would replace the run's own
    *[(f"channels: {{encoders: {{k: {{counter: c0, body: key, kind: linear, "
       f"metres_per_count: 1.0e-6, channel: {name}}}}}}}", "channels.encoders")
      for name in ("force", "sample", "time", "demand", "volts", "load_cell_ratio")],
    ("calibration: {required: [motr]}", "calibration.required"),
    ("calibration: {load_cell: {average_s: .inf}}", "calibration.load_cell.average_s"),
]


@pytest.mark.parametrize(("text", "field"), UNSAFE)
def test_unsafe_configs_are_refused_in_one_line(tmp_path: Path, text: str, field: str) -> None:
    path = tmp_path / "rig.yaml"
    path.write_text(f"backend: sim\n{text}\n")
    with pytest.raises(InputError) as info:
        config.load(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: {field}") and "\n" not in msg


def test_an_encoder_named_like_a_run_channel_is_named_in_the_refusal(tmp_path: Path) -> None:
    path = tmp_path / "rig.yaml"
    path.write_text("backend: sim\nchannels: {encoders: {k: {counter: c0, body: key, "
                    "kind: linear, metres_per_count: 1.0e-6, channel: force}}}\n")
    with pytest.raises(InputError, match="encoder k would write channel 'force', one of the "
                                         "run's own channels"):
        config.load(path)


def test_a_quoted_line_break_stays_on_one_line(tmp_path: Path) -> None:
    path = tmp_path / "rig.yaml"
    path.write_text('backend: sim\nchannels: {encoders: {"a\\nb": {counter: c0, body: key, '
                    'kind: linear, metres_per_count: 1.0e-6}}}\n')
    with pytest.raises(InputError) as info:
        config.load(path)
    assert "\n" not in str(info.value) and "channels.encoders" in str(info.value)


@pytest.mark.parametrize("output", [{}, {"min_volts": 0.0}, {"min_volts": -2.5, "max_volts": 3},
                                    {"min_volts": -10, "max_volts": 0.5}])
def test_accepted_output_ranges_write_0_v_at_zero_demand(output: dict) -> None:
    cfg = config.builtin_sim(channels={"drive_output": output})
    scaling = motor_torque.TorqueScaling.from_config(cfg.drive_scaling,
                                                     cfg.channels.drive_output)
    limiter = motor_torque.Limiter(cfg.limits, 1 / cfg.rates.control_hz)
    assert scaling.volts(limiter(0.0)[0]) == 0.0
    assert scaling.volts(1e9) == cfg.channels.drive_output.max_volts  # the upper clamp
    assert scaling.volts(-1e9) == cfg.channels.drive_output.min_volts  # the lower clamp


def test_defaults_and_round_trip_still_hold(tmp_path: Path) -> None:
    cfg = config.builtin_sim(data_folder=str(tmp_path / "d"))  # a path as YAML gives it
    assert cfg.limits.max_profile_s == 60.0 and cfg.drive.poll_period_s == 0.05
    again = config.from_mapping(cfg.model_dump(mode="json"))
    assert again == cfg


def test_motor_required_with_raw_units_runs_on_the_advance(tmp_path: Path) -> None:
    """calibration.required: [motor] without a record: refused on ni, or with use_raw_units
    the run goes on with the loop.advance_s lead (the motor has no data-sheet record)."""
    from rig.calibration.motor import demand_source

    folder = tmp_path / "cal"
    folder.mkdir()
    base = {"backend": "ni", "calibration": {"required": ["motor"],
                                             "records_folder": str(folder)}}
    with pytest.raises(MissingCalibration, match="rig calibrate motor"):
        lookup(config.from_mapping(base))
    raw = config.from_mapping({**base, "calibration": {**base["calibration"],
                                                       "use_raw_units": True}})
    cals = lookup(raw)
    assert "motor" not in cals and cals["load_cell"].nominal
    feedforward, comp = demand_source(raw, [])
    assert comp["kind"] != "motor calibration" and comp["lead_s"] == raw.loop.advance_s


def test_cli_run_refuses_an_unsafe_rig_in_one_line(tmp_path: Path) -> None:
    rig = tmp_path / "rig.yaml"
    rig.write_text(f"backend: sim\ndrive: {{port: sim}}\ndata_folder: {tmp_path / 'runs'}\n"
                   "channels: {drive_output: {min_volts: 2}}\n")
    r = CliRunner().invoke(app, ["run", str(FORTE), "--rig", str(rig)])
    _one_error_line(r, f"error: {rig}: channels.drive_output.min_volts")
    assert not (tmp_path / "runs").exists()


@pytest.mark.slow
def test_real_cli_process_refuses_a_bool_rate_with_exit_2(tmp_path: Path) -> None:
    rig = tmp_path / "rig.yaml"
    rig.write_text("backend: sim\ndrive: {port: sim}\nrates: {control_hz: true}\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}  # this tree's rig
    out = subprocess.run([sys.executable, "-m", "rig", "run", str(FORTE), "--rig", str(rig)],
                         capture_output=True, text=True, timeout=120, cwd=tmp_path, env=env,
                         check=False)
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [
        f"error: {rig}: rates.control_hz: Input should be a valid number"]
    assert not (tmp_path / "runs").exists()


# ---- profiles ----
def write(tmp_path: Path, text: str, name: str = "p.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("header", ["force_N,time_s", "time_s,force_N", " Force_N , TIME_S "])
def test_csv_header_is_read_by_name(tmp_path: Path, header: str) -> None:
    cols = [c.strip().lower() for c in header.split(",")]
    rows = [(0.0, 0.0), (0.01, 3.0), (0.03, 0.0)]  # (time, force)
    body = "".join(f"{r[cols.index('time_s')]},{r[cols.index('force_n')]}\n" for r in rows)
    p = profiles.load(write(tmp_path, f"{header}\n{body}", "f.csv"))
    np.testing.assert_array_equal(p.time, [0.0, 0.01, 0.03])
    np.testing.assert_array_equal(p.force, [0.0, 3.0, 0.0])


@pytest.mark.parametrize(("text", "field"), [
    ("time,torque\n0,0\n0.1,1\n", "line 1 column 2 'torque'"),  # time,force is read (issue 34)
    ("time_s,time_s\n0,0\n0.1,1\n", "line 1 header"),
    ("time_s,force_N,extra\n0,0,1\n", "line 1"),
    ("0,0\n0.1,1,2\n", "line 2"),
    ("time_s,force_N\n0,0\n0.1,abc\n", "line 3 force_N"),
    ("0,0\n0.1,1\n120,1\n", "points[2] time"),
])
def test_bad_csv_profiles_name_the_file_and_line(tmp_path: Path, text: str, field: str) -> None:
    path = write(tmp_path, text, "f.csv")
    with pytest.raises(InputError) as info:
        profiles.load(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: {field}") and "\n" not in msg


def test_profiles_longer_than_the_maximum_are_refused(tmp_path: Path) -> None:
    long = write(tmp_path, "segments: [{hold: 1.0e+6}]\n")
    with pytest.raises(InputError, match=r"segments\[0\]: the profile would last 1e\+06 s, "
                                         r"longer than the 60 s allowed"):
        profiles.load(long)
    p = write(tmp_path, "points: [[0, 0], [30, 1], [45, 0]]\n", "p2.yaml")
    assert profiles.load(p).duration == 45.0
    with pytest.raises(InputError, match=r"points\[2\] time: 45 s is beyond the longest profile "
                                         r"allowed, 40 s"):
        profiles.load(p, max_duration=40)


def test_cli_run_refuses_a_profile_over_the_rigs_maximum(tmp_path: Path) -> None:
    rig = write(tmp_path, f"backend: sim\ndrive: {{port: sim}}\ndata_folder: {tmp_path / 'r'}\n"
                          "limits: {max_profile_s: 0.5}\n", "rig.yaml")
    r = CliRunner().invoke(app, ["run", str(FORTE), "--rig", str(rig)])  # forte lasts 0.6 s
    _one_error_line(r, f"error: {FORTE}: segments[4]: the profile would last 0.6 s, longer than "
                       "the 0.5 s allowed (the rig's limits.max_profile_s)")
    assert not (tmp_path / "r").exists()
    huge = write(tmp_path, "segments: [{hold: 1.0e+6}]\n")
    r = CliRunner().invoke(app, ["simulate", str(huge), "--out", str(tmp_path / "o.h5")])
    _one_error_line(r, f"error: {huge}: segments[0]")
    assert not (tmp_path / "o.h5").exists()


def test_undecodable_missing_and_oversized_files_are_named(tmp_path: Path) -> None:
    bad = tmp_path / "latin.yaml"
    bad.write_bytes(b"name: caf\xe9\npoints: [[0, 0], [0.1, 1]]\n")
    with pytest.raises(InputError, match=f"^{bad}: not a UTF-8 text file"):
        profiles.load(bad)
    bad_csv = tmp_path / "latin.csv"
    bad_csv.write_bytes(b"0,0\n0.1,\xff\n")
    with pytest.raises(InputError, match=f"^{bad_csv}: not a UTF-8 text file"):
        profiles.load(bad_csv)
    ref = write(tmp_path, "csv: latin.csv\n", "ref.yaml")
    with pytest.raises(InputError, match=f"^{bad_csv}: not a UTF-8"):
        profiles.load(ref)
    big = tmp_path / "big.yaml"
    with big.open("w") as fh:
        fh.write("points:\n")
        line = "- [0, 0]\n" * 1000
        while fh.tell() <= profiles.MAX_FILE_BYTES:
            fh.write(line)
    with pytest.raises(InputError, match=f"^{big}: file is \\d+ bytes, more than the "
                                         f"{profiles.MAX_FILE_BYTES} allowed"):
        profiles.load(big)
    rig = tmp_path / "rig.yaml"
    rig.write_bytes(b"backend: sim\nname: \xff\n")
    r = CliRunner().invoke(app, ["run", str(FORTE), "--rig", str(rig)])
    _one_error_line(r, f"error: {rig}: not a UTF-8 text file")


def test_cli_refuses_an_undecodable_profile(tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_bytes(b"\xff\xfe0,0\n")
    r = CliRunner().invoke(app, ["simulate", str(bad), "--out", str(tmp_path / "o.h5")])
    _one_error_line(r, f"error: {bad}: not a UTF-8 text file")
    assert not (tmp_path / "o.h5").exists()


# ---- user effects that fail to import ----
@pytest.mark.parametrize(("source", "expected"), [
    ("import numpy as np\nx = 1 / 0\n", "line 2: ZeroDivisionError: division by zero"),
    ("def broken(:\n", "SyntaxError"),
    ("import no_such_module_here\n", "ModuleNotFoundError: No module named "
                                     "'no_such_module_here'"),
])
def test_a_user_effect_that_fails_to_import_gives_one_line(tmp_path: Path, source: str,
                                                           expected: str) -> None:
    eff = write(tmp_path, source, "my_effect.py")
    r = CliRunner().invoke(app, ["simulate", str(FORTE), "--out", str(tmp_path / "o.h5"),
                                 "-e", f"{eff}:Mine"])
    _one_error_line(r, f"error: effect '{eff}:Mine': {eff} failed to import: ", expected)
    assert not (tmp_path / "o.h5").exists()


def test_diagnose_extra_effect_that_fails_to_import_gives_one_line(tmp_path: Path) -> None:
    eff = write(tmp_path, "raise RuntimeError('not ready')\n", "my_effect.py")
    run = _run_file(tmp_path, "complete")
    r = CliRunner().invoke(app, ["diagnose", str(run), "--extra", f"{eff}:Mine",
                                 "--candidate", "compliant_string", "--jobs", "1",
                                 "--duration", "0.02"])
    _one_error_line(r, str(eff), "RuntimeError: not ready")


# ---- compare / diagnose / fit on a run that did not finish ----
def _run_file(tmp_path: Path, status: str) -> Path:
    res = ActionModel(output_rate=2000).simulate(profiles.load(FORTE), 0.03)
    path = runfile.write_result(tmp_path / f"{status.split(':')[0]}.h5", res)
    with h5py.File(path, "r+") as f:
        f.attrs["status"] = status
    return path


def test_status_warning_says_aborted_or_running(tmp_path: Path) -> None:
    aborted = _run_file(tmp_path, "aborted: interrupted (Ctrl-C)")
    running = _run_file(tmp_path, "running")
    complete = _run_file(tmp_path, "complete")
    text = ms.status_warning(aborted)
    assert text is not None and "\n" not in text
    assert text.startswith(f"warning: {aborted}: the run was aborted: interrupted (Ctrl-C)")
    text = ms.status_warning(running)
    assert text is not None and "not finished (status running" in text
    assert ms.status_warning(complete) is None


@pytest.mark.parametrize("command", [
    ["compare", "{run}", "--duration", "0.02"],
    ["diagnose", "{run}", "--candidate", "compliant_string", "--jobs", "1", "--duration",
     "0.02"],
    ["fit", "{run}", "--param", "compliant_string.stiffness", "--model", "{model}", "--jobs",
     "1", "--max-nfev", "2", "--duration", "0.02"],
])
@pytest.mark.slow
def test_analysis_commands_warn_on_an_aborted_run(tmp_path: Path, command: list[str]) -> None:
    run = _run_file(tmp_path, "aborted: drive fault")
    model = write(tmp_path, "effects: [compliant_string]\n", "m.yaml")
    args = [a.format(run=run, model=model) for a in command]
    r = CliRunner().invoke(app, args)
    warned = [ln for ln in r.stderr.splitlines() if ln.startswith("warning:")]
    assert warned == [f"warning: {run}: the run was aborted: drive fault; its last trial may "
                      f"end early and the analysis uses only the samples recorded before the "
                      f"abort"], r.output
    complete = _run_file(tmp_path, "complete")
    r = CliRunner().invoke(app, [a.format(run=complete, model=model) for a in command])
    assert "warning:" not in r.stderr


def test_a_controller_module_that_fails_to_import_gives_one_line(tmp_path: Path,
                                                                 monkeypatch) -> None:
    write(tmp_path, "x = 1 / 0\n", "my_ctl_broken.py")
    monkeypatch.syspath_prepend(str(tmp_path))
    rig = write(tmp_path, f"backend: sim\ndrive: {{port: sim}}\ndata_folder: {tmp_path / 'r'}\n"
                          "loop: {controller: 'my_ctl_broken:Ctl'}\n", "rig.yaml")
    r = CliRunner().invoke(app, ["run", str(FORTE), "--rig", str(rig)])
    _one_error_line(r, "error: loop.controller: cannot load 'my_ctl_broken:Ctl' "
                       "(ZeroDivisionError: division by zero)")
    assert not (tmp_path / "r").exists()


def test_an_oversized_rig_config_is_refused_unread(tmp_path: Path) -> None:
    path = tmp_path / "rig.yaml"
    path.write_text("backend: sim\n" + "# padding\n" * 200_000)
    with pytest.raises(InputError, match=f"^{path}: file is \\d+ bytes, more than the "
                                         f"{config.MAX_CONFIG_BYTES} allowed$"):
        config.load(path)


@pytest.mark.parametrize("argv, line", [
    (["run", "--bogus"], "rig run: No such option: --bogus (Possible options: --out)"),
    (["nosuchcmd"], "rig: No such command 'nosuchcmd'."),
    (["run", "profiles/forte.yaml", "--trials", "two"],
     "rig run: Invalid value for '--trials': 'two' is not a valid int."),
    (["simulate"], "rig simulate: Missing argument 'profile'."),
])
def test_a_mistyped_command_line_is_one_line_and_exit_2(argv, line, monkeypatch, capsys) -> None:
    # issue 37: click's usage errors were a four-line box
    from rig.cli import main

    monkeypatch.setattr(sys, "argv", ["rig", *argv])
    with pytest.raises(SystemExit) as info:
        main()
    out, errs = capsys.readouterr()
    assert info.value.code == 2 and out == ""
    assert errs.splitlines() == [f"{line} (see '{line.split(':')[0]} --help')"]


def test_rig_alone_prints_the_help(monkeypatch, capsys) -> None:
    from rig.cli import main

    monkeypatch.setattr(sys, "argv", ["rig"])
    with pytest.raises(SystemExit) as info:
        main()
    assert info.value.code == 2 and "Usage: rig [OPTIONS] COMMAND" in capsys.readouterr().out
