"""Force tracking across learning trials (issue 18), offline on the simulated drive chain.

For each drive variant (single, asymmetric, step_size) and profile (forte, piano,
two-peak): the maximum and RMS error (% of the peak) of the load cell's force
(what the loop sees, with its noise) and of the true key force, for the open-loop
8 ms advance, the static map + lag compensation (demand = profile(t + 8 ms) / K,
K = 0.9322 N/N), and each of 5 ILC trials (rig.control.ilc, defaults: the model-based,
noise-aware update through the thesis's single and rise/fall models, with the minimax
plan where it beats the Newton step; ``--no-plan``: without the plan; ``--p-type``: the
earlier P-type update) started from the advance, with each trial's note (the model
picked, its gain, whether the table changed); then the same with the load-cell PI
(rig.control.feedback, comparing with the profile) in the loop and in the learning's
model; then forte/single under twice the noise, 1 ms jitter, a drive gain drifting
down 10 % from the first trial to the last, and a learning gain 6x too high (must stop);
then learners whose models are wrong (time constants x1.3, K x0.9).
Limits (motor_torque.Limiter) acting on any learned demand are counted.

    python benchmarks/tracking.py [--trials 5] [--seed 1] [--p-type] [--no-plan]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from rig.control import feedback, ilc, offline, plant
from rig.inputs import config, profiles

ROOT = Path(__file__).resolve().parents[1]
CFG = config.from_mapping({"name": "bench", "backend": "sim", "drive": {"port": "sim"}})
HZ = 500.0
NOISE = CFG.sim.load_cell_noise_n
P_TYPE = False
PLAN = True


def fmt(m: dict[str, float], k: dict[str, float]) -> str:
    return f"{m['max_pct']:6.2f} {m['rms_pct']:5.2f} | {k['max_pct']:6.2f} {k['rms_pct']:5.2f}"


def mismatched(m: float) -> tuple[plant.DriveModel, ...]:
    """The thesis's models with their time constants x (1 + m) and K x (1 - m / 3): a
    learner whose models are wrong."""
    def bad(p: plant.ProcessModel) -> plant.ProcessModel:
        return plant.ProcessModel(p.K * (1 - m / 3), p.Tw * (1 + m), p.zeta, p.Tp3 * (1 + m))
    return tuple(plant.DriveModel(d.name + " (mismatched)", bad(d.rise), bad(d.fall))
                 for d in plant.thesis_models())


def case(name: str, variant: str, trials: int, seed: int, *, pi: bool = False,
         noise: float = NOISE, jitter: float = 0.0, drift: float = 0.0,
         factor: float = ilc.DEFAULT_LEARNING_FACTOR, mismatch: float = 0.0) -> None:
    p = profiles.load(ROOT / "profiles" / f"{name}.yaml", force_limit=CFG.limits.max_force_n)
    t = np.arange(int(np.ceil(p.duration * HZ - 1e-9)) + 1) / HZ
    r = np.array([p.at(x) for x in t])
    adv = np.array([p.at(x + 0.008) for x in t])
    rng = np.random.default_rng(seed)

    def play(u: np.ndarray, k: int = 0) -> offline.TrialResult:
        return offline.play(u, variant=variant, noise_n=noise, jitter_s=jitter,
                            gain=1.0 - drift * k / max(trials - 1, 1), rng=rng,
                            controller=feedback.LoadCellPI() if pi else None,
                            reference=r)

    label = (f"{name:8s} {variant:10s} {'PI' if pi else '--':2s} noise {noise:.2f} N jitter "
             f"{jitter * 1e3:.0f} ms drift {drift * 100:.0f} % gain x{factor:g}"
             + (f" learner's models: time constants x{1 + mismatch:g}, K x{1 - mismatch / 3:g}"
                if mismatch else ""))
    print(label)
    floor = {"measured max": max(3.0, 300 * NOISE / p.peak),
             "key max": max(2.0, 100 * NOISE / p.peak), "key rms": max(1.0, 50 * NOISE / p.peak)}
    print("  criteria (% of peak): measured max <= {measured max:.2f}, key max <= {key max:.2f}, "
          "key RMS <= {key rms:.2f}".format(**floor))
    for what, u in (("8 ms advance", adv), ("map + lag", adv / ilc.DEFAULT_GAIN_K)):
        res = play(u)
        errs = ilc.errors(r, res.measured, p.peak), ilc.errors(r, res.key_force, p.peak)
        print(f"  {what:14s} {fmt(*errs)}")
    models = () if P_TYPE else (mismatched(mismatch) if mismatch else None)
    lrn = ilc.Learner.start(r, adv, ilc.LearningFilter.default(HZ, 0.008, factor), CFG.limits,
                            HZ, noise_n=noise, models=models, step=factor,
                            controller=feedback.LoadCellPI() if pi else None, minimax=PLAN)
    limited = 0
    keys = []
    for k in range(trials):
        res = play(lrn.u, k)
        limited += res.limited if not pi else 0
        keys.append(ilc.errors(r, res.key_force, p.peak))
        m = lrn.update(res.measured, res.demand, res.lateness)
        print(f"  ILC trial {k + 1:<4d} {fmt(m, keys[-1])}  {lrn.notes[-1]}")
        if lrn.stopped:
            print(f"  stopped: {lrn.stopped}")
            break
    _, best = lrn.result()
    kb = keys[int(best["trial"]) - 1]
    print(f"  best: trial {int(best['trial'])}  {fmt(best, kb)}  limiter acted on {limited} "
          "learned demands")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=5)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--p-type", action="store_true", help="the earlier P-type update")
    ap.add_argument("--no-plan", action="store_true", help="no minimax plan (Newton steps only)")
    a = ap.parse_args()
    global P_TYPE, PLAN
    P_TYPE, PLAN = a.p_type, not a.no_plan
    print("columns: measured force max % RMS % | true key force max % RMS % (of the peak)")
    for variant in ("single", "asymmetric", "step_size"):
        for name in ("forte", "piano", "two-peak"):
            case(name, variant, a.trials, a.seed)
    for variant in ("single", "asymmetric", "step_size"):
        case("forte", variant, a.trials, a.seed, pi=True)
    case("forte", "single", a.trials, a.seed, noise=2 * NOISE)
    case("forte", "single", a.trials, a.seed, jitter=0.001)
    case("forte", "single", a.trials, a.seed, drift=0.10)
    case("forte", "single", 8, a.seed, factor=6.0)
    for name, variant in (("forte", "single"), ("forte", "asymmetric"), ("two-peak", "asymmetric")):
        case(name, variant, a.trials, a.seed, mismatch=0.3)


if __name__ == "__main__":
    main()
