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

Real recordings (``found``, used by rig run and rig import): every event carries its 95 %
interval (``Found``); a key whose rest noise buries the threshold is placed by a fit of
its start's shape (``_key_starts``); a hammer sensor that saturates short of the string
brackets the strike (``_strike_bracket``); readings clipped at a calibration table's end
(``out_of_range``) carry no event.

Accuracy against the model's own events on the simulated rig's channels (80 trials: five
truth models, eight blows of 1.2-40 N, two seeds; ``benchmarks/events.py``, figures in
docs/performance.md): key start within 0.05 ms; strike within 0.6 ms (rigid shank) and
0.75 ms (flexible shank: its ringing moves the hammer's encoder); check and key bottom
within 0.5 ms where found.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.special import fdtri  # the F distribution's quantile (scipy.stats: 1.4 s to import)

from rig.recordings.channels import EVENT_ORDER, KEY_MOVE_THRESHOLD_M  # (no numba)

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


NOISE_K = 5.0         # a noisy key has left its rest when it is this many robust SDs out
REST_SHARE = 0.1      # ... unless that is this share of its travel: it was not at rest
START_WINDOW = 40     # samples before the level in a noisy key's start fit (20 ms)
BRACKET_SAMPLES = 4   # samples of the lines into and out of a saturated range (strike)
BRACKET_LEVEL = 0.8   # ... above this share of its top reading the sensor is not read
FLAT_SAMPLES, FLAT_SHARE = 4, 0.002  # a flat top this long and close: a saturated sensor
Z95 = 1.959963984540054


@dataclass(frozen=True)
class Found:
    """An event found in a trial's channels: its time, the 95 % interval [low, high] that
    the method and the channel's noise give (s, on the trial's clock), and the method."""

    time: float
    low: float
    high: float
    method: str

    @property
    def half_width(self) -> float:
        """Half the interval's width (s): the event's timing confidence."""
        return 0.5 * (self.high - self.low)


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
        xr = x[rest] if rest.sum() >= 10 else x[:0]
        # the channel's noise at rest (robust SD; 0 for a quantized, still channel)
        self.noise = 1.4826 * float(np.median(np.abs(xr - self.x0))) if xr.size else 0.0
        self.rest_span = float(np.ptp(np.percentile(xr, [5, 95]))) if xr.size else 0.0

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


def _key_starts(m: _Motion) -> tuple[Found | None, float | None]:
    """The key's start and the sign of its travel.

    Where the channel is still at rest (its noise below the threshold's fifth), the first
    crossing of ``KEY_MOVE_THRESHOLD_M`` after t = 0, interpolated between the two samples
    that bracket it (its interval). On a noisy channel a noise spike may cross the
    threshold: the key has surely left its rest where it is ``NOISE_K`` robust SDs out
    (the level). The samples of the ``START_WINDOW`` before the level and two after it
    are fitted by a rest that starts to move at t0 as c (t - t0)^p (p = 1, 2 or 3: a push
    that starts at a speed, under a force, under a growing force; c by least squares,
    t0 on a grid); the start is the best fit's crossing of the threshold, its interval
    the crossings of every (t0, p) the F test at 5 % keeps, and half a sample.
    No start is found where the samples before t = 0 are no rest (their spread or the
    noise over ``REST_SHARE`` of the travel: a repeated note).
    """
    d = m.x - m.x0
    after = m.t >= 0
    level = max(KEY_MOVE_THRESHOLD_M, NOISE_K * m.noise)
    if not after.any() or not np.any(np.abs(d[after]) > level):
        return None, None
    if max(level, m.rest_span) > REST_SHARE * float(np.max(np.abs(d[after]))):
        return None, None  # no rest before the press (a repeated note): no start to find
    s = float(np.sign(d[after][np.argmax(np.abs(d[after]))]))
    i = int(np.argmax((s * d > level) & after))
    if i == 0:
        t0 = float(m.t[0])
        return Found(t0, t0, t0, METHODS["key_starts"]), s
    if level == KEY_MOVE_THRESHOLD_M:
        a, b = s * d[i - 1] - level, s * d[i] - level
        t_c = float(m.t[i - 1] + (m.t[i] - m.t[i - 1]) * (-a) / (b - a))
        return Found(t_c, float(m.t[i - 1]), float(m.t[i]), METHODS["key_starts"]), s
    # the start's shape fitted to the samples up to just past the level: rest, then
    # x = c (t - t0)^p (p = 1, 2, 3: a push that starts at a speed, a force, a force
    # growing); the threshold's crossing t0 + (threshold / c)^(1/p), its interval the
    # crossings of every (t0, p) the F test at 5 % does not reject
    a = max(0, i - START_WINDOW)
    tt, yy = m.t[a:i + 3], s * d[a:i + 3]
    t0s = np.arange(tt[0], m.t[i], HINGE_GRID_S * 5)
    sse_l, cross_l = [], []
    for p in (1.0, 2.0, 3.0):  # every onset at once, in sample intervals
        g = np.maximum(0.0, (tt[None, :] - t0s[:, None]) / m.dt) ** p
        gg = np.sum(g * g, axis=1)
        c = np.divide(g @ yy, gg, out=np.zeros_like(gg), where=gg > 0)
        good = c > 0
        r = yy[None, :] - c[:, None] * g
        sse_l.append(np.sum(r * r, axis=1)[good])
        cross_l.append(t0s[good] + m.dt * (KEY_MOVE_THRESHOLD_M / c[good]) ** (1 / p))
    sse, cross = np.concatenate(sse_l), np.concatenate(cross_l)
    if sse.size == 0:
        return None, None
    k = int(np.argmin(sse))
    dof = max(tt.size - 3, 1)  # t0, c and the shape
    inside = cross[sse - sse[k] <= fdtri(1, dof, 0.95) * sse[k] / dof]
    half = 0.5 * m.dt
    return Found(float(cross[k]), float(inside.min()) - half, float(inside.max()) + half,
                 METHODS["key_starts"] + f"; below the noise ({level * 1e6:.0f} um): "
                 "the start's shape (rest, then c (t - t0)^p) fitted, its 20 um crossing"), s


def _catch(m: _Motion, s: float, i_from: int, valid: np.ndarray | None = None
           ) -> tuple[float, float, float]:
    """Onset of the catch that stops motion in direction ``s`` after interval ``i_from``,
    with its 95 % interval: (t0, low, high), NaN when not found.

    Anchored at the first interval whose speed is below half the largest over the
    ``CATCH_WINDOW`` intervals before it and stays there for ``HOLD_INTERVALS`` (the felt
    holds the body); placed by
    the hinge fit over the ``CATCH_WINDOW`` intervals up to the anchor. Not found (NaN) when
    the fit leaves residuals above ``FIT_SHARE`` of the speed the catch took away (the
    motion before the catch is not a smooth flight: a ringing shank, say), or when an
    interval of the fit or the hold is outside the sensor's range (``valid`` False: a
    reading clipped at the end of its calibration stops as a catch would). The interval:
    the onsets t0 whose fit is not worse than the best by the F test at 5 % (one
    parameter, the residual variance of the best fit)."""
    nan = (math.nan, math.nan, math.nan)
    sv = s * m.v
    for a in range(max(i_from, 0) + 4, m.v.size - HOLD_INTERVALS):
        before = float(np.max(sv[max(i_from, a - CATCH_WINDOW):a]))
        if before > 0 and np.all(sv[a:a + HOLD_INTERVALS] < 0.5 * before):
            break
    else:
        return nan
    lo = max(a - CATCH_WINDOW, i_from)
    if a - lo < 4:
        return nan
    if valid is not None and not np.all(valid[lo:a + HOLD_INTERVALS]):
        return nan
    tt, vv = m.tc[lo:a + 1], m.v[lo:a + 1]
    grid = np.arange(tt[1], tt[-1], HINGE_GRID_S)
    # every onset's least squares at once (times in sample intervals: well conditioned)
    u, ug = (tt - tt[0]) / m.dt, (grid - tt[0]) / m.dt
    x = np.empty((grid.size, tt.size, 3))
    x[:, :, 0], x[:, :, 1] = 1.0, u
    x[:, :, 2] = np.maximum(0.0, u[None, :] - ug[:, None]) ** 2
    xtx = np.einsum("gni,gnj->gij", x, x)
    xtv = np.einsum("gni,n->gi", x, vv)
    ok = np.abs(np.linalg.det(xtx)) > 1e-12
    coef = np.zeros((grid.size, 3))
    coef[ok] = np.linalg.solve(xtx[ok], xtv[ok][..., None])[..., 0]
    r = np.einsum("gni,gi->gn", x, coef) - vv
    sse = np.where(ok & (-s * coef[:, 2] > 0), np.sum(r ** 2, axis=1), math.inf)
    if not np.isfinite(sse).any():
        return nan
    g_best = int(np.argmin(sse))
    best, t_best = float(sse[g_best]), float(grid[g_best])
    drop = float(np.max(sv[lo:a + 1]) - sv[a])
    if math.sqrt(best / tt.size) > FIT_SHARE * drop:
        return nan
    dof = tt.size - 4  # a, b, c and t0
    scale = max(best, 1e-30) / max(dof, 1)
    inside = grid[sse - best <= fdtri(1, max(dof, 1), 0.95) * scale]
    return t_best, float(min(inside.min(), t_best - HINGE_GRID_S)), float(
        max(inside.max(), t_best + HINGE_GRID_S))


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


def _line(t: np.ndarray, x: np.ndarray, noise: float) -> tuple[float, float, float]:
    """Least-squares line x = a + b (t - t[-1]): (a, b, SD of b from the residuals or, with
    too few, from the channel's noise)."""
    tt = t - t[-1]
    xm = np.column_stack([np.ones_like(tt), tt])
    coef, *_ = np.linalg.lstsq(xm, x, rcond=None)
    r = x - xm @ coef
    var = float(r @ r) / (tt.size - 2) if tt.size > 2 else 0.0
    var = max(var, noise ** 2)
    sd_b = math.sqrt(var * float(np.linalg.inv(xm.T @ xm)[1, 1]))
    return float(coef[0]), float(coef[1]), sd_b


def _saturates(hm: _Motion, valid: np.ndarray | None, t_from: float) -> bool:
    """Whether the hammer's sensor ends its range short of the string: readings clipped at
    the far end of its calibration (``valid`` False there), or a flat top -- the hammer
    reverses at the string within a sample or two, a saturated sensor reads the same
    value for ``FLAT_SAMPLES`` or more."""
    d = hm.x - hm.x0
    after = hm.t >= t_from
    if not after.any():
        return False
    s = float(np.sign(d[after][np.argmax(np.abs(d[after]))]))
    top = float(np.max(s * d[after]))
    if top <= 0:
        return False
    far = after & (s * d > 0.5 * top)
    if valid is not None and np.any(~valid & far):
        return True
    flat = (s * d >= top - max(FLAT_SHARE * top, hm.noise)) & after
    run = np.diff(np.flatnonzero(np.diff(np.r_[0, flat.astype(int), 0])))[::2]
    return bool(run.size and run.max() >= FLAT_SAMPLES)


def _strike_bracket(hm: _Motion, t_from: float) -> tuple[Found, int, float] | None:
    """The strike on a hammer sensor whose range ends short of the string (``_saturates``).
    Above ``BRACKET_LEVEL`` of its top reading the sensor compresses the motion, so the
    hammer's path there is not read: it crosses that level up at t_out and down at t_in
    and met the string in between. With its speeds v_out (the line through the
    ``BRACKET_SAMPLES`` samples before t_out) and v_in (after t_in), and the same
    distance D beyond the level both ways, t_out + D / v_out = t_strike = t_in - D / v_in:
    t_strike = t_out + (t_in - t_out) v_in / (v_out + v_in). The 95 % interval: that time
    with each speed 1.96 SD off (the lines' noise), widened to the same rule with the
    speeds of quadratics through the samples (a hammer still driven by the jack, or
    slowing), and half a sample each way, within [t_out, t_in]. Returns the event, the
    first sample below the level after the return, and the direction of the approach."""
    t = hm.t
    d = hm.x - hm.x0
    after = t >= t_from
    s = float(np.sign(d[after][np.argmax(np.abs(d[after]))]))
    level = BRACKET_LEVEL * float(np.max(s * d[after]))
    up = np.flatnonzero(after & (s * d >= level))
    if up.size == 0:
        return None
    i_out = int(up[0])
    down = np.flatnonzero(s * d[i_out:] < level)
    if down.size == 0 or i_out < BRACKET_SAMPLES:
        return None
    i_in = i_out + int(down[0])
    if i_in + BRACKET_SAMPLES > t.size:
        return None
    ta, xa = t[i_out - BRACKET_SAMPLES:i_out], s * d[i_out - BRACKET_SAMPLES:i_out]
    tb, xb = t[i_in:i_in + BRACKET_SAMPLES], s * d[i_in:i_in + BRACKET_SAMPLES]
    a1, b1, sd1 = _line(ta, xa, hm.noise)
    a2, b2, sd2 = _line(tb[::-1], xb[::-1], hm.noise)  # x = a2 + b2 (t - tb[0])
    if b1 <= 0 or b2 >= 0:  # not rising into the level and falling out of it
        return None
    t_out = min(max(float(ta[-1] + (level - a1) / b1), float(ta[-1])), float(t[i_out]))
    t_in = max(min(float(tb[0] + (level - a2) / b2), float(tb[0])), float(t[i_in - 1]))
    span = t_in - t_out

    def at(v_out: float, v_in: float) -> float:
        return t_out + span * v_in / (v_out + v_in)

    est = at(b1, -b2)
    tries = [at(max(b1 + i * Z95 * sd1, 1e-12), max(-b2 + j * Z95 * sd2, 1e-12))
             for i in (-1, 1) for j in (-1, 1)]
    v_a = float(np.polyfit(ta - ta[-1], xa, 2)[1])  # speeds at the level's side ends
    v_b = -float(np.polyfit(tb - tb[0], xb, 2)[1])
    tries += [at(max(v_a, 1e-12), -b2), at(b1, max(v_b, 1e-12)),
              at(max(v_a, 1e-12), max(v_b, 1e-12))]
    half = 0.5 * hm.dt  # the level's crossings are placed within a sample
    lo = max(t_out, min(tries + [est]) - half)
    hi = min(t_in, max(tries + [est]) + half)
    method = (f"hammer sensor saturated: above {BRACKET_LEVEL:.0%} of its top reading for "
              f"{span * 1e3:.1f} ms; the strike placed between by the speeds into and out of "
              f"that level at equal distance")
    return Found(est, lo, hi, method), i_in, s


HAMMER_CHANNELS = ("hammer_angle", "hammer_shank_rise")  # the hammer's motion, either


def found(time: np.ndarray, channels: Mapping[str, np.ndarray], *,
          out_of_range: Mapping[str, np.ndarray] | None = None) -> dict[str, Found]:
    """The events found in a trial's channels, each with its 95 % interval and method, in
    the order of ``EVENT_ORDER`` (see the module's docstring). ``out_of_range``: per
    channel, the samples its sensor could not read (clipped at the end of its
    calibration: rig import); no event is placed on them, and a hammer sensor whose range
    ends short of the string brackets the strike instead (``_strike_bracket``)."""
    t = np.asarray(time, float)
    out: dict[str, Found] = {}
    if t.size < 32:
        return out
    rest = rest_mask(t)
    oor = out_of_range or {}

    def valid_of(name: str) -> np.ndarray | None:
        mask = oor.get(name)
        return None if mask is None or not np.any(mask) else ~np.asarray(mask, bool)

    key = channels.get("key_dip")
    if key is not None and np.all(np.isfinite(key)):
        km = _Motion(t, np.asarray(key, float), rest)
        start, ks = _key_starts(km)
        if start is not None and ks is not None:
            out["key_starts"] = start
            i0 = int(np.searchsorted(km.tc, start.time))
            kv = valid_of("key_dip")
            tb, lo, hi = _catch(km, ks, i0, None if kv is None else kv[1:] & kv[:-1])
            if math.isfinite(tb):
                out["key_bottom"] = Found(tb, lo, hi, METHODS["key_bottom"])
    name = next((n for n in HAMMER_CHANNELS if n in channels), None)
    ham = channels.get(name) if name else None
    if name is not None and ham is not None and np.all(np.isfinite(ham)):
        hm = _Motion(t, np.asarray(ham, float), rest)
        t_from = out["key_starts"].time if "key_starts" in out else 0.0
        hv = valid_of(name)
        i_back: int | None = None
        s = 0.0
        if _saturates(hm, hv, t_from):
            bracket = _strike_bracket(hm, t_from)
            if bracket is not None:
                out["strike"], i_back, s = bracket
        else:
            reversal = _strike_reversal(hm, t, t_from)
            if reversal is not None:
                i_rev, s = reversal
                i_on = hm.onset(i_rev, s)
                out["strike"] = Found(float(hm.tc[i_on]), float(t[i_on]), float(t[i_on + 1]),
                                      METHODS["strike"])
                i_back = i_rev
        if i_back is not None:
            iv = None if hv is None else hv[1:] & hv[:-1]
            tc, lo, hi = _catch(hm, -s, i_back, iv)
            if math.isfinite(tc):
                out["check"] = Found(tc, lo, hi, METHODS["check"])
    return {k: out[k] for k in EVENT_ORDER if k in out}


def find(time: np.ndarray, channels: Mapping[str, np.ndarray]) -> dict[str, float]:
    """Event times (s, on the trial's clock) found in a trial's channels (``found``'s
    times)."""
    return {k: v.time for k, v in found(time, channels).items()}
