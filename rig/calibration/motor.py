"""The motor's force map and lag: steps and ramps of demanded force on a static surface.

Procedure: with the arm pressing a static surface, the drive gets a demand
sequence at the control rate (rests, steps to each level and back, ramps up
and down); the load cell (with its calibration record) gives the force.

* Static map: the settled force at the end of each step's hold against the
  demand (table, monotonic, through 0), plus a straight-line summary.
* Lag: the shift that best (least squares) aligns the map's prediction of the
  demand with the measured force over the whole record (thesis: ~8 ms).
* Dynamic model: a third-order process model K / ((1 + 2 zeta Tw s + (Tw s)^2)
  (1 + Tp3 s)), the thesis's Appendix D form (drive + motor + 100 Hz load-cell
  filter), identified with scipy's least_squares on the same record.

Runtime: ``MotorCompensation.demand(desired_n)`` inverts the map, and the loop
asks for the profile ``lag_s`` ahead: ``comp.demand_at(profile, t)``
(= ``comp.demand(profile.at(t + comp.lag_s))``). ``compensation_for(cfg)``
gives the newest motor record's compensation (identity map, lag =
``loop.advance_s`` when there is none).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import optimize, signal

from rig import loadcell as loadcell_mod
from rig import motor_torque
from rig.calibration.settings import MotorCal
from rig.daq import Bench
from rig.errors import InputError
from rig.inputs.config import RigConfig
from rig.inputs.profiles import Profile

UNITS = {"raw": "N (demand)", "calibrated": "N", "sensitivity": "N per N of demand",
         "offset": "N", "lag": "s", "time": "s"}


@dataclass(frozen=True)
class MotorCompensation:
    """Demand that makes the motor produce a desired force: inverse static map + lead."""

    lag_s: float
    map_demand_n: tuple[float, ...]
    map_force_n: tuple[float, ...]
    source: str = "identity"

    def __post_init__(self) -> None:
        d, f = np.asarray(self.map_demand_n), np.asarray(self.map_force_n)
        if d.size < 2 or d.size != f.size:
            raise InputError("map: expected two or more (demand, force) pairs of equal length")
        if np.any(np.diff(d) <= 0) or np.any(np.diff(f) <= 0):
            raise InputError("map: demand and force must both increase (a monotonic map)")
        if not 0 <= self.lag_s <= 0.1:
            raise InputError(f"lag_s: expected 0 to 0.1 s, got {self.lag_s}")

    @classmethod
    def identity(cls, lag_s: float) -> MotorCompensation:
        return cls(lag_s, (0.0, 1000.0), (0.0, 1000.0), "identity")

    def forward(self, demand_n: np.ndarray | float) -> Any:
        """Settled force (N) for a demand (N) (the static map; linear beyond the table)."""
        d, f = np.asarray(self.map_demand_n), np.asarray(self.map_force_n)
        x = np.asarray(demand_n, float)
        slope_hi = (f[-1] - f[-2]) / (d[-1] - d[-2])
        return np.where(x > d[-1], f[-1] + (x - d[-1]) * slope_hi, np.interp(x, d, f))

    def demand(self, desired_n: np.ndarray | float) -> Any:
        """Demand (N) whose settled force is ``desired_n`` (the inverse map)."""
        d, f = np.asarray(self.map_demand_n), np.asarray(self.map_force_n)
        y = np.asarray(desired_n, float)
        slope_hi = (d[-1] - d[-2]) / (f[-1] - f[-2])
        out = np.where(y > f[-1], d[-1] + (y - f[-1]) * slope_hi, np.interp(y, f, d))
        return np.maximum(out, 0.0) if out.ndim else max(0.0, float(out))

    def demand_at(self, profile: Profile, t: float) -> float:
        """What the torque loop writes at trial time t (N, before the safety limits)."""
        tt = t + self.lag_s
        return float(self.demand(float(profile.at(tt)))) if tt >= 0 else 0.0


def sequence(cfg: RigConfig, s: MotorCal) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """Demand per control period (N) and the segments (kind, level, start, end index)."""
    hz = cfg.rates.control_hz
    top = min(max(s.step_levels_n), cfg.limits.max_force_n)
    levels = [lv for lv in s.step_levels_n if 0 < lv <= cfg.limits.max_force_n]
    if len(levels) < 3:
        raise InputError(f"calibration.motor.step_levels_n: expected 3 or more levels in "
                         f"(0, {cfg.limits.max_force_n:g}] N, got {s.step_levels_n}")
    max_step = cfg.limits.max_rate_n_per_s / hz
    parts: list[np.ndarray] = [np.zeros(int(0.1 * hz))]
    segs: list[dict[str, Any]] = []
    hold = int(round(s.step_hold_s * hz))

    def add(kind: str, values: np.ndarray, level: float) -> None:
        start = sum(p.size for p in parts)
        parts.append(values)
        segs.append({"kind": kind, "level_n": level, "start": start, "end": start + values.size})

    for lv in levels:
        # a step as steep as the rate limit allows
        up = np.minimum(lv, max_step * np.arange(1, hold + 1))
        add("step_up", up, lv)
        down = np.maximum(0.0, lv - max_step * np.arange(1, hold + 1))
        add("step_down", down, 0.0)
    for dur in (s.ramp_s, 2 * s.ramp_s):
        n = int(round(dur * hz))
        add("ramp_up", np.linspace(0, top, n + 1)[1:], top)
        add("hold", np.full(int(0.05 * hz), top), top)
        add("ramp_down", np.linspace(top, 0, n + 1)[1:], 0.0)
        add("rest", np.zeros(int(0.1 * hz)), 0.0)
    return np.concatenate(parts), segs


def _hold(x: np.ndarray, spc: int) -> np.ndarray:
    return np.repeat(np.asarray(x, float), spc)


def _shift(x: np.ndarray, k: float) -> np.ndarray:
    """x delayed by k samples (fractional, linear interpolation; start held)."""
    i = np.arange(x.size, dtype=float)
    return np.interp(i - k, i, x)


def _third_order(params: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
    k, tw, zeta, tp3 = params
    num = [k]
    den = np.polymul([tw * tw, 2 * zeta * tw, 1.0], [tp3, 1.0])
    bd, ad, _ = signal.cont2discrete((num, den), dt, method="zoh")
    return signal.lfilter(np.ravel(bd), ad, u)


@dataclass
class MotorResult:
    raw_points: dict[str, Any]
    fit: dict[str, Any]
    uncertainty: dict[str, Any]
    checks: dict[str, Any]
    compensation: MotorCompensation


def analyse(cfg: RigConfig, demand: np.ndarray, segs: list[dict[str, Any]], force: np.ndarray,
            s: MotorCal) -> MotorResult:
    """Static map, lag and dynamic model from one record (force at the acquisition rate)."""
    spc = cfg.rates.samples_per_cycle
    rate = cfg.rates.acquisition_hz
    if force.size != demand.size * spc or not np.all(np.isfinite(force)):
        raise InputError(f"force: expected {demand.size * spc} finite samples, got "
                         f"{force.size}")
    tail = max(2, int(0.3 * s.step_hold_s * cfg.rates.control_hz))
    lv, fm, fs_ = [0.0], [float(np.mean(force[: int(0.08 * rate)]))], []
    for seg in segs:
        if seg["kind"] != "step_up":
            continue
        a, b = (seg["end"] - tail) * spc, seg["end"] * spc
        lv.append(seg["level_n"])
        fm.append(float(np.mean(force[a:b])))
        fs_.append(float(np.std(force[a:b], ddof=1) / math.sqrt(b - a)))
    levels, settled = np.array(lv), np.array(fm)
    order = np.argsort(levels)
    levels, settled = levels[order], settled[order]
    if np.any(np.diff(settled) <= 0):
        raise InputError("force: the settled force does not rise with the demand "
                         f"({np.round(settled, 2).tolist()} N at {levels.tolist()} N): is the "
                         f"drive enabled and the arm on the surface?")
    slope, intercept = np.polyfit(levels, settled, 1)
    # the map through the origin: the first settled value is the zero-demand reading
    m_force = settled - settled[0]
    m_force[0] = 0.0
    if np.any(np.diff(m_force) <= 0):
        raise InputError("force: the static map is not monotonic")

    comp0 = MotorCompensation(0.0, tuple(levels.tolist()), tuple(m_force.tolist()), "fit")
    pred = _hold(comp0.forward(demand), spc)
    meas = force - settled[0]
    ks = np.arange(0, int(s.max_lag_s * rate) + 1)
    cost = np.array([np.mean((meas - _shift(pred, float(k))) ** 2) for k in ks])
    k0 = int(np.argmin(cost))
    if 0 < k0 < ks.size - 1:  # parabolic refinement between samples
        c_m, c_0, c_p = cost[k0 - 1], cost[k0], cost[k0 + 1]
        den = c_m - 2 * c_0 + c_p
        k_best = k0 + (0.5 * (c_m - c_p) / den if den > 0 else 0.0)
    else:
        k_best = float(k0)
    lag = k_best / rate

    dt = 1.0 / rate
    u = _hold(demand, spc)
    x0 = np.array([float(slope), 0.004, 0.4, 0.006])

    def resid(p: np.ndarray) -> np.ndarray:
        return np.asarray(_third_order(p, u, dt) - meas, dtype=float)

    sol = optimize.least_squares(resid, x0, bounds=([0.1, 1e-4, 0.05, 1e-4],
                                                    [3.0, 0.05, 2.0, 0.05]), x_scale=x0)
    rms_dyn = float(np.sqrt(np.mean(sol.fun ** 2)))
    rms_lag = float(np.sqrt(cost[k0]))
    # lag uncertainty: the curvature of the cost (~ chi^2) around its minimum
    noise_var = float(np.var(meas[: int(0.08 * rate)] - np.mean(meas[: int(0.08 * rate)]),
                             ddof=1)) if rate * 0.08 > 3 else 0.0
    if 0 < k0 < ks.size - 1 and den > 0 and noise_var > 0:
        curv = den / (1.0 / rate) ** 2        # d2(mean sq)/d(lag)^2
        u_lag = math.sqrt(2 * noise_var / (curv * meas.size))
    else:
        u_lag = 0.5 / rate
    u_lag = math.hypot(u_lag, 0.5 / rate / math.sqrt(3))  # resolution of the shift search
    comp = MotorCompensation(lag, comp0.map_demand_n, comp0.map_force_n, "fit")
    fit = {"model": "static map (table) + lag; third-order dynamic model",
           "sensitivity": float(slope), "offset": float(intercept), "lag_s": lag,
           "map_demand_n": list(comp.map_demand_n), "map_force_n": list(comp.map_force_n),
           "zero_demand_force_n": float(settled[0]),
           "dynamic_model": {"form": "K / ((1 + 2 zeta Tw s + (Tw s)^2)(1 + Tp3 s))",
                             "K": float(sol.x[0]), "Tw_s": float(sol.x[1]),
                             "zeta": float(sol.x[2]), "Tp3_s": float(sol.x[3]),
                             "rms_residual_n": rms_dyn},
           "lag_rms_residual_n": rms_lag}
    unc = {"coverage_factor": 2, "lag_s": 2 * u_lag,
           "settled_force_n": [2 * v for v in fs_],
           "map_force_expanded_n": 2 * float(np.max(fs_)) if fs_ else math.nan}
    checks = {"lag_within_search": 0 < k0 < ks.size - 1,
              "dynamic_model_converged": bool(sol.success)}
    raw = {"control_hz": cfg.rates.control_hz, "acquisition_hz": rate,
           "demand_n": demand.tolist(), "segments": segs,
           "force_n": np.round(force, 5).tolist()}
    return MotorResult(raw, fit, unc, checks, comp)


def measure(cfg: RigConfig, bench: Bench, s: MotorCal,
            load_cell: tuple[float, float]) -> tuple[np.ndarray, list[dict[str, Any]],
                                                     np.ndarray]:
    """Run the sequence on the bench: (demand per period, segments, force N at 2 kHz)."""
    demand, segs = sequence(cfg, s)
    ratio = bench.drive_static(demand)
    force = np.asarray(loadcell_mod.to_newtons(ratio, *load_cell), float)
    return demand, segs, force


def tracking(cfg: RigConfig, bench: Bench, profile: Profile, comp: MotorCompensation | None,
             load_cell: tuple[float, float], shift_s: float = 0.0) -> dict[str, float]:
    """Drive ``profile`` on the static surface (uncompensated if comp is None: demand =
    profile(t)) and measure the force; maximum |measured(t + shift) - desired(t)| as % of
    the profile's peak (the thesis's measure, with its 8 ms shift when shift_s = 0.008)."""
    hz = cfg.rates.control_hz
    spc = cfg.rates.samples_per_cycle
    t = np.arange(int(math.ceil(profile.duration * hz)) + int(0.05 * hz)) / hz
    desired = np.array([float(profile.at(x)) for x in t])
    demand = desired if comp is None else np.array([comp.demand_at(profile, x) for x in t])
    demand = np.minimum(demand, cfg.limits.max_force_n)
    ratio = bench.drive_static(demand)
    force = np.asarray(loadcell_mod.to_newtons(ratio, *load_cell), float)
    ts = np.arange(force.size) / cfg.rates.acquisition_hz
    want = np.interp(ts, t, desired)
    got = np.interp(ts + shift_s, ts, force)
    keep = ts + shift_s <= ts[-1]
    err = np.abs(got - want)[keep]
    peak = float(desired.max())
    return {"max_error_pct": float(err.max() / peak * 100), "max_error_n": float(err.max()),
            "rms_error_n": float(np.sqrt(np.mean(err ** 2))), "peak_n": peak,
            "shift_s": shift_s, "samples": int(spc * t.size)}


def compensation_from_record(rec: dict[str, Any]) -> MotorCompensation:
    fit = rec["fit"]
    return MotorCompensation(float(fit["lag_s"]), tuple(fit["map_demand_n"]),
                             tuple(fit["map_force_n"]),
                             f"{rec.get('created', '?')} {rec.get('content_hash', '')}")


def compensation_for(cfg: RigConfig) -> MotorCompensation:
    """The newest valid motor record's compensation for this rig (identity map and
    lag = loop.advance_s when there is none) -- what the torque loop should use."""
    from rig.calibration import records
    from rig.calibration.settings import records_folder

    found = records.newest_valid(records_folder(cfg), "motor", cfg)
    if found is None:
        return MotorCompensation.identity(cfg.loop.advance_s)
    return compensation_from_record(found[0])


def record_in_use(full_records: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The motor calibration record among a run's embedded records, if it uses one."""
    return next((r for r in full_records if r.get("sensor") == "motor"), None)


def demand_source(cfg: RigConfig, full_records: list[dict[str, Any]]
                  ) -> tuple[Callable[[Profile, float], float], dict[str, Any]]:
    """The loop's feedforward and what it is: the motor calibration's compensation (inverse
    static map of the profile ``lag_s`` ahead) when the run uses a motor record, else the
    profile ``loop.advance_s`` ahead (the thesis's open-loop lag compensation)."""
    rec = record_in_use(full_records)
    if rec is None:
        advance = cfg.loop.advance_s

        def ahead(profile: Profile, t: float) -> float:
            return motor_torque.feedforward(profile, t, advance)

        return ahead, {"kind": "advance", "lead_s": advance,
                       "source": "loop.advance_s (no motor calibration record)"}
    comp = compensation_from_record(rec)
    return comp.demand_at, {"kind": "motor calibration", "lead_s": comp.lag_s,
                            "map_demand_n": list(comp.map_demand_n),
                            "map_force_n": list(comp.map_force_n),
                            "record": rec["content_hash"], "created": rec["created"]}
