"""`rig --version`, `rig info` and `rig plot` (issue 15) on a hand-made measured run file
(real HDF5 through rig.recordings.runfile, known values) and in a real subprocess."""

from __future__ import annotations

import hashlib
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from rig import __version__
from rig.analysis import quicklook
from rig.cli import app
from rig.recordings import runfile

runner = CliRunner()


@pytest.fixture()
def measured(tmp_path: Path) -> Path:
    """A two-trial measured run: hammer angle a ramp to -0.3 rad, key dip to 10 mm, events
    written out of time order, lateness of the 500 Hz loop 0..0.2 ms, two calibrations."""
    path = tmp_path / "meas.h5"
    cals = [{"sensor": "load_cell", "nominal": False, "sensitivity": 1.8e-5, "offset": 0.0,
             "raw_units": "V/V", "units": "N", "source": "rig calibrate loadcell"},
            {"sensor": "hammer", "nominal": True, "sensitivity": 3.8e-5, "offset": 0.0,
             "raw_units": "counts", "units": "rad", "source": "data sheet"}]
    lat = {"cycles": 200.0, "median_s": 1e-4, "p99_s": 2e-4, "max_s": 2e-4, "missed": 0.0,
           "late_cycles": 0.0}
    with runfile.RunWriter(path, "measured", {"calibrations": cals,
                                              "loop_lateness": lat}) as w:
        for i in range(2):
            t = np.arange(-0.05, 0.15, 1 / 2000)
            tw = w.trial()
            tw.append("channels", {"time": t, "hammer_angle": -0.3 * np.clip(t / 0.1, 0, 1),
                                   "key_dip": 0.01 * np.clip(t / 0.06, 0, 1),
                                   "force": 20 * np.clip(t / 0.05, 0, 1)},
                      {"time": "s", "hammer_angle": "rad", "key_dip": "m", "force": "N"})
            tc = np.arange(0, 0.2, 1 / 500)
            tw.append("commands", {"time": tc, "lateness": np.linspace(0, 2e-4, tc.size),
                                   "missed": np.zeros(tc.size)},
                      {"time": "s", "lateness": "s", "missed": "1"})
            tw.write_events({"strike": 0.1, "key_starts": 0.001, "let_off": 0.098,
                             "check": float("nan")})
            tw.set_attrs(status="complete", t0=i * 0.3)
    return path


def test_version() -> None:
    r = runner.invoke(app, ["--version"])
    assert r.exit_code == 0 and r.output.startswith(f"rig {__version__} (git ")


def test_info_shows_calibrations_loop_ranges_and_events_in_time_order(measured: Path) -> None:
    r = runner.invoke(app, ["info", str(measured)])
    assert r.exit_code == 0, r.output
    out = r.output
    assert "measured run, status complete" in out
    assert re.search(r"load_cell\s+1\.8e-05 N per V/V, offset 0, measured", out)
    assert "hammer             3.8e-05 rad per counts" in out and "nominal" in out
    assert "loop: 200 cycles, lateness median 0.100 ms, p99 0.200 ms" in out
    assert "loop: 100 cycles, lateness median 0.100 ms" in out  # per trial, from commands
    assert re.search(r"hammer_angle\s+rad\s+-300 \.\. -?0 mrad", out)
    assert re.search(r"key_dip\s+m\s+0 \.\. 10 mm", out)
    first = out.split("trial 1:")[0]
    order = [m.group(1) for m in re.finditer(r"event (\w+)", first)]
    assert order == ["key_starts", "let_off", "strike", "check"]  # NaN last
    assert re.search(r"event check\s+--", first)


def test_plot_png_and_window_and_overwrite_refusal(measured: Path, tmp_path: Path) -> None:
    png = tmp_path / "q.png"
    r = runner.invoke(app, ["plot", str(measured), "--trial", "1", "--window", "0.05:0.12",
                            "--channel", "hammer_angle", "--out", str(png)])
    assert r.exit_code == 0, r.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    import matplotlib.image as mpimg

    img = mpimg.imread(png)
    assert img.shape[0] > 200 and img.shape[1] > 600
    digest = hashlib.sha256(png.read_bytes()).hexdigest()
    r = runner.invoke(app, ["plot", str(measured), "--out", str(png)])
    assert r.exit_code == 2 and "exists (use --force" in r.output
    assert hashlib.sha256(png.read_bytes()).hexdigest() == digest  # byte-identical
    r = runner.invoke(app, ["plot", str(measured), "--out", str(png), "--force"])
    assert r.exit_code == 0 and hashlib.sha256(png.read_bytes()).hexdigest() != digest


@pytest.mark.parametrize(("args", "message"), [
    (["--window", "0.09"], "window: expected START:END"),
    (["--window", "0.09:0.05"], "window: START must be before END"),
    (["--window", "5:6"], "window: no samples of trial 0"),
    (["--trial", "7"], "trial: 7 is not a trial"),
    (["--channel", "jack_angle"], "channel: 'jack_angle' is not a channel"),
    (["--out", "x.pdf"], "out: expected a .html or .png path"),
])
def test_plot_bad_input_names_the_field(measured: Path, tmp_path: Path, args: list[str],
                                        message: str) -> None:
    before = sorted(tmp_path.iterdir())
    r = runner.invoke(app, ["plot", str(measured), *args], catch_exceptions=False)
    assert r.exit_code == 2 and message in r.output, r.output
    assert sorted(tmp_path.iterdir()) == before  # nothing written


@pytest.mark.browser
def test_plot_html_in_a_subprocess_renders_in_chromium(measured: Path, tmp_path: Path) -> None:
    env = dict(os.environ)
    r = subprocess.run([sys.executable, "-m", "rig", "plot", str(measured), "--window",
                        "0.05:0.12"], capture_output=True, text=True, env=env, check=False,
                       cwd=tmp_path, timeout=120)
    out = measured.with_name("meas-trial0.html")
    assert r.returncode == 0, r.stderr
    assert f"wrote {out}" in r.stdout
    text = out.read_text()
    assert re.search(r"<script[^>]*\bsrc=", text) is None
    assert "let-off 98.00 ms" in text and "strike 100.00 ms" in text
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("chromium is not installed (tools/test.sh installs it)")
    cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
           "--enable-logging=stderr", "--v=0", "--virtual-time-budget=8000", "--dump-dom",
           out.resolve().as_uri()]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=180, check=False)
    assert not [ln for ln in res.stderr.splitlines() if "Uncaught" in ln
                or "ERROR:CONSOLE" in ln]
    assert 'data-plots-drawn="1"' in res.stdout and 'data-errors="' not in res.stdout


def test_parse_window_open_ends() -> None:
    assert quicklook.parse_window("0.05:") == (0.05, float("inf"))
    assert quicklook.parse_window(":0.09") == (float("-inf"), 0.09)
    assert quicklook.parse_window(None) is None


def test_candidate_chart_is_not_clipped_and_shows_values() -> None:
    """A candidate that makes the held-out error four times worse (-300 %) is drawn at
    -300 % with its value, not clipped at -100 %."""
    from types import SimpleNamespace

    from rig.analysis import report

    def cand(name: str, removal: float, sig: bool) -> SimpleNamespace:
        return SimpleNamespace(name=name, removal=removal, significant=sig, error="")

    diag = SimpleNamespace(min_gain=0.2, candidates=[
        cand("compliant_string", 0.955, True), cand("key_liftoff", -3.0, False),
        SimpleNamespace(name="broken", removal=-math.inf, significant=False, error="failed")])
    fig = report._candidates(diag)
    bar = fig.data[0]
    assert list(bar.y) == ["key_liftoff", "compliant_string"]  # best on top
    assert list(bar.x) == pytest.approx([-300.0, 95.5])
    assert list(bar.text) == ["-300.0 %", "95.5 %"]
    lo, hi = fig.layout.xaxis.range
    assert lo < -300 and hi > 95.5
