"""Models against a measured trial: aligned residuals, errors per channel, phase and event.

Each model is simulated at the trial's sample rate from t = 0 (the profile's
start) under the trial's input, so its samples fall on the measurement's.
Channels compared: every calibrated channel the trial holds (the force too
unless it is the input); a channel a model does not produce (e.g. shank strain
of a rigid shank) is predicted as zero. Errors: RMS, RMS normalized by the
measured channel's range, maximum; the same per phase of the blow (phases
bounded by the measured events); and the events piano makers care about.

Measured events come from the run file when it has them (simulated runs);
otherwise each is located by the local time shift that best aligns the first
model's channel with the measurement in a window around that model's event
(strike, let-off, check on the hammer angle; key start, key bottom on the
key dip), which is how a timing error shows in encoder data. Measured events that
contradict the order of a blow (``BLOW_ORDER``: let-off after the strike, the key released
before it reached the bottom, ...) are flagged (``Comparison.flags``: warnings under the
table, ``flags`` in --json), never silently reported.

A displacement sensor whose radius is a fitted unknown (an imported map's
``geometry: {radius: fit, angle_of: hammer_angle}``) is compared as that angle through
the radius and direction that best fit the first model (least squares of the displacement
against the model's angle, both from rest, over the samples the sensor does not saturate;
``Comparison.fitted``); its saturated samples are left out of the comparison.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rig.analysis import measurement as ms
from rig.analysis.events import BLOW_ORDER, order_flags  # noqa: F401 (BLOW_ORDER: here before)
from rig.analysis.measurement import Measurement
from rig.errors import InputError
from rig.model.action import CHANNEL_UNITS, EVENT_ORDER, ActionModel, SimResult

PHASES: tuple[tuple[str, str | None, str | None], ...] = (
    ("rest", None, "key_starts"),
    ("key descent", "key_starts", "let_off"),
    ("let-off to strike", "let_off", "strike"),
    ("string contact", "strike", "string_release"),
    ("flight back to the check", "string_release", "check"),
    ("check", "check", "key_release"),
    ("release", "key_release", None),
)
EVENT_CHANNELS: dict[str, tuple[str, ...]] = {
    "key_starts": ("key_dip", "key_angle", "whippen_angle"),
    "toe_meets_button": ("hammer_angle", "whippen_angle"),
    "let_off": ("hammer_angle", "whippen_angle"),
    "strike": ("hammer_angle", "shank_strain"),
    "string_release": ("hammer_angle", "shank_strain"),
    "check": ("hammer_angle",),
    "key_bottom": ("key_dip", "key_angle"),
    "key_release": ("key_dip", "key_angle"),
}
# the measured channels that drive the model under each input: reported as the input
# (the model's tracking of them), never scored as a residual
INPUT_CHANNELS: dict[str, tuple[str, ...]] = {"force": ("force",), "command": (),
                                              "motion": ("key_dip", "key_angle")}
# the event errors that matter to piano makers (name, event or None, units)
KEY_EVENTS: tuple[tuple[str, str, str], ...] = (
    ("strike time", "strike", "ms"),
    ("hammer speed at strike", "", "m/s"),
    ("let-off time", "let_off", "ms"),
    ("check time", "check", "ms"),
    ("key-bottom time", "key_bottom", "ms"),
)


@dataclass
class ChannelError:
    rms: float
    nrms: float   # RMS / range of the measured channel
    max: float
    units: str
    modelled: bool = True


@dataclass
class ModelComparison:
    """One model against the trial."""

    label: str
    result: SimResult
    predicted: dict[str, np.ndarray]
    residual: dict[str, np.ndarray]
    errors: dict[str, ChannelError]
    phase_errors: dict[str, dict[str, float]]   # channel -> phase -> normalized RMS
    events: dict[str, float]
    event_errors: dict[str, float]              # KEY_EVENTS name -> model - measured
    strike_speed: float = math.nan

    @property
    def ok(self) -> bool:
        return self.result.success

    def mean_nrms(self, channels: Sequence[str] | None = None) -> float:
        names = list(channels) if channels is not None else list(self.errors)
        vals = [self.errors[c].nrms for c in names if c in self.errors]
        return float(np.sqrt(np.mean(np.square(vals)))) if vals else math.nan


@dataclass
class Comparison:
    """Several models against one trial."""

    measurement: Measurement
    input: str
    time: np.ndarray
    channels: list[str]
    measured: dict[str, np.ndarray]
    ranges: dict[str, float]
    noise: dict[str, float]
    events: dict[str, float]
    event_source: dict[str, str]
    strike_speed: float
    phases: list[tuple[str, float, float]]
    models: list[ModelComparison] = field(default_factory=list)
    # the measured channels that drive the models (input motion: the key's) -> the first
    # model's RMS tracking error, in the channel's units; not scored
    inputs: dict[str, float] = field(default_factory=dict)
    # measured events that contradict the order of a blow (BLOW_ORDER), one line each;
    # printed under the table and in --json: reported, never silently
    flags: list[str] = field(default_factory=list)
    # a compared angle read from a displacement sensor through a fitted radius -> the fit
    # (channel, radius_m, sign, samples, saturated, rms_m: the fit's residual)
    fitted: dict[str, dict[str, Any]] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """The comparison's figures as plain data (``rig compare --json``, docs/json.md)."""
        return {
            "trial": self.measurement.label, "input": self.input, "channels": list(self.channels),
            "ranges": dict(self.ranges), "noise": dict(self.noise),
            "events": dict(self.events), "event_source": dict(self.event_source),
            "strike_speed": self.strike_speed,
            "phases": [{"name": p, "start_s": a, "end_s": b} for p, a, b in self.phases],
            "inputs": dict(self.inputs),
            "fitted": {c: dict(v) for c, v in self.fitted.items()},
            "flags": list(self.flags),
            "models": [{
                "label": m.label, "ok": m.ok, "message": m.result.message,
                "errors": {c: {"rms": e.rms, "nrms": e.nrms, "max": e.max, "units": e.units,
                               "modelled": e.modelled} for c, e in m.errors.items()},
                "phase_errors": {c: dict(v) for c, v in m.phase_errors.items()},
                "events": dict(m.events), "event_errors": dict(m.event_errors),
                "strike_speed": m.strike_speed} for m in self.models]}


def _rest_value(time: np.ndarray, x: np.ndarray, rest: np.ndarray) -> float:
    return float(np.mean(x[rest])) if rest.any() else float(x[0])


def prepare(meas: Measurement, input: str = "force", duration: float | None = None,
            channels: Sequence[str] | None = None) -> tuple[np.ndarray, list[str],
                                                             dict[str, np.ndarray]]:
    """The comparison window, the channels compared and the measured signals (rest removed)."""
    dur = meas.duration if duration is None else min(float(duration), meas.duration)
    window = (meas.time >= 0) & (meas.time <= dur + 1e-9)
    avail = meas.signal_channels()
    # a displacement sensor with a fitted radius stands for its angle (filled in by
    # ``fit_geometries`` once the model has run)
    geo = {a: c for c, a in ms.fitted_geometries(meas).items() if a not in avail}
    if channels is None:
        # the input is not compared, nor a channel no model has (an imported sensor's own)
        names = [c for c in avail if c not in INPUT_CHANNELS.get(input, ())
                 and c in CHANNEL_UNITS] + list(geo)
    else:
        names = list(channels)
        for c in names:
            if c not in avail and c not in geo:
                raise InputError(f"channels: {c!r} is not a calibrated channel of "
                                 f"{meas.label} (it has {avail})")
    if not names:
        other = [c for c in avail if c not in CHANNEL_UNITS]
        raise InputError(f"channels: {meas.label} has no channel to compare besides the input"
                         + (f" ({', '.join(other)}: not channels of the model)" if other
                            else ""))
    rest = meas.rest_mask()
    measured = {}
    for c in names:
        x = meas.channels[geo.get(c, c)]
        off = _rest_value(meas.time, x, rest) if meas.relative(c) or c in geo else 0.0
        measured[c] = x[window] - off  # (a fitted sensor's: its displacement, for now)
    return meas.time[window], names, measured


def fit_geometries(meas: Measurement, time: np.ndarray, measured: dict[str, np.ndarray],
                   ref_pred: dict[str, np.ndarray]) -> dict[str, dict[str, Any]]:
    """Turn each fitted-radius sensor's displacement in ``measured`` into its angle (in
    place): the signed radius c minimizing sum (d - c theta)^2 over the unsaturated
    samples, theta the reference model's angle (both from rest), then theta = d / c, NaN
    where the sensor saturates (its extreme reading held, as a clipped lookup table
    leaves it). Returns the fits."""
    out: dict[str, dict[str, Any]] = {}
    for sensor, angle in ms.fitted_geometries(meas).items():
        if angle not in measured or angle in meas.channels or angle not in ref_pred:
            continue
        d, th = measured[angle], ref_pred[angle]
        sat = saturated(d)
        ok = ~sat & np.isfinite(th)
        den = float(np.sum(th[ok] ** 2))
        if ok.sum() < 10 or not den > 0:
            raise InputError(f"{meas.label}: {sensor}: too few samples to fit its radius "
                             f"against the model's {angle}")
        c = float(np.sum(d[ok] * th[ok]) / den)
        if c == 0.0:
            raise InputError(f"{meas.label}: {sensor}: does not move with the model's {angle}")
        theta = d / c
        theta[sat] = math.nan
        measured[angle] = theta
        resid = d[ok] - c * th[ok]
        out[angle] = {"channel": sensor, "radius_m": abs(c), "sign": 1 if c > 0 else -1,
                      "samples": int(ok.sum()), "saturated": int(sat.sum()),
                      "rms_m": float(np.sqrt(np.mean(resid ** 2)))}
    return out


def saturated(d: np.ndarray) -> np.ndarray:
    """A displacement sensor's saturated samples: its extreme readings held two samples
    or more (as a clipped lookup table leaves them)."""
    span = float(np.ptp(d)) or 1.0
    sat = (d >= np.max(d) - 1e-9 * span) | (d <= np.min(d) + 1e-9 * span)
    return sat & _held(d, sat)


def _held(d: np.ndarray, extreme: np.ndarray) -> np.ndarray:
    """Of the samples at an extreme, those held there (two or more in a row): a sensor's
    saturation, not a single sample that happens to be the extreme."""
    prev = np.r_[False, extreme[:-1]]
    nxt = np.r_[extreme[1:], False]
    return extreme & (prev | nxt)


def predicted_channels(result: SimResult, time: np.ndarray, names: Sequence[str],
                       relative: dict[str, bool], rest_at_start: bool = False
                       ) -> dict[str, np.ndarray]:
    """A simulation's channels on the measurement's samples (NaN past its end; zero if absent).
    Relative channels from the rest: the mean of the simulation's first ``REST_S``, or with
    ``rest_at_start`` its first sample (the rest state it starts from: under the motion
    input the key moves from t = 0, as an imported stroke's starts at its onset, and the
    first 10 ms are not at rest)."""
    out = {}
    rt = result.time
    for c in names:
        if c not in result.channels:
            out[c] = np.zeros(time.shape)
            continue
        x = np.asarray(result.channels[c], float)
        if x.size == 0:
            out[c] = np.full(time.shape, math.nan)
            continue
        rest = rt <= rt[0] if rest_at_start else rt < min(ms.REST_S, rt[0] + ms.REST_S)
        off = _rest_value(rt, x, rest) if relative[c] else 0.0
        y = np.interp(time, rt, x) - off
        if rt.size > 1:
            y[time > rt[-1] + 0.5 * float(rt[1] - rt[0])] = math.nan
        out[c] = y
    return out


def local_shift(time: np.ndarray, measured: np.ndarray, model: np.ndarray, t_event: float,
                half_window: float = 0.004, max_shift: float = 0.006,
                step: float = 2e-5) -> float:
    """Time shift tau (s) for which model(t - tau) best matches the measurement near t_event."""
    if not math.isfinite(t_event):
        return math.nan
    win = (time >= t_event - half_window) & (time <= t_event + half_window)
    ok = win & np.isfinite(model) & np.isfinite(measured)
    if ok.sum() < 5:
        return math.nan
    tw, mw = time[ok], measured[ok]
    good = np.isfinite(model)
    taus = np.arange(-max_shift, max_shift + step / 2, step)
    sse = np.array([np.sum((np.interp(tw - tau, time[good], model[good]) - mw) ** 2)
                    for tau in taus])
    i = int(np.argmin(sse))
    if i in (0, taus.size - 1):
        return math.nan
    a, b, c = sse[i - 1], sse[i], sse[i + 1]
    den = a - 2 * b + c
    frac = 0.5 * (a - c) / den if den > 0 else 0.0
    return float(taus[i] + frac * step)


def _slope(time: np.ndarray, x: np.ndarray, t0: float, t1: float) -> float:
    sel = (time >= t0) & (time <= t1) & np.isfinite(x)
    if sel.sum() < 3:
        return math.nan
    return float(np.polyfit(time[sel], x[sel], 1)[0])


def head_speed(result: SimResult) -> float:
    """Hammer-head speed (m/s) at the last sample before the strike: in free flight it is
    the strike speed within gravity's 5 mm/s per ms, while interpolating across the impact
    (as ``SimResult.strike_speed`` does) mixes in the rebound at low output rates."""
    ts = result.events.get("strike", math.nan)
    if not math.isfinite(ts) or "hammer_head_velocity" not in result.channels:
        return math.nan
    i = int(np.searchsorted(result.time, ts, side="right")) - 1
    return float(result.channels["hammer_head_velocity"][i]) if i >= 0 else math.nan


def _strike_speed(time: np.ndarray, angle: np.ndarray, t_strike: float) -> float:
    """Hammer angular speed (rad/s) over the 2 ms before the strike."""
    return _slope(time, angle, t_strike - 0.002, t_strike - 0.00025)


def measured_events(meas: Measurement, time: np.ndarray, measured: dict[str, np.ndarray],
                    ref: SimResult, ref_pred: dict[str, np.ndarray]
                    ) -> tuple[dict[str, float], dict[str, str]]:
    """Event times of the trial: a simulation's own from the file, else the local shift
    against the reference (sub-sample), else the time found in the measured channels
    (rig.analysis.events: to about a sample) if the file has it."""
    ev: dict[str, float] = {}
    src: dict[str, str] = {}
    for name in EVENT_ORDER:
        if name in meas.events and not meas.found(name):
            ev[name], src[name] = meas.events[name], "run file"
            continue
        t_model = ref.events.get(name, math.nan)
        ev[name], src[name] = math.nan, "not found"
        for c in EVENT_CHANNELS.get(name, ()):
            if c in measured and c in ref_pred:
                tau = local_shift(time, measured[c], ref_pred[c], t_model)
                if not math.isfinite(tau):  # the model is several ms off: look wider
                    tau = local_shift(time, measured[c], ref_pred[c], t_model,
                                      half_window=0.008, max_shift=0.02)
                if math.isfinite(tau):
                    ev[name], src[name] = t_model + tau, f"aligned on {c}"
                    break
        if not math.isfinite(ev[name]) and name in meas.events:
            ev[name], src[name] = meas.events[name], "found in the run file"
    return ev, src


def phases_from(events: dict[str, float], t_end: float) -> list[tuple[str, float, float]]:
    """Phase windows [start, end) bounded by the events; phases whose events are missing
    run to the next event that happened."""
    bounds = []
    for name, a, b in PHASES:
        ta = 0.0 if a is None else events.get(a, math.nan)
        bounds.append((name, ta, b))
    out = []
    for i, (name, ta, _) in enumerate(bounds):
        if not math.isfinite(ta):
            continue
        tb = t_end
        for later in bounds[i + 1:]:
            if math.isfinite(later[1]) and later[1] > ta:
                tb = later[1]
                break
        tb = min(tb, t_end)
        if tb > ta:
            out.append((name, ta, tb))
    return out


def compare(meas: Measurement, models: Sequence[tuple[str, ActionModel]], input: str = "force",
            duration: float | None = None, channels: Sequence[str] | None = None,
            results: Sequence[SimResult] | None = None) -> Comparison:
    """Simulate each (label, model) under the trial's input and compare it with the trial."""
    if not models:
        raise InputError("models: expected at least one model")
    time, names, measured = prepare(meas, input, duration, channels)
    # (a fitted sensor's angle is relative, as the encoder angles are)
    rel = {c: meas.relative(c) or (c not in meas.channels and CHANNEL_UNITS.get(c) == "rad")
           for c in names}
    sims = list(results) if results is not None else [
        ms.simulate(m, meas, input, duration) for _, m in models]
    preds = [predicted_channels(r, time, names, rel, input == "motion") for r in sims]
    ref_i = next((i for i, r in enumerate(sims) if r.success), 0)
    fitted = fit_geometries(meas, time, measured, preds[ref_i])
    events, src = measured_events(meas, time, measured, sims[ref_i], preds[ref_i])
    flags = order_flags(events, 0.5 / meas.rate)
    t_end = float(time[-1]) + 1.0 / meas.rate
    phases = phases_from(events, t_end)
    ranges = {c: float(np.nanmax(measured[c]) - np.nanmin(measured[c])) or 1.0
              for c in names}
    noise = {c: ms.noise_sigma(measured[c][np.isfinite(measured[c])]) for c in names}
    # measured hammer speed: the reference model's head speed scaled by the ratio of the
    # hammer's angular speeds before the strike (the head's lever is the model's geometry)
    ref = sims[ref_i]
    speed = math.nan
    if "hammer_angle" in measured and math.isfinite(events.get("strike", math.nan)) \
            and math.isfinite(head_speed(ref)):
        w_meas = _strike_speed(time, measured["hammer_angle"], events["strike"])
        rt = ref.time
        w_ref = _strike_speed(rt, ref.channels["hammer_angle"], ref.events["strike"])
        if w_ref:
            speed = head_speed(ref) * w_meas / w_ref
    if "strike" in meas.events and "hammer_head_velocity" in meas.channels:
        i = int(np.searchsorted(meas.time, meas.events["strike"], side="right")) - 1
        speed = float(meas.channels["hammer_head_velocity"][max(i, 0)])
    comp = Comparison(meas, input, time, names, measured, ranges, noise, events, src, speed,
                      phases, inputs=_tracking(meas, input, time, ref, names), fitted=fitted,
                      flags=flags)
    for (label, _), res, pred in zip(models, sims, preds, strict=True):
        comp.models.append(_score(comp, label, res, pred))
    return comp


def _tracking(meas: Measurement, input: str, time: np.ndarray, ref: SimResult,
              compared: Sequence[str]) -> dict[str, float]:
    """Under the motion input, the key channels' RMS tracking error of the reference
    simulation (rest removed alike), for those the trial has and that are not compared on
    request. (Under the force input the model's force is the measured one by construction.)"""
    if input != "motion":
        return {}
    names = [c for c in INPUT_CHANNELS[input] if c in meas.channels
             and c not in compared and c in ref.channels]
    if not names:
        return {}
    rest = meas.rest_mask()
    window = (meas.time >= 0) & (meas.time <= time[-1] + 1e-9)
    pred = predicted_channels(ref, time, names, {c: meas.relative(c) for c in names},
                              rest_at_start=True)
    out = {}
    for c in names:
        x = meas.channels[c]
        off = _rest_value(meas.time, x, rest) if meas.relative(c) else 0.0
        r = pred[c] - (x[window] - off)
        r = r[np.isfinite(r)]
        out[c] = float(np.sqrt(np.mean(r ** 2))) if r.size else math.nan
    return out


def _score(comp: Comparison, label: str, res: SimResult,
           pred: dict[str, np.ndarray]) -> ModelComparison:
    resid = {c: pred[c] - comp.measured[c] for c in comp.channels}
    errors = {}
    for c in comp.channels:
        r = resid[c][np.isfinite(resid[c])]
        rms = float(np.sqrt(np.mean(r ** 2))) if r.size else math.nan
        errors[c] = ChannelError(rms, rms / comp.ranges[c],
                                 float(np.max(np.abs(r))) if r.size else math.nan,
                                 comp.measurement.units.get(c, "") or CHANNEL_UNITS.get(c, ""),
                                 c in res.channels)
    perphase: dict[str, dict[str, float]] = {}
    for c in comp.channels:
        perphase[c] = {}
        for p, a, b in comp.phases:
            sel = (comp.time >= a) & (comp.time < b) & np.isfinite(resid[c])
            perphase[c][p] = float(np.sqrt(np.mean(resid[c][sel] ** 2)) / comp.ranges[c]) \
                if sel.any() else math.nan
    ev = dict(res.events)
    ee: dict[str, float] = {}
    for name, event, units in KEY_EVENTS:
        if not event:
            ee[name] = head_speed(res) - comp.strike_speed
        else:
            ee[name] = (ev.get(event, math.nan) - comp.events.get(event, math.nan)) * 1e3 \
                if units == "ms" else math.nan
    return ModelComparison(label, res, pred, resid, errors, perphase, ev, ee, head_speed(res))


def table(comp: Comparison) -> str:
    """A plain-text table: models side by side, per channel and per key event."""
    labels = [m.label for m in comp.models]
    w = max(12, *(len(x) + 2 for x in labels))
    lines = [f"{comp.measurement.label}: input {comp.input}, {comp.time[-1] * 1e3:.0f} ms "
             f"at {comp.measurement.rate:g} Hz"]
    head = f"{'channel':<26}{'':>8}" + "".join(f"{x:>{w}}" for x in labels)
    lines += [head, "-" * len(head)]
    for c, rms in comp.inputs.items():
        units = comp.measurement.units.get(c, "")
        lines.append(f"{c + ' [' + units + ']':<26}{'input':>8}   the key's measured motion "
                     f"drives the models ({labels[0]} follows it within {rms:.3g} {units} "
                     f"RMS; not scored)")
    for c, f in comp.fitted.items():
        lines.append(f"{c + ' [rad]':<26}{'fitted':>8}   read from {f['channel']} through a "
                     f"radius fitted to {labels[0]}: {f['radius_m'] * 1e3:.3g} mm (sign "
                     f"{f['sign']:+d}, fit RMS {f['rms_m'] * 1e3:.3g} mm, "
                     f"{f['saturated']} saturated samples left out)")
    for c in comp.channels:
        units = comp.measurement.units.get(c, "") or CHANNEL_UNITS.get(c, "")
        for kind, key in (("RMS", "rms"), ("norm.", "nrms"), ("max", "max")):
            vals = []
            for m in comp.models:
                e = m.errors[c]
                v = getattr(e, key)
                vals.append(f"{v * 100:.2f} %" if key == "nrms" else f"{v:.3g}")
            name = f"{c} [{units}]" if kind == "RMS" else ""
            lines.append(f"{name:<26}{kind:>8}" + "".join(f"{v:>{w}}" for v in vals))
    lines.append(f"{'all channels':<26}{'norm.':>8}" + "".join(
        f"{m.mean_nrms() * 100:>{w - 2}.2f} %" for m in comp.models))
    lines.append("-" * len(head))
    for name, event, units in KEY_EVENTS:
        meas_v = comp.strike_speed if not event else comp.events.get(event, math.nan) * 1e3
        vals = [f"{m.event_errors[name]:+.3g}" if math.isfinite(m.event_errors[name])
                else "n/a" for m in comp.models]
        lines.append(f"{name + ' err [' + units + ']':<26}{'':>8}" + "".join(
            f"{v:>{w}}" for v in vals) + (f"   (measured {meas_v:.4g})" if math.isfinite(
                meas_v) else "   (not found in the measurement)"))
    fails = [f"{m.label}: simulation failed ({m.result.message})" for m in comp.models
             if not m.ok]
    flags = [f"warning: measured events out of order: {f}" for f in comp.flags]
    return "\n".join(lines + fails + flags)
