"""Soak: a long `rig run` on the real-time simulated rig; memory, lost samples, lateness.

    python benchmarks/soak.py                      # 10 minutes of forte blows
    python benchmarks/soak.py --minutes 3 --out /tmp/soak
    python benchmarks/soak.py --trials 200          # issue 37's 200-trial soak
    python benchmarks/soak.py --trials 200 --lockstep   # the same, paced by the plant

Runs `python -m rig run PROFILE --trials N` (N trials fill the requested time) in a
subprocess and prints: the resident memory (RSS) of each of its processes (the run's
process, the acquisition process, the simulated plant) shortly after the loop started and
just before it ended, with the change in % (and its private part, RssAnon, apart from the
shared memory it touched, RssShmem: the simulated card's ring fills its pages as it goes
round the first time, acquisition.buffer_s, which is no leak); the samples acquired
against the sample counter (lost samples = counter span - samples in the file, gaps
between trials counted); the loop's lateness per minute of the run (median, p99, max,
late cycles). Goals: 0 lost samples, RSS flat (issue 37: no process growing by more than
5 MB), lateness not growing. The acquisition's writing path alone, faster:
benchmarks/acquisition_memory.py.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]


def _rss_mb(pid: int, field: str = "VmRSS") -> float | None:
    """A process's resident memory (MB): ``VmRSS`` in all, ``RssAnon`` its private memory
    (what a leak grows), ``RssShmem`` the shared memory it touched (the simulated card's
    ring, acquisition.buffer_s: its pages count once touched, up to the ring's size)."""
    try:
        for ln in Path(f"/proc/{pid}/status").read_text().splitlines():
            if ln.startswith(field + ":"):
                return int(ln.split()[1]) / 1024
    except OSError:
        return None
    return None


def _tree(pid: int) -> dict[str, int]:
    """The run's processes by role: main, acquisition, plant (spawned children)."""
    out = {"main": pid}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            cmd = (d / "cmdline").read_bytes()
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) != pid or b"spawn_main" not in cmd:
            continue
        fds = []
        with contextlib.suppress(OSError):
            fds = [os.readlink(f) for f in (str(p) for p in (d / "fd").iterdir())]
        out["acquisition" if any(f.endswith(".h5") for f in fds) else "plant"] = int(d.name)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="length of the run (default 10)")
    ap.add_argument("--trials", type=int, default=None,
                    help="this many trials instead of --minutes' worth")
    ap.add_argument("--profile", type=Path, default=ROOT / "profiles" / "forte.yaml")
    ap.add_argument("--out", type=Path, default=None, help="folder for the rig config and file")
    ap.add_argument("--light", action="store_true",
                    help="simulate the action without effects and strain gauge (a plant that "
                         "keeps up on a loaded machine)")
    ap.add_argument("--buffer-s", type=float, default=None,
                    help="acquisition.buffer_s (the simulated card buffer; a larger one rides "
                         "out a plant starved for seconds by other load)")
    ap.add_argument("--drive-timeout-s", type=float, default=None,
                    help="drive.timeout_s (the simulated drive's thread answers late when the "
                         "machine is overloaded)")
    ap.add_argument("--sample-s", type=float, default=5.0, help="RSS sampling period (s)")
    ap.add_argument("--lockstep", action="store_true",
                    help="the simulated rig steps as fast as it can instead of in real time "
                         "(rig run --lockstep): the same processes, files and writers, with the "
                         "plant pacing the loop, so a loaded machine cannot abort the run")
    args = ap.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="rig-soak-"))
    out.mkdir(parents=True, exist_ok=True)
    cfg = {"name": "soak", "backend": "sim", "drive": {"port": "sim"},
           "sim": {"realtime": not args.lockstep}, "data_folder": str(out)}
    if args.drive_timeout_s is not None:
        cfg["drive"]["timeout_s"] = args.drive_timeout_s  # type: ignore[index]
    if args.buffer_s is not None:
        cfg["acquisition"] = {"buffer_s": args.buffer_s}
    if args.light:
        cfg["sim"]["effects"] = []  # type: ignore[index]
        cfg["channels"] = {"strain_gauge": {"enabled": False}}
    rig_file = out / "soak-rig.yaml"
    rig_file.write_text(yaml.safe_dump(cfg))

    from rig.inputs import config, profiles

    rc = config.from_mapping(cfg)
    prof = profiles.load(args.profile, force_limit=rc.limits.max_force_n)
    per_trial = rc.loop.settle_s + prof.duration + rc.loop.rest_s
    trials = args.trials or max(1, math.ceil(args.minutes * 60 / per_trial))
    run_file = out / "soak.h5"
    if run_file.exists():
        run_file.unlink()
    print(f"soak: {trials} trials of {prof.name} ({per_trial:.2f} s each, "
          f"{trials * per_trial / 60:.1f} min), files in {out}", flush=True)
    cmd = [sys.executable, "-m", "rig", "run", str(args.profile), "--rig", str(rig_file),
           "--trials", str(trials), "-o", str(run_file)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert proc.stdout is not None
    lines: list[str] = []
    for ln in proc.stdout:  # until the loop starts
        lines.append(ln.rstrip())
        if ln.startswith("running "):
            break
    time.sleep(min(10.0, args.sample_s))
    roles = _tree(proc.pid)
    fields = ("VmRSS", "RssAnon", "RssShmem")
    first = {(r, f): _rss_mb(p, f) for r, p in roles.items() for f in fields}
    last = dict(first)
    t0 = time.monotonic()
    import threading

    rest: list[str] = []
    reader = threading.Thread(target=lambda: rest.extend(ln.rstrip() for ln in proc.stdout),
                              daemon=True)  # type: ignore[union-attr]
    reader.start()
    series: list[tuple[float, dict[str, float | None]]] = []  # (s, VmRSS per process)
    while proc.poll() is None:
        time.sleep(args.sample_s)
        now = {(r, f): _rss_mb(p, f) for r, p in roles.items() for f in fields}
        if all(v is not None for v in now.values()):
            last = now
            series.append((time.monotonic() - t0, {r: now[(r, "VmRSS")] for r in roles}))
    reader.join(timeout=5)
    lines += rest
    print(f"rig run exit code {proc.returncode} after {time.monotonic() - t0:.0f} s of "
          f"sampling; its last line: {lines[-1] if lines else ''}")
    print("RSS (MB) after the loop started -> before it ended (in all; private, RssAnon; "
          "shared memory touched, RssShmem):")
    for r, p in roles.items():
        a, b = first.get((r, "VmRSS")), last.get((r, "VmRSS"))
        if a and b:
            parts = []
            for f in fields[1:]:
                fa, fb = first.get((r, f)), last.get((r, f))
                if fa is not None and fb is not None:
                    parts.append(f"{f} {fa:.1f} -> {fb:.1f} ({fb - fa:+.1f} MB)")
            print(f"  {r:12s} (pid {p}): {a:7.1f} -> {b:7.1f}  ({b - a:+.1f} MB, "
                  f"{(b - a) / a * 100:+.1f} %); {'; '.join(parts)}")

    if len(series) >= 5:  # growth still going on, or done early (a warm-up)?
        print("RSS (MB) through the run, at 0/25/50/75/100 % of the sampling:")
        for q in (0, 0.25, 0.5, 0.75, 1.0):
            ts, rss = series[min(len(series) - 1, int(q * (len(series) - 1)))]
            print(f"  {ts:6.0f} s  " + "  ".join(f"{r} {v:.1f}" for r, v in rss.items()
                                                 if v is not None))

    with h5py.File(run_file, "r") as f:
        status = str(f.attrs["status"])
        samples, counters, ticks, late, missed = 0, [], [], [], []
        for name in sorted(k for k in f if k.startswith("trial_")):
            g = f[name]
            if "channels" not in g or "commands" not in g:
                continue
            s = g["channels/sample"][:]
            samples += s.size
            counters.append(s)
            ticks.append(g["commands/tick"][:])
            late.append(g["commands/lateness"][:])
            missed.append(g["commands/missed"][:])
        hz = rc.rates.control_hz
    s = np.concatenate(counters) if counters else np.zeros(0)
    span = int(s.max() - s.min() + 1) if s.size else 0
    gaps = int(np.sum(np.diff(s) != 1)) if s.size else 0
    print(f"file status {status}; samples {samples}, counter span {span}, lost "
          f"{span - samples}, counter jumps {gaps}")
    if not ticks:
        return 1
    tick = np.concatenate(ticks)
    lat = np.concatenate(late) * 1e3
    miss = np.concatenate(missed)
    minute = (tick / hz // 60).astype(int)
    print("loop lateness per minute (ms): minute  median    p99     max  late(>"
          f"{rc.limits.late_threshold_s * 1e3:g} ms)  missed")
    for m in np.unique(minute):
        sel = minute == m
        x = lat[sel]
        print(f"  {m:3d}  {np.median(x):7.3f}  {np.percentile(x, 99):7.3f}  {x.max():7.3f}  "
              f"{int(np.sum(x > rc.limits.late_threshold_s * 1e3)):6d}  {int(miss[sel].sum()):6d}")
    return 0 if status == "complete" and span == samples else 1


if __name__ == "__main__":
    raise SystemExit(main())
