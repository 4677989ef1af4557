"""Iterative learning control of the key force across trials.

One trial's feedforward is a table ``u`` (N) on the loop's 500 Hz trial-time grid
(``t_j = j / control_hz`` from the profile's start). After a trial with measured
load-cell force ``y`` the error ``e = r - y`` (r: the profile on the same grid) updates it:

    u_{k+1} = Q( u_k + L e_k ),   (L e)_j = gain * e_{j + lead}

* L, the learning filter: a gain and a time advance of ``lead`` cycles. The drive
  (Eq. D.1, thesis Appendix D) lags the demand by ~8 ms and has a static gain K
  (0.93 N/N); the error a demand change makes shows up ``lead`` cycles later, so
  the update looks that far ahead, and gain = ``learning_factor / K``.
  ``LearningFilter.from_record`` takes K (the record's ``sensitivity``) and the lag
  (``lag_s``) from the motor calibration record (`rig calibrate motor`); without
  one, ``LearningFilter.default`` uses the thesis's single model's K (0.9322 N/N)
  and ``loop.advance_s`` (8 ms), with learning_factor 1.0.
* Q, the robustness filter: a zero-phase (forward-backward) 2nd-order Butterworth
  low-pass at ``q_cutoff_hz`` (default 100 Hz), applied to the whole table after each
  update; it stops the learning from chasing load-cell noise and the drive's
  un-modelled high-frequency behaviour (the learning converges where |Q(1 - L G)| < 1).
* The limits: every learned table is clipped to [0, limits.max_force_n] and its
  change per cycle to ``limits.max_rate_n_per_s * dt`` (``limit_table``), so no
  learned demand asks for what ``motor_torque.Limiter`` would have to cut.
* Divergence: ``Learner.update`` keeps the best trial (lowest RMS error) and stops
  (``Learner.stopped``) when a trial's RMS error exceeds the best's by ``grow_factor``
  (default 1.5), or when two trials are worse than the best: their RMS error
  beyond the load cell's noise (sqrt(rms^2 - noise_n^2)) exceeds the best's by
  10 % + 0.1 noise_n (a noise-level difference is not divergence).
* The gain of the k-th update is gain x max(1 / k, min_gain_fraction = 0.5): the
  first update takes the full gain, later ones half, so the load cell's noise
  learned into the table does not build up at the full gain while a drifting
  drive is still followed.

SI units throughout: forces N, times s.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.signal import butter, filtfilt

from rig.config import Limits
from rig.errors import InputError

DEFAULT_GAIN_K = 0.9322        # N/N, actuator.process_model_all K of the thesis (Eq. D.1)
DEFAULT_LEARNING_FACTOR = 1.0  # fraction of the error (divided by K) learned per trial
DEFAULT_Q_CUTOFF_HZ = 100.0


@dataclass(frozen=True)
class LearningFilter:
    """L: gain (N of demand per N of error) and lead (cycles); Q: cutoff (Hz)."""

    gain: float
    lead: int
    q_cutoff_hz: float = DEFAULT_Q_CUTOFF_HZ
    source: str = "default"

    def __post_init__(self) -> None:
        if not 0 < self.gain < 10:
            raise InputError(f"learning gain: expected 0 to 10 N/N, got {self.gain}")
        if not 0 <= self.lead <= 100:
            raise InputError(f"learning lead: expected 0 to 100 cycles, got {self.lead}")
        if not self.q_cutoff_hz > 0:
            raise InputError(f"q_cutoff_hz: expected > 0 Hz, got {self.q_cutoff_hz}")

    @classmethod
    def default(cls, control_hz: float, advance_s: float,
                factor: float = DEFAULT_LEARNING_FACTOR) -> LearningFilter:
        return cls(factor / DEFAULT_GAIN_K, int(round(advance_s * control_hz)),
                   source=f"default (K {DEFAULT_GAIN_K} N/N, lead loop.advance_s "
                          f"{advance_s * 1e3:g} ms)")

    @classmethod
    def from_record(cls, rec: dict[str, Any], control_hz: float,
                    factor: float = DEFAULT_LEARNING_FACTOR) -> LearningFilter:
        """From a motor calibration record: K = fit.sensitivity, lead = fit.lag_s."""
        fit = rec["fit"]
        k = float(fit["sensitivity"])
        lag = float(fit["lag_s"])
        return cls(factor / k, int(round(lag * control_hz)),
                   source=f"motor calibration {rec.get('content_hash', '?')} (K {k:.4f} N/N, "
                          f"lag {lag * 1e3:.2f} ms)")


def q_filter(u: np.ndarray, cutoff_hz: float, rate_hz: float) -> np.ndarray:
    """Zero-phase 2nd-order Butterworth low-pass (forward and backward; no lag)."""
    if cutoff_hz >= 0.5 * rate_hz:
        return u.copy()
    b, a = butter(2, cutoff_hz / (0.5 * rate_hz))
    return np.asarray(filtfilt(b, a, u, padtype="constant", padlen=min(len(u) - 1, 60)))


def limit_table(u: np.ndarray, limits: Limits, dt: float) -> np.ndarray:
    """Clip to [0, max_force] and the per-cycle change to max_rate * dt, starting from 0
    (the demand before a trial) and returning to 0 within the limits at the end."""
    v = np.clip(np.asarray(u, float), 0.0, limits.max_force_n)
    step = limits.max_rate_n_per_s * dt
    out = np.empty_like(v)
    last = 0.0
    for j, x in enumerate(v):
        last = min(last + step, max(last - step, x))
        out[j] = last
    # backward pass: the table's end must be reachable from 0 (it returns to zero after)
    nxt = 0.0
    for j in range(len(out) - 1, -1, -1):
        nxt = min(out[j], nxt + step)
        out[j] = nxt
    return out


def errors(reference: np.ndarray, measured: np.ndarray, peak: float) -> dict[str, float]:
    """Maximum and RMS of |r - y| (N and % of the profile's peak)."""
    e = np.abs(np.asarray(reference) - np.asarray(measured))
    mx, rms = float(e.max()), float(np.sqrt(np.mean(e ** 2)))
    return {"max_n": mx, "rms_n": rms, "max_pct": 100 * mx / peak, "rms_pct": 100 * rms / peak}


@dataclass
class Learner:
    """The learning across trials on a fixed grid; ``u`` is the next trial's table."""

    reference: np.ndarray
    u: np.ndarray
    filt: LearningFilter
    limits: Limits
    control_hz: float
    grow_factor: float = 1.5
    noise_n: float = 0.0
    min_gain_fraction: float = 0.5
    history: list[dict[str, float]] = field(default_factory=list)
    best_u: np.ndarray | None = None
    best: dict[str, float] | None = None
    stopped: str | None = None
    _worse: int = 0

    @classmethod
    def start(cls, reference: np.ndarray, initial: np.ndarray, filt: LearningFilter,
              limits: Limits, control_hz: float, **kw: Any) -> Learner:
        r = np.asarray(reference, float)
        u0 = limit_table(np.asarray(initial, float), limits, 1.0 / control_hz)
        if u0.shape != r.shape:
            raise InputError(f"initial feedforward: expected {r.shape[0]} points, got "
                             f"{u0.shape[0]}")
        return cls(r, u0, filt, limits, control_hz, **kw)

    @property
    def peak(self) -> float:
        return float(self.reference.max())

    def update(self, measured: np.ndarray) -> dict[str, float]:
        """Learn from the trial just played with ``self.u``; its errors (with ``trial``)."""
        y = np.asarray(measured, float)
        if y.shape != self.reference.shape:
            raise InputError(f"measured force: expected {self.reference.shape[0]} points, got "
                             f"{y.shape[0]}")
        err = errors(self.reference, y, self.peak)
        err["trial"] = float(len(self.history) + 1)
        self.history.append(err)
        if self.best is None or err["rms_n"] < self.best["rms_n"]:
            self.best, self.best_u, self._worse = err, self.u.copy(), 0
        else:
            # a trial worse than the best by more than the noise can explain
            if self._above_noise(err["rms_n"]) > 1.1 * self._above_noise(self.best["rms_n"]) \
                    + 0.1 * self.noise_n:
                self._worse += 1
            if err["rms_n"] > self.grow_factor * self.best["rms_n"] or self._worse >= 2:
                self.stopped = (f"the error grew (trial {int(err['trial'])}: RMS "
                                f"{err['rms_pct']:.2f} % against {self.best['rms_pct']:.2f} % "
                                f"in trial {int(self.best['trial'])}); kept trial "
                                f"{int(self.best['trial'])}")
                assert self.best_u is not None
                self.u = self.best_u.copy()
                return err
        e = self.reference - y
        m = self.filt.lead
        # full gain first, then at least min_gain_fraction of it: less noise learned in
        gain = self.filt.gain * max(1.0 / len(self.history), self.min_gain_fraction)
        shifted = np.r_[e[m:], np.full(m, e[-1])] if m else e
        new = q_filter(self.u + gain * shifted, self.filt.q_cutoff_hz, self.control_hz)
        self.u = limit_table(new, self.limits, 1.0 / self.control_hz)
        return err

    def _above_noise(self, rms_n: float) -> float:
        """The RMS error the load cell's noise does not explain (N)."""
        return float(np.sqrt(max(rms_n ** 2 - self.noise_n ** 2, 0.0)))

    def result(self) -> tuple[np.ndarray, dict[str, float]]:
        """The best table played and its errors."""
        if self.best_u is None or self.best is None:
            raise InputError("no trial learned from yet")
        return self.best_u.copy(), dict(self.best)
