"""The best key-force tracking any feedforward can reach on the simulated drive (issue 18).

Noise-free, on the learner's (= the simulated) drive model, with the loop's limits
(demand in [0, limits.max_force_n], rate <= limits.max_rate_n_per_s): the minimax
key-force error (% of the peak) over every 500 Hz demand sequence
(rig.control.bound): the thesis's single model, then the rise/fall pair with one
mode switch (rising, then falling from cycle k: a monotone release; k scanned), with two
(falling from k1, rising again from k2: a release that brakes), and with the modes free
(a mixed-integer programme to ``--time-limit`` s, at most ``--switches`` mode changes,
0 meaning any number, each a demand change >= ``--switch-step`` N). Each demand found is checked
by playing it noise-free through rig.control.offline (the 2 kHz simulated drive).

    python benchmarks/tracking_bound.py [--profile forte] [--time-limit 240]
                                        [--switches 0] [--switch-step 0.001]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from rig.control import bound, offline, plant
from rig.errors import InputError
from rig.inputs import config, profiles

ROOT = Path(__file__).resolve().parents[1]
CFG = config.from_mapping({"name": "bench", "backend": "sim", "drive": {"port": "sim"}})
HZ = 500.0


def played(d: np.ndarray, r: np.ndarray, variant: str, peak: float) -> str:
    res = offline.play(d, variant=variant, noise_n=0.0, limits=CFG.limits)
    return (f"played: key max {100 * np.abs(r - res.key_force).max() / peak:.3f} %, "
            f"limiter acted {res.limited}x")


def scan(model: plant.DriveModel, r: np.ndarray, falls: list[tuple[int, int]]
         ) -> tuple[tuple[int, int], bound.Bound] | None:
    """The best of the mode sequences falling over [k1, k2) (rising elsewhere)."""
    n = r.size
    best = None
    for k1, k2 in falls:
        rising = (np.arange(n) < k1) | (np.arange(n) >= k2)
        try:
            b = bound.fixed_modes(model, r, rising, CFG.limits, HZ)
        except InputError:   # no demand plays this mode sequence
            continue
        if best is None or b.max_error_n < best[1].max_error_n:
            best = ((k1, k2), b)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profile", default="forte")
    ap.add_argument("--time-limit", type=float, default=240.0)
    ap.add_argument("--switches", type=int, nargs="*", default=[0])
    ap.add_argument("--switch-step", type=float, default=bound.SWITCH_STEP_N,
                    help="the smallest demand change (N) a mode switch is made with")
    a = ap.parse_args()
    p = profiles.load(ROOT / "profiles" / f"{a.profile}.yaml", force_limit=CFG.limits.max_force_n)
    t = np.arange(int(np.ceil(p.duration * HZ - 1e-9)) + 1) / HZ
    r = np.array([p.at(x) for x in t])
    n = r.size
    pct = 100 / p.peak
    single, risefall = plant.thesis_models()
    b = bound.fixed_modes(single, r, np.ones(n, bool), CFG.limits, HZ)
    print(f"{a.profile}, single model: key max {pct * b.max_error_n:.3f} % "
          f"({played(b.demand, r, 'single', p.peak)})")
    # where the profile falls from its peak: the release the falling model must follow
    top = int(np.flatnonzero(r >= p.peak)[-1])
    one = scan(risefall, r, [(k, n) for k in range(top - 15, top + 10)])
    if one is None:
        return
    (k, _), b = one
    print(f"{a.profile}, rise/fall, one switch (falling from cycle {k}): key max "
          f"{pct * b.max_error_n:.3f} % ({played(b.demand, r, 'asymmetric', p.peak)})")
    two = scan(risefall, r, [(k1, k2) for k1 in range(k - 4, k + 5, 2)
                             for k2 in range(k1 + 8, min(n, k1 + 60), 3)])
    if two is not None:
        (k1, k2), b = two
        print(f"{a.profile}, rise/fall, two switches (falling from cycle {k1}, rising from "
              f"{k2}): key max {pct * b.max_error_n:.3f} % "
              f"({played(b.demand, r, 'asymmetric', p.peak)})", flush=True)
    for s in a.switches:
        t0 = time.time()
        b = bound.best_demand(risefall, r, CFG.limits, HZ, max_switches=s or None,
                              time_limit_s=a.time_limit, switch_step_n=a.switch_step)
        print(f"{a.profile}, rise/fall, modes free ({'<= ' + str(s) if s else 'any number of'}"
              f" switches, each >= {a.switch_step:g} N): key max {pct * b.max_error_n:.3f} % "
              f"with {b.switches} switches; {'optimal' if b.optimal else 'time limit'}, no "
              f"demand below {pct * b.dual_bound_n:.3f} % ({time.time() - t0:.0f} s; "
              f"{played(b.demand, r, 'asymmetric', p.peak)})", flush=True)


if __name__ == "__main__":
    main()
