"""`rig import` (issue 38): recordings of other labs through a map into a run file, their
calibration, their segmentation into strokes, and the refusals of bad maps and files."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from rig.cli import app
from rig.errors import InputError
from rig.recordings import calibration as cal
from rig.recordings import mapfile, readers, runfile
from rig.recordings import segment as sg
from rig.services import importer

ROOT = Path(__file__).resolve().parents[1]
KAWAI = ROOT / "examples" / "kawai-kg3c"
KAWAI_TXT = KAWAI / "hammer_damper_2K_17b.txt"
KAWAI_SHA256 = "145dddefcda5dbfe2aa0bb55fc550d0a6f7d5f61e623d25d4d00c344997a5400"


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _blows(rate: float = 1000.0, n: int = 3, seed: int = 1) -> tuple[np.ndarray, np.ndarray,
                                                                      np.ndarray]:
    """A key dip (m) with ``n`` half-sine presses of 10 mm, 0.2 s each, 0.5 s apart, noise
    of 10 um; returns time, key dip and force (N, 5 N per mm)."""
    t = np.arange(int(rate * (0.4 + 0.5 * n))) / rate
    dip = np.zeros_like(t)
    for k in range(n):
        a = 0.3 + 0.5 * k
        inside = (t >= a) & (t <= a + 0.2)
        dip[inside] = 0.01 * np.sin(np.pi * (t[inside] - a) / 0.2)
    rng = np.random.default_rng(seed)
    return t, dip + rng.normal(0, 1e-5, t.size), 5000.0 * dip


# --- text files -------------------------------------------------------------------------

def test_csv_with_a_header_and_a_time_column(tmp_path):
    t, dip, f = _blows()
    rows = "\n".join(f"{a * 1e3:.3f},{b:.6f},{c * 1e3:.4f}" for a, b, c in zip(t, f, dip,
                                                                             strict=True))
    src = _write(tmp_path / "blow.csv", "time_ms,force_N,dip_mm\n" + rows + "\n")
    m = _write(tmp_path / "map.yaml", """
time: {column: time_ms, units: ms}
columns:
  - {column: force_N, channel: force, units: N}
  - {column: dip_mm, channel: key_dip, units: mm}
""")
    res = importer.import_files([src], m, tmp_path / "run.h5")
    run = runfile.read(tmp_path / "run.h5")
    assert run.kind == "measured" and run.status == "complete" and len(run.trials) == 1
    tr = run.trials[0]
    np.testing.assert_allclose(tr.channels["time"], t - t[0], atol=1e-9)
    np.testing.assert_allclose(tr.channels["force"], f, atol=1e-4)
    np.testing.assert_allclose(tr.channels["key_dip"], dip, atol=6e-8)  # 4 decimals of mm
    assert tr.units == {"time": "s", "force": "N", "key_dip": "m"}
    prov = run.metadata["import"]["files"][0]
    import hashlib
    assert prov["sha256"] == hashlib.sha256(src.read_bytes()).hexdigest()
    assert run.metadata["import_map"] == m.read_text()
    assert res.trials[0].samples == t.size


def test_csv_without_a_header_at_a_sample_rate_and_tsv(tmp_path):
    t, dip, f = _blows(rate=500.0)
    m = _write(tmp_path / "map.yaml", """
header: false
sample_rate_hz: 500
columns:
  - {column: 2, channel: force, units: kN, calibration: {linear: {scale: 0.001}}}
""")
    for sep, name in ((",", "a.csv"), ("\t", "a.tsv")):
        src = _write(tmp_path / name, "\n".join(f"{a:.6f}{sep}{b:.6f}" for a, b in
                                                 zip(dip, f, strict=True)))
        importer.import_files([src], m, tmp_path / f"{name}.h5")
        tr = runfile.read(tmp_path / f"{name}.h5").trials[0]
        np.testing.assert_allclose(tr.channels["time"], np.arange(t.size) / 500.0)
        np.testing.assert_allclose(tr.channels["force"], f, atol=1e-5)  # kN * 1e-3 -> N


def test_whitespace_text_with_comments(tmp_path):
    src = _write(tmp_path / "log.txt", "# sensor log\n# two columns\n"
                 + "\n".join(f"  {i * 0.1:.3f}   {i}" for i in range(50)) + "\n")
    m = _write(tmp_path / "map.yaml", """
sample_rate_hz: 100
columns:
  - column: 2
    channel: key_angle
    units: deg
    calibration: {polynomial: [1, 2, 0.5]}
""")
    importer.import_files([src], m, tmp_path / "r.h5")
    tr = runfile.read(tmp_path / "r.h5").trials[0]
    x = np.arange(50.0)
    np.testing.assert_allclose(tr.channels["key_angle"], np.deg2rad(1 + 2 * x + 0.5 * x * x))


def test_tdms_written_by_nptdms(tmp_path):
    import nptdms  # a dependency of rig (pyproject.toml); never skipped

    t, dip, f = _blows(rate=2000.0)
    path = tmp_path / "rig.tdms"
    with nptdms.TdmsWriter(str(path)) as w:
        w.write_segment([
            nptdms.ChannelObject("Measurements", "Force", f,
                                 properties={"wf_increment": 0.0005}),
            nptdms.ChannelObject("Measurements", "Dip", dip * 1e3,
                                 properties={"wf_increment": 0.0005})])
    m = _write(tmp_path / "map.yaml", """
columns:
  - {column: Measurements/Force, channel: force, units: N}
  - {column: Measurements/Dip, channel: key_dip, units: mm}
""")
    importer.import_files([path], m, tmp_path / "r.h5")
    tr = runfile.read(tmp_path / "r.h5").trials[0]
    np.testing.assert_allclose(tr.channels["time"], np.arange(t.size) * 0.0005)
    np.testing.assert_allclose(tr.channels["force"], f)
    np.testing.assert_allclose(tr.channels["key_dip"], dip)
    bad = _write(tmp_path / "bad.yaml", "columns:\n  - {column: Measurements/Nope, "
                 "channel: force, units: N}\n")
    with pytest.raises(InputError, match=r"rig.tdms: column 'Measurements/Nope' not found"):
        importer.import_files([path], bad, tmp_path / "r2.h5")


def test_tdms_without_nptdms_is_refused_with_the_install_line(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "nptdms", None)  # as where npTDMS is not installed
    path = _write(tmp_path / "x.tdms", "not really")
    with pytest.raises(InputError, match=r"x.tdms: reading TDMS needs the npTDMS package.*"
                                         r"pip install 'npTDMS"):
        readers.read(path, "tdms")


def test_geometry_arc_and_sine():
    g = mapfile.Geometry(0.1)
    np.testing.assert_allclose(g.angle(np.array([0.0, 0.01, -0.02])), [0.0, 0.1, -0.2])
    s = mapfile.Geometry(0.1, "sine")
    np.testing.assert_allclose(s.angle(np.array([0.05])), [math.pi / 6])
    with pytest.raises(InputError, match="exceeds the radius"):
        s.angle(np.array([0.2]))


def test_hdf5_columns_with_geometry(tmp_path):
    t, dip, f = _blows()
    src = tmp_path / "other.h5"
    with h5py.File(src, "w") as h:
        h["daq/t"] = t
        h["daq/matrix"] = np.c_[f, dip * 1e3]
    m = _write(tmp_path / "map.yaml", """
time: {column: /daq/t}
columns:
  - {column: /daq/matrix, index: 1, channel: force, units: N}
  - column: /daq/matrix
    index: 2
    channel: hammer_angle
    units: mm
    geometry: {radius: 100, radius_units: mm, model: sine}
""")
    importer.import_files([src], m, tmp_path / "r.h5")
    tr = runfile.read(tmp_path / "r.h5").trials[0]
    np.testing.assert_allclose(tr.channels["force"], f)
    np.testing.assert_allclose(tr.channels["hammer_angle"], np.arcsin(dip / 0.1))
    assert tr.units["hammer_angle"] == "rad"


def test_several_files_become_consecutive_trials(tmp_path):
    t, dip, f = _blows(rate=1000.0, n=2)
    srcs = []
    for k in range(2):
        srcs.append(_write(tmp_path / f"take{k}.csv", "force,dip\n" + "\n".join(
            f"{b * (k + 1):.6f},{c:.8f}" for b, c in zip(f, dip, strict=True))))
    m = _write(tmp_path / "map.yaml", "sample_rate_hz: 1000\ncolumns:\n"
               "  - {column: force, channel: force, units: N}\n"
               "  - {column: dip, channel: key_dip, units: m}\nsegment: {channel: key_dip}\n")
    res = importer.import_files(srcs, m, tmp_path / "r.h5")
    assert [(r.trial, r.file) for r in res.trials] == [(0, "take0.csv"), (1, "take0.csv"),
                                                       (2, "take1.csv"), (3, "take1.csv")]
    run = runfile.read(tmp_path / "r.h5")
    assert [x["name"] for x in run.metadata["import"]["files"]] == ["take0.csv", "take1.csv"]
    assert run.trials[2].attrs["source_file"] == "take1.csv"
    # the second file's force is twice the first's
    assert math.isclose(float(run.trials[2].channels["force"].max()),
                        2 * float(run.trials[0].channels["force"].max()), rel_tol=1e-3)
    with pytest.raises(InputError, match="--split-repeats: not with --whole"):
        importer.import_files(srcs, m, tmp_path / "w.h5", segment=False, split_repeats=True)
    whole = importer.import_files(srcs, m, tmp_path / "w.h5", segment=False)
    assert len(whole.trials) == 2 and whole.trials[1].samples == t.size


# --- calibration ------------------------------------------------------------------------

def _steps(tmp_path: Path, calibration: str, units: str = "1") -> list[cal.Step]:
    m = _write(tmp_path / "c.yaml", f"sample_rate_hz: 1\ncolumns:\n  - column: 1\n"
               f"    channel: sensor\n    units: '{units}'\n    description: a sensor\n"
               f"    calibration:\n{calibration}")
    return mapfile.load(m, importer.vocabulary()).columns[0].steps


def test_lookup_table_piecewise_linear_by_hand(tmp_path):
    steps = _steps(tmp_path, """
      - lookup:
          columns: [value, reading]
          table: [[20, 3], [10, 1], [0, 0]]      # readings decreasing: sorted
""")
    x = np.array([0.0, 0.5, 1.0, 2.0, 3.0])
    y, clipped, _ = cal.apply(steps, x, np.arange(5.0), "test")
    np.testing.assert_allclose(y, [0, 5, 10, 15, 20])  # by hand: 0.5 -> 5, 2 -> 15
    assert clipped == 0


def test_lookup_table_monotone_cubic_by_hand(tmp_path):
    """PCHIP through (0, 0), (1, 1), (2, 1): the slope at 1 is 0 (the secants' signs
    differ), at 0 the three-point end slope (3 * 1 - 0) / 2 = 1.5; the Hermite cubic at
    0.5 is 0.125 * 1.5 + 0.5 * 1 = 0.6875, and [1, 2] stays 1 (no overshoot)."""
    steps = _steps(tmp_path, """
      - lookup: {table: [[0, 0], [1, 1], [2, 1]], interpolation: pchip}
""")
    y, _, _ = cal.apply(steps, np.array([0.5, 1.0, 1.5, 1.9]), np.arange(4.0), "test")
    np.testing.assert_allclose(y, [0.6875, 1.0, 1.0, 1.0], atol=1e-12)


def test_pchip_is_scipys_curve():
    from scipy.interpolate import PchipInterpolator

    rng = np.random.default_rng(5)
    for n in (2, 3, 5, 16):
        x = np.sort(rng.uniform(0, 10, n))
        y = rng.normal(0, 1, n) if n % 2 else np.cumsum(rng.uniform(0, 1, n))
        xi = np.linspace(x[0], x[-1], 501)
        np.testing.assert_allclose(cal.pchip(x, y, xi), PchipInterpolator(x, y)(xi),
                                   rtol=1e-10, atol=1e-12)


def test_the_channel_vocabulary_is_the_models():
    from rig.model.vocabulary import CHANNEL_DOCS, CHANNEL_UNITS
    from rig.recordings.channels import CHANNELS

    model = {n: (u, CHANNEL_DOCS.get(n, "")) for n, u in CHANNEL_UNITS.items()
             if n != "time" and not n.startswith("contact_")}
    assert {n: CHANNELS[n] for n in model} == model


def test_the_event_vocabulary_is_the_models():
    from rig.model import vocabulary as v
    from rig.recordings import channels as c

    assert c.EVENT_DOCS == v.EVENT_DOCS and c.EVENT_ORDER == v.EVENT_ORDER
    assert c.KEY_MOVE_THRESHOLD_M == v.KEY_MOVE_THRESHOLD_M


def test_lookup_out_of_range_refused_or_clipped_and_counted(tmp_path):
    src = _write(tmp_path / "s.csv", "x\n-1\n0\n0.5\n1\n2\n3\n")
    base = ("sample_rate_hz: 10\ncolumns:\n  - column: x\n    channel: sensor\n"
            "    units: '1'\n    description: a sensor\n    calibration:\n"
            "      - lookup: {table: [[0, 0], [1, 10]]%s}\n")
    refuse = _write(tmp_path / "refuse.yaml", base % "")
    with pytest.raises(InputError, match=r"3 samples outside the lookup table's readings "
                                         r"\[0, 1\], the first at sample 0"):
        importer.import_files([src], refuse, tmp_path / "r.h5")
    assert not (tmp_path / "r.h5").exists()
    clip = _write(tmp_path / "clip.yaml", base % ", out_of_range: clip")
    importer.import_files([src], clip, tmp_path / "r.h5")
    run = runfile.read(tmp_path / "r.h5")
    np.testing.assert_allclose(run.trials[0].channels["sensor"], [0, 0, 5, 10, 10, 10])
    assert run.metadata["import"]["files"][0]["clipped_samples"] == {"sensor": 3}
    with h5py.File(tmp_path / "r.h5") as h:
        assert h["trial_000/channels/sensor"].attrs["clipped_samples"] == 3


def test_kawai_calibration_at_the_table_points(tmp_path):
    """The example map's key calibration at three of the author's table points, by hand:
    the ADC value 0.3 + 0.58 * reading is the key front at position * 16/32 inch."""
    m = mapfile.load(KAWAI / "map.yaml", importer.vocabulary())
    key = next(c for c in m.columns if c.channel == "key_dip")
    steps = [s for s in key.steps if not isinstance(s, cal.Tare)]
    adc = 0.3 + 0.58 * np.array([0.0365, 0.3650, 1.0])
    y, _, _ = cal.apply(steps, adc, np.arange(3.0), "test")
    np.testing.assert_allclose(y * key.factor, np.array([7, 12, 15]) / 16 * 0.5 * 0.0254,
                               rtol=1e-9)


# --- segmentation -----------------------------------------------------------------------

def test_segmentation_of_separate_strokes_is_calibration_and_noise_proof():
    t, dip, _ = _blows(rate=1000.0, n=3)
    ref = sg.segment(t, dip)
    assert len(ref.strokes) == 3
    for k, s in enumerate(ref.strokes):  # the presses start at 0.3 + 0.5 k s
        assert abs(s.onset_s - (0.3 + 0.5 * k)) < 0.01
        assert abs(s.release_s - (0.5 + 0.5 * k)) < 0.01
        assert s.presses == 1
    rng = np.random.default_rng(7)
    for gain, offset, noise in ((-3.0, 2.0, 0.0), (1e4, -7.0, 0.0), (1.0, 0.0, 2e-4)):
        x = gain * (dip + rng.normal(0, noise, dip.size)) + offset
        got = sg.segment(t, x)
        assert len(got.strokes) == 3
        # a gain, an offset, a sign: the same samples; 20x the noise: off = 5 sigma = 1 mm
        # is reached 6.4 ms into a 10 mm half sine of 0.2 s
        tol = 1e-9 if noise == 0 else 0.008
        for a, b in zip(ref.strokes, got.strokes, strict=True):
            assert abs(a.onset_s - b.onset_s) <= tol and abs(a.release_s - b.release_s) <= tol


def test_a_repeated_note_is_one_trial_unless_split():
    t = np.arange(1500) / 1000.0
    x = np.zeros_like(t)
    first = (t >= 0.3) & (t <= 0.5)
    x[first] = np.sin(np.pi * (t[first] - 0.3) / 0.2)
    x[(t > 0.4) & (t <= 0.5)] = np.maximum(x[(t > 0.4) & (t <= 0.5)], 0.4)
    second = (t >= 0.45) & (t <= 0.75)
    x[second] = np.maximum(x[second], np.sin(np.pi * (t[second] - 0.45) / 0.3))
    x += np.random.default_rng(3).normal(0, 1e-3, t.size)
    one = sg.segment(t, x)
    assert len(one.strokes) == 1 and one.strokes[0].presses == 2
    two = sg.segment(t, x, split_repeats=True)
    assert len(two.strokes) == 2 and all(s.presses == 1 for s in two.strokes)
    assert 0.44 < two.strokes[1].onset_s < 0.5  # cut at the lowest point between presses


def _kawai_key() -> tuple[np.ndarray, np.ndarray]:
    m = mapfile.load(KAWAI / "map.yaml", importer.vocabulary())
    rec = importer.read_recording(m, KAWAI_TXT)
    return rec.time, rec.channels["key_dip"]


# Start of each motion read by eye from the raw damper column (the ADC leaves its rest
# level), README order: 1 hammer moved slowly, 2 very slow, 3 medium, 4 fast then slide
# off, 5-7 single fast, 8-15 repeated (the half press at 38.45 s before the 12th), 16 fast.
KAWAI_ONSETS = [5.8, 16.3, 24.95, 27.76, 33.56, 34.92, 36.06, 37.70, 37.93, 38.15, 38.37,
                38.47, 38.80, 39.02, 39.24, 40.28]
SLOW = {0, 1}  # a creeping start: the calibrated key leaves its rest earlier


def test_kawai_strokes_are_found():
    t, key = _kawai_key()
    seg = sg.segment(t, key)
    assert len(seg.strokes) == 16
    for k, (s, ref) in enumerate(zip(seg.strokes, KAWAI_ONSETS, strict=True)):
        lo = ref - (1.0 if k in SLOW else 0.1)
        assert lo < s.onset_s < ref + 0.05, (k, s.onset_s, ref)
        assert s.peak > (0.2 if k == 0 else 0.9) * seg.span
    assert [s.presses for s in seg.strokes] == [1] * 11 + [2] + [1] * 4  # the half press
    split = sg.segment(t, key, split_repeats=True)
    assert len(split.strokes) == 17
    half = split.strokes[11]
    assert half.peak < 0.5 * seg.span and abs(split.strokes[12].onset_s - 38.58) < 0.03


# The key's start on the six single fast strokes, read by hand off the tared key samples
# (printed at 0.5 ms, ms from each stroke's onset): where the key leaves its rest noise
# (about 65 um RMS) for good. The hammer sensor saturates 3.7 mm up the shank, short of
# the string, for 5-6 ms around every strike: the strike is not seen, only bracketed.
KAWAI_KEY_STARTS_MS = {3: -2.2, 4: -1.8, 5: -1.2, 6: -0.9, 7: -0.9, 15: -0.9}
# The other events of strokes 2 (medium), 3 (fast, sliding off), 4-6 (fast, held) and 15
# (fast, sliding off), read by eye off the samples printed at 0.5 ms (key_dip and
# hammer_shank_rise in mm, ms from the stroke's onset; * = clipped at the table's end):
# - key bottom: the key sensor's table ends at 11.015 mm (15/32 in). The held key rests
#   at 10.93-11.00 mm, so its felt is met no deeper than that: the key's bottom is where
#   its approach reaches that depth, just before the first clipped sample, e.g. trial 4
#   "34.5:10.366 35.0:10.892 35.5:11.015*" -> 35.0; trial 2 "137.5:10.854 138.0:10.962
#   138.5*" -> 138.0; 3 "31.5:10.511 32.0:10.960 32.5*" -> 32.0; 5 "33.5:10.358
#   34.0:10.880 34.5*" -> 34.0; 6 "35.5:10.520 36.0:10.926 36.5*" -> 36.0; 15
#   "31.5:10.431 32.0:10.928 32.5*" -> 32.0.
# - check: after the strike the hammer falls at a steady speed, then the back check
#   slows it to a stop (its lowest point 2.1-2.2 mm up, 4-5 ms later) where it is held;
#   the check is where the fall's speed starts to drop: trial 4 falls 33-42 um per sample
#   until 53.0 (2.356), then 37, 33, 29, 16 um -> 53.0; trial 3 "47.5:2.480 48.5:2.405
#   49.5:2.316 50.5:2.239 51.5:2.183" (-75, -89, -77, -56 um/ms) -> 50.0; trial 5
#   "50.5:2.422 51.5:2.346 52.5:2.278 53.5:2.219 54.5:2.186" (-76, -68, -59, -33) -> 52.75;
#   trial 15 "48.5:2.365 49.5:2.284 50.5:2.212 51.5:2.168" (-81, -72, -44) -> 50.0.
#   Trials 2 and 6 (None): the hammer slows over 10-15 ms (trial 2 from 50 to 0 mm/s in
#   steps of 10-20 um per sample, its noise about 10 um) with no onset the eye can place
#   within a millisecond; the finder must not claim one either.
# - key release: the key leaves its felt no earlier than it comes back up through the
#   depth it rested at on its bottom (the felt's surface is no deeper), nor than it leaves
#   the depth it held just before by the key start's 20 um; the later of the two, in
#   each trial's own rest-relative travel (tare differs by up to 0.05 mm): trial 5 rested
#   at 11.006, "569.5:11.009 570.0:11.005" -> 569.8; trial 4 rested at 11.02, drifting
#   up "755.5:11.023 756.0:11.020 756.5:11.018" -> 756.0; trial 3 rested at 10.99,
#   pressed to 11.017 at 1287.0, "1287.5:10.994 1288.0:10.955" -> 1287.5; trial 6 held
#   11.045 (deeper than its resting 11.041 only by its noise), 20 um less at
#   "567.5:11.027 568.0:11.024" -> 567.7; trial 2 eased off its felt to 10.637 at 1427,
#   rising from it "1429.5:10.634 1430.0:10.632 1430.5:10.630" -> 1430.0; trial 15 held
#   beyond the table (clipped to 1119.0), "1119.5:11.043 1120.0:10.994" -> 1119.4.
# - let-off and the strike are not read: both happen while the hammer sensor is beyond
#   its table (5-6 ms around each strike).
KAWAI_KEY_BOTTOMS_MS = {2: 138.0, 3: 32.0, 4: 35.0, 5: 34.0, 6: 36.0, 15: 32.0}
KAWAI_CHECKS_MS = {2: None, 3: 50.0, 4: 53.0, 5: 52.75, 6: None, 15: 50.0}
KAWAI_KEY_RELEASES_MS = {2: 1430.0, 3: 1287.5, 4: 756.0, 5: 569.8, 6: 567.7, 15: 1119.4}


def test_kawai_bottom_check_and_release_within_1_ms_of_the_hand_reading(tmp_path):
    """The key bottom (bracketed at the key sensor's table end), the check (a noisy
    hammer sensor) and the key release on the real strokes: each found within 1 ms of the
    hand reading, its 95 % interval holding the reading to within 1 ms and no wider
    than the data allow; no check claimed where the eye finds none; no events out of the
    order of a blow (rig import would warn)."""
    import h5py
    out = tmp_path / "k.h5"
    r = CliRunner().invoke(app, ["import", str(KAWAI_TXT), "--map", str(KAWAI / "map.yaml"),
                                 "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert "warning" not in r.output, r.output
    refs = {"key_bottom": (KAWAI_KEY_BOTTOMS_MS, 1.5), "check": (KAWAI_CHECKS_MS, 4.0),
            "key_release": (KAWAI_KEY_RELEASES_MS, 30.0)}  # event: (readings, widest ms)
    with h5py.File(out) as f:
        for k in (0, 1):  # the slow hand motions: the hammer pushed up, no strike
            assert "strike" not in f[f"trial_{k:03d}"].get("events", {}), k
        for name, (readings, widest) in refs.items():
            for k, ref_ms in readings.items():
                ev = f[f"trial_{k:03d}/events"]
                if ref_ms is None:
                    assert name not in ev, (name, k)
                    continue
                e = ev[name]
                t_ms = float(e[()]) * 1e3
                lo, hi = e.attrs["interval_low"] * 1e3, e.attrs["interval_high"] * 1e3
                assert abs(t_ms - ref_ms) <= 1.0, (name, k, t_ms, ref_ms)
                assert lo - 1.0 <= ref_ms <= hi + 1.0 and lo <= t_ms <= hi, (name, k, lo, hi)
                assert hi - lo < widest, (name, k, lo, hi)
                assert "event_order_flags" not in f[f"trial_{k:03d}"].attrs


def test_kawai_events_found_with_their_intervals(tmp_path):
    """rig import finds the events on the real strokes and stores each with its 95 %
    interval: key starts within 1 ms of the hand reading (which its interval holds),
    the strike inside the stretch the hammer sensor reads its top."""
    import h5py
    out = tmp_path / "k.h5"
    r = CliRunner().invoke(app, ["import", str(KAWAI_TXT), "--map", str(KAWAI / "map.yaml"),
                                 "--out", str(out)])
    assert r.exit_code == 0, r.output
    with h5py.File(out) as f:
        for k, ref_ms in KAWAI_KEY_STARTS_MS.items():
            g = f[f"trial_{k:03d}"]
            ev = g["events"]
            ks = ev["key_starts"]
            t_ks = float(ks[()]) * 1e3
            lo, hi = ks.attrs["interval_low"] * 1e3, ks.attrs["interval_high"] * 1e3
            assert abs(t_ks - ref_ms) <= 1.0 and lo <= ref_ms <= hi, (k, t_ks, lo, hi)
            assert ks.attrs["source"].startswith("found in the measured")
            st = ev["strike"]
            t = g["channels/time"][()]
            h = g["channels/hammer_shank_rise"][()]
            top = np.flatnonzero(h >= 0.9995 * h.max())  # the saturated stretch
            assert t[top[0]] <= float(st[()]) <= t[top[-1]], k
            assert st.attrs["interval_low"] <= float(st[()]) <= st.attrs["interval_high"]
            assert "saturated" in st.attrs["method"]
            assert st.attrs["interval_high"] - st.attrs["interval_low"] < 8e-3


# --- the command ------------------------------------------------------------------------

def test_cli_imports_the_kawai_recording(tmp_path):
    out = tmp_path / "kawai.h5"
    r = CliRunner().invoke(app, ["import", str(KAWAI_TXT), "--map", str(KAWAI / "map.yaml"),
                                 "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert "wrote" in r.output and "16 trials" in r.output
    run = runfile.read(out)
    assert [f"trial_{i:03d}" for i in range(16)] == sorted(
        n for n in h5py.File(out) if n.startswith("trial_"))
    assert run.metadata["import"]["files"][0]["sha256"] == KAWAI_SHA256
    assert len(run.metadata["segments"]) == 16
    tr = run.trials[3]
    assert tr.units["key_dip"] == "m" and tr.units["hammer_shank_rise"] == "m"
    assert tr.channels["time"][0] < 0 < tr.channels["time"][-1]   # rest before the onset
    assert 0.010 < float(np.max(tr.channels["key_dip"])) < 0.012  # 15/32 in at the bottom
    assert abs(tr.attrs["t0"] - 27.755) < 0.01
    info = CliRunner().invoke(app, ["info", str(out)])
    assert info.exit_code == 0 and "imported from hammer_damper_2K_17b.txt (text, sha256 " \
        "145dddefcda5dbfe) through" in info.output
    # refused without --force, replaced with it
    again = CliRunner().invoke(app, ["import", str(KAWAI_TXT), "--map",
                                     str(KAWAI / "map.yaml"), "--out", str(out),
                                     "--split-repeats"])
    assert again.exit_code == 2 and "--force" in again.output
    forced = CliRunner().invoke(app, ["import", str(KAWAI_TXT), "--map",
                                      str(KAWAI / "map.yaml"), "--out", str(out),
                                      "--split-repeats", "--force"])
    assert forced.exit_code == 0 and "17 trials" in forced.output


@pytest.mark.slow
def test_the_real_cli_imports_the_shipped_example(tmp_path):
    out = tmp_path / "kawai.h5"
    proc = subprocess.run([sys.executable, "-m", "rig", "import", str(KAWAI_TXT), "--map",
                           str(KAWAI / "map.yaml"), "--out", str(out)],
                          capture_output=True, text=True, timeout=300,
                          env={**os.environ, "COLUMNS": "120"})
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().endswith("16 trials")
    assert runfile.read(out).metadata["import"]["files"][0]["sha256"] == KAWAI_SHA256


# --- refusals ---------------------------------------------------------------------------

GOOD = """sample_rate_hz: 10
columns:
  - column: 1
    channel: force
    units: N
"""

BAD_MAPS = [
    ("columns: [\n", r"line \d+: not valid YAML"),
    ("sample_rate_hz: 10\ncolumns: []\n", r"line 2: columns: expected a non-empty list"),
    ("sample_rate_hz: 10\n", r"line 1: columns: missing"),
    ("sample_rate_hz: 10\nchannels: []\ncolumns: []\n", r"line 2: channels: unknown field"),
    (GOOD.replace("units: N", "units: furlong"), r"line 5: columns\[0\].units: unknown units"),
    (GOOD.replace("units: N", "units: mm"), r"line 5: columns\[0\].units: channel force is "
                                            r"stored in N"),
    (GOOD.replace("force", "finger_temp"), r"line 4: columns\[0\].channel: 'finger_temp' is "
                                           r"not a run-file channel"),
    (GOOD.replace("force", "Bad Name"), r"line 4: columns\[0\].channel: expected a channel"),
    (GOOD.replace("column: 1", "column: 0"), r"line 3: columns\[0\].column: expected"),
    (GOOD.replace("sample_rate_hz: 10", "sample_rate_hz: -5"),
     r"line 1: sample_rate_hz: expected a positive number"),
    (GOOD + "time: {column: 2}\n", r"line 6: time: give either time or sample_rate_hz"),
    (GOOD + "    calibration:\n      - stretch: 2\n",
     r"line 7: columns\[0\].calibration\[0\]: unknown calibration 'stretch'"),
    (GOOD + "    calibration:\n      - linear: {scale: two}\n",
     r"line 7: columns\[0\].calibration\[0\].linear.scale: expected a number"),
    (GOOD + "    calibration:\n      - normalize: {zero: 1, span: 0}\n",
     r"line 7: columns\[0\].calibration\[0\].normalize.span: must not be 0"),
    (GOOD + "    calibration:\n      - lookup:\n          table:\n            - [0, 0]\n"
            "            - [1, 1]\n            - [1, 2]\n",
     r"line 11: columns\[0\].calibration\[0\].lookup.table\[2\]: the readings must be "
     r"strictly"),
    (GOOD + "    calibration:\n      - lookup:\n          table:\n            - [0, 0, 3]\n"
            "            - [1, 1]\n",
     r"line 9: columns\[0\].calibration\[0\].lookup.table\[0\]: expected a row of two"),
    (GOOD + "    calibration:\n      - lookup: {table: [[0, 0], [1, 1]], out_of_range: "
            "wrap}\n", r"line 7: columns\[0\].calibration\[0\].lookup.out_of_range: expected "
                       r"refuse or clip"),
    (GOOD + "    geometry: {radius: 0.1}\n",
     r"line 5: columns\[0\].units: a geometry reads a displacement as an angle"),
    (GOOD.replace("force\n    units: N", "hammer_angle\n    units: m") +
     "    geometry: {radius: -1}\n", r"line 6: columns\[0\].geometry.radius: expected a "
                                    r"positive number"),
    # a fitted radius (issue 38): a sensor's own channel, read as a model angle, on the arc
    (GOOD.replace("force\n    units: N", "shank_rise\n    units: mm\n    description: x") +
     "    geometry: {radius: fit}\n", r"line 7: columns\[0\].geometry: angle_of: missing"),
    (GOOD.replace("force\n    units: N", "shank_rise\n    units: mm\n    description: x") +
     "    geometry: {radius: fit, angle_of: key_dip}\n",
     r"line 7: columns\[0\].geometry.angle_of: expected one of the model's angle channels"),
    (GOOD.replace("force\n    units: N", "shank_rise\n    units: mm\n    description: x") +
     "    geometry: {radius: fit, angle_of: hammer_angle, model: sine}\n",
     r"line 7: columns\[0\].geometry.model: radius: fit reads the displacement on the arc"),
    (GOOD.replace("force\n    units: N", "shank_rise\n    units: mm\n    description: x") +
     "    geometry: {radius: 9, angle_of: hammer_angle}\n",
     r"line 7: columns\[0\].geometry.angle_of: only with radius: fit"),
    (GOOD.replace("force\n    units: N", "hammer_angle\n    units: mm") +
     "    geometry: {radius: fit, angle_of: hammer_angle}\n",
     r"line 4: columns\[0\].channel: radius: fit stores the displacement under a channel of "
     r"its own"),
    (GOOD + "  - {column: 2, channel: force, units: N}\n",
     r"line 6: columns\[1\]: channel force is also columns\[0\]'s"),
    (GOOD + "segment: {channel: key_dip}\n", r"line 6: segment.channel: expected one of the "
                                             r"mapped channels"),
    (GOOD + "segment: {channel: force, min_rest_s: 0}\n",
     r"line 6: segment.min_rest_s: expected a positive number"),
    (GOOD + "format: xlsx\n", r"line 6: format: expected one of"),
    ("- 1\n- 2\n", r"line 1: expected a mapping with columns"),
    ("sample_rate_hz: 10\nsample_rate_hz: 20\ncolumns: []\n",
     r"line 2: sample_rate_hz: given twice"),
    (GOOD + "    calibration:\n      - polynomial: []\n",
     r"line 7: columns\[0\].calibration\[0\].polynomial: expected the coefficients"),
    (GOOD + "    calibration:\n      - tare: {seconds: 0}\n",
     r"line 7: columns\[0\].calibration\[0\].tare.seconds: expected a positive number"),
    (GOOD + "    calibration:\n      - lookup: {table: [[0, 0], [1, 1]], columns: [a, b]}\n",
     r"line 7: columns\[0\].calibration\[0\].lookup.columns: expected \[reading, value\]"),
    (GOOD + "time: {column: 1, units: m}\n".replace("time", "header: maybe\ntime"),
     r"line 6: header: expected true, false or auto"),
]


@pytest.mark.parametrize(("text", "message"), BAD_MAPS)
def test_every_bad_map_is_refused_with_one_line(tmp_path, text, message):
    src = _write(tmp_path / "data.csv", "1,2\n3,4\n5,6\n")
    m = _write(tmp_path / "map.yaml", text)
    out = tmp_path / "r.h5"
    r = CliRunner().invoke(app, ["import", str(src), "--map", str(m), "--out", str(out)])
    assert r.exit_code == 2, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {m}: "), r.output
    import re
    assert re.search(message, lines[0]), lines[0]
    assert not out.exists() and not list(tmp_path.glob(".r.h5*"))


BAD_FILES = [
    ("time,force\n0,1\n0.1,x\n", "header: true\ntime: {column: time}\n",
     r"data.csv: line 3: column 'force': not a number: 'x'"),
    ("time,force\n0,1\n0.1,2,3\n", "time: {column: time}\n", r"data.csv: line 3: "),
    ("time,force\n0,1\n0,2\n", "time: {column: time}\n",
     r"data.csv: time column 'time': not increasing at sample 1"),
    ("t,force\n0,1\n0.1,2\n", "time: {column: time}\n", r"data.csv: column 'time' not found"),
    ("force\n1\n3\n", "", r"map.yaml: sample_rate_hz: missing"),
    ("", "sample_rate_hz: 10\n", r"data.csv: no data"),
    ("1,2\n3,4\n", "sample_rate_hz: 10\n", None),  # column 'force' by name, no header
]


@pytest.mark.parametrize(("data", "head", "message"), BAD_FILES)
def test_bad_files_are_refused_with_one_line(tmp_path, data, head, message):
    src = _write(tmp_path / "data.csv", data)
    m = _write(tmp_path / "map.yaml", head + "columns:\n  - {column: force, channel: force, "
                                             "units: N}\n")
    out = tmp_path / "r.h5"
    r = CliRunner().invoke(app, ["import", str(src), "--map", str(m), "--out", str(out)])
    assert r.exit_code == 2, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.output
    if message is not None:
        import re
        assert re.search(message, lines[0]), lines[0]
    assert not out.exists() and not list(tmp_path.glob(".r.h5*"))


def test_a_failure_while_writing_leaves_nothing(tmp_path, monkeypatch):
    src = _write(tmp_path / "d.csv", "1\n2\n3\n4\n")
    m = _write(tmp_path / "map.yaml", GOOD)
    out = tmp_path / "r.h5"
    out.write_bytes(b"the user's file")

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(runfile.TrialWriter, "append", boom)
    with pytest.raises(OSError, match="disk full"):
        importer.import_files([src], m, out, force=True)
    assert out.read_bytes() == b"the user's file" and not list(tmp_path.glob(".r.h5*"))


def test_json_output_follows_its_schema(tmp_path):
    import json
    import re

    jsonschema = pytest.importorskip("jsonschema")
    text = (ROOT / "docs" / "json.md").read_text()
    schema = next(s for s in (json.loads(b) for b in re.findall(r"^```json\n(.*?)^```", text,
                                                                  re.S | re.M))
                  if s["$id"] == "rig.import/1")
    t, dip, f = _blows()
    src = _write(tmp_path / "b.csv", "force,dip\n" + "\n".join(
        f"{b:.6f},{c:.8f}" for b, c in zip(f, dip, strict=True)))
    m = _write(tmp_path / "map.yaml", "sample_rate_hz: 1000\ncolumns:\n"
               "  - {column: force, channel: force, units: N}\n"
               "  - {column: dip, channel: key_dip, units: m}\nsegment: {channel: key_dip}\n")
    for extra in ([], ["--whole"]):
        out = tmp_path / f"r{len(extra)}.h5"
        r = CliRunner().invoke(app, ["import", str(src), "--map", str(m), "--out", str(out),
                                     "--json", *extra])
        assert r.exit_code == 0, r.output
        doc = json.loads(r.output)
        jsonschema.validate(doc, schema)
        assert len(doc["trials"]) == (1 if extra else 3)


def test_the_docs_example_map_is_valid(tmp_path):
    import re

    text = (ROOT / "docs" / "import.md").read_text()
    body = re.search(r"^```yaml\n(.*?)^```", text, re.S | re.M).group(1)
    m = mapfile.load(_write(tmp_path / "map.yaml", body), importer.vocabulary())
    assert [c.channel for c in m.columns] == ["force", "key_dip", "hammer_angle"]
    assert m.segment is not None and m.segment.channel == "key_dip"
    assert m.columns[2].geometry is not None and m.columns[2].stored_units == "rad"


def test_readers_name_the_missing_column_number(tmp_path):
    src = _write(tmp_path / "d.txt", "1 2\n3 4\n")
    table = readers.read(src, "text")
    assert table.order == ["1", "2"] and not table.header
    with pytest.raises(InputError, match=r"d.txt: column 3: the file has 2 columns"):
        table.get(3)
    assert math.isclose(float(table.get(2)[1]), 4.0)


def test_import_warns_of_events_out_of_the_order_of_a_blow(tmp_path, monkeypatch):
    """Events found out of the order of a blow are flagged by rig import (printed, in
    --json's warnings, stored as the trial's event_order_flags), never silently stored."""
    from rig.analysis import events

    t, dip, _ = _blows(n=1)
    src = _write(tmp_path / "blow.csv", "\n".join(f"{b * 1e3:.4f}" for b in dip) + "\n")
    m = _write(tmp_path / "map.yaml", "header: false\nsample_rate_hz: 1000\ncolumns:\n"
                                      "  - {column: 1, channel: key_dip, units: mm}\n")
    real = events.found

    def swapped(time, channels, **kw):  # the key's bottom placed before its start
        out = real(time, channels, **kw)
        start = out["key_starts"]
        out["key_bottom"] = events.Found(start.time - 0.01, start.time - 0.011,
                                         start.time - 0.009, "test")
        return out

    monkeypatch.setattr(events, "found", swapped)
    r = CliRunner().invoke(app, ["import", str(src), "--map", str(m), "--out",
                                 str(tmp_path / "run.h5"), "--whole"])
    assert r.exit_code == 0, r.output
    assert "warning: trial 0: events out of the order of a blow: key_starts at" in r.output
    with h5py.File(tmp_path / "run.h5") as f:
        flags = [str(x) for x in f["trial_000"].attrs["event_order_flags"]]
    assert len(flags) == 1 and "is after key_bottom" in flags[0]
    js = CliRunner().invoke(app, ["import", str(src), "--map", str(m), "--out",
                                  str(tmp_path / "run2.h5"), "--whole", "--json"])
    assert json.loads(js.output)["warnings"][0].startswith("trial 0: events out of")
    monkeypatch.setattr(events, "found", real)
    clean = CliRunner().invoke(app, ["import", str(src), "--map", str(m), "--out",
                                     str(tmp_path / "run3.h5"), "--whole"])
    assert clean.exit_code == 0 and "warning" not in clean.output
