"""What a residual looks like: where it is, and whether it is a bias, a lag, an
oscillation (and at what frequency) or a shift of an event.

For a channel's residual r = model - measured over a phase:

- bias: the share of r's mean square in its mean, ``mean(r)^2 / mean(r^2)``;
- lag: the share removed by shifting the model in time (best shift within
  +-10 ms over the whole trial), with that shift;
- oscillation: the share of r's power within +-15 % of its strongest spectral
  peak above 40 Hz (after removing a 5 ms running mean), with the frequency;
- timing: an event of the trial that the model places more than two samples
  (and 0.3 ms) away.

The kind reported is the one with the largest share, if that share is at
least 0.3; otherwise ``shape``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rig.analysis import compare as cp
from rig.analysis.compare import Comparison, ModelComparison

MIN_SHARE = 0.3
OSC_MIN_HZ = 40.0


@dataclass
class ResidualSignature:
    """The residual of one channel in one phase."""

    channel: str
    phase: str
    nrms: float                 # RMS / measured range in this phase
    excess: float               # RMS over the channel's noise
    kind: str                   # bias | lag | oscillation | timing | shape
    bias_share: float
    lag_share: float
    lag_s: float
    osc_share: float
    frequency_hz: float
    events: dict[str, float] = field(default_factory=dict)   # event -> model - measured (s)

    def text(self) -> str:
        parts = [f"bias {self.bias_share:.0%}",
                 f"lag {self.lag_share:.0%}" + (f" ({self.lag_s * 1e3:+.2f} ms)"
                                                if math.isfinite(self.lag_s) else ""),
                 f"oscillation {self.osc_share:.0%}"
                 + (f" at {self.frequency_hz:.0f} Hz" if math.isfinite(self.frequency_hz)
                    else "")]
        ev = ", ".join(f"{k} {v * 1e3:+.2f} ms" for k, v in self.events.items()
                       if math.isfinite(v))
        return (f"{self.channel} in {self.phase}: {self.kind}, {self.nrms * 100:.2f} % of range "
                f"({self.excess:.1f} x noise); " + "; ".join(parts) + (f"; timing: {ev}"
                                                                      if ev else ""))


def _oscillation(r: np.ndarray, rate: float) -> tuple[float, float]:
    n = r.size
    if n < 16:
        return 0.0, math.nan
    w = max(3, int(round(0.005 * rate)) | 1)
    kernel = np.ones(w) / w
    hp = r - np.convolve(np.pad(r, w // 2, mode="edge"), kernel, mode="valid")[:n]
    total = float(np.sum(r ** 2))
    if total <= 0:
        return 0.0, math.nan
    win = np.hanning(n)
    spec = np.abs(np.fft.rfft(hp * win)) ** 2
    f = np.fft.rfftfreq(n, 1.0 / rate)
    band = f >= OSC_MIN_HZ
    if not band.any() or spec[band].max() <= 0:
        return 0.0, math.nan
    i = int(np.flatnonzero(band)[np.argmax(spec[band])])
    f0 = float(f[i])
    near = (f >= 0.85 * f0 - (f[1] - f[0])) & (f <= 1.15 * f0 + (f[1] - f[0]))
    share_hp = float(spec[near].sum() / spec.sum())
    share = share_hp * float(np.sum(hp ** 2)) / total
    return min(share, 1.0), f0


def lag_of(comp: Comparison, mc: ModelComparison, channel: str) -> tuple[float, float]:
    """(best time shift of the model, share of the residual it removes) over the trial."""
    t = comp.time
    meas, pred = comp.measured[channel], mc.predicted[channel]
    good = np.isfinite(pred)
    if good.sum() < 10:
        return math.nan, 0.0
    mid = float(t[good][0] + t[good][-1]) / 2
    half = float(t[good][-1] - t[good][0]) / 2
    tau = cp.local_shift(t, meas, pred, mid, half_window=half, max_shift=0.01, step=5e-5)
    if not math.isfinite(tau):
        return math.nan, 0.0
    shifted = np.interp(t - tau, t[good], pred[good])
    r0 = pred[good] - meas[good]
    r1 = shifted[good] - meas[good]
    s0 = float(np.sum(r0 ** 2))
    return tau, (1 - float(np.sum(r1 ** 2)) / s0) if s0 > 0 else 0.0


def common_shift(comp: Comparison, mc: ModelComparison, align_s: float) -> float:
    """The one time shift (within +-align_s) of the model that best matches every channel
    (residuals normalized by the channels' ranges)."""
    if align_s <= 0:
        return 0.0
    t = comp.time
    dt = 1.0 / comp.measurement.rate
    best, best_tau = math.inf, 0.0
    for tau in np.arange(-align_s, align_s + dt / 20, dt / 10):
        sse = 0.0
        for c in comp.channels:
            p = mc.predicted[c]
            ok = np.isfinite(p)
            if ok.sum() < 2:
                continue
            r = (np.interp(t - tau, t[ok], p[ok]) - comp.measured[c])[ok] / comp.ranges[c]
            sse += float(np.sum(r ** 2))
        if sse < best:
            best, best_tau = sse, float(tau)
    return best_tau


def signatures(comp: Comparison, mc: ModelComparison,
               align_s: float = 0.0) -> list[ResidualSignature]:
    """Every (channel, phase) residual's signature, largest normalized residual first.

    With ``align_s`` the residual is taken after the model's best common time shift within
    +-align_s (as diagnose scores candidates), so a whole-blow jitter does not rank first.
    """
    out = []
    rate = comp.measurement.rate
    tau = common_shift(comp, mc, align_s)
    for c in comp.channels:
        lag, lag_share = lag_of(comp, mc, c)
        sig = comp.noise.get(c, math.nan)
        r_all = mc.residual[c]
        if tau != 0.0:
            pred = mc.predicted[c]
            ok = np.isfinite(pred)
            r_all = np.where(ok, np.interp(comp.time - tau, comp.time[ok], pred[ok]),
                             math.nan) - comp.measured[c]
        for p, a, b in comp.phases:
            sel = (comp.time >= a) & (comp.time < b) & np.isfinite(r_all)
            if sel.sum() < 2:
                continue
            r = r_all[sel]
            ms = float(np.mean(r ** 2))
            rms = math.sqrt(ms)
            bias = float(np.mean(r)) ** 2 / ms if ms > 0 else 0.0
            osc, f0 = _oscillation(r, rate)
            events = {}
            for name, t_meas in comp.events.items():
                if a - 1e-9 <= t_meas < b and name in cp.EVENT_CHANNELS \
                        and c in cp.EVENT_CHANNELS[name]:
                    dt = mc.events.get(name, math.nan) - t_meas
                    if math.isfinite(dt) and abs(dt) > max(2.0 / rate, 3e-4):
                        events[name] = dt
            shares = {"bias": bias, "lag": lag_share, "oscillation": osc}
            kind = max(shares, key=lambda k: shares[k])
            if shares[kind] < MIN_SHARE:
                kind = "timing" if events else "shape"
            out.append(ResidualSignature(c, p, rms / comp.ranges[c],
                                 rms / sig if sig and sig > 0 else math.inf, kind, bias,
                                 lag_share, lag, osc, f0 if osc >= 0.1 else math.nan, events))
    out.sort(key=lambda s: -s.nrms)
    return out


def worst_channels(comp: Comparison, mc: ModelComparison) -> list[tuple[str, float]]:
    """Channels by normalized RMS residual, largest first."""
    return sorted(((c, mc.errors[c].nrms) for c in comp.channels), key=lambda x: -x[1])
