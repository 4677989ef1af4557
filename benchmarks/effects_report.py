"""Figures of the thesis's two effects on the forte (and piano) blow, for docs/model.md.

    .venv/bin/python benchmarks/effects_report.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rig.inputs import profiles
from rig.model import kernel as k
from rig.model.action import ActionModel
from rig.model.effects import RailLift, rail_lift

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
              f"{(s['check_s'] - s['string_release_s']) * 1e3:.1f} ms after release, "
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
    key_liftoff_report(forte, piano)


def keytop_speed(res) -> float:
    return float(np.gradient(res.channels["key_dip"], res.time).max())


def release_time(profile: profiles.Profile) -> float:
    return float(profile.time[np.flatnonzero(profile.force == profile.peak)[-1]])


def with_release(profile: profiles.Profile, release: float, tail: float = 0.3) -> profiles.Profile:
    """The profile's rise and hold, then a ramp to 0 N in ``release`` s and ``tail`` s at 0."""
    t0 = release_time(profile)
    keep = profile.time <= t0
    pts = [*zip(profile.time[keep], profile.force[keep], strict=True),
           (t0 + release, 0.0), (t0 + release + tail, 0.0)]
    return profiles.from_points(pts, name=f"{profile.name}, {release * 1e3:.0f} ms release")


def lift_text(lift: RailLift) -> str:
    return (f"{lift.height * 1e3:.3f} mm (clearance {lift.clearance * 1e3:+.3f} mm, "
            f"no rail force {lift.airborne * 1e3:.1f} ms)")


def key_liftoff_report(forte: profiles.Profile, piano: profiles.Profile) -> None:
    model = ActionModel(effects=["key_liftoff"])
    rail = model.describe()["balance_rail"]
    rest = model.rest_state()
    revolute = ActionModel().rest_state()
    print(f"key lift-off: balance rail at y = {rail['y_m'] * 1e3:.4f} mm (offset "
          f"{rail['offset_m'] * 1e3:+.4f} mm from Table A.2's Pg1); rest y_k "
          f"{rest[k.QYK] * 1e6:.2e} um, key angle - revolute {rest[k.QK] - revolute[k.QK]:.1e} rad")
    rigid = ActionModel()
    for pname, prof in (("forte", forte), ("piano", piano)):
        res = model.simulate(prof)
        released = release_time(prof)
        bottom = rail_lift(res, res.events["key_bottom"] - 0.002, released)
        fall = rail_lift(res, released)
        r = rigid.simulate(prof)
        print(f"key lift-off, {pname}: bottoming {lift_text(bottom)}; fall-back "
              f"{lift_text(fall)}; strike {res.strike_speed:.3f} m/s (rigid "
              f"{r.strike_speed:.3f}); key-top speed {keytop_speed(res):.3f} m/s (rigid "
              f"{keytop_speed(r):.3f})")
    print("fall-back vs release (ms): lift, no-force time, fastest landing of the key's back "
          "on its rail (contact 3)")
    for pname, prof in (("forte", forte), ("piano", piano)):
        for release in (0.001, 0.02, 0.04, 0.06, 0.08, 0.12, 0.16):
            res = model.simulate(with_release(prof, release))
            t0 = release_time(prof)
            fall = rail_lift(res, t0)
            # the key's back lands on its back rail: fastest landing after the release
            on = res.contact("contact_force", 3) > 0
            lands = np.flatnonzero(~on[:-1] & on[1:] & (res.time[1:] > t0))
            w = res.channels["key_angular_velocity"][lands].max() if lands.size else np.nan
            print(f"  {pname} {prof.peak:g} N, release {release * 1e3:3.0f}: "
                  f"{fall.height * 1e3:.3f} mm, {fall.airborne * 1e3:4.1f} ms, {w:.2f} rad/s")

if __name__ == "__main__":
    main()
