"""`rig run` says what it is doing while the simulated rig starts (issue 16)."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.inputs import config
from rig.services import run as svc

pytestmark = pytest.mark.realtime  # what these tests cost (pyproject.toml)

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_run_says_what_the_start_is_doing(tmp_path: Path) -> None:
    profile = tmp_path / "short.yaml"
    profile.write_text("name: short\nsegments:\n  - {hold: 0.01}\n  - {ramp: 0.02, to: 5}\n"
                       "  - {ramp: 0.02, to: 0}\n")
    cfg = config.from_mapping({
        "name": "test", "backend": "sim", "drive": {"port": "sim", "poll_period_s": 0.01},
        "sim": {"realtime": False}, "loop": {"rest_s": 0.05}, "data_folder": str(tmp_path)})
    lines: list[str] = []
    report = svc.run(profile, cfg, out=tmp_path / "r.h5", on_line=lines.append)
    assert report.complete

    def first(text: str) -> int:
        return next(i for i, line in enumerate(lines) if line.startswith(text))

    # in the order they happen, before the loop's first line
    assert (first("building the simulated rig's action model")
            < first("starting the acquisition process")
            < first("enabling the drive")
            < first("running short"))
