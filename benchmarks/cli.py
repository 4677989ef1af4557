"""Whole-process wall times of the commands users wait for (issue 16).

    .venv/bin/python benchmarks/cli.py                 # best of 7, interleaved
    .venv/bin/python benchmarks/cli.py --repeats 15 --pause 0.5

Prints, side by side from one run, the wall time (best and median of N fresh
processes, started round-robin so a slow spell of the shared machine hits all
of them alike) of:

- bare ``python -c "import numba, h5py"`` (the floor: what any simulation needs),
- ``rig --help``, ``rig info RUN.h5``,
- ``rig simulate profiles/forte.yaml`` without and with a one-parameter file
  (``--params`` overriding ``contacts.4.D``),

and the ratios against the targets: ``rig simulate`` <= 2x the bare import, a
one-parameter file <= 1.5x no file. Caches are warmed first (numba's compiled
code, the rest state: both are on disk after the first run), so the figures
are what a user waits for on every run after the first. The commands run in a
temporary folder with the interpreter running this script.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_SIMULATE_VS_BARE = 2.0
TARGET_PARAMS_VS_NONE = 1.5


def wall(cmd: list[str], cwd: Path) -> float:
    """Wall time of one process, s; a failure stops the benchmark with its output."""
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    took = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stdout}{proc.stderr}")
    return took


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=7, help="processes per command (best of)")
    ap.add_argument("--pause", type=float, default=0.2, help="s between processes")
    args = ap.parse_args()
    py = sys.executable
    profile = str(ROOT / "profiles" / "forte.yaml")
    with tempfile.TemporaryDirectory(prefix="rig-bench-cli-") as tmp:
        work = Path(tmp)
        (work / "p.yaml").write_text("contacts: {4: {D: 3.0}}\n", encoding="utf-8")
        n = iter(range(1_000_000))

        def simulate(*extra: str) -> list[str]:
            return [py, "-m", "rig", "simulate", profile, "-o", str(work / f"s{next(n)}.h5"),
                    *extra]

        commands = {
            'python -c "import numba, h5py"': lambda: [py, "-c", "import numba, h5py"],
            "rig --help": lambda: [py, "-m", "rig", "--help"],
            "rig info RUN.h5": lambda: [py, "-m", "rig", "info", str(work / "run.h5")],
            "rig simulate forte": simulate,
            "rig simulate forte --params p.yaml (1 parameter)":
                lambda: simulate("--params", str(work / "p.yaml")),
        }
        # warm up: numba's cache, the rest states of both parameter sets, the run file
        wall([py, "-m", "rig", "simulate", profile, "-o", str(work / "run.h5")], work)
        wall(simulate("--params", str(work / "p.yaml")), work)
        times: dict[str, list[float]] = {name: [] for name in commands}
        for _ in range(args.repeats):
            for name, make in commands.items():
                times[name].append(wall(make(), work))
                time.sleep(args.pause)
    best = {name: min(t) for name, t in times.items()}
    print(f"whole-process wall time, best / median of {args.repeats} "
          f"(python {sys.version.split()[0]}, load average {os.getloadavg()[0]:.2f})")
    for name, t in times.items():
        print(f"  {name:<52} {best[name]:6.3f} / {statistics.median(t):6.3f} s")
    names = list(commands)
    bare, sim, par = best[names[0]], best[names[3]], best[names[4]]
    r1, r2 = sim / bare, par / sim
    print(f"rig simulate / bare import: {r1:.2f}x (target <= {TARGET_SIMULATE_VS_BARE:g}x: "
          f"{'met' if r1 <= TARGET_SIMULATE_VS_BARE else 'NOT met'})")
    print(f"one-parameter file / no file: {r2:.2f}x (target <= {TARGET_PARAMS_VS_NONE:g}x: "
          f"{'met' if r2 <= TARGET_PARAMS_VS_NONE else 'NOT met'})")


if __name__ == "__main__":
    main()
