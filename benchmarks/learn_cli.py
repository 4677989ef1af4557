"""Learning through the real loop (issue 41): `rig run --learn N` on the simulated rig in
real time, as a user runs it, then a plain `rig run` that uses the learned record.

    .venv/bin/python benchmarks/learn_cli.py                 # 10 runs, seeds 101-110
    .venv/bin/python benchmarks/learn_cli.py --runs 3 --learn 5 --first-seed 101

Each run is a fresh data folder (no earlier learned record) and a simulated rig whose seed
is the run's (sim.seed: the load cell's noise, its true sensitivity and offset, the plant's
draws), the built-in drive model, real-time loop (no --lockstep). As in the lab
(docs/running.md, "Calibrate, then a first run"), the load cell is calibrated first
(`rig calibrate loadcell --points`, 0-5-0 kg): uncalibrated, the simulated load cell's
drawn offset (up to +-2.4 N in seeds 101-103) is in every force the learner reads, and a
positive one is an error at the profile's 0 N that no push removes (measured: seeds
101-103 kept 8.78, 10.27, 4.43 %; the same code with the calibration: see
docs/performance.md). `rig run --learn` says so when the load cell has no record.
Prints per run the load cell's maximum error of
every learning trial (% of the profile's peak, as `rig run --learn` prints it), the kept
trial, whether a trial played before the kept one was better by the printed criterion (an
RMS error lower by more than the printed noise spread, or both a lower RMS and a lower
maximum error: must never happen), and the maximum error of the next plain run read from its
run file (the recorded load-cell force at each loop cycle's tick against the profile, as
`rig run --learn` reads its trials: rig.services.learn.load_cell_at_cycles) and whether its
RMS error is within the kept trial's plus the noise spread (the record holds); then the
median and worst of the kept and next-run figures. Per run also the loop's lateness in
the learning trials (p99, max, missed ticks), how far the load cell's force lagged the
demand (the drive's own lag is a few ms), and in how many cycles of the learning trials
and the next run the loop read an older sample than the recorded one (the plant process
behind real time; the maximum error of those late reads, ``commands/measured_force``, is
printed beside for the next run). Then the record is played once more on the same rig
with a noise-free load cell (``sim.load_cell_noise_n: 0``; the seed's true calibration and
plant): the table's own error, and from it the chance that the load cell's noise (white,
0.22 N) takes a plain run beyond 3 % (``beyond``); their sum over the runs is how many of
the next runs above 3 % the noise alone explains. Issue 41's targets: kept median
<= 2.5 %, worst <= 3 %; next run <= 3 %. Seeds 101 and up are the benchmark's block, never
used by the tests (tests/test_tracking.py uses seeds 1-5).
"""

from __future__ import annotations

import argparse
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rig.control import ilc
from rig.inputs import config, profiles
from rig.loop import backends
from rig.recordings import runfile
from rig.services import learn as learn_svc

ROOT = Path(__file__).resolve().parents[1]
RIG = Path(sys.executable).with_name("rig")
ROW = re.compile(r"^\s*(\d+)\s+([\d.]+)\s+([\d.]+)\s+\S+\.h5$")
TARGET_PCT = 3.0   # issue 41: the next plain run's maximum error, % of the peak
KEPT = re.compile(r"learned feedforward: trial (\d+) .*noise spread, ([\d.]+) %")


def plain_error(path: Path, profile: profiles.Profile, hz: float) -> dict[str, float]:
    t = learn_svc.grid(profile, hz)
    ref = np.array([profile.at(x) for x in t])
    return ilc.errors(ref, learn_svc.load_cell_at_cycles(path, t.size), profile.peak)


def beyond(error: np.ndarray, sigma: float, limit: float) -> float:
    """The chance that a run whose noise-free error is ``error`` (N) reads a maximum error
    beyond ``limit`` (N) on a load cell with white noise ``sigma`` (N): 1 - prod_j P(|e_j +
    w_j| <= limit)."""
    from scipy.stats import norm

    e = np.asarray(error, float)
    if sigma <= 0:
        return float(np.abs(e).max() > limit)
    inside = norm.cdf((limit - e) / sigma) - norm.cdf((-limit - e) / sigma)
    return float(1.0 - np.prod(inside))


def late_reads(path: Path, n: int) -> int:
    """Cycles at which the loop read an older load-cell sample than the recorded force at
    that cycle's tick (the plant process behind real time)."""
    seen = learn_svc.measured_force(path, n)
    return int(np.sum(np.abs(seen - learn_svc.load_cell_at_cycles(path, n)) > 1e-9))


def force_lag_s(demand: np.ndarray, force: np.ndarray, hz: float) -> float:
    """How far the load cell's force lags the demand written (s): from the demand's first
    rise through half its peak to the force's. The drive's own lag is a few ms; a plant
    process that cannot keep real time on a loaded machine delivers its samples late, and
    the loop then reads old forces (seen: 0.3 s and more)."""
    d, y = np.asarray(demand, float), np.asarray(force, float)
    half = 0.5 * float(d.max())
    if half <= 0 or not np.any(y >= half):
        return float("inf")
    return float(np.argmax(y >= half) - np.argmax(d >= half)) / hz


def one(seed: int, n: int, profile_path: Path, folder: Path,
        lockstep: bool = False) -> dict[str, object]:
    rig_yaml = folder / "rig.yaml"
    rig_yaml.write_text(f"name: bench\nbackend: sim\ndrive: {{port: sim}}\n"
                        f"data_folder: {folder}\nsim: {{seed: {seed}}}\n")
    points = folder / "masses.csv"
    points.write_text("mass_kg\n" + "\n".join(map(str, [0, 1, 2, 3, 4, 5, 4, 3, 2, 1, 0]))
                      + "\n")
    cal = subprocess.run([str(RIG), "calibrate", "loadcell", "--rig", str(rig_yaml),
                          "--points", str(points)], capture_output=True, text=True,
                         timeout=600)
    if cal.returncode != 0:
        raise SystemExit(f"seed {seed}: rig calibrate loadcell exited {cal.returncode}\n"
                         f"{cal.stdout[-2000:]}\n{cal.stderr[-2000:]}")
    t0 = time.perf_counter()
    step = ["--lockstep"] if lockstep else []
    res = subprocess.run([str(RIG), "run", str(profile_path), "--rig", str(rig_yaml),
                          "--learn", str(n), "-o", str(folder / "learn.h5"), *step],
                         capture_output=True, text=True, timeout=1800)
    learn_s = time.perf_counter() - t0
    if res.returncode != 0:
        raise SystemExit(f"seed {seed}: rig run --learn exited {res.returncode}\n"
                         f"{res.stdout[-2000:]}\n{res.stderr[-2000:]}")
    rows = [(int(m[1]), float(m[2]), float(m[3]))
            for m in map(ROW.match, res.stdout.splitlines()) if m]
    kept_m = KEPT.search(res.stdout)
    assert kept_m and rows, res.stdout
    kept, spread = int(kept_m[1]), float(kept_m[2])
    stop_m = re.search(r"learning stopped: (.*)", res.stdout)
    kept_max, kept_rms = next((mx, rms) for k, mx, rms in rows if k == kept)
    # better by the printed criterion: an RMS lower beyond the noise spread, or lower in
    # both RMS and maximum (the printed figures are rounded to 0.01 %)
    worse_kept = any(rms < kept_rms - spread - 0.01 or (rms < kept_rms and mx < kept_max)
                     for k, mx, rms in rows if k < kept)
    cfg = config.load(rig_yaml)
    # the loop's timing in the learning trials: how far the real-time figures are the loop's
    lat, missed, lag, late = [], 0, 0.0, 0
    prof = profiles.load(profile_path, force_limit=cfg.limits.max_force_n)
    t_grid = learn_svc.grid(prof, cfg.rates.control_hz)
    ref = np.array([prof.at(x) for x in t_grid])
    for k, _, _ in rows:
        late += late_reads(folder / f"learn-learn{k}.h5", t_grid.size)
        tr = runfile.read(folder / f"learn-learn{k}.h5").trials[0]
        lat.append(np.asarray(tr.commands["lateness"], float))
        missed += int(np.sum(tr.commands["missed"]))
        lag = max(lag, force_lag_s(tr.commands["demand"], tr.commands["measured_force"],
                                   cfg.rates.control_hz))
    lateness = np.concatenate(lat) * 1e3 if lat else np.zeros(1)
    res2 = subprocess.run([str(RIG), "run", str(profile_path), "--rig", str(rig_yaml),
                           "-o", str(folder / "again.h5"), *step],
                          capture_output=True, text=True, timeout=600)
    if res2.returncode != 0 or "using the learned feedforward" not in res2.stdout:
        raise SystemExit(f"seed {seed}: the plain run did not use the record\n{res2.stdout}")
    again = plain_error(folder / "again.h5", prof, cfg.rates.control_hz)
    # the table's own error: the record played once more on the same rig with a noise-free
    # load cell (the seed's true calibration and plant; only the noise off), and the chance
    # that the load cell's noise takes a plain run with it beyond the 3 % target
    quiet_yaml = folder / "quiet.yaml"
    quiet_yaml.write_text(rig_yaml.read_text().replace(
        f"sim: {{seed: {seed}}}", f"sim: {{seed: {seed}, load_cell_noise_n: 0}}"))
    res3 = subprocess.run([str(RIG), "run", str(profile_path), "--rig", str(quiet_yaml),
                           "-o", str(folder / "quiet.h5"), *step],
                          capture_output=True, text=True, timeout=600)
    if res3.returncode != 0 or "using the learned feedforward" not in res3.stdout:
        raise SystemExit(f"seed {seed}: the noise-free run did not use the record\n"
                         f"{res3.stdout}")
    own = ref - learn_svc.load_cell_at_cycles(folder / "quiet.h5", t_grid.size)
    p_over = beyond(own, backends.load_cell_noise_n(cfg), TARGET_PCT / 100.0 * prof.peak)
    seen = ilc.errors(ref, learn_svc.measured_force(folder / "again.h5", t_grid.size), prof.peak)
    return {"seed": seed, "trials": rows, "kept": kept, "kept_max": kept_max,
            "kept_rms": kept_rms, "spread": spread, "worse_kept": worse_kept,
            "next_max": again["max_pct"], "next_rms": again["rms_pct"],
            "holds": again["rms_pct"] <= kept_rms + spread + 0.01, "learn_s": learn_s,
            "p99_ms": float(np.percentile(lateness, 99)), "max_ms": float(lateness.max()),
            "missed": missed, "lag_s": lag, "stopped": stop_m[1] if stop_m else "",
            "late_learn": late, "late_next": late_reads(folder / "again.h5", t_grid.size),
            "next_seen_max": seen["max_pct"],
            "own_max": 100.0 * float(np.abs(own).max()) / prof.peak, "p_over": p_over}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--learn", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=101)
    ap.add_argument("--profile", type=Path, default=ROOT / "profiles" / "forte.yaml")
    ap.add_argument("--lockstep", action="store_true",
                    help="lock-step instead of real time: the same learner without the "
                         "loop's timing (not the acceptance figures)")
    ap.add_argument("--keep", type=Path, default=None,
                    help="keep each seed's folder (run files, records) under this folder")
    args = ap.parse_args()
    out = []
    print(f"rig run {args.profile.name} --learn {args.learn}, "
          f"{'lock-step' if args.lockstep else 'real time'}, seeds "
          f"{args.first_seed}-{args.first_seed + args.runs - 1}; max error % of the peak",
          flush=True)
    for i in range(args.runs):
        seed = args.first_seed + i
        if args.keep is not None:
            kept_dir = args.keep / f"seed{seed}"
            kept_dir.mkdir(parents=True, exist_ok=False)
            r = one(seed, args.learn, args.profile, kept_dir, args.lockstep)
        else:
            with tempfile.TemporaryDirectory() as d:
                r = one(seed, args.learn, args.profile, Path(d), args.lockstep)
        out.append(r)
        trials = ", ".join(f"{mx:.2f}" for _, mx, _ in r["trials"])  # type: ignore[attr-defined]
        if r["stopped"]:
            print(f"seed {r['seed']}: learning stopped: {r['stopped']}")
        print(f"seed {r['seed']}: trials {trials} -> kept trial {r['kept']} "
              f"({r['kept_max']:.2f} %, RMS {r['kept_rms']:.2f} %"
              f"{'; AN EARLIER TRIAL WAS BETTER' if r['worse_kept'] else ''}; spread "
              f"{r['spread']:.2f} %); next run "
              f"{r['next_max']:.2f} % (RMS {r['next_rms']:.2f} %, "
              f"{'within' if r['holds'] else 'BEYOND'} the kept RMS + spread); learning took "
              f"{r['learn_s']:.0f} s; loop lateness p99 {r['p99_ms']:.2f} ms, max "
              f"{r['max_ms']:.1f} ms, {r['missed']} missed ticks, load-cell force behind the "
              f"demand by up to {1e3 * float(r['lag_s']):.0f} ms in the learning trials; "
              f"late reads {r['late_learn']} cycles in the learning trials, {r['late_next']} "
              f"in the next run (its error by the loop's reads {r['next_seen_max']:.2f} %); "
              f"the table's own error (noise-free load cell) {r['own_max']:.2f} %, chance "
              f"of a plain run beyond {TARGET_PCT:g} % {100 * float(r['p_over']):.1f} %",
              flush=True)
    kept = [float(r["kept_max"]) for r in out]  # type: ignore[arg-type]
    nxt = [float(r["next_max"]) for r in out]  # type: ignore[arg-type]
    own = [float(r["own_max"]) for r in out]  # type: ignore[arg-type]
    print(f"the tables' own error (noise-free load cell): median {statistics.median(own):.2f} "
          f"%, worst {max(own):.2f} %; plain runs expected beyond {TARGET_PCT:g} % by the "
          f"noise alone: {sum(float(r['p_over']) for r in out):.2f} of {len(out)}")  # type: ignore[arg-type, misc]
    print(f"kept: median {statistics.median(kept):.2f} %, worst {max(kept):.2f} % "
          f"(targets 2.5 / 3 %); next run: median {statistics.median(nxt):.2f} %, worst "
          f"{max(nxt):.2f} % (target 3 %); kept worse than an earlier trial: "
          f"{sum(bool(r['worse_kept']) for r in out)} of {len(out)}; next-run RMS beyond the "
          f"kept's + spread: {sum(not r['holds'] for r in out)} of {len(out)}")


if __name__ == "__main__":
    main()
