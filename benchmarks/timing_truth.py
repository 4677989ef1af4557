"""How often the timing verdict speaks against the truth itself (rig.analysis.timing).

    PYTHONPATH=. .venv/bin/python benchmarks/timing_truth.py --first-seed 0 --seeds 20

For each seed of the wide diagnosis benchmark (benchmarks/diagnose_wide.py: its blows, window,
noise, base offsets, hidden library effects and user effect), the run is synthesized and the
events found in its trials are timed against two models: the truth model (the seed's base
offsets, hidden effects and user effect; not the sensor-side load-cell filter, which acts
on the measured force the model is driven by) and the default base model. A model is
flagged when some event lies outside its measured interval on the same side on every trial
(``Timing.unexplained``, what the diagnosis's timing verdict says). The truth should never
be flagged where the model run is the whole truth (no sensor-side filter); the base model,
a few per cent off and missing the hidden physics, often is. No diagnosis is run (a few
seconds a seed). Figures: docs/performance.md, "The blow's events".
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import diagnose_wide as wide  # noqa: E402 (the benchmark's draws, beside this file)


def run_seed(seed: int) -> tuple[bool, list, list, float, list]:
    """(sensor-side filter drawn, the truth's unexplained events, the base model's, s, the
    timed rows)."""
    from rig.analysis import measurement as ms
    from rig.analysis import timing as tm
    from rig.model.action import ActionModel

    d = wide.draw(seed)
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run.h5"
        wide.synth_run(d, d.blows, run, seed)
        meas = ms.load(run)
        windows = [min(d.window if d.window else ms.blow_window(m)[0], m.duration)
                   for m in meas]
        t0 = time.perf_counter()
        t = tm.timing([("base", ActionModel()), ("truth", wide.truth_model(d))], meas,
                      "force", windows)
        return (d.filter_hz is not None, t.unexplained("truth"), t.unexplained("base"),
                time.perf_counter() - t0, t.rows)


def _said(flags: Sequence[tuple[str, int, float, float]]) -> str:
    return ", ".join(f"{e} on {n} ({lo * 1e3:+.1f} to {hi * 1e3:+.1f} ms)"
                     for e, n, lo, hi in flags) or "-"


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--seeds", type=int, default=20)
    a = ap.parse_args(argv)
    seeds = list(range(a.first_seed, a.first_seed + a.seeds))
    banner = wide.reserved_banner(seeds)
    if banner:
        print(banner)
    fair = truth_flagged = base_flagged = 0
    rows = []
    for seed in seeds:
        filtered, truth, base, seconds, timed = run_seed(seed)
        if not filtered:
            rows += timed
        fair += not filtered
        truth_flagged += bool(truth) and not filtered
        base_flagged += bool(base)
        print(f"seed {seed}{' (sensor-side filter)' if filtered else ''}: truth {_said(truth)}; "
              f"base {_said(base)} [{seconds:.1f} s]", flush=True)
    print(f"truth flagged: {truth_flagged} of {fair} seeds without a sensor-side filter; "
          f"base model flagged: {base_flagged} of {len(seeds)} seeds")
    print("the truth's time of each event against the one found (seeds without a filter; "
          "ms): model - found, and how far beyond the found interval and 1.96 SD of the "
          "model's spread")
    print(f"{'event':<12}{'trials':>7}{'mean':>8}{'sd':>7}{'max |err|':>10}{'beyond>0':>9}"
          f"{'max beyond':>11}")
    for e in ("strike", "check", "key_bottom"):
        got = [r for r in rows if r.event == e and math.isfinite(r.models["truth"])]
        if not got:
            continue
        err = np.array([r.models["truth"] - r.measured for r in got]) * 1e3
        beyond = np.array([abs(r.beyond("truth", 0.0)) for r in got]) * 1e3
        print(f"{e:<12}{len(got):>7}{np.mean(err):>+8.2f}{np.std(err, ddof=1):>7.2f}"
              f"{np.max(np.abs(err)):>10.2f}{int(np.sum(beyond > 0)):>9}"
              f"{np.max(beyond):>11.2f}")


if __name__ == "__main__":
    main()
