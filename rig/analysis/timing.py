"""When a model's events happen, against the events found in the measured trials.

A least-squares fit scores samples. A blow's events (the key starting, the hammer's strike,
the back check's catch, the key reaching its bottom) are the marks a piano maker times,
and a measured trial finds them in its own channels with a 95 % interval
(rig.analysis.events; rig import stores the intervals, other runs have them found here).
A model that predicts the samples better but still places an event outside its measured
interval on every trial has not found what moves that event; one that moves an event out
of the interval the base model had it in has fitted the samples at that event's expense.
Both are the marks of a stand-in: an effect that fits the residual's shape for another
reason than the physics behind it (docs/workflow.md, "Event timing"; docs/real-data.md:
on the Kawai KG-3C the compliant string the diagnosis fits leaves the strike 4-5 ms early).

The model's own time of an event is uncertain too: the input that drives it (the measured
force, or the key's measured motion) carries noise, and a soft blow's strike moves by
milliseconds with it (the key's dry friction decides when a slow push gets going). Each
model is therefore also run on ``DRAWS`` copies of each trial's input with fresh white
noise of the input's own level (as ``fit.input_noise_responses`` does for the residuals),
and an event counts as outside only when the model's time is beyond the measured interval
by more than ``Z`` times the spread of its times over those draws plus ``tolerance``.

The tolerance (``TOLERANCE_S``, 1 ms) is the found intervals' own shortfall: they come
from each method's fit and the sensor's noise, not from how the method's mark (the first
departure from the approach, a hinge in the velocity) sits against the model's event (the
felt's first contact), and a soft felt's force builds before the mark shows. Timed against
the truth itself on the wide diagnosis benchmark's development seeds 0-49 and 200-249
(``benchmarks/timing_truth.py``, 85 seeds without a sensor-side filter, 2026-11-27), the
truth's event lay beyond the found interval widened by its spread by up to 1.01 ms
(strike), 1.19 ms (check) and 0.49 ms (key bottom) on single trials; a tolerance of 0.5 ms
(diagnose's whole-trial shift, ``align_s``) flagged the truth's key bottom on both trials
of a reserved seed (1042, where the base model was the truth: 0.6-0.7 ms).

Timed events: the strike, the check and the key's bottom (under ``--input motion``
the model's key follows the measured key, and its bottom marks where the model's front
felt is). The key's start is not timed: a threshold crossing on a noisy key sensor is
found early by the noise itself (1.1-1.5 ms on every trial of a simulated run whose truth
the model was), and under a slow push its time is mostly the input's noise; nor is its
release, which ends the default window.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from rig.analysis import events as evt
from rig.analysis import fit as ft
from rig.analysis import measurement as ms
from rig.model.action import ActionModel

TOLERANCE_S = 1e-3   # beyond the measured interval (and the spread) by more: outside
TIMED = ("strike", "check", "key_bottom")  # the model's response, found reliably
INPUT_CHANNEL = {"force": "force", "motion": "key_dip"}  # the input whose noise is drawn
DRAWS = 8            # noisy copies of each trial's input per model
Z = 1.96             # ... and the model's event is outside beyond this many of their SDs
AFTER_S = 0.02       # a trial is simulated to this long after its last timed event
MIN_TRIALS = 2       # an event unexplained on every one of at least this many trials: said


@dataclass(frozen=True)
class Timed:
    """One event of one trial: the measured time and 95 % interval (s), and each model's
    time of it (nan: the model had no such event in the window)."""

    event: str
    trial: str
    measured: float
    low: float
    high: float
    models: dict[str, float]
    spread: dict[str, float]  # label -> SD (s) of the model's time over the input's draws

    def beyond(self, label: str, tolerance: float) -> float:
        """How far (s) the model's event lies outside the measured interval widened by
        ``tolerance`` plus ``Z`` of its spread under the input's noise: negative early,
        positive late, 0 inside; inf when the model has no such event in the span it was
        simulated for (``AFTER_S`` past the trial's last found event, or the window's end):
        a hammer that never reaches the string is later than any found strike."""
        t = self.models.get(label, math.nan)
        if not math.isfinite(t):
            return math.inf
        w = tolerance + Z * self.spread.get(label, 0.0)
        if not math.isfinite(w):
            return 0.0
        if t < self.low - w:
            return t - (self.low - w)
        if t > self.high + w:
            return t - (self.high + w)
        return 0.0

    def as_dict(self) -> dict[str, Any]:
        def num(v: float) -> float | None:
            return v if math.isfinite(v) else None

        return {"event": self.event, "trial": self.trial, "measured": self.measured,
                "low": self.low, "high": self.high,
                "models": {k: num(v) for k, v in self.models.items()},
                "spread": {k: num(v) for k, v in self.spread.items()}}


@dataclass
class Timing:
    """The timed events of several trials under several models (the first: the base)."""

    rows: list[Timed] = field(default_factory=list)
    labels: list[str] = field(default_factory=list)
    tolerance: float = TOLERANCE_S

    def events(self) -> list[str]:
        return [e for e in evt.EVENT_ORDER if any(r.event == e for r in self.rows)]

    def of(self, event: str, label: str) -> tuple[np.ndarray, np.ndarray]:
        """The model's signed errors (model - measured, s; inf where the model has no such
        event) and distances beyond the interval (s; ``Timed.beyond``) on every trial
        where the event was found."""
        rs = [r for r in self.rows if r.event == event]
        err = np.array([r.models.get(label, math.nan) - r.measured for r in rs])
        out = np.array([r.beyond(label, self.tolerance) for r in rs])
        return np.where(np.isfinite(err), err, math.inf), out

    def unexplained(self, label: str) -> list[tuple[str, int, float, float]]:
        """Events the model places outside their interval, on the same side, on every one
        of at least ``MIN_TRIALS`` trials (a missing event counts as late): (event, trials,
        least and most error, s; inf where the model has none)."""
        out = []
        for e in self.events():
            err, beyond = self.of(e, label)
            if (beyond.size >= MIN_TRIALS and np.all(beyond != 0)
                    and (np.all(beyond < 0) or np.all(beyond > 0))):
                out.append((e, int(beyond.size), float(np.min(err)), float(np.max(err))))
        return out

    def moved_out(self, label: str, base: str) -> list[tuple[str, int, int]]:
        """Events the base model placed inside their interval on most of the trials it has
        them on and the model outside (or nowhere) on them: (event, such trials, trials
        the base model has the event on)."""
        out = []
        for e in self.events():
            rs = [r for r in self.rows if r.event == e]
            both = [r for r in rs if math.isfinite(r.models.get(base, math.nan))]
            moved = [r for r in both if r.beyond(base, self.tolerance) == 0
                     and r.beyond(label, self.tolerance) != 0]
            if moved and len(moved) * 2 > len(both):
                out.append((e, len(moved), len(both)))
        return out

    def lines(self) -> list[str]:
        """A line per event and model: median error, trials outside its interval."""
        if not self.rows:
            return []
        head = (f"event timing against the events found in the measured trials (model - "
                f"measured; outside: beyond the measured 95 % interval by more than "
                f"{self.tolerance * 1e3:.1f} ms plus {Z:.2f} SD of the model's time under the "
                "input's noise):")
        out = [head]
        for e in self.events():
            parts = []
            for label in self.labels:
                err, beyond = self.of(e, label)
                got = err[np.isfinite(err)]
                none = f", none on {err.size - got.size}" if got.size < err.size else ""
                if got.size == 0:
                    parts.append(f"{label}: none on {err.size}")
                    continue
                parts.append(f"{label} {np.median(got) * 1e3:+.2f} ms (median), outside on "
                             f"{int(np.sum(beyond != 0))} of {err.size}{none}")
            n = sum(1 for r in self.rows if r.event == e)
            out.append(f"  {_name(e)} ({n} trial{'s' if n != 1 else ''}): "
                       + "; ".join(parts))
        return out

    def verdict(self, label: str, base: str) -> str:
        """What the timing says of the chosen model (``label``) against the base model
        (``base``; the same label when nothing was chosen): events it leaves outside their
        interval on every trial, events it moves out of the interval the base model had
        them in; "" when neither."""
        said = []
        own = label == base
        unexplained_base = {x[0] for x in self.unexplained(base)}
        for e, n, lo, hi in self.unexplained(label):
            same = "" if own or e not in unexplained_base else ", as the base model does"
            said.append(f"the {_name(e)} is outside its measured interval on "
                        f"{'both' if n == 2 else f'all {n}'} trials ({_span(lo, hi)}{same})")
        if not own:
            for e, k, n in self.moved_out(label, base):
                said.append(f"it moves the {_name(e)} out of the measured interval the base "
                            f"model had it in on {k} of {n} trials")
        if not said:
            return ""
        who = "the base model" if own else label
        tail = (": what moves these events is missing from the model (an effect, base "
                "parameters off, or physics outside the library)" if own else
                ": an effect that is the physics behind the residual also puts the blow's "
                "events where they were measured, so what is chosen may stand in for "
                "physics outside the library or base parameters off (--base), or another "
                "effect is missing beside it")
        return f"timing of {who}: " + "; ".join(said) + tail

    def as_dict(self) -> dict[str, Any]:
        return {"tolerance": self.tolerance, "labels": list(self.labels),
                "rows": [r.as_dict() for r in self.rows]}


def _name(event: str) -> str:
    return event.replace("_", " ")


def _span(lo: float, hi: float) -> str:
    """The least and most error as text; a model with no such event is said so."""
    if not math.isfinite(lo):
        return "the model has none"
    a, b = lo * 1e3, hi * 1e3
    if not math.isfinite(hi):
        return f"{a:+.1f} ms or none"
    return f"{a:+.1f} ms" if abs(b - a) < 0.05 else f"{a:+.1f} to {b:+.1f} ms"


def found_events(meas: ms.Measurement) -> dict[str, evt.Found]:
    """The trial's events found in its channels with their 95 % intervals: as the run file
    stores them (rig import, which knows where a sensor's readings were clipped), else
    found now (rig.analysis.events.found) from its channels."""
    stored = {k: evt.Found(meas.events[k], lo, hi, "")
              for k, (lo, hi) in meas.event_interval.items()
              if k in meas.events and meas.found(k)}
    if stored:
        return stored
    return evt.found(meas.time, meas.channels)


def model_events(model: ActionModel, meas: ms.Measurement, input: str, duration: float,
                 names: Sequence[str], draws: int = DRAWS, seed: int = 0
                 ) -> dict[str, tuple[float, float]]:
    """The model's time of each event driven by the trial, and the SD of that time over
    ``draws`` copies of the trial's input with fresh white noise of its level (inf when the
    event is missing from half of them or more; 0 when the input carries no noise)."""
    first = ms.simulate(model, meas, input, duration).events
    times = {k: float(first.get(k, math.nan)) for k in names}
    channel = INPUT_CHANNEL.get(input)
    if channel is None or channel not in meas.channels or draws < 2:
        return {k: (t, 0.0) for k, t in times.items()}
    sigma = ft.input_noise_sigma(meas, channel)
    rng = np.random.default_rng(seed)
    seen: dict[str, list[float]] = {k: [] for k in names}
    for _ in range(draws):
        x = np.asarray(meas.channels[channel], float)
        noisy = replace(meas, channels={**meas.channels,
                                        channel: x + rng.normal(0.0, sigma, x.shape)})
        ev = ms.simulate(model, noisy, input, duration).events
        for k in names:
            t = float(ev.get(k, math.nan))
            if math.isfinite(t):
                seen[k].append(t)
    return {k: (times[k], float(np.std(seen[k], ddof=1)) if 2 * len(seen[k]) > draws
                else math.inf) for k in names}


def timing(models: Sequence[tuple[str, ActionModel]], measurements: Sequence[ms.Measurement],
           input: str, windows: Sequence[float], tolerance: float = TOLERANCE_S,
           draws: int = DRAWS) -> Timing:
    """Each model's events against the events found in each trial (within its window
    ``windows[i]`` s), driven by ``input`` as the diagnosis drives it, with their spread
    under the input's noise (``model_events``)."""
    out = Timing([], [label for label, _ in models], tolerance)
    for i, (meas, window) in enumerate(zip(measurements, windows, strict=True)):
        found = {k: f for k, f in found_events(meas).items()
                 if k in TIMED and 0.0 <= f.time <= window}
        if not found:
            continue
        dur = min(window, max(f.high for f in found.values()) + AFTER_S)
        times: dict[str, dict[str, float]] = {k: {} for k in found}
        spread: dict[str, dict[str, float]] = {k: {} for k in found}
        for label, model in models:
            got = model_events(model, meas, input, dur, list(found), draws, seed=i)
            for k, (t, sd) in got.items():
                times[k][label], spread[k][label] = t, sd
        for k, f in found.items():
            out.rows.append(Timed(k, meas.label, f.time, f.low, f.high, times[k], spread[k]))
    return out
