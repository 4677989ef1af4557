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
sigma) over every fitted parameter of a correctly chosen effect, the share of seeds
whose final model (the chosen set, or the base model when nothing is chosen) leaves a
held-out residual above its noise floor (``left``: diagnose's remainder test at 5 %; where
every hidden effect is a library one and the set is exact this is a false claim of
physics outside the library), and the time per diagnose.

``--vary`` draws, per seed, what the fixed suite keeps fixed (the hidden-effect cases a
product is judged on differ from its tests in all of these): each fitted parameter of a
hidden effect (x 0.5-0.75 or x 1.35-2.2 of its default, log-uniform, within its bounds;
a parameter whose default is 0 at 5-15 % of its upper bound), both blows (a forte-like
blow of 25-32 N with its rise, hold and release times, and a softer one of 14-24 N), the
noise level (x 0.7-1.5, log-uniform), the load-cell filter's cutoff when it is hidden
(50-200 Hz) and the window (each trial's default, bounded by its events, in 2 of 5
seeds; else the first 0.12-0.22 s). The draws are printed with each seed.
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
    ap.add_argument("--input", default="force", help="the models' input: force or motion")
    ap.add_argument("--weights", choices=("none", "noise"), default="none",
                    help="diagnose's sample weights (docs/workflow.md; default: diagnose's)")
    ap.add_argument("--vary", action="store_true",
                    help="draw effect values, blows, noise, filter and window per seed")
    args = ap.parse_args()

    sys.path.insert(0, str(ROOT / "tests"))
    from test_analysis_hidden import blows, truth_values  # the suite's own truths

    from rig.analysis import diagnose as dg
    from rig.analysis import measurement as ms
    from rig.analysis import synth
    from rig.model.action import ActionModel
    from rig.model.effects import BUILTIN

    print(f"{'case':<46}{'top-1':>8}{'set':>8}{'alarm':>8}{'cover95':>12}{'left':>8}"
          f"{'s/diag':>8}")
    for case in args.cases.split(","):
        hidden = [] if case == "none" else case.removeprefix("pair:").split("+")
        filtered = any(n in SENSOR_SIDE for n in hidden)
        top1 = exact = alarms = covered = checked = left = 0
        times = []
        per_param: dict[str, list[float]] = {}  # z = (value - truth) / sigma per seed
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            if args.vary:
                draw = varied(case, seed, hidden)
                values, profs = draw["values"], draw["blows"]
                duration, noise = draw["duration"], draw["noise"]
                cfg = synth.default_rig()
                if filtered:
                    cfg = cfg.model_copy(update={"sim": cfg.sim.model_copy(
                        update={"load_cell_filter_hz": draw["filter_hz"]})})
                print(f"  seed {seed}: {draw['text']}", flush=True)
            else:
                values = {n: truth_values(BUILTIN[n]) for n in hidden}
                profs, duration, noise, cfg = blows(), args.duration, 1.0, None
            truth = ActionModel(effects=[{n: values[n]} for n in hidden
                                         if n not in SENSOR_SIDE])
            with tempfile.TemporaryDirectory() as tmp:
                run = Path(tmp) / "run.h5"
                synth.synth(truth, profs, run, cfg=cfg, seed=seed, duration=duration,
                            load_cell_filter=filtered, noise_scale=noise)
                meas = ms.load(run)
                t0 = time.perf_counter()
                diag = dg.diagnose(ActionModel(), meas, duration=duration, jobs=args.jobs,
                                   input=args.input, weights=args.weights)
                times.append(time.perf_counter() - t0)
            names = diag.chosen_names
            top1 += bool(names) and names[0] in hidden
            exact += sorted(names) == sorted(hidden)
            alarms += bool(names)
            final = diag.final
            for n in names:
                if n not in hidden or n in SENSOR_SIDE:
                    continue
                for p, v in values[n].items():
                    key = f"{n}.{p}"
                    if final is None or key not in final.values:
                        continue
                    s = final.sigma.get(key, float("nan"))
                    checked += 1
                    covered += abs(final.values[key] - v) <= 1.96 * s
                    per_param.setdefault(key, []).append((final.values[key] - v) / s)
            rem = diag.remainder
            left += rem is not None and rem.significant
            shown = (f"; left {rem.ratio:.2g} x the floor (p = {rem.p:.2g})"
                     if rem is not None else "")
            print(f"  seed {seed}: chose {names or 'nothing'} in {times[-1]:.1f} s{shown}",
                  flush=True)
            for note in diag.notes:
                if note.startswith(("valley", "refitted", "round ")) or " dropped: " in note:
                    print(f"    {note}", flush=True)
        k = args.seeds
        cover = f"{covered}/{checked}" if checked else "-"
        top = f"{top1 / k:.2f}" if hidden else "-"
        alarm = f"{alarms / k:.2f}" if not hidden else "-"
        print(f"{case:<46}{top:>8}{exact / k:>8.2f}{alarm:>8}{cover:>12}{left / k:>8.2f}"
              f"{statistics.mean(times):>8.1f}", flush=True)
        for key, zs in per_param.items():  # which parameter's interval is too narrow
            inside = sum(abs(z) <= 1.96 for z in zs)
            rms = statistics.fmean(z * z for z in zs) ** 0.5
            print(f"    {key:<40} covered {inside}/{len(zs)}, z mean "
                  f"{statistics.fmean(zs):+.2f}, z rms {rms:.2f} (1 if honest)", flush=True)


def varied(case: str, seed: int, hidden: list[str]) -> dict:
    """One seed's draws for ``--vary`` (reproducible from the case and the seed)."""
    import zlib

    import numpy as np

    from rig.inputs import profiles
    from rig.model.effects import BUILTIN

    rng = np.random.default_rng([seed, zlib.crc32(case.encode())])

    def away() -> float:  # a factor off the default: x 0.5-0.75 or x 1.35-2.2
        lo, hi = (0.5, 0.75) if rng.random() < 0.5 else (1.35, 2.2)
        return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))

    values: dict[str, dict[str, float]] = {}
    for n in hidden:
        values[n] = {}
        for p in BUILTIN[n].parameters:
            if not p.fitted or n in SENSOR_SIDE:  # hidden in the sensor chain: filter_hz
                continue
            lo, hi = p.bounds
            v = p.default * away() if p.default > 0 else hi * rng.uniform(0.05, 0.15)
            values[n][p.name] = float(min(max(v, lo), hi))
    peak_a, peak_b = rng.uniform(25.0, 32.0), rng.uniform(14.0, 24.0)
    rise_a, rise_b = rng.uniform(0.06, 0.10), rng.uniform(0.07, 0.12)
    hold_a, rel_a = rng.uniform(0.12, 0.20), rng.uniform(0.03, 0.05)
    hold_b, rel_b = rng.uniform(0.12, 0.20), rng.uniform(0.03, 0.06)

    def blow(peak: float, rise: float, hold: float, rel: float, name: str) -> profiles.Profile:
        t = np.cumsum([0.0, 0.02, rise, hold, rel, 0.12])
        return profiles.from_points(list(zip(t, [0, 0, peak, peak, 0, 0], strict=True)),
                                    name=name)

    duration = None if rng.random() < 0.4 else float(rng.uniform(0.12, 0.22))
    noise = float(np.exp(rng.uniform(np.log(0.7), np.log(1.5))))
    filter_hz = float(np.exp(rng.uniform(np.log(50.0), np.log(200.0))))
    shown = ", ".join(f"{n}.{p} {v:.4g}" for n, ps in values.items() for p, v in ps.items())
    text = (f"{shown + '; ' if shown else ''}blows {peak_a:.1f} N (rise {rise_a * 1e3:.0f} ms) "
            f"and {peak_b:.1f} N (rise {rise_b * 1e3:.0f} ms); noise x{noise:.2f}; window "
            + ("default" if duration is None else f"{duration:.3f} s")
            + (f"; filter {filter_hz:.0f} Hz" if "load_cell_filter" in hidden else ""))
    return {"values": values, "blows": [blow(peak_a, rise_a, hold_a, rel_a, "A"),
                                        blow(peak_b, rise_b, hold_b, rel_b, "B")],
            "duration": duration, "noise": noise, "filter_hz": filter_hz, "text": text}


if __name__ == "__main__":
    main()
