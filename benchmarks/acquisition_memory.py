"""The acquisition's memory over many trials: its writing path alone, fast.

    python benchmarks/acquisition_memory.py                 # 200 trials of 2 s
    python benchmarks/acquisition_memory.py --trials 40 --cache-kb 0   # HDF5's default cache
    python benchmarks/acquisition_memory.py --trials 20 --no-sync    # the journal not synced

Feeds rig.loop.acquisition.Acquisition (the class the acquisition process runs) 2 kHz rows of
the built-in simulated rig's width in 20 ms reads, the loop's 500 Hz records, and flushes
every 0.24 s into a run file and its journal, as the process does; prints the process's
resident memory (RSS) every ``--every`` trials, its growth from the first trial, and the
time spent flushing. ``--cache-kb`` sets HDF5's metadata cache of the run file (default:
rig.recordings.runfile.METADATA_CACHE_BYTES; 0 = HDF5's own adaptive default). ``--no-sync``: the
journal's records are not synced to the disk at each flush (rig.journal.JournalWriter.sync;
the difference in flushing time is the sync's cost, also printed per flush). The whole run
with its processes: benchmarks/soak.py.
"""

from __future__ import annotations

import argparse
import queue
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np


def rss_mb() -> float:
    for ln in Path("/proc/self/status").read_text().splitlines():
        if ln.startswith("VmRSS:"):
            return int(ln.split()[1]) / 1024
    return float("nan")


class _NoMessages:
    def get_nowait(self) -> Any:
        raise queue.Empty


def main() -> int:
    from rig.calibration import records as cal_records
    from rig.inputs import config
    from rig.loop import journal
    from rig.loop.acquisition import Acquisition
    from rig.recordings import runfile
    from rig.sensors import table as sensor_table
    from rig.sim_backend.daq import row_width

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=200)
    ap.add_argument("--trial-s", type=float, default=2.0, help="seconds of samples per trial")
    ap.add_argument("--cache-kb", type=int, default=runfile.METADATA_CACHE_BYTES // 1024)
    ap.add_argument("--every", type=int, default=20, help="print every N trials")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--no-sync", action="store_true", help="do not sync the journal")
    args = ap.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="rig-acqmem-"))
    cfg = config.from_mapping({"backend": "sim", "data_folder": str(out)})
    path = out / "acq.h5"
    for p in (path, journal.journal_path(path)):
        p.unlink(missing_ok=True)
    writer = runfile.RunWriter(path, "measured", {"note": "benchmark"}, crash_safe=True)
    if args.cache_kb:
        runfile.limit_metadata_cache(writer.file, args.cache_kb * 1024)
    else:  # HDF5's default adaptive cache
        import h5py

        h5py.File(path.with_suffix(".default.h5"), "w").close()
        d = h5py.File(path.with_suffix(".default.h5"), "r")
        writer.file.id.set_mdc_config(d.id.get_mdc_config())
        d.close()
    jw = journal.JournalWriter.create(path, durable=not args.no_sync)
    sync_s, syncs = [0.0], [0]
    plain_sync = jw.sync

    def timed_sync() -> None:
        t0 = time.perf_counter()
        plain_sync()
        sync_s[0] += time.perf_counter() - t0
        syncs[0] += 1

    jw.sync = timed_sync  # type: ignore[method-assign]
    acq = Acquisition(cfg, cal_records.lookup(cfg), writer, _NoMessages(), None, jw)
    width = row_width(cfg)
    col = sensor_table.column(cfg, sensor_table.SAMPLE)
    rate = cfg.rates.acquisition_hz
    per_trial = int(args.trial_s * rate)
    read = int(0.02 * rate)
    n = 0
    flush_s = 0.0
    first = None
    rng = np.random.default_rng(1)
    print(f"cache {args.cache_kb or 'HDF5 default'} KB; {args.trials} trials of "
          f"{args.trial_s} s; journal {'not ' if args.no_sync else ''}synced; {out}")
    for k in range(args.trials):
        acq.handle(("trial", k, n, n + per_trial // 10))
        for j in range(per_trial // read):
            rows = rng.standard_normal((read, width)) * 1e-3
            rows[:, col] = np.arange(n, n + read)
            n += read
            acq.take(rows)
            if j % 12 == 11:
                acq.handle(("commands", k, {c: rng.standard_normal(30)
                                            for c in sensor_table.COMMAND_UNITS}))
                t0 = time.perf_counter()
                acq.write_pending()
                flush_s += time.perf_counter() - t0
        acq.write_pending()
        now = rss_mb()
        first = now if first is None else first
        if (k + 1) % args.every == 0 or k == 0 or k + 1 == args.trials:
            print(f"trial {k + 1:4d}: RSS {now:7.1f} MB ({now - first:+.1f} MB since trial 1), "
                  f"flushing {flush_s / ((k + 1) * args.trial_s) * 100:.1f} % of real time",
                  flush=True)
    acq.finish("complete", {}, {})
    jw.close()
    print(f"acquisition writer: RSS growth {rss_mb() - (first or 0):+.1f} MB over "
          f"{args.trials} trials; flushing {flush_s:.2f} s in all, of which syncing the "
          f"journal {sync_s[0]:.2f} s ({syncs[0]} syncs, "
          f"{1e3 * sync_s[0] / max(syncs[0], 1):.2f} ms each)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
