"""Strain-gauge calibration: offset nulling at rest, then a shunt step of known strain.

With the shank at rest the bridge is nulled (NI: hardware nulling on the
SCXI-1520) and its residual ratio averaged: that is the record's ``offset``
(V/V). A shunt resistor Rs across the quarter-bridge gauge Rg is a known
equivalent strain, -Rg / (GF (Rg + Rs)); reading the step with the config's
gauge factor GF and lead resistance gives a measured strain, and the gain
adjustment = equivalent / measured. The record's ``sensitivity`` is the
effective gauge factor GF / gain, which the quarter-bridge formula of
``rig.strain`` then uses. A gain beyond 1 +- ``tolerance`` is refused (wrong
resistor, gauge factor or wiring). NI's own shunt calibration
(``perform_bridge_shunt_cal`` with bridge_resistance = Rg) is run afterwards
and its gain adjustment recorded as a cross-check.

Uncertainty (k = 2): the step's reading noise, the shunt and gauge resistor
tolerances (each weighted by Rs / (Rg + Rs)) and the gauge factor's own
tolerance, which no shunt can see; the offset's from the reading noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from rig import strain as strain_mod
from rig.calibration.settings import StrainCal
from rig.daq import Bench, bridge_range
from rig.errors import InputError
from rig.inputs.config import RigConfig
from rig.strain import shunt_equivalent_strain

UNITS = {"raw": "V/V", "calibrated": "m/m", "sensitivity": "gauge factor (1)",
         "offset": "V/V", "strain": "m/m", "resistance": "ohm"}


@dataclass
class StrainResult:
    raw_points: dict[str, Any]
    fit: dict[str, Any]
    uncertainty: dict[str, Any]
    checks: dict[str, Any]


def _stats(r: np.ndarray, n_settle: int) -> tuple[float, float, int, float]:
    avg = r[n_settle:] if r.size > n_settle + 1 else r
    return float(avg.mean()), float(avg.std(ddof=1)), int(avg.size), float(np.abs(r).max())


def calibrate(cfg: RigConfig, bench: Bench, s: StrainCal) -> StrainResult:
    """Run nulling and the shunt step on ``bench``; ValueError (one line) if refused."""
    g = cfg.channels.strain_gauge
    if not g.enabled:
        raise InputError("channels.strain_gauge.enabled: the rig has no strain gauge")
    rng = bridge_range(cfg, "strain_gauge")
    n_settle = int(round(s.settle_s * bench.rate_hz))
    nulling = bench.null_offset("strain_gauge")
    bench.shunt("strain_gauge", False, s.shunt_resistor_ohm)
    rest = _stats(bench.read_bridge("strain_gauge", s.settle_s + s.average_s), n_settle)
    bench.shunt("strain_gauge", True, s.shunt_resistor_ohm)
    try:
        shunted = _stats(bench.read_bridge("strain_gauge", s.settle_s + s.average_s), n_settle)
    finally:
        bench.shunt("strain_gauge", False, s.shunt_resistor_ohm)
    for name, st in (("at rest", rest), ("with the shunt", shunted)):
        if st[3] >= 0.98 * rng:
            raise InputError(f"strain gauge {name}: the bridge is saturated ({st[3] * 1e3:.3f} "
                             f"mV/V against +-{rng * 1e3:g} mV/V): null the bridge, check the "
                             f"gauge and its wiring")
    rg, gf, rl, rs = (g.nominal_resistance_ohm, g.gage_factor, g.lead_wire_resistance_ohm,
                      s.shunt_resistor_ohm)
    e_eq = shunt_equivalent_strain(rg, gf, rs)
    e_meas = float(strain_mod.to_strain(shunted[0], gf, rest[0], rl, rg))
    if e_meas == 0 or math.copysign(1, e_meas) != math.copysign(1, e_eq):
        raise InputError(f"shunt step: out of tolerance: it reads {e_meas * 1e6:.1f} "
                         f"microstrain, expected about {e_eq * 1e6:.1f} (no step, or the "
                         f"wrong sign: check the shunt circuit and the bridge wiring)")
    gain = e_eq / e_meas
    if abs(gain - 1) > s.tolerance:
        raise InputError(f"shunt step: out of tolerance: it reads {e_meas * 1e6:.1f} "
                         f"microstrain for {e_eq * 1e6:.1f} expected (gain adjustment "
                         f"{gain:.4f}, allowed 1 +- {s.tolerance:g}): check the shunt resistor, "
                         f"the gauge factor and the lead resistance in the config")
    driver_gain = bench.driver_shunt_cal("strain_gauge", rs)
    vr = shunted[0] - rest[0]
    u_step_rel = math.hypot(rest[1] / math.sqrt(rest[2]), shunted[1] / math.sqrt(shunted[2])) \
        / abs(vr)
    w = rs / (rg + rs)
    budget = {"step_reading_noise": u_step_rel,
              "shunt_resistor": w * s.shunt_rel_halfwidth / math.sqrt(3),
              "gauge_resistance": w * s.gauge_resistance_rel_halfwidth / math.sqrt(3),
              "gauge_factor": s.gage_factor_rel_halfwidth / math.sqrt(3)}
    u_rel = math.sqrt(sum(v * v for v in budget.values()))
    gf_eff = gf / gain
    u_off = rest[1] / math.sqrt(rest[2])
    raw = {"rest": {"ratio_v_per_v": rest[0], "std_v_per_v": rest[1], "samples": rest[2],
                    "peak_abs_v_per_v": rest[3]},
           "shunt": {"ratio_v_per_v": shunted[0], "std_v_per_v": shunted[1],
                     "samples": shunted[2], "peak_abs_v_per_v": shunted[3]},
           "nulling": nulling}
    fit = {"model": "quarter bridge I, shunt-calibrated", "sensitivity": gf_eff,
           "offset": rest[0], "gain_adjustment": gain, "gage_factor_config": gf,
           "lead_wire_resistance_ohm": rl, "gauge_resistance_ohm": rg, "shunt_resistor_ohm": rs,
           "shunt_equivalent_strain": e_eq, "shunt_measured_strain": e_meas,
           "driver_gain_adjustment": driver_gain}
    unc = {"coverage_factor": 2, "sensitivity": 2 * u_rel * gf_eff,
           "sensitivity_relative": 2 * u_rel, "offset_v_per_v": 2 * u_off,
           "offset_strain": 2 * u_off * 4 / gf_eff * (1 + rl / rg),
           "budget_relative_standard": budget}
    checks = {"gain_within_tolerance": True, "tolerance": s.tolerance,
              "driver_agrees": None if driver_gain is None else
              abs(driver_gain - gain) <= max(s.tolerance / 5, 2 * u_rel)}
    return StrainResult(raw, fit, unc, checks)
