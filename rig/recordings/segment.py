"""Split a long recording into strokes, one per key motion, from one channel (the key's).

The method (docs/import.md, "Segmentation") works in the channel's own units and uses
only levels relative to its rest and noise, so a linear calibration (gain, offset, sign)
does not change the result:

1. The noise: ``sigma`` is the median standard deviation of the 50 ms windows of the
   quietest half (a held or resting key is quiet; a moving one is not).
2. The rest level: the quiet windows' medians are put in bins of 6 sigma (at least 1/500
   of the signal's span); the fullest bin is the rest, and ``rest`` is the median of its
   windows' samples. The key's travel ``u`` is the departure from rest toward the larger
   excursion (the 0.1 / 99.9 percentiles), so a sensor that reads lower when pressed
   works too; ``span`` is the travel's 99.9th percentile.
3. Thresholds with hysteresis: ``on = max(on_noise sigma, on_fraction span)``,
   ``off = max(off_noise sigma, off_fraction span)`` (defaults 10 sigma / 15 %,
   5 sigma / 0.5 %): a stroke presses the key at least 15 % of the recording's deepest
   travel, which leaves out the key's rebound on its rest rail after a release. A
   stroke is a run of samples above ``off`` that reaches ``on`` and lasts at least
   ``min_stroke_s`` (5 ms; shorter is a spike); runs closer than ``min_rest_s`` (15 ms)
   are one stroke. Its onset is where ``u`` rose above ``off``, its release where ``u``
   fell below ``off`` for at least ``min_rest_s``.
4. Presses within a stroke (a repeated note, the key not back at rest between): the
   travel (smoothed over 2.5 ms) read as a zigzag; a press is a peak reaching ``on``
   from which the key rises back by at least ``repeat_drop`` (20 %) of the peak's
   travel (and ``off``) before pressing again by as much. The key's bounce on its front
   punching (about 10 % on the Kawai recording) is not a press. A stroke stays one
   trial with its number of presses; ``split_repeats`` cuts it at the lowest point
   between presses.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from rig.errors import InputError

DEFAULTS: dict[str, float] = {"on_noise": 10.0, "off_noise": 5.0, "on_fraction": 0.15,
                              "off_fraction": 0.005, "min_stroke_s": 0.005,
                              "min_rest_s": 0.015, "pre_s": 0.1, "post_s": 0.1,
                              "repeat_drop": 0.2}
WINDOW_S = 0.05


@dataclass
class Stroke:
    """One trial's key motion (times on the recording's clock, s)."""

    onset_s: float
    release_s: float
    peak: float          # largest travel from rest (channel units)
    peak_s: float
    presses: int
    start: int           # sample range of the trial (pre- and post-roll included)
    stop: int
    i_onset: int
    i_release: int

    @property
    def duration_s(self) -> float:
        return self.release_s - self.onset_s

    def row(self) -> dict[str, Any]:
        d = asdict(self)
        d["duration_s"] = self.duration_s
        return d


@dataclass
class Segmentation:
    strokes: list[Stroke]
    rest: float
    sigma: float
    span: float
    sign: float
    on: float
    off: float
    options: dict[str, float]
    split_repeats: bool

    def describe(self) -> dict[str, Any]:
        return {"method": "hysteresis thresholds on the key's travel from its rest level "
                          "(rig.recordings.segment; docs/import.md)",
                "rest": self.rest, "noise_sigma": self.sigma, "span": self.span,
                "direction": "up" if self.sign > 0 else "down", "on": self.on,
                "off": self.off, "split_repeats": self.split_repeats, **self.options}


def _windows(x: np.ndarray, n: int) -> np.ndarray:
    m = x.size // n
    return x[: m * n].reshape(m, n)


def rest_and_noise(x: np.ndarray, rate: float) -> tuple[float, float]:
    """(rest level, noise sigma) of a channel, from its quiet 50 ms windows."""
    n = max(8, int(round(WINDOW_S * rate)))
    w = _windows(x, n)
    if w.shape[0] < 4:
        raise InputError(f"segment: the recording is too short to find its rest "
                         f"({x.size} samples; at least {4 * n})")
    sd = w.std(axis=1)
    sigma = float(np.median(np.sort(sd)[: max(1, sd.size // 2)]))
    lo, hi = np.percentile(x, [0.1, 99.9])
    sigma = max(sigma, 1e-12 * max(1.0, abs(float(hi)), abs(float(lo))))
    quiet = sd <= 3.0 * sigma
    med = np.median(w[quiet], axis=1)
    width = max(6.0 * sigma, (float(hi) - float(lo)) / 500.0)
    bins = np.floor((med - med.min()) / width).astype(int)
    fullest = int(np.bincount(bins).argmax())
    rest = float(np.median(w[quiet][bins == fullest]))
    return rest, sigma


def segment(t: np.ndarray, x: np.ndarray, *, split_repeats: bool = False,
            options: dict[str, float] | None = None) -> Segmentation:
    """The strokes of key channel ``x`` sampled at times ``t`` (see the module's doc)."""
    opt = {**DEFAULTS, **(options or {})}
    x = np.asarray(x, float)
    t = np.asarray(t, float)
    if x.size < 16:
        raise InputError(f"segment: too few samples ({x.size})")
    rate = 1.0 / float(np.median(np.diff(t)))
    rest, sigma = rest_and_noise(x, rate)
    lo, hi = np.percentile(x, [0.1, 99.9])
    sign = 1.0 if hi - rest >= rest - lo else -1.0
    u = sign * (x - rest)
    span = float(np.percentile(u, 99.9))
    on = max(opt["on_noise"] * sigma, opt["on_fraction"] * span)
    off = max(opt["off_noise"] * sigma, opt["off_fraction"] * span)
    if not span > on:
        return Segmentation([], rest, sigma, span, sign, on, off, opt, split_repeats)
    min_rest = max(1, int(round(opt["min_rest_s"] * rate)))
    min_stroke = max(1, int(round(opt["min_stroke_s"] * rate)))
    above_off = u > off
    # runs of samples above "off", merged across gaps shorter than min_rest
    edges = np.flatnonzero(np.diff(np.r_[0, above_off.astype(np.int8), 0]))
    runs = [[int(a), int(b)] for a, b in zip(edges[0::2], edges[1::2], strict=True)]
    merged: list[list[int]] = []
    for a, b in runs:
        if merged and a - merged[-1][1] < min_rest:
            merged[-1][1] = b
        else:
            merged.append([a, b])
    spans = [(a, b) for a, b in merged
             if b - a >= min_stroke and float(u[a:b].max()) > on]
    smooth_n = max(1, int(round(0.0025 * rate)))
    kernel = np.ones(smooth_n) / smooth_n
    strokes: list[tuple[int, int, int]] = []   # (onset, release, presses)
    for a, b in spans:
        seg = np.convolve(u[a:b], kernel, mode="same") if smooth_n > 1 else u[a:b]
        peaks, valleys = find_presses(seg, opt["repeat_drop"], off, on)
        if split_repeats and len(peaks) > 1:
            cuts = [a] + [a + v for v in valleys] + [b]
            strokes += [(c0, c1, 1) for c0, c1 in zip(cuts[:-1], cuts[1:], strict=True)]
        else:
            strokes.append((a, b, max(1, len(peaks))))
    pre = int(round(opt["pre_s"] * rate))
    post = int(round(opt["post_s"] * rate))
    out: list[Stroke] = []
    for k, (a, b, presses) in enumerate(strokes):
        prev_end = strokes[k - 1][1] if k else 0
        next_start = strokes[k + 1][0] if k + 1 < len(strokes) else x.size
        start = max(a - pre, prev_end, 0)
        stop = min(b + post, next_start, x.size)
        ipk = a + int(np.argmax(u[a:b]))
        out.append(Stroke(float(t[a]), float(t[min(b, x.size - 1)]), float(u[ipk]),
                          float(t[ipk]), presses, int(start), int(stop), a, b))
    return Segmentation(out, rest, sigma, span, sign, on, off, opt, split_repeats)


def find_presses(u: np.ndarray, drop: float, floor: float, height: float = 0.0
                 ) -> tuple[list[int], list[int]]:
    """Peaks and the valleys between them of one stroke's (smoothed) travel: a zigzag with
    hysteresis. A peak is confirmed when the travel falls from it by ``max(drop * peak,
    floor)``; the next press starts when the travel rises from the valley by as much (of
    the previous peak). Peaks lower than ``height`` are not presses (a finger resting on the
    key). Returns (peak indices, the lowest point between consecutive peaks)."""
    peaks: list[int] = []
    valleys: list[int] = []
    rising, ip, iv = True, 0, 0
    vals = u.tolist()
    for i, v in enumerate(vals):
        if rising:
            if v >= vals[ip]:
                ip = i
            elif vals[ip] - v >= max(drop * vals[ip], floor):
                if peaks:
                    valleys.append(iv)
                peaks.append(ip)
                rising, iv = False, i
        elif v <= vals[iv]:
            iv = i
        elif v - vals[iv] >= max(drop * vals[peaks[-1]], floor):
            rising, ip = True, i
    if rising and (not peaks or ip != peaks[-1]) and vals[ip] - (vals[iv] if peaks else 0.0
                                                                  ) >= floor:
        if peaks:
            valleys.append(iv)
        peaks.append(ip)  # a press held to the stroke's end
    peaks = [p for p in peaks if vals[p] >= height]
    valleys = [p0 + int(np.argmin(u[p0:p1])) for p0, p1 in zip(peaks[:-1], peaks[1:],
                                                                 strict=True)]
    return peaks, valleys
