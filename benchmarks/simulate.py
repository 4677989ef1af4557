"""Speed and accuracy of a forte blow: the compiled model against a plain reference.

    .venv/bin/python benchmarks/simulate.py            # everything (the reference takes minutes)
    .venv/bin/python benchmarks/simulate.py --quick    # skip the plain-numpy BDF reference

Prints, for the rigid base model and the full model (flexible shank + key
lift-off): wall time of ``ActionModel.simulate`` (best and median of N runs,
compilation excluded), simulated time, their ratio (target <= 0.1), and the
ratio against scipy ``solve_ivp(method="BDF")`` on the same equations run as
plain Python/numpy (numba disabled) at the same tolerances, with the
differences in strike time (target <= 0.1 ms) and strike speed (target <= 1 %).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MODELS = {"rigid": [], "full": ["flexible_shank", "key_liftoff"]}


def measure(effects: list[str], repeats: int, integrator: str | None) -> dict[str, float]:
    from rig import profiles
    from rig.model.action import ActionModel
    from rig.model.integrators import by_name

    profile = profiles.load(ROOT / "profiles" / "forte.yaml")
    model = ActionModel(effects=effects,
                        integrator=by_name(integrator) if integrator else None)
    model.simulate(profile)  # compile and find the rest state outside the timing
    walls, res = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = model.simulate(profile)
        walls.append(time.perf_counter() - t0)
    assert res is not None
    return {"wall_best_s": min(walls), "wall_median_s": statistics.median(walls),
            "simulated_s": profile.duration, "strike_s": res.events["strike"],
            "strike_speed_m_s": res.strike_speed, "steps": res.stats["steps"],
            "rhs_calls": res.stats["rhs"], "integrator": model.integrator.name,
            "success": float(res.success)}


def reference(effects: list[str]) -> dict[str, float]:
    """The same blow with scipy BDF on the uncompiled right-hand side, in a subprocess."""
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    code = ("import json, sys; sys.path.insert(0, {!r}); import simulate as b; "
            "print(json.dumps(b.measure({!r}, 1, 'scipy-BDF')))".format(str(ROOT / "benchmarks"),
                                                                   effects))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True, cwd=ROOT)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="skip the plain-numpy BDF reference")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--models", nargs="*", default=list(MODELS), choices=list(MODELS))
    args = ap.parse_args()
    for name in args.models:
        effects = MODELS[name]
        m = measure(effects, args.repeats, None)
        ratio = m["wall_best_s"] / m["simulated_s"]
        print(f"[{name}] {m['integrator']}: wall best {m['wall_best_s'] * 1e3:.1f} ms, median "
              f"{m['wall_median_s'] * 1e3:.1f} ms for {m['simulated_s']:.3f} s simulated; "
              f"ratio {ratio:.3f} (target <= 0.1) {'OK' if ratio <= 0.1 else 'MISSED'}; "
              f"{m['steps']:.0f} steps, {m['rhs_calls']:.0f} RHS calls")
        print(f"[{name}] strike {m['strike_s'] * 1e3:.3f} ms at {m['strike_speed_m_s']:.4f} m/s")
        if args.quick:
            continue
        r = reference(effects)
        dt = abs(m["strike_s"] - r["strike_s"]) * 1e3
        dv = abs(m["strike_speed_m_s"] / r["strike_speed_m_s"] - 1) * 100
        gain = r["wall_best_s"] / m["wall_best_s"]
        print(f"[{name}] reference scipy BDF, plain numpy RHS: wall {r['wall_best_s']:.1f} s "
              f"({r['rhs_calls']:.0f} RHS calls); speed-up {gain:.0f}x; strike "
              f"{r['strike_s'] * 1e3:.3f} ms at {r['strike_speed_m_s']:.4f} m/s")
        print(f"[{name}] agreement: strike time {dt:.4f} ms (target <= 0.1) "
              f"{'OK' if dt <= 0.1 else 'MISSED'}, strike speed {dv:.3f} % (target <= 1) "
              f"{'OK' if dv <= 1 else 'MISSED'}")


if __name__ == "__main__":
    main()
