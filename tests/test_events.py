"""Events found in a measured trial's channels without a model (rig.analysis.events):
exact answers on constructed motions, and the model's own events on the simulated rig's
measurement-like channels (encoder counts, load-cell noise)."""

from __future__ import annotations

import numpy as np
import pytest

from rig.analysis import events
from rig.analysis import synth as sy
from rig.inputs import profiles
from rig.model.action import ActionModel

RATE = 2000.0
COUNT = 2 * np.pi / 163840  # the hammer encoder's count (rad)


def _counts(x: np.ndarray, q: float = COUNT) -> np.ndarray:
    return np.round(x / q) * q


def _hammer(t: np.ndarray, t_strike: float, t_check: float | None = None) -> np.ndarray:
    """Rest, an approach at 25 rad/s from 10 ms, an abrupt reversal at ``t_strike`` to a
    rebound at 8 rad/s; with ``t_check``, a catch from then on whose deceleration grows
    linearly (velocity 8 - c (t - t_check)^2) until the hammer is held, 2 ms later."""
    fine = np.arange(t[0], t[-1] + 1e-7, 1e-7)  # integrate finely, sample at the rate
    vf = _velocity_at(fine, t_strike, t_check)
    x = np.concatenate([[0.0], np.cumsum(vf[:-1] * np.diff(fine))])
    return _counts(np.interp(t, fine, x))


def _velocity_at(t: np.ndarray, t_strike: float, t_check: float | None) -> np.ndarray:
    v = np.where(t < 0.01, 0.0, -25.0)
    v = np.where(t >= t_strike, 8.0, v)
    if t_check is not None:
        c = 8.0 / 0.002 ** 2
        v = np.where(t >= t_check, np.clip(8.0 - c * (t - t_check) ** 2, 0.0, None), v)
    return v


@pytest.mark.parametrize("t_strike", [0.05, 0.05012, 0.05031, 0.05049])
def test_an_abrupt_reversal_is_the_strike_within_half_a_sample(t_strike: float) -> None:
    t = np.arange(-0.02, 0.1, 1 / RATE)
    found = events.find(t, {"hammer_angle": _hammer(t, t_strike)})
    assert abs(found["strike"] - t_strike) <= 0.5 / RATE + 1e-9
    assert "check" not in found  # the rebound is never caught


@pytest.mark.parametrize("t_check", [0.0702, 0.07031, 0.0705])
def test_a_catch_whose_force_rises_linearly_is_placed_to_a_tenth_of_a_sample(
        t_check: float) -> None:
    t = np.arange(-0.02, 0.12, 1 / RATE)
    found = events.find(t, {"hammer_angle": _hammer(t, 0.05, t_check)})
    assert abs(found["check"] - t_check) < 0.1 / RATE


def test_a_hammer_that_turns_back_short_of_the_string_has_no_strike() -> None:
    t = np.arange(-0.02, 0.15, 1 / RATE)
    tm = np.clip(t - 0.01, 0.0, None)
    h = _counts(-25.0 * tm + 0.5 * 500.0 * tm ** 2)  # slows to a stop at 60 ms, falls back
    assert events.find(t, {"hammer_angle": h}) == {}


def test_a_key_at_rest_has_no_events() -> None:
    t = np.arange(-0.02, 0.2, 1 / RATE)
    rng = np.random.default_rng(0)
    found = events.find(t, {"key_dip": _counts(rng.normal(0, 0.3e-6, t.size), 0.5e-6),
                            "hammer_angle": _counts(rng.normal(0, 1e-5, t.size))})
    assert found == {}


@pytest.mark.parametrize("profile", ["profiles/forte.yaml", "examples/hidden-string/mezzo.yaml",
                                     "profiles/piano.yaml"])
def test_found_events_agree_with_the_models_own_on_the_simulated_rig(profile: str) -> None:
    """The channels of `rig synth` (the truth model through the simulated rig's drive, load
    cell and encoders): every event found within 0.6 ms of the model's (over 80 trials of
    five models and eight blows, benchmarks/events.py: 0.58 ms at most with a rigid shank),
    the key's start within 0.05 ms."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    st = sy.synth_trial(ActionModel(), profiles.load(root / profile), sy.default_rig(), 3, 0.3,
                        True, 1.0)
    found = events.find(st.channels["time"], st.channels)
    truth = st.truth.events
    assert {"key_starts", "strike", "check"} <= set(found)
    assert abs(found["key_starts"] - truth["key_starts"]) < 5e-5
    for name, t in found.items():
        assert abs(t - truth[name]) < 6e-4, (name, t, truth[name])
    assert list(found) == [n for n in events.EVENT_ORDER if n in found]


# ---- confidence: each event's 95 % interval, on noisy and saturating channels ----
def test_every_found_event_carries_an_interval_that_holds_its_time() -> None:
    t = np.arange(-0.02, 0.2, 1 / RATE)
    found = events.found(t, {"hammer_angle": _hammer(t, 0.05031, 0.08)})
    assert set(found) == {"strike", "check"}
    for e in found.values():
        assert e.low <= e.time <= e.high and e.half_width <= 0.5e-3 and e.method
    assert found["strike"].low <= 0.05031 <= found["strike"].high
    assert found["check"].low - 1e-4 <= 0.08 <= found["check"].high + 1e-4


def _noisy_key(rng: np.random.Generator, t: np.ndarray, t0: float, sd: float) -> np.ndarray:
    """A key at rest that starts at ``t0`` with a constant acceleration of 60 m/s^2 (a
    fast press: 2 mm in 8 ms), read with white noise of ``sd``."""
    x = np.where(t > t0, 0.5 * 60.0 * (t - t0) ** 2, 0.0)
    return x + rng.normal(0.0, sd, t.size)


def test_a_noisy_keys_start_interval_covers_the_true_start() -> None:
    """With rest noise of 65 um (the Kawai recording's key sensor) the 20 um threshold is
    inside the noise: the start is found after the key surely left its rest, and its
    interval covers the time the true motion passed 20 um in >= 90 % of 200 draws."""
    rng = np.random.default_rng(7)
    t = np.arange(-0.1, 0.05, 1 / RATE)
    covered, n = 0, 200
    for _ in range(n):
        t0 = float(rng.uniform(0.0005, 0.0015))
        truth = t0 + np.sqrt(2 * events.KEY_MOVE_THRESHOLD_M / 60.0)
        e = events.found(t, {"key_dip": _noisy_key(rng, t, t0, 65e-6)})["key_starts"]
        assert e.low <= e.time <= e.high and e.high - e.low < 8e-3
        covered += e.low <= truth <= e.high
    assert covered / n >= 0.9, covered


def _saturating_hammer(t: np.ndarray, t_s: float, v_out: float, v_in: float,
                       top: float, rng: np.random.Generator) -> np.ndarray:
    """A hammer flying at ``v_out`` to the string at ``t_s`` and back at ``v_in``, read by
    a sensor that compresses the motion toward ``top`` (a CNY-70 near its range's end:
    y = top tanh(x / top)) and is clipped at 0.9 top (its calibration table's end), with
    5 um noise: like the Kawai recording's shank sensor, out of range for a few ms."""
    x = np.where(t < t_s, v_out * (t - t_s), -v_in * (t - t_s)) + 7e-3  # string 7 mm up
    x = np.clip(x, 0.0, None)
    y = top * np.tanh(x / top)
    return np.minimum(y + rng.normal(0, 5e-6, t.size), 0.9 * top)


@pytest.mark.parametrize("ratio", [0.4, 0.6, 0.8])
def test_a_strike_beyond_the_sensors_range_is_bracketed_and_placed(ratio: float) -> None:
    """The string is beyond the hammer sensor's range: the strike is placed from the
    speeds into and out of the sensor's top; its interval covers the true time."""
    rng = np.random.default_rng(3)
    t = np.arange(-0.05, 0.1, 1 / RATE)
    for t_s in (0.03, 0.03017, 0.03041):
        h = _saturating_hammer(t, t_s, 1.0, ratio * 1.0, 3.7e-3, rng)
        e = events.found(t, {"hammer_shank_rise": h})["strike"]
        assert "saturated" in e.method
        assert e.low <= t_s <= e.high, (t_s, e)
        assert abs(e.time - t_s) < 1e-3


def test_a_reading_clipped_at_the_table_end_is_no_key_bottom() -> None:
    """A key sensor whose calibration ends before the key's bottom reads a flat top: that
    is no catch of the front felt; without the out-of-range mask it would look like one."""
    t = np.arange(-0.05, 0.1, 1 / RATE)
    x = np.clip(np.where(t > 0, 0.4 * t, 0.0), None, 0.0105)  # 0.4 m/s, clipped at 10.5 mm
    plain = events.found(t, {"key_dip": x})
    assert "key_bottom" in plain  # the clip stops the reading as a felt would
    masked = events.found(t, {"key_dip": x}, out_of_range={"key_dip": x >= 0.0105})
    assert "key_bottom" not in masked and "key_starts" in masked


def test_a_noisy_hammers_check_is_found_with_an_interval_that_covers_it() -> None:
    """A hammer sensor with white noise of 0.3 mrad (its velocity's noise 0.85 rad/s,
    a tenth of the rebound's 8 rad/s: more than the 5 % of the speed lost a quantized
    encoder's hinge fit may leave): the strike is found in every draw, the check (its
    fit judged against the sensor's own noise) in most, its interval covering the true
    catch in 90 % of those."""
    rng = np.random.default_rng(5)
    t = np.arange(-0.02, 0.2, 1 / RATE)
    fine = np.arange(t[0], t[-1] + 1e-7, 1e-7)
    n, found, covered = 40, 0, 0
    for _ in range(n):
        t_check = 0.08 + float(rng.uniform(0.0, 0.0005))
        vf = _velocity_at(fine, 0.05031, t_check)
        x = np.concatenate([[0.0], np.cumsum(vf[:-1] * np.diff(fine))])
        ev = events.found(t, {"hammer_angle": np.interp(t, fine, x)
                              + rng.normal(0.0, 3e-4, t.size)})
        assert abs(ev["strike"].time - 0.05031) <= 1e-3
        if "check" in ev:
            found += 1
            c = ev["check"]
            assert abs(c.time - t_check) < 2.5e-3 and c.half_width < 2.5e-3
            covered += c.low <= t_check <= c.high
    assert found >= 0.6 * n and covered >= 0.9 * found, (found, covered)


def _clipped_key(t: np.ndarray, rng: np.random.Generator, surface: float = 0.010
                 ) -> tuple[np.ndarray, float, float]:
    """A key at 0.8 m/s from t = 0 meeting its felt at 10 mm (t = 12.5 ms), compressing it
    by 0.4 mm within 0.8 ms, then resting at 10.1 mm until it is let up at 0.2 m/s from
    0.1 s; read with 2 um noise by a sensor whose table ends at 10.2 mm. Returns the
    reading, the true bottom and the true release (the key back through 10 mm). Another
    ``surface`` moves the felt and the resting depth with it."""
    v0, w = 0.8, 2000.0
    held = surface + 0.0001
    t_b = surface / v0
    t_m = t_b + 0.5 * np.pi / w
    x = np.where(t > 0, v0 * t, 0.0)
    x = np.where(t >= t_b, surface + v0 / w * np.sin(w * (t - t_b)), x)
    x = np.where(t >= t_m, held + (surface + v0 / w - held) * np.exp(-(t - t_m) / 0.003), x)
    x = np.where(t >= 0.1, np.maximum(held - 0.2 * (t - 0.1), 0.0), x)
    return (np.minimum(x + rng.normal(0.0, 2e-6, t.size), 0.0102), t_b,
            0.1 + 0.0001 / 0.2)


def test_a_key_bottom_beyond_the_sensors_table_is_bracketed_and_its_release_found() -> None:
    """The key's sensor reads clipped at its table's end while the felt is compressed:
    the key bottom is bracketed between its approach's last undisturbed sample and its
    reaching the depth it rests at (read), the true contact inside; the release (back up
    through the felt's surface) found with an interval that holds it."""
    rng = np.random.default_rng(2)
    t = np.arange(-0.05, 0.2, 1 / RATE)
    x, t_b, t_r = _clipped_key(t, rng)
    ev = events.found(t, {"key_dip": x}, out_of_range={"key_dip": x >= 0.0102})
    b = ev["key_bottom"]
    assert "table ends before the bottom" in b.method
    assert b.low <= t_b <= b.high and abs(b.time - t_b) < 0.5e-3 and b.high - b.low < 1.5e-3
    r = ev["key_release"]
    assert r.low <= t_r <= r.high and abs(r.time - t_r) < 1e-3, (r, t_r)


def test_a_key_that_rests_beyond_the_sensors_table_brackets_its_bottom() -> None:
    """The felt (10.3 mm) and the resting depth beyond the table's end (10.2 mm): the
    bottom is bracketed from the approach's last undisturbed sample to the key's first
    reading after it comes back into range, the true contact inside; its release too."""
    rng = np.random.default_rng(4)
    t = np.arange(-0.05, 0.2, 1 / RATE)
    x, t_b, t_r = _clipped_key(t, rng, surface=0.0103)
    ev = events.found(t, {"key_dip": x}, out_of_range={"key_dip": x >= 0.0102})
    b = ev["key_bottom"]
    assert "beyond the table" in b.method and b.low <= t_b <= b.high
    assert abs(b.time - t_b) < 0.5e-3 and b.high > 0.1  # back in range after the let-up
    r = ev["key_release"]
    assert "beyond the sensor's table" in r.method  # the true release is on a sample:
    assert r.low - 1e-9 <= t_r <= r.high and abs(r.time - t_r) < 1e-3, (r, t_r)
