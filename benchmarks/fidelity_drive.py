"""Fidelity rows for the simulated drive and the fingertip (issue 12; benchmarks/fidelity.py
imports ``rows()``).

Each row: quantity, thesis (value), section, model (value), deviation, tolerance, ok.
The drive's figures come from the built-in simulated rig's chain, noise-free: the 500 Hz
demand held into ``sim.drive_model`` (default ``single``, Eq. D.1 with the load-cell
filter inside), then the simulated load cell (no second filter unless
``sim.load_cell_filter_hz`` is set); the fingertip's from Eq. 3.12-3.13 alone.

    python benchmarks/fidelity_drive.py [--variant single|asymmetric|step_size] [--split]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from rig.inputs import config, profiles
from rig.inputs.config import RigConfig
from rig.inputs.params import Parameters
from rig.model.fingertip import constant_speed_force
from rig.sim_backend.drive_model import DriveResponse
from rig.sim_backend.sensors import SensorSet

FORTE = Path(__file__).resolve().parents[1] / "profiles" / "forte.yaml"
SHIFT_S = 0.008


def recorded_force(demand_n: np.ndarray, cfg: RigConfig) -> tuple[np.ndarray, np.ndarray]:
    """Sample times (s) and the force the load cell records (N, noise-free) for a demand
    held over each control period (the built-in rig's chain)."""
    rate = cfg.rates.acquisition_hz
    spc = cfg.rates.samples_per_cycle
    drive = DriveResponse(1.0 / rate, cfg.sim.drive_model, cfg.sim.process_time_unit_s)
    force = np.concatenate([np.maximum(drive.step(float(u), spc), 0.0) for u in demand_n])
    quiet = cfg.model_copy(update={"sim": cfg.sim.model_copy(update={"load_cell_noise_n": 0.0})})
    lc = SensorSet.from_config(quiet)["load_cell"]
    lc.sensitivity, lc.offset = 1.0, 0.0  # in newtons: the chain's filter, no calibration
    return np.arange(1, force.size + 1) / rate, lc.measure(force)


def step_settling_s(cfg: RigConfig, step_n: float = 10.0, band: float = 0.02) -> float:
    """Time (s) after a step of the demand until the record stays within ``band`` of its
    final value (Fig. D.1's 10 N steps)."""
    hz = cfg.rates.control_hz
    demand = np.r_[np.zeros(int(0.02 * hz)), np.full(int(0.5 * hz), step_n)]
    t, y = recorded_force(demand, cfg)
    t = t - 0.02
    final = y[-1]
    outside = np.nonzero(np.abs(y - final) > band * abs(final))[0]
    return float(t[outside[-1] + 1])


def forte(cfg: RigConfig, calibrated: bool = True) -> dict[str, float]:
    """The forte profile as the demand (over the drive's static gain when ``calibrated``,
    as a motor calibration's map does): the best-aligning lag (least squares) and the
    maximum |record(t) - profile(t - 8 ms)| as a fraction of the peak (Section 2.8)."""
    prof = profiles.load(FORTE)
    dt = 1.0 / cfg.rates.control_hz
    tc = np.arange(0.0, prof.duration, dt)
    desired = prof.at(tc)
    gain = float(Parameters.default().get("actuator.process_model_all.K"))
    t, y = recorded_force(desired / gain if calibrated else desired, cfg)
    lags = np.arange(0.0, 0.030, 1e-4)
    sse = [float(np.sum((y / gain - np.interp(t - lag, tc, desired)) ** 2)) for lag in lags]
    shifted = np.abs(y - np.interp(t - SHIFT_S, tc, desired))
    return {"lag_s": float(lags[int(np.argmin(sse))]),
            "max_error_after_shift": float(shifted.max() / desired.max()),
            "max_error_unshifted": float(np.max(np.abs(y - np.interp(t, tc, desired)))
                                         / desired.max())}


def _row(quantity: str, thesis: float, section: str, model: float, unit: str, scale: float,
         lo: float, hi: float, digits: int = 1) -> dict[str, Any]:
    fmt = f"{{:.{digits}f}}"
    tol = (f"<= {fmt.format(hi * scale)} {unit}" if lo == -np.inf else
           f"{fmt.format(lo * scale)}-{fmt.format(hi * scale)} {unit}")
    return {"quantity": quantity, "thesis": f"{fmt.format(thesis * scale)} {unit}",
            "section": section, "model": f"{fmt.format(model * scale)} {unit}",
            "deviation": f"{(model - thesis) / thesis * 100:+.0f} %", "tolerance": tol,
            "ok": bool(lo <= model <= hi)}


def rows(variant: str = "single") -> list[dict[str, Any]]:
    """The drive's and the fingertip's rows of the fidelity table."""
    cfg = config.builtin_sim(sim={"drive_model": variant})
    act = Parameters.default().get("actuator")
    cal = forte(cfg, calibrated=True)
    raw = forte(cfg, calibrated=False)
    settle = step_settling_s(cfg)
    pulp = dict(Parameters.default().get("fingertip_kelvin_model"))
    slow = constant_speed_force(0.2, 1.6, pulp)
    fast = constant_speed_force(80.0, 1.6, pulp)
    lag_t = act["open_loop_lag_s"]
    err_t = act["open_loop_max_error_after_shift"]
    settle_t = act["step_settle_s"]
    tag = "" if variant == "single" else f" [{variant}]"
    return [
        _row(f"drive lag, forte, load-cell filter included{tag}", lag_t, "2.8", cal["lag_s"],
             "ms", 1e3, lag_t - 0.002, lag_t + 0.002),
        _row(f"drive settling after a 10 N step (2 % band){tag}", settle_t, "App. D, D.1",
             settle, "ms", 1e3, 0.7 * settle_t, 1.3 * settle_t, 0),
        _row(f"forte max error after the 8 ms shift, static gain calibrated{tag}", err_t,
             "2.8, Fig. 2.15", cal["max_error_after_shift"], "%", 100, -np.inf, 1.5 * err_t, 2),
        _row(f"forte max error after the 8 ms shift, uncalibrated (gain K){tag}",
             err_t, "2.8, Fig. 2.15", raw["max_error_after_shift"], "%", 100, -np.inf,
             1.5 * err_t, 2),
        _row("fingertip force, 1.6 mm at 0.2 mm/s", 1.9, "4.3, Fig. 4.15", slow, "N", 1.0,
             1.9 * 0.95, 1.9 * 1.05, 2),
        _row("fingertip force, 1.6 mm at 80 mm/s", 5.3, "4.3, Fig. 4.15", fast, "N", 1.0,
             5.3 * 0.95, 5.3 * 1.05, 2),
    ]


def split_check() -> dict[str, float]:
    """Why the filter stays inside the drive model: can a plant *before* the 100 Hz filter
    reproduce Eq. D.1 (single model, 2 ms units) once filtered?

    * the best third-order plant P (Eq. D.1's form, gain K) with filter x P fitted to G's
      step (least squares, 0-150 ms): its largest miss, as a fraction of the step;
    * the exact inverse G / filter, made proper by four poles at 2 kHz: the share of the
      step the motor would have to deliver within 0.2 ms, and the remaining miss."""
    from scipy import optimize, signal

    m = Parameters.default().get("actuator.process_model_all")
    u = 0.002
    K, Tw, z, Tp3 = m["K"], m["Tw"] * u, m["zeta"], m["Tp3"] * u
    t = np.arange(0.0, 0.15, 1e-4)
    b, a = signal.butter(4, 2 * np.pi * 100.0, analog=True)

    def den(tw: float, zz: float, tp: float) -> np.ndarray:
        return np.polymul([tw * tw, 2 * zz * tw, 1.0], [tp, 1.0])

    g = signal.step(signal.lti([K], den(Tw, z, Tp3)), T=t)[1]

    def miss(p: np.ndarray) -> np.ndarray:
        num, dd = np.polymul([K], b), np.polymul(den(*p), a)
        return np.asarray(signal.step(signal.lti(num, dd), T=t)[1] - g)

    best = min((optimize.least_squares(miss, x0, bounds=([1e-5, 0.05, 1e-5], [0.05, 3, 0.05]),
                                       x_scale=[1e-3, 0.1, 1e-3])
                for x0 in [(Tw * 0.6, z, Tp3 * 0.6), (Tw * 0.3, 0.7, Tp3 * 0.5),
                           (Tw, z, Tp3 * 0.3)]), key=lambda r: r.cost)
    wf = 2 * np.pi * 2000.0
    fast = np.poly1d([1 / wf, 1.0]) ** 4
    inv_num = K * np.asarray(a) / b[-1]
    inv_den = np.polymul(den(Tw, z, Tp3), fast.coeffs)
    tt = np.arange(0.0, 0.08, 5e-5)
    p_step = signal.step(signal.lti(inv_num, inv_den), T=tt)[1]
    filt = signal.step(signal.lti(np.polymul(inv_num, b), np.polymul(inv_den, a)), T=tt)[1]
    g2 = signal.step(signal.lti([K], den(Tw, z, Tp3)), T=tt)[1]
    return {"third_order_plant_max_miss": float(np.abs(miss(best.x)).max() / K),
            "inverse_share_within_0_2_ms": float(p_step[np.searchsorted(tt, 2e-4)] / K),
            "inverse_max_miss": float(np.abs(filt - g2).max() / K)}


def table(rs: list[dict[str, Any]]) -> str:
    keys = ("quantity", "thesis", "section", "model", "deviation", "tolerance", "ok")
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for r in rs:
        lines.append("| " + " | ".join("yes" if r[k] is True else "NO" if r[k] is False
                                       else str(r[k]) for k in keys) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", default="single", choices=("single", "asymmetric",
                                                            "step_size"))
    ap.add_argument("--split", action="store_true",
                    help="also check whether a plant before the filter could reproduce Eq. D.1")
    args = ap.parse_args()
    t0 = time.perf_counter()
    rs = rows(args.variant)
    print(table(rs))
    if args.split:
        for k, v in split_check().items():
            print(f"{k}: {v * 100:.1f} % of the step")
    print(f"({time.perf_counter() - t0:.1f} s)")


if __name__ == "__main__":
    main()
