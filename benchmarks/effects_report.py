"""Figures of the thesis's two effects on the forte (and piano) blow, for docs/model.md.

    .venv/bin/python benchmarks/effects_report.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rig import profiles
from rig.model.action import ActionModel

ROOT = Path(__file__).resolve().parents[1]


def scuffing_mm(res) -> float:
    on = res.contact("contact_force", 12) > 0
    return float(np.ptp(res.contact("contact_point_x", 12)[on])) * 1e3


def main() -> None:
    forte = profiles.load(ROOT / "profiles" / "forte.yaml")
    piano = profiles.load(ROOT / "profiles" / "piano.yaml")
    rigid = ActionModel().simulate(forte)
    flex_model = ActionModel(effects=["flexible_shank"])
    flex = flex_model.simulate(forte)
    print(f"shank first mode (linearised, pinned hammer): "
          f"{flex_model.describe()['shank_first_mode_hz']:.1f} Hz")
    for name, res in (("rigid", rigid), ("flexible shank", flex)):
        s = res.summary()
        print(f"forte, {name}: strike {s['strike_s'] * 1e3:.2f} ms at {s['strike_speed_m_s']:.3f}"
              f" m/s, string contact {s['string_contact_s'] * 1e3:.2f} ms, back check "
              f"{(s['backcheck_catch_s'] - s['string_release_s']) * 1e3:.1f} ms after release, "
              f"scuffing {scuffing_mm(res):.3f} mm")
    t, ev = flex.time, flex.events
    tip = flex.channels["shank_tip_deflection"]
    around = (t > ev["strike"] - 0.002) & (t < ev["string_release"] + 0.002)
    before = t < ev["strike"]
    peak = np.abs(tip[around]).max()
    print(f"flexible shank: largest tip deflection around the strike {peak * 1e3:.2f}"
          f" mm ({peak / 0.086 * 100:.2f} % of the shank), backward while "
          f"accelerating {tip[before].min() * 1e3:.2f} mm; strain "
          f"{flex.channels['shank_strain'].min() * 1e6:.0f} to "
          f"{flex.channels['shank_strain'].max() * 1e6:.0f} microstrain")
    dv = (flex.strike_speed - rigid.strike_speed) / flex.strike_speed * 100
    print(f"strike speed change (flex - rigid) / flex: {dv:+.2f} %")
    # the thesis's measure: head speed difference during the contact period (Fig. 4.5)
    tau = np.linspace(0.0, ev["string_release"] - ev["strike"], 200)
    v_flex = np.interp(ev["strike"] + tau, t, flex.channels["hammer_head_velocity"])
    v_rig = np.interp(rigid.events["strike"] + tau, rigid.time,
                      rigid.channels["hammer_head_velocity"])
    during = np.abs(v_flex - v_rig).max() / flex.strike_speed * 100
    print(f"head speed difference during string contact (strike-aligned): up to {during:.1f} % "
          f"of the strike speed (thesis: up to 27 %)")
    for name in ("key_angle", "whippen_angle", "jack_angle", "repetition_angle", "hammer_angle"):
        d = np.abs(flex.channels[name] - rigid.channels[name])[before].max()
        print(f"  {name}: largest difference before the strike {d:.2e} rad "
              f"({d / np.ptp(rigid.channels[name]) * 100:.2f} % of its range)")
    lift_model = ActionModel(effects=["key_liftoff"])
    for pname, prof in (("forte", forte), ("piano", piano)):
        res = lift_model.simulate(prof)
        lift, tt, e = res.channels["key_lift"] - res.channels["key_lift"][0], res.time, res.events
        b = (tt > e["key_bottom"] - 0.002) & (tt < e["key_bottom"] + 0.03)
        print(f"key lift-off, {pname}: {lift[b].max() * 1e3:.3f} mm when the key bottoms, "
              f"{lift[tt > e['key_release']].max() * 1e3:.3f} mm when it falls back; "
              f"strike speed {res.strike_speed:.3f} m/s")


if __name__ == "__main__":
    main()
