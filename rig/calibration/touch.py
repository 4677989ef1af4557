"""The feel of the action on the rig: down- and up-weight from slow force ramps.

The motor is the technician's weights. One trial of ``rig measure touch`` is one force
profile run through the torque loop (``rig.services.run``): an approach from 0 to
``from_g`` (below the down-weight), a slow ramp up to ``to_g`` at ``rate_g_s`` (the key
leaves its rest and runs down to its stop: its balance force falls along the stroke, so no
weight holds it mid-stroke), a hold, and a slow ramp down to ``low_g`` (the key leaves its
pressed stop and runs back up). ``condition`` such presses come first and are not
recorded: a technician works the key once before weighing it, so that every recorded press
starts from the state a press leaves (with friction that sticks, the action's state depends
on its history; from the assembled rest the first press is an outlier). From the key
encoder's dip and the load cell's force:

* the key **goes** on a ramp when its dip has left the dip at the ramp's start (its rest
  under ``from_g``, its pressed stop under ``to_g``) by ``threshold_mm`` (0.25 mm: the
  touch stroke's first step, past the felts' compression); the force there is the
  ``travel`` rule's weight;
* it **started** at the last sample before that where the dip was still on its elastic
  trend (a straight line fitted to the dip over the ramp's first part, while the key sat
  on its felts or its stop): within ``onset_counts`` encoder counts, or five times the
  fit's RMS residual when that is larger (the encoder's noise on a real rig); the force
  there is the ``onset`` rule's weight;
* forces are read from a straight line fitted to the load cell over the whole slow ramp
  (the drive follows the demand; one sample's noise is ~0.2 N, the line's at a point ~100
  times less).

``rule``: ``travel`` (a technician's: the weight at which the key has moved the threshold)
on an action that sticks -- every real one, and the simulated rig with ``sim.friction:
stick`` -- where the key may creep quasi-statically before it goes and the onset would find
the start of that creep; ``onset`` on the simulated rig's regularised friction laws, which
carry no force at zero speed: there the key creeps off at the frictionless balance, the
onset is that balance and the threshold's force only adds the ramp's run-on while the key
travels it. ``auto`` (the default) picks ``onset`` for the simulated rig with
``sim.friction: regularised`` and ``travel`` otherwise (rig.services.measure_touch).

``down_weight`` is the force at which the key goes down from rest, ``up_weight`` the force
at which it comes back up from its pressed stop; ``balance_weight`` and ``friction`` are
(DW + UW) / 2 and (DW - UW) / 2 per trial. Each figure: the trials' mean, their standard
deviation and the spread ``2 sd`` (k = 2). Forces in N inside; grams-force at the key top
(N / G0 x 1000) in the record's figures, where the motor presses: the model's key front.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rig.errors import InputError
from rig.inputs import profiles

G0 = 9.80665  # m/s^2: grams-force = N / G0 x 1000 (as rig.model.touch)
UNITS = {"raw": "N (load cell), m (key dip)", "calibrated": "g (grams-force at the key top)",
         "force": "N", "dip": "m", "time": "s", "weights": "g"}
FIGURES = ("down_weight", "up_weight", "balance_weight", "friction")
SKIP_S = 0.3  # s after a ramp's knot left out of the fits (the drive's lag and settling)
FIT_SHARE = 0.4  # the dip's elastic trend is fitted over this share of the ramp before it goes
RULES = ("auto", "travel", "onset")  # auto: resolved by the rig (rig.services.measure_touch)


def grams(force_n: float) -> float:
    return force_n / G0 * 1e3


def newtons(grams_: float) -> float:
    return grams_ * 1e-3 * G0


@dataclass(frozen=True)
class Ramps:
    """The presses of one trial (grams at the key top, g/s, mm, s)."""

    from_g: float = 25.0
    to_g: float = 70.0
    low_g: float = 10.0
    rate_g_s: float = 2.0
    threshold_mm: float = 0.25
    onset_counts: float = 10.0
    approach_s: float = 0.5
    hold_s: float = 1.0
    rule: str = "auto"  # which force is the weight: travel (at the threshold) or onset
    condition: int = 1  # presses before the recorded trials, not recorded

    def check(self, max_force_n: float) -> None:
        """One-line InputError naming the option for a press that cannot work."""
        for name in ("from_g", "to_g", "rate_g_s", "threshold_mm", "onset_counts",
                     "approach_s", "hold_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"--{_opt(name)}: expected a positive number, got {v:g}")
        if self.rule not in RULES:
            raise InputError(f"--rule: expected one of {', '.join(RULES)}, got {self.rule!r}")
        if isinstance(self.condition, bool) or not isinstance(self.condition, int) \
                or self.condition < 0:
            raise InputError(f"--condition: expected 0 or more presses, got {self.condition!r}")
        if not (math.isfinite(self.low_g) and self.low_g >= 0):
            raise InputError(f"--low: expected 0 g or more, got {self.low_g:g}")
        if not self.low_g < self.from_g < self.to_g:
            raise InputError(f"--from, --to, --low: expected low < from < to, got "
                             f"{self.low_g:g}, {self.from_g:g}, {self.to_g:g} g")
        if newtons(self.to_g) > max_force_n:
            raise InputError(f"--to: {self.to_g:g} g ({newtons(self.to_g):.3f} N) is over the "
                             f"rig's limits.max_force_n ({max_force_n:g} N)")
        if self.threshold_mm > 5:
            raise InputError(f"--threshold: expected at most 5 mm of key dip, got "
                             f"{self.threshold_mm:g}")

    def knots(self) -> list[tuple[float, float]]:
        """(time s, force N) of the trial's profile."""
        up = (self.to_g - self.from_g) / self.rate_g_s
        down = (self.to_g - self.low_g) / self.rate_g_s
        t1 = self.approach_s
        t2 = t1 + up
        t3 = t2 + self.hold_s
        return [(0.0, 0.0), (t1, newtons(self.from_g)), (t2, newtons(self.to_g)),
                (t3, newtons(self.to_g)), (t3 + down, newtons(self.low_g))]

    def presses(self, n: int, let_go_s: float = 0.3, gap_s: float = 0.5, lead_s: float = 0.0
                ) -> tuple[list[list[float]], float]:
        """``n`` trials one after the other, each after ``lead_s`` at no force, let go to no
        force ``let_go_s`` after its ramp down, the next one's lead starting ``gap_s`` after
        that ramp's end: the (time s, force N) points and the period (s)."""
        knots = self.knots()
        period = lead_s + knots[-1][0] + gap_s
        points: list[list[float]] = []
        for i in range(n):
            start = i * period + lead_s
            points += [[start + t, f] for t, f in knots]
            points.append([start + knots[-1][0] + let_go_s, 0.0])
        points.append([n * period, 0.0])
        return points, period

    def segments(self) -> dict[str, tuple[float, float]]:
        """The slow ramps' (start, end) times (s on the trial's clock)."""
        k = self.knots()
        return {"down": (k[1][0], k[2][0]), "up": (k[3][0], k[4][0])}

    def profile(self, max_force_n: float, max_duration: float) -> profiles.Profile:
        return profiles.from_points(
            [list(p) for p in self.knots()], name="touch-ramps",
            description=f"rig measure touch: {self.from_g:g} -> {self.to_g:g} g at "
                        f"{self.rate_g_s:g} g/s, hold {self.hold_s:g} s, -> {self.low_g:g} g",
            source="rig measure touch", force_limit=max_force_n, max_duration=max_duration)


def _opt(name: str) -> str:
    return {"from_g": "from", "to_g": "to", "low_g": "low", "rate_g_s": "rate",
            "threshold_mm": "threshold", "onset_counts": "onset-counts",
            "approach_s": "approach", "hold_s": "hold", "rule": "rule",
            "condition": "condition"}[name]


@dataclass
class Start:
    """Where the key started to move on one ramp (the onset) and where it had gone."""

    force_n: float  # at the onset
    time_s: float
    dip_m: float
    went_s: float  # when it had gone threshold_mm
    onset_tol_m: float  # the departure from the elastic trend taken as a start
    went_force_n: float = math.nan  # the force when it had gone threshold_mm
    went_dip_m: float = math.nan
    ref_dip_m: float = math.nan  # the dip at the ramp's start the travel is counted from

    def weight_n(self, rule: str) -> float:
        """The force the ``rule`` (travel or onset) takes as the weight."""
        if rule == "travel":
            return self.went_force_n
        if rule == "onset":
            return self.force_n
        raise ValueError(f"rule: expected travel or onset, got {rule!r}")


def _line(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    coef = np.polyfit(t, y, 1)
    res = y - np.polyval(coef, t)
    return coef, float(np.sqrt(np.mean(res ** 2)))


def find_start(t: np.ndarray, dip: np.ndarray, force: np.ndarray, seg: tuple[float, float],
               sign: int, ramps: Ramps, count_m: float, what: str) -> Start:
    """The start of the key's motion on the ramp ``seg``: ``sign`` +1 down, -1 up."""
    t0, t1 = seg
    on = (t >= t0) & (t <= t1)
    if on.sum() < 10:
        raise InputError(f"{what}: the run has no samples of its ramp ({t0:g}-{t1:g} s)")
    ts, ds, fs = t[on], dip[on], force[on]
    ref = float(np.median(ds[ts <= t0 + 0.1]))
    gone = np.flatnonzero(sign * (ds - ref) > ramps.threshold_mm * 1e-3)
    if gone.size == 0:
        raise InputError(
            f"--to, --low: the key did not go {'down' if sign > 0 else 'up'} by "
            f"{ramps.threshold_mm:g} mm on the ramp ({what}): "
            + ("raise --to" if sign > 0 else "lower --low"))
    i_gone = int(gone[0])
    t_gone = float(ts[i_gone])
    fit_end = t0 + SKIP_S + FIT_SHARE * (t_gone - t0 - SKIP_S)
    win = (ts >= t0 + SKIP_S) & (ts <= fit_end)
    if win.sum() < 50 or fit_end - t0 - SKIP_S < 0.2:
        raise InputError(f"--from: the key went {ramps.threshold_mm:g} mm only "
                         f"{t_gone - t0:.2f} s into the ramp ({what}): too early to see it "
                         f"start; " + ("lower --from" if sign > 0 else "raise --from / --to"))
    coef, rms = _line(ts[win], ds[win])
    tol = max(ramps.onset_counts * count_m, 5.0 * rms)
    dev = sign * (ds[:i_gone] - np.polyval(coef, ts[:i_gone]))
    inside = np.flatnonzero(dev <= tol)
    i0 = int(inside[-1]) if inside.size else 0
    fwin = ts >= t0 + SKIP_S
    fcoef, _ = _line(ts[fwin], fs[fwin])
    t_start = float(ts[i0])
    return Start(float(np.polyval(fcoef, t_start)), t_start, float(ds[i0]), t_gone, tol,
                 went_force_n=float(np.polyval(fcoef, t_gone)), went_dip_m=float(ds[i_gone]),
                 ref_dip_m=ref)


@dataclass
class TouchMeasurement:
    """The trials' starts and the figures with their spread."""

    ramps: Ramps
    trials: list[dict[str, Start]]
    figures: dict[str, dict[str, float]] = field(default_factory=dict)
    load_cell_zero_g: float = math.nan  # k = 2: the zero of the load cell's record, in g

    def per_trial_g(self) -> dict[str, list[float]]:
        rule = self.ramps.rule
        dw = [grams(tr["down"].weight_n(rule)) for tr in self.trials]
        uw = [grams(tr["up"].weight_n(rule)) for tr in self.trials]
        return {"down_weight": dw, "up_weight": uw,
                "balance_weight": [(d + u) / 2 for d, u in zip(dw, uw, strict=True)],
                "friction": [(d - u) / 2 for d, u in zip(dw, uw, strict=True)]}

    def raw_points(self) -> list[dict[str, Any]]:
        return [{press: {"force_n": s.weight_n(self.ramps.rule), "onset_force_n": s.force_n,
                         "time_s": s.time_s, "dip_m": s.dip_m,
                         "went_s": s.went_s, "went_force_n": s.went_force_n,
                         "went_dip_m": s.went_dip_m, "ref_dip_m": s.ref_dip_m,
                         "onset_tolerance_m": s.onset_tol_m}
                 for press, s in tr.items()} for tr in self.trials]


def summarise(ramps: Ramps, trials: list[dict[str, Start]]) -> TouchMeasurement:
    m = TouchMeasurement(ramps, trials)
    for name, vals in m.per_trial_g().items():
        v = np.asarray(vals, float)
        sd = float(v.std(ddof=1)) if v.size > 1 else math.nan
        m.figures[name] = {"mean_g": float(v.mean()), "sd_g": sd, "spread_g": 2 * sd,
                           "mean_n": newtons(float(v.mean())), "trials": float(v.size),
                           "min_g": float(v.min()), "max_g": float(v.max())}
    return m


def analyse(trial_channels: list[dict[str, np.ndarray]], ramps: Ramps,
            count_m: float) -> TouchMeasurement:
    """The starts of every recorded trial (``time``, ``force`` N, ``key_dip`` m channels);
    ``ramps.rule`` travel or onset (``auto`` is the rig's to resolve)."""
    if ramps.rule not in ("travel", "onset"):
        raise ValueError(f"rule: expected travel or onset, got {ramps.rule!r} (auto is "
                         f"resolved by the rig: rig.services.measure_touch.resolve_rule)")
    segs = ramps.segments()
    out = []
    for k, ch in enumerate(trial_channels):
        for need in ("time", "force", "key_dip"):
            if need not in ch:
                raise InputError(f"trial {k}: the run has no {need!r} channel (the key "
                                 f"encoder, channels.encoders.key, and the load cell)")
        t, f, d = (np.asarray(ch[n], float) for n in ("time", "force", "key_dip"))
        out.append({"down": find_start(t, d, f, segs["down"], +1, ramps, count_m,
                                       f"trial {k}, down"),
                    "up": find_start(t, d, f, segs["up"], -1, ramps, count_m,
                                     f"trial {k}, up")})
    return summarise(ramps, out)
