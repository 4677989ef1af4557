"""Time of `rig import` on the shipped Kawai KG-3C recording (50 s at 2 kHz, 100 001 rows):
reading the text, calibrating both columns through the map's lookup tables, segmenting the
key into its strokes and writing the run file -- in a fresh interpreter, imports included,
as a user's `rig import` runs.

    .venv/bin/python benchmarks/import_kawai.py      # a few seconds

Prints the median of ``--repeats`` runs of the whole command (wall time of the process)
and, in-process and warm, of the service call alone. Target (issue 38): < 2 s.
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
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    src, map_file = EXAMPLE / "hammer_damper_2K_17b.txt", EXAMPLE / "map.yaml"
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "kawai.h5"
        walls = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "rig", "-q", "import", str(src), "--map",
                            str(map_file), "--out", str(out), "--force"], check=True,
                           capture_output=True)
            walls.append(time.perf_counter() - t0)
        from rig.services import importer

        importer.import_files([src], map_file, out, force=True)  # warm the imports
        warm = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            res = importer.import_files([src], map_file, out, force=True)
            warm.append(time.perf_counter() - t0)
    print(f"rig import of {src.name} ({res.recordings[0].time.size} samples, "
          f"{len(res.trials)} strokes): command {statistics.median(walls):.2f} s "
          f"(median of {args.repeats}, fresh process), service call "
          f"{statistics.median(warm):.2f} s (warm)")


if __name__ == "__main__":
    main()
