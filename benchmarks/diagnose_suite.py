"""Hidden-effect suite of `rig diagnose` over noise seeds (issue 13).

    .venv/bin/python benchmarks/diagnose_suite.py                     # 20 seeds per case
    .venv/bin/python benchmarks/diagnose_suite.py --seeds 3 --cases none,key_liftoff

Cases: ``none`` (nothing hidden), each library effect alone (``<name>``) and pairs
(``pair:<a>+<b>``). Each seed synthesizes a fresh run (two trials: the forte profile
and a 24 N blow, the simulated rig's drive and sensor chain, fresh noise) from a truth
with the hidden effects (fitted parameters moved off their defaults as in
tests/test_analysis_hidden.py; the load-cell filter hidden the physical way, in the
sensor chain), diagnoses the rigid base model (joint search, all candidates) and
scores it. Prints per case: top-1 accuracy (the first chosen effect is a hidden one),
set recovery (the chosen set is exactly the hidden set), the false-alarm rate (``none``:
anything chosen), the coverage of the stated 95 % intervals (|value - truth| <= 1.96
sigma) over every fitted parameter of a correctly chosen effect, and the time per
diagnose.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_CASES = ("none,compliant_string,load_cell_filter,backcheck_law,key_liftoff,"
                 "pair:compliant_string+load_cell_filter,pair:flexible_shank+drive_dynamics,"
                 "pair:backcheck_law+compliant_string")
SENSOR_SIDE = {"load_cell_filter"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--cases", default=DEFAULT_CASES)
    ap.add_argument("--duration", type=float, default=0.15)
    ap.add_argument("--jobs", type=int, default=None)
    args = ap.parse_args()

    sys.path.insert(0, str(ROOT / "tests"))
    from test_analysis_hidden import blows, truth_values  # the suite's own truths

    from rig.analysis import diagnose as dg
    from rig.analysis import measurement as ms
    from rig.analysis import synth
    from rig.model.action import ActionModel
    from rig.model.effects import BUILTIN

    print(f"{'case':<46}{'top-1':>8}{'set':>8}{'alarm':>8}{'cover95':>12}{'s/diag':>8}")
    for case in args.cases.split(","):
        hidden = [] if case == "none" else case.removeprefix("pair:").split("+")
        truth_effects = [{n: truth_values(BUILTIN[n])} for n in hidden if n not in SENSOR_SIDE]
        filtered = any(n in SENSOR_SIDE for n in hidden)
        truth = ActionModel(effects=truth_effects)
        top1 = exact = alarms = covered = checked = 0
        times = []
        per_param: dict[str, list[float]] = {}  # z = (value - truth) / sigma per seed
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            with tempfile.TemporaryDirectory() as tmp:
                run = Path(tmp) / "run.h5"
                synth.synth(truth, blows(), run, seed=seed, duration=args.duration,
                            load_cell_filter=filtered)
                meas = ms.load(run)
                t0 = time.perf_counter()
                diag = dg.diagnose(ActionModel(), meas, duration=args.duration,
                                   jobs=args.jobs)
                times.append(time.perf_counter() - t0)
            names = diag.chosen_names
            top1 += bool(names) and names[0] in hidden
            exact += sorted(names) == sorted(hidden)
            alarms += bool(names)
            final = diag.final
            for n in names:
                if n not in hidden or n in SENSOR_SIDE:
                    continue
                for p, v in truth_values(BUILTIN[n]).items():
                    key = f"{n}.{p}"
                    if final is None or key not in final.values:
                        continue
                    s = final.sigma.get(key, float("nan"))
                    checked += 1
                    covered += abs(final.values[key] - v) <= 1.96 * s
                    per_param.setdefault(key, []).append((final.values[key] - v) / s)
            print(f"  seed {seed}: chose {names or 'nothing'} in {times[-1]:.1f} s",
                  flush=True)
            for note in diag.notes:
                if note.startswith("valley"):
                    print(f"    {note}", flush=True)
        k = args.seeds
        cover = f"{covered}/{checked}" if checked else "-"
        top = f"{top1 / k:.2f}" if hidden else "-"
        alarm = f"{alarms / k:.2f}" if not hidden else "-"
        print(f"{case:<46}{top:>8}{exact / k:>8.2f}{alarm:>8}{cover:>12}"
              f"{statistics.mean(times):>8.1f}", flush=True)
        for key, zs in per_param.items():  # which parameter's interval is too narrow
            inside = sum(abs(z) <= 1.96 for z in zs)
            rms = statistics.fmean(z * z for z in zs) ** 0.5
            print(f"    {key:<40} covered {inside}/{len(zs)}, z mean "
                  f"{statistics.fmean(zs):+.2f}, z rms {rms:.2f} (1 if honest)", flush=True)


if __name__ == "__main__":
    main()
