"""Calibration of rig.analysis.stats on correlated noise like 2 kHz residuals (issue 13):
the held-out improvement test holds its false-alarm rate on noise alone and the HAC
(Newey-West) intervals of a least-squares fit cover the truth at their nominal rate, where
independent-noise intervals do not."""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

from rig.analysis import stats

N, SEG = 600, [300, 300]  # two trials' channels of 0.15 s at 2 kHz


def coloured(rng: np.random.Generator, n: int = N) -> np.ndarray:
    """Noise through a resonant 2nd-order filter (ringing at ~100 Hz at 2 kHz) plus a slow
    AR(1) part: strongly autocorrelated, like a sensor chain's residual."""
    w = rng.standard_normal(n)
    r, th = 0.97, 2 * math.pi * 100 / 2000
    ring = lfilter([1.0], [1, -2 * r * math.cos(th), r * r], w)
    slow = lfilter([1.0], [1, -0.95], rng.standard_normal(n))
    return ring / ring.std() + 0.5 * slow / slow.std()


def test_improvement_test_holds_its_level_on_noise_alone() -> None:
    rng = np.random.default_rng(1)
    t = np.arange(N) / 2000
    alarms, reps = 0, 400
    for _ in range(reps):
        e = coloured(rng)
        # a change fitted on other (training) noise: smooth, independent of e, small
        delta = 0.05 * np.sin(2 * math.pi * 30 * t + rng.uniform(0, 6))
        _, p = stats.improvement_test(e, e - delta, SEG)
        alarms += p <= 0.05
    assert alarms / reps <= 0.08, alarms / reps
    # and it finds a real improvement of the same size against the same noise
    found = 0
    for _ in range(100):
        e = coloured(rng)
        miss = 1.0 * np.sin(2 * math.pi * 30 * t)
        _, p = stats.improvement_test(e + miss, e, SEG)
        found += p <= 0.05
    assert found >= 80, found


def test_hac_intervals_cover_where_independent_noise_ones_do_not() -> None:
    rng = np.random.default_rng(2)
    t = np.arange(N) / 2000
    X = np.column_stack([np.sin(2 * math.pi * 20 * t), np.exp(-t / 0.05)])
    truth = np.array([1.0, -0.5])
    cover_hac, cover_iid = np.zeros(2), np.zeros(2)
    reps = 300
    for _ in range(reps):
        y = X @ truth + 0.3 * coloured(rng)
        beta, *_ = np.linalg.lstsq(X, y, rcond=None)
        r = y - X @ beta
        se_hac = np.sqrt(np.diag(stats.sandwich_cov(X, r, SEG)))
        se_iid = np.sqrt(np.diag(np.linalg.inv(X.T @ X)) * (r @ r) / (N - 2))
        cover_hac += np.abs(beta - truth) <= 1.96 * se_hac
        cover_iid += np.abs(beta - truth) <= 1.96 * se_iid
    assert np.all(cover_hac / reps >= 0.85), cover_hac / reps  # each parameter's interval
    assert np.all(cover_iid / reps < 0.7), cover_iid / reps  # what the old errors looked like


def test_values_print_and_round_to_their_uncertainty() -> None:
    assert stats.fmt(63.4123, 0.2211, "Hz") == "63.41 +- 0.22 Hz"
    assert stats.fmt(0.016912, 0.00201, "1") == "0.0169 +- 0.0020"
    assert stats.fmt(19387.2, 3456.0, "N/m") == "19400 +- 3500 N/m"
    assert "nan" not in stats.fmt(3e-13, math.nan, "s")
    assert stats.fmt(math.nan, 1.0) == "not determined"
    assert stats.round_to(0.12064, 0.0049) == 0.1206
    assert stats.round_to(19387.2, 3456.0) == 19400.0
