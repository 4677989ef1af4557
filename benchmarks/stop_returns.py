"""Where a press in time leaves the key, and what the return from there weighs (issue 40):

    PYTHONPATH=. .venv/bin/python benchmarks/stop_returns.py

The shipped model, every friction element sticking, pressed in time by a conditioning press
and a second press (``rig.model.touch.stop_returns``; docs/touch.md, "The up-weight after a
press in time"), each row of the table one force profile: as the test's ramps (0 -> 44 g in
0.5 s, 44 -> 58 g at 2 g/s, held 1 s, down to 14 g at 2 g/s, then to none in 0.3 s and 0.3 s
at none) and variations of it. Prints, for the second press, the key's stop (dip, and which
of the drop screw (contact 11) and the front punching (contact 2) carries it), how far the
jack is off its whippen stop (contact 5) and the up-weight of the quasi-static return from
there (0.25 mm up). First, the check: the test's three presses (let go to none between
them) simulated in time with ``ActionModel.simulate`` and read by the travel rule on their
2 g/s ramps down, against ``stop_returns`` at the ends of their holds.
"""

from __future__ import annotations

import time

import numpy as np

from rig.calibration import touch as ct
from rig.model import touch
from rig.model.action import ActionModel, Stepper


def presses(rate: float = 2.0, frm: float = 44.0, to: float = 58.0, low: float = 14.0,
            drop: float = 0.3, gap: float = 0.3, ramp_down: bool = True,
            hold_at: float | None = None) -> tuple[np.ndarray, float]:
    """(knots (time s, force N), the second press's end of hold). ``hold_at``: the
    second press's force held from there on instead of rising to ``to``."""
    pts, t = [[0.0, 0.0]], 0.0
    for last in (False, True):
        top = to if not last or hold_at is None else hold_at
        t += 0.5
        pts.append([t, frm])
        t += (top - frm) / rate
        pts.append([t, top])
        t += 1.0
        pts.append([t, top])
        if not last:
            if ramp_down:
                t += (to - low) / rate
                pts.append([t, low])
            t += drop
            pts.append([t, 0.0])
            t += gap
            pts.append([t, 0.0])
    knots = np.array(pts)
    knots[:, 1] = [ct.newtons(g) for g in knots[:, 1]]
    return knots, t


def went_g(model: ActionModel, knots: np.ndarray, t_from: float) -> float:
    """The force (g) where the key, pressed in time by ``knots``, has gone 0.25 mm below
    where it stood at ``t_from``."""
    pressed = ActionModel(touch.sticking_parameters(model.params))
    st = touch._Statics(pressed)
    s = Stepper(pressed, pressed.rest_state(), keep_history=False)
    s.advance_table(t_from, knots[:, 0], knots[:, 1])
    start = st.keytop_y(s.y)
    t = t_from
    while start - st.keytop_y(s.y) < touch.FIRST_M:
        t += 0.005
        s.advance_table(t, knots[:, 0], knots[:, 1])
    return ct.grams(float(np.interp(t, knots[:, 0], knots[:, 1])))


def check(model: ActionModel) -> None:
    """The simulation's own ramps down against the quasi-static returns."""
    from rig.inputs import profiles

    ramps = ct.Ramps(from_g=44.0, to_g=58.0, low_g=14.0, rate_g_s=2.0)
    knots = ramps.knots()
    points, period = ramps.presses(3)
    pts = np.array(points)
    pressed = ActionModel(touch.sticking_parameters(model.params), output_rate=2000.0)
    sim = pressed.simulate(profiles.from_points(points, name="presses", description="",
                                                source="benchmark", force_limit=50.0,
                                                max_duration=1e3))
    t, dip = sim.time, sim.channels["key_dip"]
    force = np.interp(t, pts[:, 0], pts[:, 1])
    holds = [i * period + knots[3][0] for i in range(3)]
    returns = touch.stop_returns(model, pts[:, 0], pts[:, 1], holds)
    for i, r in enumerate(returns):
        on = (t >= i * period) & (t < (i + 1) * period)
        up = ct.find_start(t[on] - i * period, dip[on], force[on], ramps.segments()["up"], -1,
                           ramps, 5e-7, f"press {i}")
        print(f"press {i}: the simulation's ramp down {ct.grams(up.went_force_n):6.2f} g, "
              f"the return from its stop at {r['stop_dip_m'] * 1e3:.2f} mm "
              f"{r['up_weight']:6.2f} g")


def main() -> None:
    model = ActionModel()
    check(model)
    rows: list[tuple[str, dict]] = [("as the test's ramps", {})]
    rows += [(f"ramps at {r:g} g/s", {"rate": r}) for r in (0.25, 0.5, 1.0, 1.5, 1.8, 2.2,
                                                            3.0, 4.0)]
    rows += [("from 40 g", {"frm": 40.0}), ("from 42 g", {"frm": 42.0}),
             ("from 45 g", {"frm": 45.0}), ("to 55 g", {"to": 55.0}),
             ("to 62 g", {"to": 62.0}), ("down to 10 g", {"low": 10.0}),
             ("down to 18 g", {"low": 18.0}), ("1 s at no force between", {"gap": 1.0}),
             ("let go in 0.05 s", {"drop": 0.05}),
             ("let go from 58 g in 0.3 s, no ramp down", {"ramp_down": False})]
    # the second press held where the key had gone 0.25 mm: a weight just above it
    knots, _ = presses()
    second = float(knots[np.flatnonzero(knots[:, 1] == 0.0)[-1], 0])
    held = went_g(model, knots, second + 0.5)
    rows.append((f"second press held at {held:.2f} g, where the key had gone 0.25 mm",
                 {"hold_at": held}))
    print(f"{'the presses':62s} {'stop':>8s}  by               jack off  up-weight")
    t0 = time.perf_counter()
    for name, kw in rows:
        knots, end = presses(**kw)
        (r,) = touch.stop_returns(model, knots[:, 0], knots[:, 1], [end])
        pen = r["penetration_m"]
        by = "front punching" if pen[2] > 0 else "drop screw" if pen[11] > 0 else "?"
        print(f"{name:62s} {r['stop_dip_m'] * 1e3:6.2f} mm  {by:15s}  {-pen[5] * 1e3:5.2f} mm"
              f"  {r['up_weight']:6.2f} g")
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
