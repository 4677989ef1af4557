"""Time of a full `rig diagnose` of a forte run against the base model, all candidates.

    .venv/bin/python benchmarks/diagnose.py             # 2 repeats, 2 trials, joint search
    .venv/bin/python benchmarks/diagnose.py --repeats 1 --trials 1 --single

The run: `rig synth` of the whole forte profile (0.6 s at 2 kHz, ``--trials`` trials, the
built-in simulated rig: drive model, noisy load cell, quantized encoders) from a truth
with a compliant string; the analysis model is the rigid base model, so every effect of
the library is a candidate (held-out: alternate 2 ms blocks). By default the load cell
is unfiltered, so that the string is the one missing piece; ``--filtered`` passes the
force through the load cell's 100 Hz filter too (two missing pieces). The model is
compiled and warmed outside the timing. Target: under 60 s on this machine.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--jobs", type=int, default=None, help="processes (default: cores)")
    ap.add_argument("--filtered", action="store_true", help="filter the load cell at 100 Hz")
    ap.add_argument("--trials", type=int, default=2, help="trials of the forte blow")
    ap.add_argument("--single", action="store_true", help="single-candidate ranking only")
    args = ap.parse_args()

    from rig.analysis import diagnose as dg
    from rig.analysis import measurement as ms
    from rig.analysis import synth
    from rig.inputs import profiles
    from rig.model.action import ActionModel
    from rig.model.effects import BUILTIN

    forte = profiles.load(ROOT / "profiles" / "forte.yaml")
    truth = ActionModel(effects=[{"compliant_string": {"stiffness": 3e4}}])
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "forte.h5"
        synth.synth(truth, [forte], path, seed=11, load_cell_filter=args.filtered,
                    trials=args.trials)
        meas = ms.load(path)
    base = ActionModel()
    for name in BUILTIN:  # compile every effect's code paths and warm the caches
        ActionModel(effects=[name], output_rate=2000).simulate(forte, 0.03)
    walls = []
    diag = None
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        diag = dg.diagnose(base, meas, jobs=args.jobs, single=args.single)
        walls.append(time.perf_counter() - t0)
    assert diag is not None
    print(f"forte run ({'filtered' if args.filtered else 'unfiltered'} load cell): "
          f"{len(meas)} trial(s) of {meas[0].duration:.3f} s at {meas[0].rate:g} Hz, "
          f"{'single-candidate ranking' if args.single else 'joint search'}, "
          f"{len(diag.candidates)} candidates, {os.cpu_count()} cores, jobs "
          f"{args.jobs or os.cpu_count()}")
    print(f"diagnose wall: best {min(walls):.1f} s, median {statistics.median(walls):.1f} s "
          f"(target < 60 s: {'met' if min(walls) < 60 else 'missed'})")
    for line in diag.report_lines():
        print(line)


if __name__ == "__main__":
    main()
