"""Events found in a measured trial's channels without a model (rig.analysis.events):
exact answers on constructed motions, and the model's own events on the simulated rig's
measurement-like channels (encoder counts, load-cell noise)."""

from __future__ import annotations

import numpy as np
import pytest

from rig import profiles
from rig.analysis import events
from rig.analysis import synth as sy
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
