"""The rough edges of `rig run` (issue 37): an unwritable output folder and a folder given
as a file are refused in one line with exit 2, a crashing controller's traceback goes to
stderr, and ``backend: sim`` implies the simulated drive."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from rig.cli import app
from rig.inputs import config

PROFILE = "name: p\nsegments:\n  - {hold: 0.02}\n  - {ramp: 0.05, to: 5}\n  - {ramp: 0.05, to: 0}\n"


def _files(tmp: Path, **extra) -> tuple[Path, Path]:
    prof = tmp / "p.yaml"
    prof.write_text(PROFILE)
    rig = tmp / "rig.yaml"
    rig.write_text(yaml.safe_dump({"name": "edges", "backend": "sim",
                                   "data_folder": str(tmp / "runs"), **extra}))
    return prof, rig


@pytest.fixture
def read_only(tmp_path: Path, tmpfs):
    """A folder nobody may write to: a read-only tmpfs (root ignores permissions), else a
    folder without write permission."""
    if os.geteuid() == 0:
        yield tmpfs("ro,size=64m", "ro")
        return
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    yield ro
    ro.chmod(0o755)


def test_an_unwritable_output_folder_is_one_line_and_exit_2(tmp_path: Path,
                                                             read_only: Path) -> None:
    prof, rig = _files(tmp_path)
    for args in (["-o", str(read_only / "run.h5")], ["-o", str(read_only / "sub" / "run.h5")],
                 ["-o", str(read_only / "run.h5"), "--force"]):
        res = CliRunner().invoke(app, ["run", str(prof), "--rig", str(rig), *args])
        assert res.exit_code == 2, res.output
        last = res.stderr.strip().splitlines()
        assert len(last) == 1 and last[0].startswith("error: --out: cannot write "), res.stderr
        assert "Traceback" not in res.output
    _, rig2 = _files(tmp_path)
    rig2.write_text(yaml.safe_dump({"backend": "sim", "data_folder": str(read_only / "d")}))
    res = CliRunner().invoke(app, ["run", str(prof), "--rig", str(rig2)])
    assert res.exit_code == 2 and res.stderr.strip().startswith("error: data_folder: cannot "
                                                                "write"), res.output
    assert list(read_only.iterdir()) == []


def test_a_folder_given_as_a_file_says_so(tmp_path: Path) -> None:
    prof, rig = _files(tmp_path)
    folder = tmp_path / "afolder"
    folder.mkdir()
    cases = [(["run", str(folder), "--rig", str(rig)], f"{folder}: is a folder"),
             (["run", str(prof), "--rig", str(folder)], f"{folder}: is a folder"),
             (["run", str(prof), "--rig", str(rig), "-o", str(folder)],
              f"--out: {folder} is a folder"),
             (["info", str(folder)], f"{folder}: is a folder"),
             (["recover", str(folder)], f"{folder}: is a folder")]
    for args, text in cases:
        res = CliRunner().invoke(app, args)
        assert res.exit_code == 2, (args, res.output)
        lines = res.stderr.strip().splitlines()
        assert len(lines) == 1 and text in lines[0], (args, res.stderr)


def test_backend_sim_implies_the_simulated_drive_unless_a_port_is_named() -> None:
    assert config.from_mapping({"backend": "sim"}).drive.port == "sim"
    assert config.from_mapping({"backend": "sim", "drive": {"timeout_s": 0.5}}).drive.port \
        == "sim"
    assert config.from_mapping({"backend": "sim", "drive": {"port": "/dev/pts/9"}}
                               ).drive.port == "/dev/pts/9"
    assert config.from_mapping({"backend": "ni"}).drive.port == "/dev/ttyS0"
    # what a run file records reads back the same
    cfg = config.from_mapping({"backend": "sim"})
    assert config.from_mapping(yaml.safe_load(cfg.to_yaml())).drive.port == "sim"


@pytest.mark.slow
def test_a_crashing_controller_traceback_goes_to_stderr(tmp_path: Path, monkeypatch) -> None:
    (tmp_path / "crashing.py").write_text(
        "class Crash:\n    def reset(self):\n        pass\n"
        "    def __call__(self, t, ff, measured):\n        return 1 / 0\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    prof, rig = _files(tmp_path, loop={"controller": "crashing:Crash", "rest_s": 0.05},
                       sim={"realtime": False})  # (only backend: sim: the sim drive)
    res = CliRunner().invoke(app, ["run", str(prof), "--rig", str(rig), "-o",
                                   str(tmp_path / "r.h5")])
    assert res.exit_code == 1, res.output
    assert "Traceback" not in res.stdout and "ZeroDivisionError" not in res.stdout, res.stdout
    assert "Traceback (most recent call last)" in res.stderr
    assert res.stderr.strip().splitlines()[-1].startswith("ABORTED: ZeroDivisionError")
