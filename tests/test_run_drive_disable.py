"""A drive that does not take its disable command at the run's end (issue 36): the run
still finishes its file, the failure is reported on the trace (the CLI's stderr) and
recorded in the run file's metadata (``drive_disable_failed``), not swallowed."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.inputs import config
from rig.loop.drive import Drive, DriveError
from rig.recordings import runfile
from rig.services import run as svc


def _short_run(tmp_path: Path) -> tuple[Path, config.RigConfig]:
    """A 0.11 s blow to 5 N on the simulated rig, lock-step (not real time)."""
    prof = tmp_path / "short.yaml"
    prof.write_text("name: short\nsegments:\n  - {hold: 0.01}\n  - {ramp: 0.05, to: 5}\n"
                    "  - {ramp: 0.05, to: 0}\n")
    cfg = config.from_mapping({"name": "t", "backend": "sim", "data_folder": str(tmp_path),
                               "drive": {"port": "sim", "poll_period_s": 0.01},
                               "sim": {"realtime": False}, "loop": {"rest_s": 0.05}})
    return prof, cfg


@pytest.mark.slow
def test_a_failed_drive_disable_is_reported_and_recorded(tmp_path: Path, monkeypatch) -> None:
    prof, cfg = _short_run(tmp_path)
    disables: list[bool] = []

    def refuse(self: Drive) -> None:
        disables.append(self.enabled)
        raise DriveError("no answer to the disable command")

    monkeypatch.setattr(Drive, "disable", refuse)
    said: list[str] = []
    rep = svc.run(prof, cfg, out=tmp_path / "run.h5", on_line=lambda s: None,
                  on_trace=said.append)
    assert disables == [True]  # the run's end tried it once, on the enabled drive
    warned = [s for s in said if "disable" in s]
    assert len(warned) == 1 and "DriveError: no answer to the disable command" in warned[0]
    run = runfile.read(rep.path)
    assert run.status == "complete"  # the blow itself ran to its end
    assert run.metadata["drive_disable_failed"] == "DriveError: no answer to the disable command"


@pytest.mark.slow
def test_a_drive_that_disables_leaves_no_such_record(tmp_path: Path) -> None:
    prof, cfg = _short_run(tmp_path)
    rep = svc.run(prof, cfg, out=tmp_path / "run.h5", on_line=lambda s: None)
    assert "drive_disable_failed" not in runfile.read(rep.path).metadata
