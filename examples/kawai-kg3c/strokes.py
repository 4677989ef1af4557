"""The Kawai KG-3C's strokes beside the model's (docs/real-data.md).

    python examples/kawai-kg3c/strokes.py kawai.h5 [TRIAL ...]

For each trial of an imported run (examples/kawai-kg3c/map.yaml; all but the two slow
hand motions by default) one line for the real action, read from its two sensors without
a model, and one for the default model driven by the key's measured motion
(`rig compare --input motion`: the key follows it both ways), the hammer sensor read as
the hammer's angle through the radius fitted to the model:

- strike: the real hammer sensor passing 90 % of its range (it saturates a few mm below
  the string; on the single fast strokes the model's string contact falls within 2 ms of
  it, tests/test_real_data.py); the model's first string contact. Times from the stroke's
  onset (the key leaving its rest, docs/import.md);
- key at strike: the key's travel then (mm);
- bottom-strike: when the key passes 97 % of the deepest travel the sensor reads (the
  calibration table ends at 15/32 in, 11.04 mm after the tare: the real key's bottom is
  at or beyond it) minus the strike, the model's key passing the same travel; ms;
- check: the hammer's rise (at the sensor, mm from rest) where it comes to rest after the
  strike (the back check holds it: the first 10 ms after the strike's fall within 0.05
  mm), and when (ms after the strike); the model's from its hammer angle through the
  fitted radius;
- strikes: string contacts in the trial (real: the sensor's passes through 90 %, back
  below 50 % in between; model: contacts starting 30 ms or more after the last ended,
  re-strikes sooner than that counted after the +).
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from rig.analysis import compare as cp
from rig.analysis import measurement as ms
from rig.model.action import ActionModel

REBOUND_S = 0.030
HOLD_S, HOLD_M = 0.010, 0.05e-3
DEEP = 0.97


def passes(t: np.ndarray, x: np.ndarray, hi: float, lo: float) -> list[float]:
    """Times ``x`` rises through ``hi``, counted again only after falling below ``lo``."""
    out, up = [], False
    for ti, v in zip(t, x, strict=True):
        if not up and v > hi:
            up = True
            out.append(float(ti))
        elif up and v < lo:
            up = False
    return out


def settle(t: np.ndarray, x: np.ndarray, after: float) -> tuple[float, float]:
    """(time, value) where ``x`` first stays within HOLD_M for HOLD_S after ``after``."""
    dt = float(np.median(np.diff(t)))
    n = max(2, int(round(HOLD_S / dt)))
    idx = np.nonzero(t > after + 0.002)[0]
    for i in idx:
        w = x[i:i + n]
        if w.size == n and float(np.ptp(w)) < HOLD_M:
            return float(t[i]), float(x[i])
    return math.nan, math.nan


def real_row(meas: ms.Measurement) -> dict[str, float]:
    t = meas.time
    h = meas.channels["hammer_shank_rise"] - float(np.mean(
        meas.channels["hammer_shank_rise"][meas.rest_mask()]))
    k = meas.channels["key_dip"] - float(np.mean(meas.channels["key_dip"][meas.rest_mask()]))
    top = float(np.max(h))
    strikes = passes(t, h, 0.9 * top, 0.5 * top)
    ts = strikes[0] if strikes else math.nan
    kmax = float(np.max(k))
    tb = float(t[np.argmax(k >= DEEP * kmax)])
    tc, hc = settle(t, h, ts) if strikes else (math.nan, math.nan)
    return {"strike": ts, "key": float(np.interp(ts, t, k)) if strikes else math.nan,
            "bottom": tb - ts, "check_mm": hc, "check": tc - ts, "strikes": len(strikes),
            "again": 0, "depth": kmax}


def model_row(meas: ms.Measurement, model: ActionModel) -> tuple[dict[str, float], float]:
    comp = cp.compare(meas, [("base model", model)], "motion")
    res = comp.models[0].result
    t = res.time
    r = comp.fitted["hammer_angle"]["radius_m"]
    sign = comp.fitted["hammer_angle"]["sign"]
    k = res.channels["key_dip"] - float(res.channels["key_dip"][0])
    h = sign * r * (res.channels["hammer_angle"] - float(res.channels["hammer_angle"][0]))
    on = res.contact("contact_penetration", 12) > 0
    d = np.diff(on.astype(int))
    ons, offs = t[np.nonzero(d == 1)[0] + 1], t[np.nonzero(d == -1)[0] + 1]
    blows = [x for i, x in enumerate(ons) if i == 0 or x - offs[i - 1] >= REBOUND_S]
    ts = float(ons[0]) if ons.size else math.nan
    depth = real_row(meas)["depth"]
    deep = np.nonzero(k >= DEEP * depth)[0]
    tb = float(t[deep[0]]) if deep.size else math.nan
    tc, hc = settle(t, h, ts) if ons.size else (math.nan, math.nan)
    return ({"strike": ts, "key": float(np.interp(ts, t, k)) if ons.size else math.nan,
             "bottom": tb - ts, "check_mm": hc, "check": tc - ts, "strikes": len(blows),
             "again": int(ons.size) - len(blows), "depth": float(np.max(k))}, r)


def fmt(label: str, row: dict[str, float]) -> str:
    def num(x: float, scale: float, f: str) -> str:
        return format(x * scale, f) if math.isfinite(x) else "-"
    again = f"+{row['again']}" if row["again"] else ""
    return (f"{label:<11}{num(row['strike'], 1e3, '.1f'):>8}{num(row['key'], 1e3, '.2f'):>8}"
            f"{num(row['bottom'], 1e3, '.1f'):>9}{num(row['check_mm'], 1e3, '.2f'):>9}"
            f"{num(row['check'], 1e3, '.1f'):>8}{row['strikes']:>6}{again}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run")
    ap.add_argument("trials", nargs="*", type=int)
    a = ap.parse_args()
    model = ActionModel.from_yaml(None)
    n = len(ms.load(a.run, None, input="motion"))
    picks = a.trials or list(range(2, n))
    print(f"{'trial':<11}{'strike':>8}{'key':>8}{'bottom':>9}{'check':>9}{'at':>8}"
          f"{'strikes':>8}")
    print(f"{'':<11}{'ms':>8}{'mm':>8}{'-strike':>9}{'mm':>9}{'ms':>8}")
    for i in picks:
        meas = ms.load(a.run, [i], input="motion")[0]
        row, r = model_row(meas, model)
        print(fmt(f"{i} real", real_row(meas)))
        print(fmt("  model", row) + f"   (radius {r * 1e3:.2f} mm)")


if __name__ == "__main__":
    main()
