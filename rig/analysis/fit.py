"""Least-squares fits of model and effect parameters to one or many trials.

A target is a model parameter (a dotted path such as ``contacts.4.D``) or an
effect's parameter (``effect_name.param``), optionally with bounds
(``NAME=LO:HI``). The residual is every compared channel's (model - measured)
divided by the measured channel's range, on the chosen samples of every
trial, so each channel weighs the same. Parameters spanning decades are fitted
in log space. Finite-difference Jacobians evaluate their columns in parallel
(one process per core, forked so user effects loaded from files come along).

Uncertainty: the HAC (Newey-West) sandwich covariance ``(J'J)^-1 S (J'J)^-1`` at
the solution, ``S`` the long-run covariance of the scores ``J_t r_t`` summed
over lags within each trial's channel with Bartlett weights up to the lag where
the residual's autocorrelation fades (rig.analysis.stats): 2 kHz residuals are
strongly autocorrelated and independent-noise errors would be far too small.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.optimize import least_squares

from rig.analysis import compare as cp
from rig.analysis import measurement as ms
from rig.analysis.measurement import Measurement
from rig.errors import InputError
from rig.model.action import ActionModel
from rig.model.effects import LOG_SHIFT, Effect
from rig.model.integrators import Integrator

if TYPE_CHECKING:
    from rig.analysis.executor import Executor

FAILED_PENALTY = 1.0
ALIGN_S = 0.0  # residual (in channel ranges) of samples a failed simulation lacks


@dataclass
class Target:
    """One fitted quantity."""

    label: str
    effect: str | None      # effect name, or None for a model parameter
    key: str                # effect parameter name or parameter path
    value: float            # starting value
    lo: float
    hi: float
    units: str = ""
    scan: int = 0           # start-scan points it needs at least (EffectParameter.scan)
    shift: float = 0.0      # > 0: fitted in log(v + shift) though lo is 0 (EffectParameter.log)

    @property
    def log(self) -> bool:
        """Fitted in log(v + shift): a positive range over decades, or a scale quantity
        whose bounds start at 0 (``shift`` > 0)."""
        return self.shift > 0 or (self.lo > 0 and self.hi / self.lo >= 20
                                  and self.value >= 3 * self.lo)

    def to_u(self, v: float) -> float:
        s = self.shift
        return (math.log((v + s) / (self.value + s)) if self.log
                else (v - self.value) / self.scale)

    def from_u(self, u: float) -> float:
        s = self.shift
        v = ((self.value + s) * math.exp(u) - s if self.log
             else self.value + u * self.scale)
        return min(max(v, self.lo), self.hi)

    def dv_du(self, v: float) -> float:
        return v + self.shift if self.log else self.scale

    @property
    def scale(self) -> float:
        return 0.1 * (self.hi - self.lo)

    @property
    def u_bounds(self) -> tuple[float, float]:
        return self.to_u(self.lo), self.to_u(self.hi)


def _parse_bounds(text: str, name: str) -> tuple[float, float]:
    try:
        lo_s, hi_s = text.split(":")
        lo, hi = float(lo_s), float(hi_s)
    except ValueError:
        raise InputError(f"param: {name}: expected NAME=LO:HI bounds, got {text!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise InputError(f"param: {name}: expected finite bounds LO < HI, got {text!r}")
    return lo, hi


def target(model: ActionModel, spec: str, extra: Sequence[Effect] = ()) -> Target:
    """A fit target from ``NAME`` or ``NAME=LO:HI`` for this model (and extra effects)."""
    name, _, bounds = spec.partition("=")
    name = name.strip()
    effects = {e.name: e for e in (*model.effects, *extra)}
    # an effect's name may hold dots (a base-parameter candidate, ``base:bodies.key.mass``)
    head, _, rest = next(((e, "", name[len(e) + 1:]) for e in sorted(effects, key=len,
                                                                     reverse=True)
                          if name.startswith(e + ".")), name.partition("."))
    if head in effects and rest:
        eff = effects[head]
        specs = {p.name: p for p in eff.parameters}
        if rest not in specs:
            raise InputError(f"param: {name}: effect {head} has no parameter {rest!r} "
                             f"(it has {sorted(specs)})")
        p = specs[rest]
        lo, hi = _parse_bounds(bounds, name) if bounds else p.bounds
        lo, hi = max(lo, p.bounds[0]), min(hi, p.bounds[1])
        v0 = min(max(float(eff.values[rest]), lo), hi)
        # a scale quantity from 0: log(v + shift), the shift a share of its default
        shift = LOG_SHIFT * p.default if p.log and lo == 0 < p.default else 0.0
        return Target(name, head, rest, v0, lo, hi, p.units, p.scan, shift)
    try:
        v0 = model.params.get(name)
    except (KeyError, ValueError, TypeError):
        raise InputError(f"param: {name}: not a model parameter path (e.g. contacts.4.D) nor "
                         f"an effect parameter of this model (e.g. "
                         f"{next(iter(effects), 'flexible_shank')}.<name>)") from None
    if isinstance(v0, bool) or not isinstance(v0, int | float):
        raise InputError(f"param: {name}: expected a numeric parameter, got {v0!r}")
    v0 = float(v0)
    if bounds:
        lo, hi = _parse_bounds(bounds, name)
    elif v0 > 0:
        lo, hi = v0 / 20, v0 * 20
    elif v0 < 0:
        lo, hi = v0 * 20, v0 / 20
    else:
        raise InputError(f"param: {name} is 0; give bounds as {name}=LO:HI")
    return Target(name, None, name, min(max(v0, lo), hi), lo, hi)


def rebuild(base: ActionModel, add: Sequence[Effect | type[Effect]] = (),
            values: dict[str, float] | None = None, targets: Sequence[Target] = (),
            rate: float | None = None) -> ActionModel:
    """A fresh model: base's parameters and effects, extra effects, target values set.

    The base's integrator is kept unless an effect adds Python forces or states and the
    integrator is compiled: then the model integrates with scipy-LSODA (the default for
    such models; see ``python_integrator_note``)."""
    params = base.params.copy()
    effects: list[Effect] = []
    for e in base.effects:
        effects.append(type(e)(**{k: e.values[k] for k in e.explicit}))
    for a in add:
        if isinstance(a, Effect):
            effects.append(type(a)(**{k: a.values[k] for k in a.explicit}))
        else:
            effects.append(a())
    by_name = {e.name: e for e in effects}
    for t in targets:
        v = (values or {}).get(t.label, t.value)
        if t.effect is None:
            params.set(t.key, v)
        else:
            if t.effect not in by_name:
                raise InputError(f"param: {t.label}: effect {t.effect} is not in the model")
            by_name[t.effect].set(t.key, v)
    integrator: Integrator | None = base.integrator
    if any(e.runs_in_python() for e in effects) and \
            not base.integrator.name.startswith("scipy-"):
        integrator = None  # a compiled integrator cannot call Python forces: scipy-LSODA
    model = ActionModel(params, effects, integrator, output_rate=rate or base.output_rate)
    model.rest_state()  # shared by every model with the same equations
    return model


def python_integrator_note(base: ActionModel, classes: Sequence[type[Effect]]) -> str:
    """One sentence when some of ``classes`` make ``rebuild`` leave the base's compiled
    integrator for scipy-LSODA (empty otherwise)."""
    if base.integrator.name.startswith("scipy-"):
        return ""
    names = [c.name for c in classes if c().runs_in_python()]
    if not names:
        return ""
    return (f"{', '.join(names)} computes forces in Python: its models integrate with "
            f"scipy-LSODA instead of {base.integrator.name} (slower)")


@dataclass
class Data:
    """Prepared trials: compared signals and the samples a fit or a score uses."""

    measurements: list[Measurement]
    input: str
    duration: float | None
    channels: list[list[str]]
    time: list[np.ndarray]
    measured: list[dict[str, np.ndarray]]
    ranges: list[dict[str, float]]
    noise: list[dict[str, float]]
    masks: list[np.ndarray]
    align_s: float = ALIGN_S
    windows: list[float | None] | None = None  # per-trial durations (None: ``duration``)
    # per trial: a compared angle read from a displacement sensor whose radius is a fitted
    # unknown (an imported map's ``radius: fit``) -> its saturated samples. Such a channel
    # is compared in the sensor's units: the model's angle times the radius that fits it
    # best at every evaluation (least squares, closed form), the saturated samples left
    # out (``_sensor_units``).
    geometry: list[dict[str, np.ndarray]] | None = None
    # per trial, per channel: each sample's weight on its residual (None: every sample
    # weighs 1). ``noise_weights`` makes them from a noise model: a sample whose prediction
    # the input force's noise moves a lot tells little about the model
    weights: list[dict[str, np.ndarray]] | None = None

    @classmethod
    def build(cls, measurements: Sequence[Measurement], input: str = "force",
              duration: float | None = None, channels: Sequence[str] | None = None,
              masks: Sequence[np.ndarray] | None = None, align_s: float = 0.0,
              windows: Sequence[float | None] | None = None) -> Data:
        """Prepared trials; each trial's window is ``windows[i]`` when given, else
        ``duration`` (None: the whole trial)."""
        times, names, meas, ranges, noise, geo = [], [], [], [], [], []
        wins = list(windows) if windows is not None else [duration] * len(measurements)
        if len(wins) != len(measurements):
            raise InputError(f"windows: expected {len(measurements)}, got {len(wins)}")
        for m, w in zip(measurements, wins, strict=True):
            t, n, d = cp.prepare(m, input, w, channels)
            times.append(t)
            names.append(n)
            meas.append(d)
            ranges.append({c: float(np.ptp(d[c])) or 1.0 for c in n})
            noise.append({c: ms.noise_sigma(d[c]) for c in n})
            geo.append({a: cp.saturated(d[a]) for a in ms.fitted_geometries(m).values()
                        if a in n and a not in m.channels})
        mk = list(masks) if masks is not None else [np.ones(t.shape, bool) for t in times]
        return cls(list(measurements), input, duration, names, times, meas, ranges, noise, mk,
                   align_s, None if windows is None else wins,
                   geo if any(geo) else None)

    def subset(self, masks: Sequence[np.ndarray]) -> Data:
        return Data(self.measurements, self.input, self.duration, self.channels, self.time,
                    self.measured, self.ranges, self.noise, list(masks), self.align_s,
                    self.windows, self.geometry, self.weights)

    def weight(self, i: int, c: str) -> np.ndarray | float:
        """Trial ``i``'s channel ``c``'s sample weights on the masked samples (1.0 when the
        data have none)."""
        if self.weights is None or c not in self.weights[i]:
            return 1.0
        return self.weights[i][c][self.masks[i]]

    def window(self, i: int) -> float | None:
        """Trial ``i``'s analysis duration (s; None: the whole trial)."""
        return self.windows[i] if self.windows is not None else self.duration

    def simulate(self, model: ActionModel) -> list[dict[str, np.ndarray]]:
        """Each trial's predicted channels (rest removed), NaN where the simulation failed."""
        out: list[dict[str, np.ndarray]] = []
        for i, m in enumerate(self.measurements):
            if not self.masks[i].any():
                out.append({})
                continue
            res = ms.simulate(model, m, self.input, self.window(i))
            rel = {c: m.relative(c) for c in self.channels[i]}
            pred = cp.predicted_channels(res, self.time[i], self.channels[i], rel)
            geo = list(self.geometry[i]) if self.geometry else []
            if geo:  # angles from the model's rest, as compare reads them (imported strokes)
                pred.update(cp.predicted_channels(res, self.time[i], geo, dict.fromkeys(
                    geo, True), self.input == "motion"))
            out.append(self._sensor_units(i, pred))
        return out

    def _sensor_units(self, i: int, pred: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Trial ``i``'s predicted angles that a fitted-radius sensor reads, in the sensor's
        units: c theta with the signed radius c = sum(d theta) / sum(theta^2) over the
        masked, unsaturated samples; the saturated samples take the measured value (no
        residual: the sensor did not read the motion there)."""
        if not self.geometry or not self.geometry[i]:
            return pred
        out = dict(pred)
        for angle, sat in self.geometry[i].items():
            th, d = pred.get(angle), self.measured[i][angle]
            if th is None:
                continue
            ok = ~sat & self.masks[i] & np.isfinite(th)
            den = float(np.sum(th[ok] ** 2))
            c = float(np.sum(d[ok] * th[ok]) / den) if den > 0 else math.nan
            out[angle] = np.where(sat, d, c * th)
        return out

    def shifts(self, preds: list[dict[str, np.ndarray]]) -> list[float]:
        """Each trial's shift of its predictions in time (s) that ``aligned`` applies: the
        one shift on a grid of a tenth of a sample within +-``align_s`` that best matches
        the masked samples (0 for a trial with no prediction or no masked sample)."""
        out = []
        for i, pred in enumerate(preds):
            if self.align_s <= 0 or not pred or not self.masks[i].any():
                out.append(0.0)
                continue
            t = self.time[i]
            dt = float(t[1] - t[0]) if t.size > 1 else 1.0
            taus = np.arange(-self.align_s, self.align_s + dt / 20, dt / 10)
            best, best_tau = math.inf, 0.0
            for tau in taus:
                sse = 0.0
                for c in self.channels[i]:
                    y = np.interp(t - tau, t, pred[c])
                    r = (y - self.measured[i][c])[self.masks[i]] / self.ranges[i][c]
                    sse += float(np.sum(np.where(np.isfinite(r), r, FAILED_PENALTY) ** 2))
                if sse < best:
                    best, best_tau = sse, float(tau)
            out.append(best_tau)
        return out

    def aligned(self, preds: list[dict[str, np.ndarray]],
                shifts: Sequence[float] | None = None) -> list[dict[str, np.ndarray]]:
        """Each trial's predictions shifted in time by the one shift (within +-``align_s``)
        that best matches the masked samples (``shifts``), or by the given ``shifts``: the
        input's noise moves a whole blow by a few tenths of a ms from trial to trial, which
        no model can (or should) explain."""
        if shifts is None:
            if self.align_s <= 0:
                return preds
            shifts = self.shifts(preds)
        out = []
        for i, pred in enumerate(preds):
            if not pred or not self.masks[i].any():
                out.append(pred)
                continue
            t = self.time[i]
            out.append({c: np.interp(t - shifts[i], t, pred[c]) for c in self.channels[i]})
        return out

    def residuals(self, preds: list[dict[str, np.ndarray]],
                  shifts: Sequence[float] | None = None) -> np.ndarray:
        """Normalized residuals (model - measured) / range on the masked samples (aligned,
        or shifted by the given ``shifts``)."""
        parts = []
        for i, pred in enumerate(self.aligned(preds, shifts)):
            if not self.masks[i].any():
                continue
            for c in self.channels[i]:
                r = (pred[c] - self.measured[i][c])[self.masks[i]] / self.ranges[i][c]
                parts.append(np.where(np.isfinite(r), r * self.weight(i, c), FAILED_PENALTY))
        return np.concatenate(parts) if parts else np.zeros(0)

    def noise_vector(self) -> np.ndarray:
        """Each residual's output-noise level (channel noise / range, times the sample's
        weight), in ``residuals``'s order."""
        parts = [np.full(int(self.masks[i].sum()), self.noise[i][c] / self.ranges[i][c])
                 * self.weight(i, c)
                 for i in range(len(self.measurements)) if self.masks[i].any()
                 for c in self.channels[i]]
        return np.concatenate(parts) if parts else np.zeros(0)

    def weight_vector(self) -> np.ndarray | None:
        """Each residual's weight, in ``residuals``'s order (None when the data have no
        weights)."""
        if self.weights is None:
            return None
        parts = [np.broadcast_to(np.asarray(self.weight(i, c), float),
                                 (int(self.masks[i].sum()),))
                 for i in range(len(self.measurements)) if self.masks[i].any()
                 for c in self.channels[i]]
        return np.concatenate(parts) if parts else np.zeros(0)

    def segments(self) -> list[int]:
        """Lengths of the contiguous parts of ``residuals`` (one per trial and channel)."""
        return [int(m.sum()) for i, m in enumerate(self.masks) if m.any()
                for _ in self.channels[i]]

    def segment_channels(self) -> list[str]:
        """The channel of each of ``segments``'s parts, in order."""
        return [c for i, m in enumerate(self.masks) if m.any() for c in self.channels[i]]

    def segment_trials(self) -> list[int]:
        """The trial (index into ``measurements``) of each of ``segments``'s parts, in
        order."""
        return [i for i, m in enumerate(self.masks) if m.any() for _ in self.channels[i]]

    def channel_ms(self, preds: list[dict[str, np.ndarray]]) -> dict[str, tuple[float, float]]:
        """Per channel over the masked samples (aligned; weighted when the data have
        ``weights``): (mean square / range^2, mean square / noise^2)."""
        acc: dict[str, list[float]] = {}
        for i, pred in enumerate(self.aligned(preds)):
            if not self.masks[i].any():
                continue
            for c in self.channels[i]:
                r = (pred[c] - self.measured[i][c])[self.masks[i]]
                r = np.where(np.isfinite(r), r * self.weight(i, c),
                             FAILED_PENALTY * self.ranges[i][c])
                a = acc.setdefault(c, [0.0, 0.0, 0.0])
                a[0] += float(np.sum(r ** 2)) / self.ranges[i][c] ** 2
                sig = self.noise[i][c]
                a[1] += float(np.sum(r ** 2)) / (sig ** 2 if sig > 0 else 1.0)
                a[2] += r.size
        return {c: (a[0] / a[2], a[1] / a[2]) for c, a in acc.items() if a[2] > 0}


BLOW_TOLERANCE = 0.1  # trials whose force peak and impulse agree this closely: one blow


def _blow_keys(measurements: Sequence[Measurement]) -> list[tuple[float, float]] | None:
    """Each trial's measured force peak and impulse over the first 0.4 s (the blow); None
    when a trial has no force channel."""
    keys: list[tuple[float, float]] = []
    for m in measurements:
        f = m.channels.get("force")
        if f is None:
            return None
        t = np.asarray(m.time, float)
        sel = (t >= 0) & (t <= 0.4)
        ff = np.asarray(f, float)[sel] if sel.sum() >= 2 else np.asarray(f, float)
        tt = t[sel] if sel.sum() >= 2 else t
        dt = float(np.median(np.diff(tt))) if tt.size >= 2 else 0.0
        keys.append((float(np.max(ff)), float(np.sum(np.clip(ff, 0, None))) * dt))
    return keys


def blows(measurements: Sequence[Measurement], tolerance: float = BLOW_TOLERANCE
          ) -> list[int]:
    """Which blow each trial is (0, 1, ... in order of first appearance): trials whose
    measured force has the same peak and impulse (over the first 0.4 s, the blow) within
    ``tolerance`` are repeats of one blow. Every trial its own blow when a trial has no
    force channel."""
    keys = _blow_keys(measurements)
    return list(range(len(measurements))) if keys is None else _grouped(keys, tolerance)


def _grouped(keys: Sequence[tuple[float, float]], tolerance: float) -> list[int]:
    """``blows`` from the trials' force keys (``_blow_keys``)."""
    out: list[int] = []
    reps: list[tuple[float, float]] = []
    for k in keys:
        for j, r in enumerate(reps):
            if all(abs(a - b) <= tolerance * max(abs(a), abs(b), 1e-12)
                   for a, b in zip(k, r, strict=True)):
                out.append(j)
                break
        else:
            reps.append(k)
            out.append(len(reps) - 1)
    return out


def held_out_trials(data: Data) -> list[int]:
    """The trials ``split_masks`` holds out (none with one trial: blocks of it are).

    With several blows, the blows are ranked by their force (the strongest trial's peak,
    then its impulse; by first appearance without a force channel) and those at odd ranks
    are held out: the strongest blow is always fitted on and, with three or more, the
    weakest too, so that a held-out blow lies within the fitted blows' range where the run
    allows. A model fitted on gentle blows alone is extrapolated to a strong one, where
    the back check, the string and the shank act in ways a gentle blow never pins down
    (measured, issue 39, wide benchmark development seed 603: a back check hidden, two
    2.6 N piano blows and a 32 N held one; fitted on the piano blows its values predicted
    the held blow worse than the base model, fitted on the held blow they predicted the
    piano blows 51 % better, the truth's own 52 %)."""
    n = len(data.measurements)
    if n < 2:
        return []
    keys = _blow_keys(data.measurements)
    if keys is None:  # every trial its own blow, in the order recorded
        return [i for i in range(n) if i % 2 == 1]
    group = _grouped(keys, BLOW_TOLERANCE)
    if max(group) == 0:  # one blow repeated
        return [i for i in range(n) if i % 2 == 1]
    strength = {g: max(k for k, gi in zip(keys, group, strict=True) if gi == g)
                for g in set(group)}
    order = sorted(strength, key=lambda g: (-strength[g][0], -strength[g][1], g))
    held = set(order[1::2])
    return [i for i in range(n) if group[i] in held]


def split_masks(data: Data, block_s: float = 0.002) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Training and held-out samples: with several blows (``blows``), the trials of every
    other blow by force (``held_out_trials``: the strongest fitted on) are held out, so
    that the scores say how a model fitted on some blows predicts another; with several
    trials of one blow, alternate trials; else alternate blocks of ``block_s`` within the
    one trial."""
    n = len(data.measurements)
    if n >= 2:
        held = set(held_out_trials(data))
        train = [np.full(t.shape, i not in held) for i, t in enumerate(data.time)]
        test = [np.full(t.shape, i in held) for i, t in enumerate(data.time)]
        return train, test
    t = data.time[0]
    block = np.floor((t - t[0]) / block_s).astype(int) % 2 == 0
    return [block], [~block]


@dataclass
class FitResult:
    targets: list[Target]
    values: dict[str, float]
    sigma: dict[str, float]
    cost_start: float             # mean normalized square residual at the start
    cost: float                   # ... at the solution
    nfev: int
    status: int
    message: str
    history: list[float] = field(default_factory=list)
    corr: np.ndarray | None = None  # correlation matrix of the targets (HAC covariance)

    @property
    def success(self) -> bool:
        return self.status > 0


# -- the residual at a point: a module-level task for the executor seam (rig.analysis.executor) --
def _residual_at(problem: tuple[Any, ...], u: np.ndarray) -> np.ndarray:
    """The residual vector of ``problem`` = (base, add, targets, rate, data) at ``u``."""
    base, add, targets, rate, data = problem
    values = {t.label: t.from_u(float(x)) for t, x in zip(targets, u, strict=True)}
    return np.asarray(data.residuals(data.simulate(rebuild(base, add, values, targets, rate))))


def scan_order(targets: Sequence[Target]) -> list[int]:
    """The order in which ``fit``'s start scan takes the targets: those that ask for more
    scan points (``Target.scan``: a narrow basin) first, the rest as given. The scan moves
    one target at a time from the best point so far, so a target scanned late is scanned
    where the earlier ones left the others; a narrow basin scanned last is looked for at
    the others' values for the wrong basin (measured, issue 39, wide benchmark development
    seed 1489: the back check's stiffness scanned first at the default friction went to a
    scale of 11.9, where the friction's best, 0.375, lies in a valley whose floor stays 40 %
    above the truth's cost; the friction scanned first at the default stiffness lands in
    the true well, 0.22-0.24)."""
    return sorted(range(len(targets)), key=lambda j: -targets[j].scan)


def fit(base: ActionModel, data: Data, specs: Sequence[str | Target],
        add: Sequence[Effect | type[Effect]] = (), *, jobs: int | None = None,
        executor: Executor | None = None,
        max_nfev: int = 40, diff_step: float = 0.02, scan: int = 0,
        scan_labels: Sequence[str] | None = None,
        progress: Callable[[float, float, str], None] | None = None,
        input_noise_draws: int = 0, starts: Sequence[Mapping[str, float]] = (),
        multistart: int = 1) -> FitResult:
    """Fit the targets by least squares on ``data``'s masked samples (within bounds); with
    ``scan`` > 0 first scan ``scan`` points (or the target's own ``Target.scan``, if more)
    across the bounds of each target (or of those in ``scan_labels``) one at a time, in
    ``scan_order``, for a better start; ``max_nfev`` 0 stops there (the
    scan's best point, its cost, no uncertainties). With ``input_noise_draws`` > 1
    the uncertainties include the input force's noise (``input_noise_cov``).

    ``starts``: more start points, each values keyed by label (a label left out keeps its
    starting value), costed beside the scan's; ``multistart`` > 1 runs the least squares
    from that many of the lowest-cost distinct points (scan, starts, the start itself) and
    keeps the lowest cost (``nfev`` then counts every run).

    The Jacobian's columns run on ``executor`` (rig.analysis.executor: local processes or a Dask
    cluster; the problem travels once per worker) or, without one, on ``jobs`` local
    processes (1: here)."""
    extra = [a if isinstance(a, Effect) else a() for a in add]
    targets = [s if isinstance(s, Target) else target(base, s, extra) for s in specs]
    if not targets:
        raise InputError("param: expected at least one parameter to fit")
    labels = [t.label for t in targets]
    if len(set(labels)) != len(labels):
        raise InputError(f"param: each parameter may appear once, got {labels}")
    rate = data.measurements[0].rate

    def values_of(u: np.ndarray) -> dict[str, float]:
        return {t.label: t.from_u(float(x)) for t, x in zip(targets, u, strict=True)}

    problem = (base, tuple(add), tuple(targets), rate, data)
    last: list[tuple[np.ndarray, np.ndarray]] = []

    def fun(u: np.ndarray) -> np.ndarray:
        if last and np.array_equal(last[0][0], u):
            return last[0][1]
        r = _residual_at(problem, u)
        last[:] = [(u.copy(), r)]
        return r

    from rig.analysis.executor import LocalExecutor, run_all

    own = executor is None and (jobs is None or jobs > 1) and len(targets) > 1
    ex = LocalExecutor(jobs) if own else executor
    history: list[float] = []
    calls = [0]
    budget = max_nfev * (len(targets) + 1)

    def tick(r: np.ndarray, n: int = 1) -> None:
        calls[0] += n
        history.append(float(np.mean(r ** 2)))
        if progress is not None:
            progress(min(calls[0], budget), budget, f"cost {history[-1]:.3g}")

    def fun_logged(u: np.ndarray) -> np.ndarray:
        r = fun(u)
        tick(r)
        return r

    def jac(u: np.ndarray) -> np.ndarray:
        r0 = fun(u)
        lo, hi = zip(*(t.u_bounds for t in targets), strict=True)
        pts = []
        for j in range(len(targets)):
            h = diff_step * max(1.0, abs(u[j]))
            up = u.copy()
            up[j] = u[j] + h if u[j] + h <= hi[j] else u[j] - h
            pts.append(up)
        if ex is not None and ex.workers > 1:
            cols = run_all(ex, _residual_at, pts, shared=problem)
        else:
            cols = [fun(p) for p in pts]
        tick(r0, len(pts) + 1)
        return np.column_stack([(c - r0) / (p[j] - u[j])
                                for j, (c, p) in enumerate(zip(cols, pts, strict=True))])

    try:
        u0 = np.zeros(len(targets))
        lo, hi = (np.array(b) for b in zip(*(t.u_bounds for t in targets), strict=True))
        r0 = fun_logged(u0)
        best = float(np.mean(r0 ** 2))
        tried = [(best, u0)]
        if scan > 0:  # coarse one-at-a-time scan across the bounds for a good start
            for j in scan_order(targets):
                if scan_labels is not None and targets[j].label not in scan_labels:
                    continue
                n = max(scan, targets[j].scan)
                for q in (np.arange(n) + 0.5) / n:
                    u = u0.copy()
                    u[j] = lo[j] + q * (hi[j] - lo[j])
                    c = float(np.mean(fun_logged(u) ** 2))
                    tried.append((c, u))
                    if c < best:
                        best, u0 = c, u
        for start in starts:
            unknown = set(start) - set(labels)
            if unknown:
                raise InputError(f"starts: {sorted(unknown)} are not fitted ({labels})")
            u = np.clip([t.to_u(start[t.label]) if t.label in start else 0.0
                         for t in targets], lo, hi)
            c = float(np.mean(fun_logged(u) ** 2))
            tried.append((c, u))
            if c < best:
                best, u0 = c, u
        if max_nfev <= 0:  # the scan's best start only
            return FitResult(targets, values_of(u0), {t.label: math.nan for t in targets},
                             float(np.mean(r0 ** 2)), best, calls[0], 0, "scan only",
                             history, None)
        sol, nfev = None, 0
        for u_start in distinct_starts(tried, hi - lo, multistart):
            run = least_squares(fun_logged, u_start, jac=jac, bounds=(lo, hi), x_scale=1.0,
                                max_nfev=max_nfev, xtol=1e-4, ftol=1e-6, gtol=1e-8)
            nfev += int(run.nfev)
            if sol is None or run.cost < sol.cost:
                sol = run
        assert sol is not None
    finally:
        if own and ex is not None:
            ex.close()
    values = values_of(sol.x)
    sigma, corr = _uncertainty(targets, values, sol.fun, sol.jac, data.segments())
    if input_noise_draws > 1:  # both parts from one Jacobian with the shifts held
        lin = linearize(base, add, targets, values, data, diff_step=diff_step)
        extra_cov = None if lin is None else input_noise_cov(
            base, add, targets, values, data, draws=input_noise_draws, lin=lin)
        if lin is not None and extra_cov is not None:
            sigma, corr = linearized_uncertainty(targets, values, lin, data.segments())
            sigma, corr = combine_uncertainty(labels, sigma, corr, extra_cov)
    return FitResult(targets, values, sigma, float(np.mean(r0 ** 2)),
                     float(np.mean(sol.fun ** 2)), nfev, int(sol.status),
                     str(sol.message), history, corr)


DISTINCT_START = 0.1  # starts closer than this share of every target's range are one


def distinct_starts(tried: Sequence[tuple[float, np.ndarray]], span: np.ndarray, n: int
                    ) -> list[np.ndarray]:
    """The ``n`` lowest-cost points of ``tried`` (cost, u) that differ from each other by
    more than ``DISTINCT_START`` of ``span`` in some target (the lowest first)."""
    out: list[np.ndarray] = []
    for _, u in sorted(tried, key=lambda cu: cu[0]):
        if all(np.any(np.abs(u - v) > DISTINCT_START * span) for v in out):
            out.append(u)
        if len(out) == n:
            break
    return out


def sobol_starts(targets: Sequence[Target], n: int, seed: int = 0) -> list[dict[str, float]]:
    """``n`` start points spread jointly over the targets' bounds (a scrambled Sobol
    sequence in the fitted coordinates: log-spaced where the target is), keyed by label."""
    from scipy.stats import qmc

    if not targets or n < 1:
        return []
    pts = qmc.Sobol(len(targets), seed=seed).random(n)
    out = []
    for row in pts:
        start = {}
        for t, q in zip(targets, row, strict=True):
            lo, hi = t.u_bounds
            start[t.label] = t.from_u(lo + float(q) * (hi - lo))
        out.append(start)
    return out


INPUT_NOISE_DRAWS = 32  # noise draws of the input-noise covariance (input_noise_cov)


def input_noise_sigma(meas: Measurement, channel: str = "force") -> float:
    """Noise level (1 sigma, the channel's units) of a trial's input channel, by default
    its measured key force (N): the larger of the robust second-difference estimate
    (``noise_sigma``) and the spread over the rest samples (``Measurement.rest_mask``;
    seen only when there are at least 10)."""
    f = np.asarray(meas.channels[channel], float)
    sig = ms.noise_sigma(f)
    rest = meas.rest_mask()
    if rest.sum() >= 10:
        sig = max(sig, float(np.std(f[rest], ddof=1)))
    return sig if math.isfinite(sig) else 0.0


def input_noise_responses(model: ActionModel, data: Data, *, draws: int = INPUT_NOISE_DRAWS,
                          seed: int = 0, r0: np.ndarray | None = None,
                          antithetic: bool = False) -> np.ndarray | None:
    """How the input force's noise moves ``model``'s residuals on ``data``: a (draws, n)
    array, each row the change of ``data.residuals`` when every trial's force channel
    carries fresh white noise of its level (``input_noise_sigma``; the model smooths it
    as it smooths the measurement). None when the input is not the measured force or a
    simulation failed.

    ``antithetic``: each row is half the difference of the residuals with the noise added
    and subtracted (two simulations a row), the response's linear part: adding a second
    unit of noise also shifts the model on average (it dithers the action's dry friction
    more), a second-order change the data's own noise does not hold (on the rigid model's
    blows the rows' mean square fell 8-46 % per channel with it, towards the right model's
    residual)."""
    if data.input != "force" or draws < 2:
        return None
    if r0 is None:
        r0 = data.residuals(data.simulate(model))
    if np.any(r0 == FAILED_PENALTY):
        return None
    rng = np.random.default_rng(seed)
    levels = [input_noise_sigma(m) for m in data.measurements]
    out = np.empty((draws, r0.size))

    def residuals(noise: list[np.ndarray]) -> np.ndarray | None:
        noisy = [replace(m, channels={**m.channels, "force": np.asarray(
            m.channels["force"], float) + n}) for m, n in zip(data.measurements, noise,
                                                               strict=True)]
        dk = replace(data, measurements=noisy)
        rk = dk.residuals(dk.simulate(model))
        return None if rk.shape != r0.shape or np.any(rk == FAILED_PENALTY) else rk

    for k in range(draws):
        noise = [rng.normal(0.0, s, np.shape(m.channels["force"]))
                 for m, s in zip(data.measurements, levels, strict=True)]
        rk = residuals(noise)
        if rk is None:
            return None
        if antithetic:
            r_minus = residuals([-n for n in noise])
            if r_minus is None:
                return None
            out[k] = 0.5 * (rk - r_minus)
        else:
            out[k] = rk - r0
    return out


NOISE_WEIGHT_DRAWS = 16       # input-noise draws behind the sample weights (noise_weights)
NOISE_WEIGHT_SMOOTH_S = 0.005  # their mean square response averaged over this span (s)
NOISE_WEIGHT_RANGE = 100.0     # a sample's squared weight is at most this many times the
                               # channel's median one (the draws' estimate is rough, the
                               # model they run is the one being diagnosed)


def noise_weights(model: ActionModel, data: Data, *, draws: int = NOISE_WEIGHT_DRAWS,
                  seed: int = 1) -> list[dict[str, np.ndarray]] | None:
    """Per trial, per channel: each sample's weight on its residual from a noise model of
    the data under ``model``: white output noise (the channel's ``noise``) plus the
    model's response to the input force's noise (``input_noise_responses`` on every
    sample of every trial, its mean square over the draws averaged over
    ``NOISE_WEIGHT_SMOOTH_S``). The squared weight is the inverse of that variance (at
    most ``NOISE_WEIGHT_RANGE`` times the channel's median), scaled so that its median over
    each trial's channel is 1: a typical sample weighs as an unweighted one, the channels
    keep their equal say, and within a channel a residual counts as a Gaussian likelihood
    of that noise would count it. None when the input is not the measured force or a
    simulation failed (then every sample weighs 1).

    Scaled to a mean of 1 instead, the quietest samples set the scale: the rest before the
    blow, where the force's noise moves nothing, took up to the cap's weight, and a channel
    with more of it had its blow weigh less beside the others (hidden back-check law,
    tests/test_analysis_hidden.py's two blows: the hammer angle's samples in the catch
    weighed 0.5-0.6 in square, its first 10 ms 10.4, and the truth's held-out noise-model
    test fell from z = 4.0 unweighted to 3.2; with the median, 5.0).

    Measured (issue 39, wide benchmark seed 29: key lift-off hidden, 0.36 s windows, noise
    x 2.2): over the key's return, where the hammer and key settle, an extra unit of the
    force's noise moves the predicted angles by 5e-3 to 9e-3 of their range squared, 100-300
    times as much as during the blow; there the truth model itself predicted the held-out
    blow worse than the base model, and unweighted, lift-off "made the held-out error
    worse" although it removed 95 % of it during the blow."""
    if data.input != "force" or draws < 2:
        return None
    full = replace(data, masks=[np.ones(t.shape, bool) for t in data.time], weights=None)
    resp = input_noise_responses(model, full, draws=draws, seed=seed)
    if resp is None:
        return None
    v = np.mean(resp ** 2, axis=0)
    out: list[dict[str, np.ndarray]] = []
    s = 0
    for i, t in enumerate(full.time):
        dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
        k = max(1, int(round(NOISE_WEIGHT_SMOOTH_S / dt)))
        own: dict[str, np.ndarray] = {}
        for c in full.channels[i]:
            n = t.size
            vi = np.convolve(v[s:s + n], np.ones(k) / k, mode="same")
            s += n
            tot = (full.noise[i][c] / full.ranges[i][c]) ** 2 + vi
            med = float(np.median(tot))
            w2 = med / np.maximum(tot, med / NOISE_WEIGHT_RANGE)
            own[c] = np.sqrt(w2)
        out.append(own)
    return out


@dataclass
class Linearization:
    """The residuals of ``data`` at some values and their Jacobian for the uncertainties:
    the targets' columns (in u, forward differences as the fit's) taken with each trial's
    alignment shift held at the one chosen at the values, then one column per aligned
    trial, the residuals' derivative by that trial's shift (the shift is a fitted nuisance
    too: its columns are projected out of the targets')."""

    model: ActionModel
    r0: np.ndarray
    J: np.ndarray  # (n, p + shifts)
    p: int


def linearize(base: ActionModel, add: Sequence[Effect | type[Effect]],
              targets: Sequence[Target], values: Mapping[str, float], data: Data, *,
              diff_step: float = 0.02) -> Linearization | None:
    """``data``'s residuals and their Jacobian at ``values`` (``Linearization``), or None
    when a simulation failed.

    ``Data.aligned`` picks each trial's shift on a grid of a tenth of a sample; a step of
    a target that moves the best shift to the next point of the grid moves the whole blow
    by that tenth, and a forward difference across it takes the jump for the target's
    effect: its column comes out many times too long, and the uncertainties that many
    times too short (issue 39: a string's stiffness, two forte blows, seed 4, weighted:
    J'J 1.05 at the fit's step of 0.02 in u, 0.015-0.035 at steps of +-0.0025 to +-0.04
    that kept the shift, 290 N/m instead of about 1100)."""
    p = len(targets)
    rate = data.measurements[0].rate
    model = rebuild(base, add, dict(values), targets, rate)
    preds = data.simulate(model)
    shifts = data.shifts(preds) if data.align_s > 0 else None
    r0 = data.residuals(preds, shifts)
    if np.any(r0 == FAILED_PENALTY):
        return None
    u0 = np.array([t.to_u(float(values[t.label])) for t in targets])
    cols = []
    for j, t in enumerate(targets):
        lo, hi = t.u_bounds
        h = diff_step * max(1.0, abs(u0[j]))
        u = u0.copy()
        u[j] = u0[j] + h if u0[j] + h <= hi else u0[j] - h
        vals = {**values, **{tt.label: tt.from_u(float(x)) for tt, x in zip(targets, u,
                                                                               strict=True)}}
        r = data.residuals(data.simulate(rebuild(base, add, vals, targets, rate)), shifts)
        cols.append((r - r0) / (u[j] - u0[j]))
    if shifts is not None:
        for i, ti in enumerate(data.time):
            if not preds[i] or not data.masks[i].any() or ti.size < 2:
                continue
            d = float(ti[1] - ti[0]) / 10
            up, down = list(shifts), list(shifts)
            up[i], down[i] = shifts[i] + d, shifts[i] - d
            cols.append((data.residuals(preds, up) - data.residuals(preds, down)) / (2 * d))
    J = np.column_stack(cols)
    if not np.all(np.isfinite(J)):
        return None
    return Linearization(model, r0, J, p)


def linearized_uncertainty(targets: Sequence[Target], values: Mapping[str, float],
                           lin: Linearization, segments: Sequence[int] = ()
                           ) -> tuple[dict[str, float], np.ndarray | None]:
    """``_uncertainty`` (the HAC sandwich) from a ``Linearization``: the targets' block of
    the covariance of targets and shifts."""
    return _uncertainty(targets, dict(values), lin.r0, lin.J, segments, lin.p)


def input_noise_cov(base: ActionModel, add: Sequence[Effect | type[Effect]],
                    targets: Sequence[Target], values: Mapping[str, float], data: Data, *,
                    draws: int = INPUT_NOISE_DRAWS, seed: int = 0, diff_step: float = 0.02,
                    lin: Linearization | None = None) -> np.ndarray | None:
    """Covariance (in the targets' own units) of the fitted values that the noise of the
    measured input force causes: an errors-in-variables term the residual-based (HAC)
    covariance misses, because the model is driven by the noisy force.

    Linearized Monte Carlo: the Jacobian J of the residuals at ``values`` (``linearize``,
    or ``lin`` when given: the targets' columns with the alignment shifts held, and the
    shifts' columns), then ``draws`` copies of the trials whose force channel carries fresh
    white noise of each trial's level (``input_noise_sigma``; the model smooths it as it
    smooths the measurement); each copy's change of the residuals (re-aligned: the shifts'
    columns take their change of shift) maps to a change of the values by the
    least-squares solution -pinv(J) dr. Returns their covariance, or None when the input
    is not the measured force, a simulation failed, or fewer than 2 draws are asked.
    Assumes white input noise; noise low-passed below the model's smoothing
    (``measurement.SMOOTH_HZ``) is underestimated (docs/workflow.md)."""
    p = len(targets)
    if data.input != "force" or p == 0 or draws < 2:
        return None
    if lin is None:
        lin = linearize(base, add, targets, values, data, diff_step=diff_step)
    if lin is None:
        return None
    resp = input_noise_responses(lin.model, data, draws=draws, seed=seed, r0=lin.r0)
    if resp is None:
        return None
    dth = -(resp @ np.linalg.pinv(lin.J).T)[:, :p]
    cov_u = np.atleast_2d(np.cov(dth, rowvar=False))
    d = np.array([t.dv_du(float(values[t.label])) for t in targets])
    return np.asarray(cov_u * np.outer(d, d), float)


def combine_uncertainty(labels: Sequence[str], sigma: Mapping[str, float],
                        corr: np.ndarray | None, extra_cov: np.ndarray
                        ) -> tuple[dict[str, float], np.ndarray]:
    """Add ``extra_cov`` (value units, in ``labels`` order) to the covariance given by
    ``sigma`` and ``corr``; returns the new sigma and correlation matrix."""
    s = np.array([sigma.get(k, math.nan) for k in labels], float)
    known = np.isfinite(s)  # an undetermined value (no column of its own) stays so
    s = np.where(known, s, 0.0)
    c = corr if corr is not None else np.eye(len(labels))
    cov = c * np.outer(s, s) + extra_cov
    d = np.where(known, np.sqrt(np.clip(np.diag(cov), 0.0, None)), math.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        new_corr = cov / np.outer(d, d)
    new_corr = np.where(np.isfinite(new_corr), new_corr, 0.0)
    return {k: float(v) for k, v in zip(labels, d, strict=True)}, new_corr


NIL_COLUMN = 1e-9  # a Jacobian column this small against the largest: the target is inert


def _uncertainty(targets: Sequence[Target], values: dict[str, float], r: np.ndarray,
                 J: np.ndarray, segments: Sequence[int] = (), p: int | None = None
                 ) -> tuple[dict[str, float], np.ndarray | None]:
    """Standard errors from the HAC (Newey-West) sandwich covariance (rig.analysis.stats):
    the residual's autocorrelation within each trial's channel widens them as it must.
    With ``p``, ``J``'s first ``p`` columns are the targets' and the rest nuisances' (the
    covariance's targets' block)."""
    from rig.analysis import stats

    n, q = J.shape
    out = dict.fromkeys(values, math.nan)
    if n <= q or not np.all(np.isfinite(J)) or not np.all(np.isfinite(r)):
        return out, None
    p = q if p is None else p
    # a target whose column is nil does not move the residuals at all (the back check's
    # damping under felt hysteresis, whose law replaces the contact's damping): the data
    # say nothing of it. Its uncertainty is not determined (nan), not the zero the
    # pseudo-inverse would give it, and the others' are taken without its column.
    norms = np.linalg.norm(J, axis=0)
    live = np.ones(q, bool)
    live[:p] = norms[:p] > NIL_COLUMN * max(float(norms.max()), 1e-300)
    try:
        cov_live = stats.sandwich_cov(J[:, live], r, list(segments) or [n])
    except np.linalg.LinAlgError:
        return out, None
    cov = np.full((q, q), math.nan)
    cov[np.ix_(live, live)] = cov_live
    cov = cov[:p, :p]
    d = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(d, d)
    corr = np.where(np.isfinite(corr), corr, 0.0)
    for i, t in enumerate(targets):
        v = values[t.label]
        out[t.label] = abs(t.dv_du(v)) * float(d[i])
    return out, corr

