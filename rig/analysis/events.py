"""Events found in a measured trial's channels, without a model.

A measured run knows when its blow's events happened only from its sensors. Four of the
action's events leave a mark the rig's encoders resolve at 2 kHz; each is found on one
channel (motion from the start pose, any sign convention: directions come from the data):

- ``key_starts``: ``key_dip`` leaves its rest by more than the model's threshold
  (``KEY_MOVE_THRESHOLD_M``, 20 um of key-top travel), interpolated between samples.
- ``strike``: ``hammer_angle``. The hammer reverses at the string within a millisecond: the
  first interval after the key starts whose motion is no longer toward the hammer's
  farthest excursion, provided the hammer was still at half its top approach speed 1.5 ms
  before (a hammer that turns back short of the string slows over tens of ms: no strike).
  From there back, the intervals whose velocity (sample differences) falls short of the
  linear extrapolation of the three before it by more than the threshold; the midpoint
  of the earliest is the strike time (the contact is abrupt).
- ``check`` (``hammer_angle`` after the rebound) and ``key_bottom`` (``key_dip``): felt
  catches a moving body, and the deceleration builds over several samples. Anchored at
  the first interval whose speed is below half the largest of the eight before it and
  stays there for 4 ms (the felt holds the body), then placed by a hinge fit over those
  eight intervals: velocity = a + b t + c max(0, t - t0)^2 (a force rising linearly from
  the contact's onset t0), t0 by least squares on a 10 us grid. Not found when the fit's
  RMS residual exceeds 5 % of the speed the catch took away (a ringing flexible shank
  hides the back check's catch in the hammer's encoder).

The threshold: four quantization steps of the channel per sample interval, or five times
the robust scatter of the extrapolation's error over the twelve intervals that end four
before the anchor, whichever is larger. An event whose mark is not there (no reversal at
a string, no catch before the trial ends, a channel missing) is not found and not stored.
``let_off``, ``toe_meets_button``, ``string_release`` and ``key_release`` are not found:
at 2 kHz their marks are within one sample of a larger one (forte: let-off 0.3 ms before
the strike) or below the encoders' resolution (the string's force fades out over the
last few tenths of a millisecond).

Accuracy against the model's own events on the simulated rig's channels (80 trials: five
truth models, eight blows of 1.2-40 N, two seeds; ``benchmarks/events.py``, figures in
docs/performance.md): key start within 0.05 ms; strike within 0.6 ms (rigid shank) and
0.75 ms (flexible shank: its ringing moves the hammer's encoder); check and key bottom
within 0.5 ms where found.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from rig.model.vocabulary import EVENT_ORDER, KEY_MOVE_THRESHOLD_M

SOURCE = "found in the measured channels (rig.analysis.events)"
METHODS: dict[str, str] = {
    "key_starts": f"key_dip leaves its rest by {KEY_MOVE_THRESHOLD_M * 1e6:.0f} um "
                  "(interpolated)",
    "strike": "hammer_angle: midpoint of the first sample interval whose velocity departs "
              "from the approach before the reversal at the string",
    "check": "hammer_angle: onset of the back check's deceleration after the rebound "
             "(hinge fit to the velocity)",
    "key_bottom": "key_dip: onset of the front felt's deceleration (hinge fit to the "
                  "velocity)",
}
QUANT_STEPS = 4.0     # threshold floor: quantization steps per sample interval
SCATTER_K = 5.0       # ... or this many robust standard deviations of the extrapolation error
SCATTER_INTERVALS, SCATTER_GAP = 12, 4  # ... over these intervals, ending this far back
REVERSAL_INTERVALS = 3  # the hammer is still fast this many intervals before its reversal
HINGE_GRID_S = 1e-5
HOLD_INTERVALS = 8     # a caught body stays below half its speed this long (4 ms)
CATCH_WINDOW = 8       # intervals of the hinge fit before the anchor
FIT_SHARE = 0.05       # largest RMS residual of the hinge fit, share of the speed lost


def _extrapolation_error(v: np.ndarray) -> np.ndarray:
    """e[i] = v[i] minus the line through v[i-3], v[i-2], v[i-1] extrapolated to i (NaN for
    the first three)."""
    e = np.full(v.size, np.nan)
    if v.size > 3:
        pred = (v[:-3] + v[1:-2] + v[2:-1]) / 3.0 + (v[2:-1] - v[:-3])
        e[3:] = v[3:] - pred
    return e


class _Motion:
    """One channel's sample-interval velocities and the departure threshold."""

    def __init__(self, t: np.ndarray, x: np.ndarray, rest: np.ndarray) -> None:
        self.t, self.x = t, x
        dt = np.diff(t)
        self.dt = float(np.median(dt))
        self.tc = 0.5 * (t[1:] + t[:-1])
        self.v = np.diff(x) / dt
        self.e = _extrapolation_error(self.v)
        steps = np.abs(np.diff(x))
        steps = steps[steps > 0]
        quantized = steps.size > 0 and np.allclose(steps / steps.min(),
                                                   np.round(steps / steps.min()), atol=1e-3)
        self.floor = QUANT_STEPS * float(steps.min()) / self.dt if quantized else 0.0
        self.x0 = float(np.median(x[rest])) if rest.any() else float(x[0])

    def threshold(self, i: int) -> float:
        """The departure threshold at interval ``i``: the quantization floor, or
        ``SCATTER_K`` robust standard deviations of the extrapolation error over the
        ``SCATTER_INTERVALS`` intervals that end ``SCATTER_GAP`` before ``i``."""
        e = self.e[max(0, i - SCATTER_GAP - SCATTER_INTERVALS):max(0, i - SCATTER_GAP)]
        e = e[np.isfinite(e)]
        scatter = 1.4826 * float(np.median(np.abs(e - np.median(e)))) if e.size >= 5 else 0.0
        return max(self.floor, SCATTER_K * scatter)

    def onset(self, i_anchor: int, s: float) -> int:
        """Walk back from interval ``i_anchor`` while the velocity departs from the
        extrapolation in direction ``-s`` (a deceleration of motion in direction ``s``) by
        more than the threshold at the anchor; the earliest departed interval (``i_anchor``
        when the one before it does not depart)."""
        thr = self.threshold(i_anchor)
        i = i_anchor - 1
        while i >= 3 and -s * self.e[i] > thr:
            i -= 1
        return i + 1


REST_S = 0.01  # without enough samples before t = 0, the action is at rest this long


def rest_mask(t: np.ndarray) -> np.ndarray:
    """Samples of the action at rest: before t = 0 if there are enough, else the first
    ``REST_S``. (Here rather than in rig.analysis.measurement, which needs the model:
    ``rig run`` finds events without importing it.)"""
    before = t < 0
    return before if before.sum() >= 10 else t < min(REST_S, float(t[0]) + REST_S)


def _key_starts(m: _Motion) -> tuple[float, float | None]:
    d = m.x - m.x0
    after = m.t >= 0
    if not after.any() or not np.any(np.abs(d[after]) > KEY_MOVE_THRESHOLD_M):
        return math.nan, None
    s = float(np.sign(d[after][np.argmax(np.abs(d[after]))]))
    i = int(np.argmax((s * d > KEY_MOVE_THRESHOLD_M) & after))
    if i == 0:
        return float(m.t[0]), s
    a, b = s * d[i - 1] - KEY_MOVE_THRESHOLD_M, s * d[i] - KEY_MOVE_THRESHOLD_M
    return float(m.t[i - 1] + (m.t[i] - m.t[i - 1]) * (-a) / (b - a)), s


def _catch(m: _Motion, s: float, i_from: int) -> float:
    """Onset of the catch that stops motion in direction ``s`` after interval ``i_from``.

    Anchored at the first interval whose speed is below half the largest over the
    ``CATCH_WINDOW`` intervals before it and stays there for ``HOLD_INTERVALS`` (the felt
    holds the body); placed by
    the hinge fit over the ``CATCH_WINDOW`` intervals up to the anchor. Not found (NaN) when
    the fit leaves residuals above ``FIT_SHARE`` of the speed the catch took away (the
    motion before the catch is not a smooth flight: a ringing shank, say)."""
    sv = s * m.v
    for a in range(max(i_from, 0) + 4, m.v.size - HOLD_INTERVALS):
        before = float(np.max(sv[max(i_from, a - CATCH_WINDOW):a]))
        if before > 0 and np.all(sv[a:a + HOLD_INTERVALS] < 0.5 * before):
            break
    else:
        return math.nan
    lo = max(a - CATCH_WINDOW, i_from)
    if a - lo < 4:
        return math.nan
    tt, vv = m.tc[lo:a + 1], m.v[lo:a + 1]
    best, t_best = math.inf, math.nan
    for t0 in np.arange(tt[1], tt[-1], HINGE_GRID_S):
        x = np.column_stack([np.ones_like(tt), tt - tt[0], np.maximum(0.0, tt - t0) ** 2])
        coef, *_ = np.linalg.lstsq(x, vv, rcond=None)
        sse = float(np.sum((x @ coef - vv) ** 2))
        if sse < best and -s * coef[2] > 0:
            best, t_best = sse, float(t0)
    drop = float(np.max(sv[lo:a + 1]) - sv[a])
    if not math.isfinite(t_best) or math.sqrt(best / tt.size) > FIT_SHARE * drop:
        return math.nan
    return t_best


def _strike_reversal(hm: _Motion, t: np.ndarray, t_from: float) -> tuple[int, float] | None:
    """The interval at which the hammer reverses at the string, and the direction of its
    approach: the first interval after ``t_from`` that does not move toward the hammer's
    farthest excursion, provided the hammer was still at half its top approach speed or
    more ``REVERSAL_INTERVALS`` before it (a hammer that turns back short of the string
    slows over tens of milliseconds: no strike)."""
    d = hm.x - hm.x0
    after = np.nonzero(t >= max(0.0, t_from))[0]
    if after.size < 8:
        return None
    s = float(np.sign(d[after[np.argmax(np.abs(d[after]))]]))
    i0 = int(after[0])
    sv = s * hm.v[i0:]
    moving = np.nonzero(sv > hm.floor)[0]
    if moving.size == 0:
        return None
    back = np.nonzero(sv[moving[0]:] <= 0)[0]
    if back.size == 0:
        return None
    k = int(moving[0] + back[0])
    top = float(np.max(sv[:k]))
    if k < REVERSAL_INTERVALS or sv[k - REVERSAL_INTERVALS] < 0.5 * top:
        return None
    return i0 + k, s


def find(time: np.ndarray, channels: Mapping[str, np.ndarray]) -> dict[str, float]:
    """Event times (s, on the trial's clock) found in a trial's channels; only the events
    found (see the module's docstring), in the order of ``EVENT_ORDER``."""
    t = np.asarray(time, float)
    out: dict[str, float] = {}
    if t.size < 32:
        return out
    rest = rest_mask(t)
    key = channels.get("key_dip")
    if key is not None and np.all(np.isfinite(key)):
        km = _Motion(t, np.asarray(key, float), rest)
        t_start, ks = _key_starts(km)
        if ks is not None:
            out["key_starts"] = t_start
            i0 = int(np.searchsorted(km.tc, t_start))
            t_bottom = _catch(km, ks, i0)
            if math.isfinite(t_bottom):
                out["key_bottom"] = t_bottom
    ham = channels.get("hammer_angle")
    if ham is not None and np.all(np.isfinite(ham)):
        hm = _Motion(t, np.asarray(ham, float), rest)
        reversal = _strike_reversal(hm, t, out.get("key_starts", 0.0))
        if reversal is not None:
            i_rev, s = reversal
            out["strike"] = float(hm.tc[hm.onset(i_rev, s)])
            t_check = _catch(hm, -s, i_rev)
            if math.isfinite(t_check):
                out["check"] = t_check
    return {k: out[k] for k in EVENT_ORDER if k in out}
