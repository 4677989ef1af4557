"""How long `rig touch` takes once the model's kernel is compiled (issue 40: under 10 s):

    .venv/bin/python benchmarks/touch.py [--repeats 3]

Runs `rig touch` (a fresh process each time, as a user runs it) once to compile and fill
the caches, then ``--repeats`` times more, and prints each wall time, the best and the
in-process time of rig.model.touch.measure alone (the base model, its rest state cached).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run_cli() -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "rig", "touch"], check=True, capture_output=True,
                   cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    first = run_cli()
    print(f"rig touch, first run (compiles or loads the kernel): {first:.2f} s")
    times = [run_cli() for _ in range(args.repeats)]
    print("rig touch, compiled: " + ", ".join(f"{t:.2f}" for t in times)
          + f" s (best {min(times):.2f} s; target < 10 s)")
    from rig.model import touch
    from rig.model.action import ActionModel

    model = ActionModel()
    model.rest_state()
    t0 = time.perf_counter()
    res = touch.measure(model)
    took = time.perf_counter() - t0
    print(f"touch.measure in process: {took:.2f} s ({len(res.dip_m)} stroke points, "
          f"down-weight {res.figures['down_weight']:.2f} g)")


if __name__ == "__main__":
    main()
