"""Events found in a measured trial's channels, without a model.

A measured run knows when its blow's events happened only from its sensors. Each event is
found on one channel (motion from the start pose, any sign convention: directions come
from the data) and carries its 95 % interval (``Found``; ``found``, used by rig run and
rig import):

- ``key_starts``: ``key_dip`` leaves its rest by more than the model's threshold
  (``KEY_MOVE_THRESHOLD_M``, 20 um of key-top travel), interpolated between samples. A
  key whose rest noise buries the threshold (the Kawai's CNY-70: 65 um RMS) is placed by
  a fit of its start's shape (``_key_starts``).
- ``strike``: ``hammer_angle`` (or ``hammer_shank_rise``). The hammer reverses at the
  string within a millisecond: the first interval after the key starts whose motion is no
  longer toward the hammer's farthest excursion, provided the hammer was still at half its
  top approach speed 1.5 ms before (a hammer that turns back short of the string slows
  over tens of ms: no strike). From there back, the intervals whose velocity (sample
  differences) falls short of the linear extrapolation of the three before it by more
  than the threshold; the midpoint of the earliest is the strike time (the contact is
  abrupt). A hammer sensor that saturates short of the string (clipped at its table's end,
  or a flat top) brackets the strike instead (``_strike_bracket``), if the hammer enters
  its top level still at half its top approach speed (a hammer pushed slowly to a
  standstill reads a flat top too: the Kawai's slow hand press).
- ``check`` (``hammer_angle`` after the rebound) and ``key_bottom`` (``key_dip``, in the
  last ``BOTTOM_SHARE`` of its deepest travel: a stall mid-travel is no bottom): felt
  catches a moving body, and the deceleration builds over several samples. Anchored at
  the first interval whose speed is below half the largest of the eight before it and
  stays there for 4 ms (the felt holds the body), then placed by a hinge fit over those
  eight intervals: velocity = a + b t + c max(0, t - t0)^2 (a force rising linearly from
  the contact's onset t0), t0 by least squares on a 10 us grid, its interval the onsets
  the F test at 5 % keeps. Accepted when the fit's RMS residual is within 5 % of the
  speed the catch took away, or within what the sensor's own noise leaves (its sample
  noise from second differences, ``local_noise``, as a velocity noise, times the
  chi-square 95 % bound of the fit's degrees of freedom), and the speed taken away is
  over ``NOISE_K`` of those noise SDs. A quantized encoder has no such noise, so a
  ringing flexible shank, whose motion is not a smooth flight, still hides its catch
  (found in 2 of 16 simulated flexible-shank trials, the piano blow's); a
  noisy analogue sensor's catch is found with an interval as wide as its noise makes it
  (the Kawai's shank sensor, 2-4 um at the check on its fast strokes: 1.5-3.5 ms).
- ``key_bottom`` where the key's sensor ends its range before the bottom (readings
  clipped at the table's end, the Kawai's at 15/32 in): bracketed (``_bottom_bracket``)
  between the approach's last undisturbed sample and the key reaching the depth it
  rests at on its bottom (a held key rests on its compressed felt: the felt's surface is
  no deeper), read where that depth is inside the table; beyond it, up to the key's
  first readable sample after the clipped stretch. A key never read again gives none.
- ``key_release`` (``key_dip``): the key leaves its felt for good, no earlier than it
  leaves the depth it rested at (by the start's threshold, or ``NOISE_K`` noise SDs) and
  than it comes back up through the depth it met its felt at (the key bottom's): the
  later of the two marks (``_key_release``). The interval reaches to where the key rises
  through the shallowest depth the bottom's interval allows. A key let up slowly rises
  with its decompressing felt for tens of ms, so the release's time is only as good as
  the bottom's depth: on the simulated rig's two-peak blow (its force let down over
  80 ms; ``benchmarks/events.py --release``) the release is found 1.6 ms late with key
  lift-off (its interval holds the model's) and 16-18 ms early on the other four truth
  models (their intervals do not: the found bottom, 0.4 ms late, puts the felt's surface
  0.3 mm too deep, and the key rises through that in 16 ms).

The threshold: four quantization steps of the channel per sample interval, or five times
the robust scatter of the extrapolation's error over the twelve intervals that end four
before the anchor, whichever is larger. An event whose mark is not there (no reversal at
a string, no catch before the trial ends, a channel missing) is not found and not stored;
neither is one placed on readings clipped at a calibration table's end (``out_of_range``),
except by the brackets above. Events found out of the order of a blow (``BLOW_ORDER``,
``order_flags``) are flagged by rig import and rig compare, never silently stored.

``toe_meets_button``, ``let_off`` and ``string_release`` are not found. At 2 kHz on the
rig's encoders their marks are within one sample of a larger one (forte: let-off 0.3 ms
before the strike) or below the encoders' resolution (the string's force fades out over
the last few tenths of a millisecond). On the Kawai KG-3C recording there is no jack
sensor, and the hammer's sensor (3.7 mm of shank travel, its table's end) is saturated
for 5-6 ms around every strike, let-off included: the hammer's escapement happens where
no sensor reads.

Accuracy against the model's own events on the simulated rig's channels (80 trials: five
truth models, eight blows of 1.2-40 N, two seeds; ``benchmarks/events.py``, figures in
docs/performance.md): key start within 0.05 ms; strike within 1.4 ms (rigid shank) and
0.84 ms (flexible shank: its ringing moves the hammer's encoder); check and key bottom
within 0.55 ms where found. On the Kawai strokes
(tests/test_import.py): key start, key bottom, check and key release within 1 ms of a
hand reading.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.special import chdtri, fdtri  # chi-square, F quantiles (scipy.stats: 1.4 s to import)

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
    "key_release": "key_dip: the key's travel leaves the depth it held, for good, by the "
                   "key's start threshold",
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
BOTTOM_SHARE = 0.9    # the key's bottom lies in the last 10 % of its deepest travel (a felt
                      # compressed by a blow: a few %; a stall mid-travel is no bottom)
HELD_SAMPLES = 40     # the depth a key holds before its release: median of these (20 ms)


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


def local_noise(x: np.ndarray) -> float:
    """A channel's sample noise where it moves smoothly: the robust SD of its second
    differences over sqrt(6) (white noise's second difference has six times its variance;
    a smooth motion's, a = 1000 m/s^2 at 2 kHz, is 0.25 mm/s^2 dt^2 = 0.25 um); 0 for a
    quantized channel whose counts rarely change twice in a row."""
    d2 = np.diff(np.asarray(x, float), 2)
    if d2.size < 5:
        return 0.0
    return 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / math.sqrt(6.0)


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


def _catch(m: _Motion, s: float, i_from: int, valid: np.ndarray | None = None,
           deep: np.ndarray | None = None) -> tuple[float, float, float]:
    """Onset of the catch that stops motion in direction ``s`` after interval ``i_from``,
    with its 95 % interval: (t0, low, high), NaN when not found.

    Anchored at the first interval whose speed is below half the largest over the
    ``CATCH_WINDOW`` intervals before it and stays there for ``HOLD_INTERVALS`` (the felt
    holds the body); placed by
    the hinge fit over the ``CATCH_WINDOW`` intervals up to the anchor. Not found (NaN) when
    the fit leaves residuals above ``FIT_SHARE`` of the speed the catch took away (the
    motion before the catch is not a smooth flight: a ringing shank, say), or when an
    interval of the fit or the hold is outside the sensor's range (``valid`` False: a
    reading clipped at the end of its calibration stops as a catch would), or when the
    speed it took away is within ``NOISE_K`` SDs of the velocity's noise (``local_noise``).
    The fit is accepted when its RMS residual is within ``FIT_SHARE`` of that speed or
    within what the velocity's noise leaves (its SD times the chi-square 95 % bound of
    the fit's degrees of freedom): a noisy sensor's catch is found, a ringing encoder's
    (no noise: quantized) is not. Anchors only where ``deep`` (per interval) is True. The
    interval:
    the onsets t0 whose fit is not worse than the best by the F test at 5 % (one
    parameter, the residual variance of the best fit)."""
    nan = (math.nan, math.nan, math.nan)
    sv = s * m.v
    for a in range(max(i_from, 0) + 4, m.v.size - HOLD_INTERVALS):
        if deep is not None and not deep[a]:
            continue
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
    dof = tt.size - 4  # a, b, c and t0
    # the velocity's own noise (a sensor's, not the motion's): from the channel's local
    # sample noise over the fit and the hold (second differences), sqrt(2) of it per dt
    sd_v = math.sqrt(2.0) * local_noise(m.x[lo:a + HOLD_INTERVALS + 2]) / m.dt
    if drop < NOISE_K * sd_v:
        return nan  # the catch took away less speed than the noise hides
    noise_rms = sd_v * math.sqrt(chdtri(max(dof, 1), 0.05) / max(dof, 1))
    if math.sqrt(best / tt.size) > max(FIT_SHARE * drop, noise_rms):
        return nan
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
    # moving: faster than the quantization floor and than the rest noise's velocity
    moving = np.nonzero(sv > max(hm.floor, NOISE_K * math.sqrt(2.0) * hm.noise / hm.dt))[0]
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
    # a hammer flying to the string: still at half its top approach speed (over lines of
    # BRACKET_SAMPLES) where it enters the level, as at a reversal (_strike_reversal); a
    # hammer pushed slowly to a standstill (a hand's press) does not strike
    i_a = int(np.argmax(after))
    xs = s * d[i_a:i_out]
    if xs.size > BRACKET_SAMPLES:
        k = BRACKET_SAMPLES - 1
        if b1 < 0.5 * float(np.max(xs[k:] - xs[:-k])) / (k * hm.dt):
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


def _bottom_bracket(km: _Motion, s: float, i_from: int, valid: np.ndarray
                    ) -> tuple[Found, float] | None:
    """The key's bottom where its sensor's range ends before it (readings clipped at the
    far end of the calibration, ``valid`` False, while the key is deep: the Kawai's key
    sensor, whose table ends at 15/32 in). The key enters the unread range at the first
    clipped sample i_c; its felt was met

    - no earlier than the start of the readable approach's earliest interval whose
      velocity departs from the extrapolation of those before it (``_Motion.onset`` from
      the last readable interval: a catch that began earlier would show), less half a
      sample;
    - no later than the key first reaches the depth it rests at on its bottom (the median
      of the key's travel while it is deep, its clipped samples counted as beyond the
      table's end: a key held down rests on its compressed felt, so the felt's surface is
      no deeper), reached by the line through the last ``BRACKET_SAMPLES`` readable
      samples (at most at i_c); when that median is itself beyond the table's end, no
      later than the first readable sample after the clipped stretch (the key turned back
      inside it).

    The time given is the latest of these bounds where the resting depth is read (the
    key at a blow's speed crosses the felt's last few tenths of a millimetre within a
    fraction of a millisecond), else the entry into the clipped range. Returned with
    the depth it places the felt's surface at (the resting depth or the table's end)."""
    d = s * (km.x - km.x0)
    after = np.arange(d.size) > i_from
    top = float(np.max(d[after])) if after.any() else 0.0
    clipped = np.flatnonzero(after & ~valid & (d > 0.5 * top))
    if top <= 0 or clipped.size == 0:
        return None
    i_c = int(clipped[0])
    i_r = i_c - 1
    if i_r - BRACKET_SAMPLES < i_from or not np.all(valid[i_r - BRACKET_SAMPLES + 1:i_c]):
        return None
    deep_idx = np.flatnonzero(after & (d > BOTTOM_SHARE * top))
    # the deep stretch of this press: from the entry to the key's first return above it
    back = deep_idx[deep_idx >= i_c]
    gaps = np.flatnonzero(np.diff(back) > 1)
    stretch = back[:gaps[0] + 1] if gaps.size else back
    depth = np.where(valid[stretch], d[stretch], math.inf)  # clipped: beyond the end
    rest = float(np.median(depth))
    i_on = km.onset(i_r - 1, s)
    low = float(km.t[i_on]) - 0.5 * km.dt
    ta, xa = km.t[i_r - BRACKET_SAMPLES + 1:i_c], d[i_r - BRACKET_SAMPLES + 1:i_c]
    _, v, _ = _line(ta, xa, 0.0)
    if math.isfinite(rest):
        if rest <= d[i_r]:  # reached before the last readable sample
            k = int(np.argmax(d[i_from:i_c] >= rest)) + i_from
            a, b = d[k - 1] - rest, d[k] - rest
            high = float(km.t[k - 1] + (km.t[k] - km.t[k - 1]) * (-a) / (b - a))
        else:
            high = float(km.t[i_r]) + ((rest - d[i_r]) / v if v > 0 else km.dt)
            high = min(high, float(km.t[i_c]))
        time = high
        how = f"the depth it rests at ({rest * 1e3:.2f} mm, read)"
    else:
        ends = np.flatnonzero(valid[i_c:]) + i_c
        if ends.size == 0:
            return None  # never read again: no sign that the key stopped at all
        high = float(km.t[ends[0]])
        time = min(max(float(km.t[i_c]), low), high)
        how = "the range's end (its resting depth is beyond the table)"
    low = min(low, time)
    surface = rest if math.isfinite(rest) else float(d[i_c])
    return Found(float(time), float(low), float(max(high, time)), METHODS["key_bottom"] +
                 "; the key sensor's table ends before the bottom: bracketed between the "
                 f"approach's last undisturbed sample and {how}"), surface


def _up_through(km: _Motion, d: np.ndarray, depth: float, i_from: int, i_ret: int
                 ) -> float:
    """The last time before ``i_ret`` the travel ``d`` rises back through ``depth``
    (interpolated between samples), NaN when it was never that deep."""
    j = np.flatnonzero((d[i_from:i_ret] >= depth) & (d[i_from + 1:i_ret + 1] < depth))
    if j.size == 0:
        return math.nan
    k = i_from + int(j[-1])
    a, b = d[k] - depth, d[k + 1] - depth
    return float(km.t[k] + (km.t[k + 1] - km.t[k]) * a / (a - b))


def _key_release(km: _Motion, s: float, i_from: int, valid: np.ndarray | None,
                 bottom: Found | None, surface: float = math.nan) -> Found | None:
    """The key leaving its front felt for good: no earlier than either of two marks, and
    placed at the later one --

    - it leaves the depth it rested at (``_leaves_rest``): a key resting still on its
      bottom rests on its felt;
    - it rises back through the depth at which it met its felt (its travel at the key
      bottom's time): the felt, compressed while the key is held, pushes the key up to
      there as the finger's force falls (a key let up slowly rises with its felt for
      tens of ms before it leaves it).

    The interval: from the later of the first mark's low end and the crossing of the
    bottom's deepest possible depth (its travel at the bottom interval's high end), to
    the crossing of its shallowest (at the interval's low end: above that depth the key
    is off the felt whatever the felt's surface) or the first mark's high end, the
    later. Not found when the key does not come back up in the trial."""
    rest = _leaves_rest(km, s, i_from, valid)
    if rest is None:
        return None
    first, i_ret = rest
    if bottom is None:
        return first
    d = s * (km.x - km.x0)
    at = [float(np.interp(x, km.t, d)) for x in (bottom.time, bottom.low, bottom.high)]
    if math.isfinite(surface):  # a bracketed bottom: the depth it gave, not the clip's
        at[0] = at[2] = surface
    cross, shallow, deep = (_up_through(km, d, x, i_from, i_ret) for x in at)
    later = math.isfinite(cross) and cross > first.time
    time = cross if later else first.time
    low = min(max(first.low, deep if math.isfinite(deep) else first.low), time)
    high = max(first.high, time + 0.5 * km.dt,
               shallow + 0.5 * km.dt if math.isfinite(shallow) else time)
    how = (f"; after it, the key rose back through the depth it met its felt at "
           f"({at[0] * 1e3:.2f} mm): that crossing" if later else "")
    return Found(time, low, high, first.method + how)


def _key_back_up(d: np.ndarray, i_from: int) -> int | None:
    """The sample at which the key's travel ``d`` falls below half its deepest after
    ``i_from`` for the last time, to stay there; None when it does not."""
    if i_from >= d.size - 1:
        return None
    high = d > 0.5 * float(np.max(d[i_from:]))
    up = np.flatnonzero(high[i_from:-1] & ~high[i_from + 1:]) + i_from
    if up.size == 0 or np.any(high[up[-1] + 1:]):
        return None
    return int(up[-1])


def _leaves_rest(km: _Motion, s: float, i_from: int, valid: np.ndarray | None
                 ) -> tuple[Found, int] | None:
    """The key leaving the depth it rested at on its bottom, for good, and the sample of
    its return: the last return of its travel below half its deepest after ``i_from``
    (the key's last press), walked back to where the travel last stood within ``level``
    of the depth it held over the ``HELD_SAMPLES`` before (their median; ``level`` the
    key's start threshold, ``KEY_MOVE_THRESHOLD_M``, or ``NOISE_K`` times the channel's
    local noise if larger), interpolated between the two samples; the 95 % interval:
    half a sample and 1.96 noise SDs over the key's speed there (``_release_bracket``
    where that depth is beyond the sensor's table). None when the key does not come back
    up in the trial."""
    d = s * (km.x - km.x0)
    if i_from + HELD_SAMPLES >= d.size:
        return None
    i_ret = _key_back_up(d, i_from)
    if i_ret is None:
        return None
    sigma = local_noise(km.x[max(i_from, i_ret - 4 * HELD_SAMPLES):i_ret])
    level = max(KEY_MOVE_THRESHOLD_M, NOISE_K * sigma)
    for j in range(i_ret, i_from + HELD_SAMPLES, -1):
        if valid is not None and not valid[j]:  # held beyond the table's end (clipped)
            br = _release_bracket(km, d, j, i_ret, level)
            return None if br is None else (br, i_ret)
        held = float(np.median(d[j - HELD_SAMPLES:j]))
        if d[j] >= held - level:
            break
    else:
        return None
    if valid is not None and not np.all(valid[j - HELD_SAMPLES:j + 2]):
        br = _release_bracket(km, d, int(np.flatnonzero(~valid[:j + 2])[-1]), i_ret, level)
        return None if br is None else (br, i_ret)
    a, b = d[j] - (held - level), d[j + 1] - (held - level)
    t_c = float(km.t[j] + (km.t[j + 1] - km.t[j]) * a / (a - b)) if a != b else float(km.t[j])
    speed = abs(float(d[j + 1] - d[j])) / km.dt
    half = 0.5 * km.dt + (Z95 * sigma / speed if speed > 0 else km.dt)
    return Found(t_c, t_c - half, t_c + half, METHODS["key_release"] +
                 f" ({level * 1e6:.0f} um)"), i_ret


def _release_bracket(km: _Motion, d: np.ndarray, i_x: int, i_ret: int, level: float
                     ) -> Found | None:
    """The key's release where it held its bottom beyond its sensor's range (``i_x`` the
    last clipped sample before its return): it was still there at t[i_x], and had left
    the depth it held (at or beyond the table's end d[i_x]) by ``level`` no later than
    its travel read d[i_x] - level (interpolated); the time given is that crossing."""
    edge = float(d[i_x]) - level
    below = np.flatnonzero(d[i_x + 1:i_ret + 1] < edge)
    if below.size == 0:
        return None
    k = i_x + 1 + int(below[0])
    a, b = d[k - 1] - edge, d[k] - edge
    t_c = float(km.t[k - 1] + (km.t[k] - km.t[k - 1]) * a / (a - b))
    return Found(t_c, float(km.t[i_x]), t_c, METHODS["key_release"] + f" ({level * 1e6:.0f} "
                 "um); the key held its bottom beyond the sensor's table: bracketed between "
                 "its last clipped sample and that crossing")


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
            dk = ks * (km.x - km.x0)
            deep = dk > BOTTOM_SHARE * float(np.max(dk))
            tb, lo, hi = _catch(km, ks, i0, None if kv is None else kv[1:] & kv[:-1],
                                deep[1:] & deep[:-1])
            if math.isfinite(tb):
                out["key_bottom"] = Found(tb, lo, hi, METHODS["key_bottom"])
            surface = math.nan  # the depth a bracketed bottom places the felt at
            if "key_bottom" not in out and kv is not None:
                placed = _bottom_bracket(km, ks, i0, kv)
                if placed is not None:
                    out["key_bottom"], surface = placed
            release = _key_release(km, ks, i0, kv, out.get("key_bottom"), surface)
            if release is not None:
                out["key_release"] = release
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


# the order of a blow: each pair (a, b) must have a no later than b when both are found
BLOW_ORDER: tuple[tuple[str, str], ...] = (
    ("key_starts", "toe_meets_button"), ("key_starts", "let_off"), ("key_starts", "strike"),
    ("key_starts", "key_bottom"), ("toe_meets_button", "let_off"), ("let_off", "strike"),
    ("strike", "string_release"), ("string_release", "check"), ("strike", "check"),
    ("key_bottom", "key_release"),
)


def order_flags(events: dict[str, float], tolerance_s: float = 0.0) -> list[str]:
    """The measured events that contradict the order of a blow (``BLOW_ORDER``: let-off
    after the strike, a key release before the strike, ...), one line per pair out of
    order by more than ``tolerance_s``."""
    out = []
    for a, b in BLOW_ORDER:
        ta, tb = events.get(a, math.nan), events.get(b, math.nan)
        if math.isfinite(ta) and math.isfinite(tb) and ta > tb + tolerance_s:
            out.append(f"{a} at {ta * 1e3:.2f} ms is after {b} at {tb * 1e3:.2f} ms: the "
                       f"order of a blow says otherwise; one of them is wrong")
    return out


def find(time: np.ndarray, channels: Mapping[str, np.ndarray]) -> dict[str, float]:
    """Event times (s, on the trial's clock) found in a trial's channels (``found``'s
    times)."""
    return {k: v.time for k, v in found(time, channels).items()}
