"""`rig check encoders`: the key moves slowly through its travel; each encoder must count,
in the right direction, at the configured resolution.

The motor presses the key with a slow force ramp (the simulated rig; on NI the
operator presses it slowly by hand while the counters are read). The same
press is computed with the action model, which says where each body should
be. Checks per encoder, with the configured sign and resolution:
* it counts: at least ``min_counts`` over the travel;
* direction: its excursion has the model's sign (key dip down = +);
* resolution: the key's largest dip (~10 mm at key bottom) matches the
  model's within ``tolerance``; each angle's slope against the measured key
  dip, over the travel before let-off, matches the model's kinematics within
  ``tolerance`` (a wrong counts-per-rev or decoding is off by 2x or more).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rig.daq import Bench
from rig.inputs.config import RigConfig

UNITS = {"raw": "counts", "key_dip": "m", "angle": "rad", "slope": "rad/m"}


def press(cfg: RigConfig, seconds: float = 1.5, peak_n: float = 4.0) -> np.ndarray:
    """Force per control period (N): slow ramp up, hold, slow release, rest."""
    hz = cfg.rates.control_hz
    up = np.linspace(0, peak_n, int(seconds * hz))
    return np.concatenate([np.zeros(int(0.05 * hz)), up, np.full(int(0.3 * hz), peak_n),
                           up[::-1], np.zeros(int(0.2 * hz))])


def model_press(cfg: RigConfig, force_n: np.ndarray) -> dict[str, np.ndarray]:
    """The action model under the same press: key_dip (m) and body angles from rest (rad)."""
    from rig.model.action import ANGLE_CHANNELS, ActionModel

    rate = cfg.rates.acquisition_hz
    model = ActionModel(output_rate=rate)
    st = model.stepper()
    dt = 1.0 / cfg.rates.control_hz
    t = np.arange(force_n.size + 1) * dt
    chunk = st.advance_table(float(t[-1]), t, np.r_[0.0, force_n])
    if chunk.status != 0:
        raise RuntimeError(f"the action model failed: {chunk.message}")
    ch = model.channels(chunk.time, chunk.states, chunk.force)
    rest = model.rest_state()
    out = {"key_dip": np.asarray(ch["key_dip"])}
    for name, i in ANGLE_CHANNELS.items():
        out[name] = np.asarray(ch[name]) - float(rest[i])
    return out


@dataclass
class EncoderCheck:
    results: dict[str, dict[str, Any]]
    passed: bool

    def failures(self) -> list[str]:
        return [f"{n}: {r['problem']}" for n, r in self.results.items() if r["problem"]]


def check(cfg: RigConfig, bench: Bench, tolerance: float = 0.1, min_counts: int = 100,
          force_n: np.ndarray | None = None) -> EncoderCheck:
    """Run the press on the bench and compare every encoder with the model."""
    f = press(cfg) if force_n is None else np.asarray(force_n, float)
    counts = bench.key_travel(f)
    model = model_press(cfg, f)
    encs = cfg.channels.encoders
    key_name = next((n for n, e in encs.items() if e.body == "key" and e.kind == "linear"), None)
    results: dict[str, dict[str, Any]] = {}
    dip_meas = None
    if key_name is not None:
        e = encs[key_name]
        dip_meas = e.sign * (counts[key_name] - counts[key_name][0]) * e.si_per_count
    # The measured and the model's press are compared by key dip, never sample by sample:
    # on NI the operator's hand sets the pace and the counters are read once per control
    # period, while the model runs at the acquisition rate.
    dip_model = model["key_dip"]
    for name, e in encs.items():
        c = counts[name] - counts[name][0]
        value = e.sign * c * e.si_per_count
        span = float(np.ptp(c))
        r: dict[str, Any] = {"counts_range": span, "problem": ""}
        expected = dip_model if e.kind == "linear" else model[f"{e.body}_angle"]
        ext = int(np.argmax(np.abs(expected)))
        mext = int(np.argmax(np.abs(value)))
        r["expected_extreme"] = float(expected[ext])
        r["measured_extreme"] = float(value[mext])
        if span < min_counts:
            r["problem"] = f"does not count ({span:.0f} counts over the key travel, expected " \
                           f"at least {min_counts}): check the counter's wiring and channel"
        elif np.sign(value[mext]) != np.sign(expected[ext]):
            r["problem"] = (f"counts in the wrong direction ({value[mext]:+.4g} {e.units} where "
                            f"the action moves {expected[ext]:+.4g}): flip its sign in the config")
        elif e.kind == "linear":
            ratio = value[mext] / expected[ext]
            r["ratio_to_model"] = float(ratio)
            if abs(ratio - 1) > tolerance:
                r["problem"] = (f"resolution: key dip {value[mext] * 1e3:.2f} mm at key bottom "
                                f"where the action gives {expected[ext] * 1e3:.2f} mm (ratio "
                                f"{ratio:.3f}): check metres_per_count")
        elif dip_meas is not None:
            # before let-off, on the way down: key dips between 10 % and 60 % of the
            # shallower of the two presses' bottoms, the same dip window for both
            top_m, top_x = int(np.argmax(dip_meas)), int(np.argmax(dip_model))
            bottom = min(float(dip_meas[top_m]), float(dip_model[top_x]))
            dm, vm = dip_meas[:top_m], value[:top_m]
            dx, vx = dip_model[:top_x], expected[:top_x]
            sel_m = (dm > 0.1 * bottom) & (dm < 0.6 * bottom)
            sel_x = (dx > 0.1 * bottom) & (dx < 0.6 * bottom)
            if min(sel_m.sum(), sel_x.sum()) < 10:
                r["problem"] = "resolution: the key did not travel far enough to compare"
            else:
                s_meas = np.polyfit(dm[sel_m], vm[sel_m], 1)[0]
                s_model = np.polyfit(dx[sel_x], vx[sel_x], 1)[0]
                ratio = float(s_meas / s_model)
                r.update(slope_rad_per_m=float(s_meas), model_slope_rad_per_m=float(s_model),
                         ratio_to_model=ratio)
                if abs(ratio - 1) > tolerance:
                    r["problem"] = (f"resolution: {s_meas:.4g} rad per m of key dip where the "
                                    f"action's kinematics give {s_model:.4g} (ratio {ratio:.3f}):"
                                    f" check counts_per_rev")
        results[name] = r
    return EncoderCheck(results, all(not r["problem"] for r in results.values()))
