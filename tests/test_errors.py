"""Every error rig raises on purpose is a RigError, and the user's mistakes are one line and
exit 2 (issue 36): the exception classes of every rig module, and two mistakes through the
CLI that used to exit 1 with a traceback hint (``--learn`` with ``--trials``, a real-rig
run without its calibration record)."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
from pathlib import Path

import yaml
from typer.testing import CliRunner

import rig
from rig.cli import app
from rig.errors import InputError, RigError

ROOT = Path(__file__).resolve().parents[1]
FORTE = ROOT / "profiles" / "forte.yaml"
# signals: a BaseException on purpose, so that no `except Exception` of a cleanup eats them
NOT_ERRORS = {"rig.services.run._Stopped"}


def _modules() -> list[str]:
    return [m.name for m in pkgutil.walk_packages(rig.__path__, "rig.")
            if not m.name.endswith("__main__")]


def test_every_exception_class_of_rig_is_a_rig_error() -> None:
    found = {}
    for name in _modules():
        mod = importlib.import_module(name)
        for cname, cls in inspect.getmembers(mod, inspect.isclass):
            if cls.__module__ == name and issubclass(cls, BaseException) \
                    and not issubclass(cls, Warning):  # (warnings are not errors)
                found[f"{name}.{cname}"] = cls
    assert {"rig.loop.drive.DriveError", "rig.daq.DaqFault", "rig.loop.acquisition.DiskFull",
            "rig.calibration.records.MissingCalibration"} <= set(found)
    outside = sorted(k for k, c in found.items() if not issubclass(c, RigError)
                     and k not in NOT_ERRORS)
    assert outside == []


def test_a_missing_calibration_is_the_user_s_to_fix() -> None:
    from rig.calibration.records import MissingCalibration

    assert issubclass(MissingCalibration, InputError)
    assert issubclass(MissingCalibration, RuntimeError)  # (as before, for its callers)


def _one_line_exit_2(res, *words: str) -> None:
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    assert "Traceback" not in res.stderr and "rig -v" not in res.stderr
    for w in words:
        assert w in lines[0], lines[0]


def test_learn_with_trials_is_one_line_and_exit_2() -> None:
    res = CliRunner().invoke(app, ["run", str(FORTE), "--learn", "3", "--trials", "2"])
    _one_line_exit_2(res, "--learn", "--trials")


def test_a_real_rig_run_without_its_calibration_is_one_line_and_exit_2(tmp_path: Path) -> None:
    folder = tmp_path / "cal"
    folder.mkdir()
    rig_yaml = tmp_path / "rig.yaml"
    rig_yaml.write_text(yaml.safe_dump({
        "backend": "ni", "data_folder": str(tmp_path),
        "calibration": {"required": ["motor"], "records_folder": str(folder)}}))
    res = CliRunner().invoke(app, ["run", str(FORTE), "--rig", str(rig_yaml),
                                   "-o", str(tmp_path / "run.h5")])
    _one_line_exit_2(res, "rig calibrate motor")
    assert not (tmp_path / "run.h5").exists()
