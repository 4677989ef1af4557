"""Time of a motion-driven `rig compare` of one stroke of the shipped Kawai KG-3C recording
(issue 38's target: < 5 s): the recording is imported once (`rig import` through its map),
then `rig compare RUN.h5 --input motion --trial K` runs in a fresh interpreter, imports and
the compiled model's cache load included, as a user runs it.

    .venv/bin/python benchmarks/compare_motion.py                   # trials 2-6 and 15
    .venv/bin/python benchmarks/compare_motion.py --trials 4 --repeats 5

Prints each run's wall time and, per trial, the median; then the median over all runs.
The first run after installing or updating rig also compiles the model (about a minute):
it is run once before timing.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "kawai-kg3c"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, nargs="+", default=[2, 3, 4, 5, 6, 15])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "kawai.h5"
        subprocess.run([sys.executable, "-m", "rig", "-q", "import",
                        str(EXAMPLE / "hammer_damper_2K_17b.txt"), "--map",
                        str(EXAMPLE / "map.yaml"), "--out", str(run)], check=True,
                       capture_output=True)

        def compare(k: int) -> float:
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "rig", "compare", str(run), "--input",
                            "motion", "--trial", str(k)], check=True, capture_output=True)
            return time.perf_counter() - t0

        compare(args.trials[0])  # (the model's compile cache, once)
        every: list[float] = []
        for k in args.trials:
            walls = [compare(k) for _ in range(args.repeats)]
            every += walls
            print(f"trial {k:2d}: " + ", ".join(f"{w:.2f}" for w in walls)
                  + f" s; median {statistics.median(walls):.2f} s")
        print(f"rig compare --input motion, one stroke: median {statistics.median(every):.2f} s,"
              f" worst {max(every):.2f} s over {len(every)} runs (target < 5 s)")


if __name__ == "__main__":
    main()
