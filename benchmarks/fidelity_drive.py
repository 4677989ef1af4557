"""Fidelity rows for the simulated drive and the fingertip (issue 12; benchmarks/fidelity.py
imports ``rows()``).

Each row: quantity, thesis (value), section, model (value), deviation, tolerance, ok.
The drive's figures come from the built-in simulated rig's chain, noise-free: the 500 Hz
demand held into ``sim.drive_model`` (default ``single``, Eq. D.1 with the load-cell
filter inside), then the simulated load cell (no second filter unless
``sim.load_cell_filter_hz`` is set); the fingertip's from Eq. 3.12-3.13 alone.

    python benchmarks/fidelity_drive.py [--variant single|asymmetric|step_size]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from rig import config, profiles
from rig.config import RigConfig
from rig.model.fingertip import constant_speed_force
from rig.params import Parameters
from rig.sim_backend.drive_model import DriveModel
from rig.sim_backend.sensors import LoadCellModel

FORTE = Path(__file__).resolve().parents[1] / "profiles" / "forte.yaml"
SHIFT_S = 0.008


def recorded_force(demand_n: np.ndarray, cfg: RigConfig) -> tuple[np.ndarray, np.ndarray]:
    """Sample times (s) and the force the load cell records (N, noise-free) for a demand
    held over each control period (the built-in rig's chain)."""
    rate = cfg.rates.acquisition_hz
    spc = cfg.rates.samples_per_cycle
    drive = DriveModel(1.0 / rate, cfg.sim.drive_model, cfg.sim.process_time_unit_s)
    force = np.concatenate([np.maximum(drive.step(float(u), spc), 0.0) for u in demand_n])
    lc = LoadCellModel(1.0, 0.0, 0.0, cfg.sim.load_cell_filter_hz, rate,
                       np.random.default_rng(0))
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
    args = ap.parse_args()
    t0 = time.perf_counter()
    rs = rows(args.variant)
    print(table(rs))
    print(f"({time.perf_counter() - t0:.1f} s)")


if __name__ == "__main__":
    main()
