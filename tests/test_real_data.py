"""The model driven by a real action's measured key (issue 38): the Kawai KG-3C recording of
examples/kawai-kg3c/ imported, the key made to follow it both ways, the model's strikes
held against the real hammer's."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from rig.analysis import measurement as ms
from rig.model.action import ActionModel, SimResult
from rig.services import importer

ROOT = Path(__file__).resolve().parents[1]
KAWAI = ROOT / "examples" / "kawai-kg3c"
KAWAI_TXT = KAWAI / "hammer_damper_2K_17b.txt"

# a string contact that begins less than this after the previous one ended is the same
# blow's re-strike (the hammer bouncing back up), not a blow of its own
REBOUND_S = 0.030


def _import(tmp_path: Path, min_rest_s: float | None = None) -> Path:
    """The shipped recording imported through its map; with ``min_rest_s`` the strokes
    closer than it are one trial (0.1 s: the eight repeated notes become one trial)."""
    text = (KAWAI / "map.yaml").read_text()
    if min_rest_s is not None:
        text = text.replace("segment:\n  channel: key_dip\n",
                            f"segment:\n  channel: key_dip\n  min_rest_s: {min_rest_s}\n")
        assert "min_rest_s" in text
    m = tmp_path / "map.yaml"
    m.write_text(text)
    out = tmp_path / "kawai.h5"
    importer.import_files([KAWAI_TXT], m, out)
    return out


def _excerpt(tmp_path: Path) -> Path:
    """An excerpt of the recording imported through the shipped map: its first second of
    rest, then the fourth single fast press (trial 1)."""
    lines = KAWAI_TXT.read_text().splitlines()
    (tmp_path / "k.txt").write_text("\n".join(lines[:2000] + lines[67000:68800]) + "\n")
    run = tmp_path / "k.h5"
    importer.import_files([tmp_path / "k.txt"], KAWAI / "map.yaml", run)
    return run


def real_strikes(meas: ms.Measurement) -> np.ndarray:
    """Times the real hammer reached the string: its shank sensor rising through 90 % of its
    top (the sensor saturates there, a few mm below the string), each counted once until it
    falls back below 50 %."""
    h = meas.channels["hammer_shank_rise"]
    top = float(np.max(h))
    out, up = [], False
    for t, v in zip(meas.time, h, strict=True):
        if not up and v > 0.9 * top:
            up = True
            out.append(t)
        elif up and v < 0.5 * top:
            up = False
    return np.array(out)


def model_contacts(res: SimResult) -> tuple[np.ndarray, np.ndarray]:
    """Start and end times of the model's hammer-string contacts (contact 12)."""
    on = res.contact("contact_penetration", 12) > 0
    d = np.diff(on.astype(int))
    return res.time[np.nonzero(d == 1)[0] + 1], res.time[np.nonzero(d == -1)[0] + 1]


def blows(res: SimResult) -> tuple[np.ndarray, int]:
    """The model's blows (a string contact starting REBOUND_S or more after the previous one
    ended) and the count of re-strikes (those starting sooner)."""
    on, off = model_contacts(res)
    out, again = [], 0
    for k, t in enumerate(on):
        if k and t - off[k - 1] < REBOUND_S:
            again += 1
        else:
            out.append(t)
    return np.array(out), again


def tracking_rms(meas: ms.Measurement, res: SimResult) -> float:
    dip = meas.channels["key_dip"] - float(np.mean(meas.channels["key_dip"][meas.rest_mask()]))
    e = res.channels["key_dip"] - np.interp(res.time, meas.time, dip)
    return float(np.sqrt(np.mean(e ** 2)))


@pytest.mark.slow
def test_repeated_notes_make_as_many_blows_as_the_real_action(tmp_path):
    run = _import(tmp_path, min_rest_s=0.1)
    meas = ms.load(run, [7], input="motion")[0]
    assert meas.metadata["segments"][7]["presses"] == 9  # eight notes and the half press
    real = real_strikes(meas)
    assert real.size == 8
    res = ms.simulate(ActionModel.from_yaml(None), meas, "motion")
    assert res.success
    # the key follows the measured motion both ways (push-only: 1.8 mm RMS, 6.1 mm worst)
    assert tracking_rms(meas, res) < 0.3e-3
    got, again = blows(res)
    # as many blows as the real hammer made, each within 10 ms of the real one (the
    # push-only drive made 9, one of them 62 ms before any real strike, and struck first
    # 10 ms early); the half press strikes in neither
    assert got.size == real.size, (got, real)
    assert np.max(np.abs(got - real)) < 0.010, (got, real)
    # the model's hammer re-strikes within 15 ms in some of them, where the real hammer's
    # sensor falls straight back: a model discrepancy (the back check, issue 38), counted
    assert 0 <= again <= real.size


@pytest.mark.slow
def test_single_blows_strike_when_the_real_hammer_did(tmp_path):
    run = _import(tmp_path)
    model = ActionModel.from_yaml(None)
    for k in (4, 6):  # single fast presses, the key held
        meas = ms.load(run, [k], input="motion")[0]
        real = real_strikes(meas)
        assert real.size == 1
        res = ms.simulate(model, meas, "motion")
        got, again = blows(res)
        assert got.size == 1 and again == 0, (k, got)
        # push-only: 2-5 ms early; followed both ways: within 1.5 ms
        assert abs(got[0] - real[0]) < 0.002, (k, got, real)
        assert abs(res.events["strike"] - got[0]) < 1e-3
        assert tracking_rms(meas, res) < 0.5e-3


# --- a sensor's radius fitted: the Kawai's hammer shank sensor compared as hammer_angle ---

def test_a_fitted_radius_recovers_the_sensor_and_leaves_its_saturation_out():
    from rig.analysis import compare as cp

    t = np.arange(-0.05, 0.2, 0.0005)
    theta = np.where(t > 0, -0.37 * np.sin(np.clip(t, 0, 0.1) * np.pi / 0.2) ** 2, 0.0)
    d = -0.0093 * theta                          # a shank rising 9.3 mm per rad
    d_read = np.minimum(d, 0.003)                # the sensor saturates at 3 mm
    meas = ms.Measurement(t, {"hammer_shank_rise": d_read}, {"hammer_shank_rise": "m"},
                          metadata={"import": {"columns": [{
                              "channel": "hammer_shank_rise", "geometry": {
                                  "radius_m": None, "radius": "fit", "model": "arc",
                                  "angle_of": "hammer_angle"}}]}})
    assert ms.fitted_geometries(meas) == {"hammer_shank_rise": "hammer_angle"}
    time, names, measured = cp.prepare(meas, "motion")
    assert names == ["hammer_angle"]
    w = t >= 0
    fit = cp.fit_geometries(meas, time, measured, {"hammer_angle": theta[w]})
    f = fit["hammer_angle"]
    assert abs(f["radius_m"] - 0.0093) < 1e-12 and f["sign"] == -1 and f["rms_m"] < 1e-12
    sat = d[w] > 0.003
    assert f["saturated"] == int(sat.sum()) > 10
    got = measured["hammer_angle"]
    assert np.all(np.isnan(got[sat])) and np.allclose(got[~sat], theta[w][~sat])


@pytest.mark.slow
def test_compare_by_motion_runs_on_a_kawai_stroke_through_the_cli(tmp_path):
    import json

    from typer.testing import CliRunner

    from rig.cli import app

    run = _import(tmp_path)
    r = CliRunner().invoke(app, ["compare", str(run), "--input", "motion", "--trial", "4"])
    assert r.exit_code == 0, r.output
    assert "hammer_angle [rad]          fitted   read from hammer_shank_rise through a " \
           "radius fitted to base model: " in r.output
    j = CliRunner().invoke(app, ["compare", str(run), "--input", "motion", "--trial", "4",
                                 "--json"])
    assert j.exit_code == 0, j.output
    doc = json.loads(j.output[j.output.index("{"):])
    comp = doc["trials"][0]
    f = comp["fitted"]["hammer_angle"]
    # the shank sensor sits about a centimetre from the flange (not given by the source)
    assert 0.005 < f["radius_m"] < 0.015 and f["sign"] == -1
    assert comp["channels"] == ["hammer_angle"] and "key_dip" in comp["inputs"]
    err = comp["models"][0]["errors"]["hammer_angle"]
    assert err["nrms"] < 0.15 and err["units"] == "rad"
    assert abs(comp["models"][0]["event_errors"]["strike time"]) < 2.0  # ms


def test_events_out_of_the_order_of_a_blow_are_flagged():
    from rig.analysis import compare as cp

    good = {"key_starts": 0.001, "toe_meets_button": 0.028, "let_off": 0.030, "strike": 0.032,
            "string_release": 0.0335, "check": 0.056, "key_bottom": 0.034,
            "key_release": 0.6}
    assert cp.order_flags(good) == []
    bad = dict(good, let_off=0.0335, key_release=0.02)
    flags = cp.order_flags(bad)
    assert len(flags) == 2, flags  # let-off after the strike; the key released too early
    assert flags[0].startswith("let_off at 33.50 ms is after strike at 32.00 ms")
    assert any(f.startswith("key_bottom at 34.00 ms is after key_release at 20.00 ms")
               for f in flags)
    # within the tolerance (half a sample) is not a contradiction
    assert cp.order_flags(dict(good, let_off=0.0322), tolerance_s=0.00025) == []
    assert cp.order_flags(dict(good, strike=float("nan"))) == []


@pytest.mark.slow
def test_with_the_repetition_spring_regulated_every_single_stroke_strikes_once(tmp_path):
    # the real hammer struck once in each of the six single strokes and was held; with the
    # thesis's spring preload the model struck again in four of them (71-930 ms after the
    # first strike); regulated as technicians do (the default, docs/model.md) it strikes
    # once in each
    run = _import(tmp_path)
    model = ActionModel()
    for k in (2, 3, 4, 5, 6, 15):
        meas = ms.load(run, [k], input="motion")[0]
        assert real_strikes(meas).size == 1
        got, again = blows(ms.simulate(model, meas, "motion"))
        assert got.size == 1 and again == 0, (k, got, again)


def _motion_only(truth: ActionModel, radius: float = 0.0093, top: float = 0.9
                 ) -> ms.Measurement:
    """A stroke with no force channel, as an imported one: the key's dip (a simulated
    forte blow's, 50 ms of rest before it) and the hammer read by a displacement sensor
    at an unknown ``radius`` that saturates at ``top`` of its travel (2 um noise, then the
    clip, as a lookup table's end leaves it); the hammer's motion is ``truth``'s own,
    driven by that key motion."""
    from rig.analysis import synth as sy
    from rig.inputs import profiles

    st = sy.synth_trial(ActionModel(), profiles.load(ROOT / "profiles" / "forte.yaml"),
                        sy.default_rig(), 3, 0.15, True, 1.0)
    t = np.r_[np.arange(-100, 0) / 2000.0, st.channels["time"]]
    kd = np.r_[np.full(100, st.channels["key_dip"][0]), st.channels["key_dip"]]
    key = ms.Measurement(t, {"time": t, "key_dip": kd}, {"time": "s", "key_dip": "m"})
    res = ms.simulate(truth, key, "motion", 0.15)
    h = res.channels["hammer_angle"]
    th = np.interp(t, res.time, h, left=h[0]) - h[0]
    d = -radius * th + np.random.default_rng(1).normal(0, 2e-6, t.size)
    d = np.minimum(d, top * float(np.max(-radius * th)))
    return ms.Measurement(t, {"time": t, "key_dip": kd, "hammer_shank_rise": d},
                          {"time": "s", "key_dip": "m", "hammer_shank_rise": "m"},
                          metadata={"import": {"columns": [{
                              "channel": "hammer_shank_rise", "geometry": {
                                  "radius": "fit", "angle_of": "hammer_angle"}}]}})


def test_fit_by_motion_without_force_recovers_the_let_off_buttons_height():
    """Another action's geometry from its motion alone (issue 38): no force channel, the
    hammer seen through a sensor of unknown radius that saturates; `rig fit --input
    motion`'s fit (the radius fitted in closed form at every evaluation, the saturated
    samples left out) finds the let-off button 0.8 mm lower, within its interval."""
    from rig.analysis import fit as ft

    path = "points.ground.Pg6.at.1"  # the let-off button's height
    base = ActionModel()
    y0 = float(base.params.get(path))
    tp = base.params.copy()
    tp.set(path, y0 - 0.0008)
    meas = _motion_only(ActionModel(tp))
    data = ft.Data.build([meas], "motion", 0.15)
    assert data.channels == [["hammer_angle"]] and data.geometry is not None
    assert int(data.geometry[0]["hammer_angle"].sum()) > 5  # the saturated samples
    res = ft.fit(base, data, [f"{path}=0.064:0.069"])
    got, sd = res.values[path], res.sigma[path]
    assert abs(got - (y0 - 0.0008)) <= max(3 * sd, 2e-5), (got, sd)
    assert abs(y0 - got) > 10 * sd  # the default is excluded


def test_a_points_coordinate_is_a_parameter_path():
    from rig.errors import InputError

    p = ActionModel().params.copy()
    p.set("points.ground.Pg6.at.1", 0.066)
    assert p.get("points.ground.Pg6.at") == [-0.0580, 0.066]
    with pytest.raises(InputError, match="not an index"):
        p.get("points.ground.Pg6.at.2")


def _dwell():
    import importlib.util

    spec = importlib.util.spec_from_file_location("dwell", KAWAI / "dwell.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_string_diagnose_fits_holds_the_hammer_longer_than_the_real_one_was_there(
        tmp_path):
    """docs/real-data.md's table (examples/kawai-kg3c/dwell.py): on the five single fast
    strokes the real hammer sensor reads its top for 5.0-5.5 ms (the real contact lies
    within it); the default model's contact lasts 1.0-1.5 ms and begins 1.5-2.5 ms before
    the sensor reaches its top; with the string `rig diagnose` fits (1700 N/m) it lasts
    8.0-8.5 ms, longer than the real hammer was near the string, and ends 0.5-1.5 ms after
    the real one left."""
    run = _import(tmp_path)
    for k, real, base, soft in _dwell().rows(str(run), [3, 4, 5, 6, 15], 1700.0):
        top = real[1] - real[0]
        assert 0.0049 < top < 0.0056, (k, real)
        assert base[1] - base[0] <= 0.0016 and 0.0014 < real[0] - base[0] < 0.0026, \
            (k, real, base)
        assert soft[0] == base[0] and soft[1] - soft[0] > top + 0.002, (k, real, soft)
        assert 0.0004 < soft[1] - real[1] < 0.0016, (k, real, soft)


def test_candidates_that_cannot_act_on_a_run_driven_by_motion_are_left_out(tmp_path):
    """Driven by the key's measured motion, the model never sees a force: the drive's lag
    and the load cell's filter, which transform the input force, cannot act. They are
    named as such, left out of the pairs and later rounds, and out of the count the
    round's held-out level is divided by (issue 39): 0.05 over the 2 candidates that can
    act, not over all 4 (on the whole recording, 8 candidates and 27 pairs before)."""
    from rig.analysis import diagnose as dg

    run = _excerpt(tmp_path)
    meas = ms.load(run, None, "motion")
    d = dg.diagnose(ActionModel(), meas[1:2], input="motion", duration=0.06, jobs=1,
                    candidates=["drive_dynamics", "load_cell_filter", "flexible_shank",
                                "key_liftoff"])
    by = {c.name: c for c in d.candidates}
    for name in ("drive_dynamics", "load_cell_filter"):
        assert dg.inert(by[name]) and by[name].why_not == dg.INERT_WHY, by[name]
    for name in ("flexible_shank", "key_liftoff"):
        assert not dg.inert(by[name]) and by[name].removal > 0.05, by[name]
    assert any("drive_dynamics, load_cell_filter cannot act on these data" in n
               for n in d.notes), d.notes
    levels = {float(x) for c in by.values()
              for x in re.findall(r"> (\d\.\d+)\)", c.why_not)}
    assert levels == {0.025}, [c.why_not for c in by.values()]
    pairs = [n for n in d.notes if "pairs" in n]
    assert not pairs or "of 1 pairs" in pairs[0], pairs


@pytest.mark.slow
def test_fit_and_diagnose_by_motion_run_on_an_import_without_force(tmp_path):
    """`rig fit` and `rig diagnose` with --input motion on a file with no force channel:
    an excerpt of the Kawai recording (its first second of rest, then the fourth single
    fast press) imported through the shipped map."""
    from typer.testing import CliRunner

    from rig.cli import app

    run = _excerpt(tmp_path)
    assert "force" not in ms.load(run, None, "motion")[0].channels
    r = CliRunner().invoke(app, ["fit", str(run), "--input", "motion", "--duration", "0.08",
                                 "--param", "points.ground.Pg6.at.1=0.064:0.069"])
    assert r.exit_code == 0, r.output
    assert "points.ground.Pg6.at.1 = " in r.output
    r = CliRunner().invoke(app, ["diagnose", str(run), "--input", "motion", "--trial", "1",
                                 "--duration", "0.06", "--candidate", "key_liftoff",
                                 "--jobs", "1"])
    assert r.exit_code == 0, r.output
    assert "each candidate alone" in r.output and "hammer_angle" in r.output
    r = CliRunner().invoke(app, ["fit", str(run), "--param", "contacts.4.D"])
    assert r.exit_code == 2 and "no force channel" in r.output
