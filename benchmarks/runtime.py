"""Runtime benchmark for `rig run`: loop lateness on the simulated rig in real time next to a
bare pacing loop run at the same time, and the acquisition's sustained storage rate.

    .venv/bin/python benchmarks/runtime.py [--seconds 32] [--rigid] [--second-bare]

Prints figures and ratios (no pass/fail): targets are p99 lateness < 0.5 ms at 500 Hz, no more
missed cycles than the bare loop, and >= 20x headroom over 2 kHz x 5 channels.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from rig import calrecords, config, pacing, runfile
from rig.acquisition import Acquisition
from rig.services import run as svc


def bare_loop(seconds: float, q: mp.Queue, go: Any, priority: int) -> None:
    """A 500 Hz pacing loop doing no work (the VM's own stalls), in its own process, paced and
    scheduled as the run's loop is (sleep then spin, timer slack, the same real-time class)."""
    pacing.set_timer_slack()
    q.put("ready")
    go.wait()
    rt = pacing.realtime_priority(priority)
    dt = 0.002
    n = int(seconds / dt)
    late = np.empty(n)
    missed = 0
    events: list[tuple[float, int]] = []  # (deadline of the first missed tick, ticks missed)
    t0 = time.perf_counter() + 0.01
    i = 0
    k = 0
    while k < n:
        now = pacing.sleep_until(t0 + i * dt)
        behind = int((now - t0) / dt)
        if behind > i:
            missed += behind - i
            events.append((t0 + i * dt, behind - i))
            i = behind
        late[k] = now - (t0 + i * dt)
        k += 1
        i += 1
    q.put((float(np.median(late)), float(np.percentile(late, 99)), float(late.max()), missed,
           rt, events))


def shared_events(a: list[tuple[float, int]], b: list[tuple[float, int]], dt: float = 0.002,
                  slack: float = 0.004) -> int:
    """How many of ``a``'s miss events (start, ticks) overlap one of ``b``'s within ``slack``:
    a stall both loops saw is the machine's, one only one loop saw is that loop's (or its CPU's)."""
    n = 0
    for s, m in a:
        if any(t - slack <= s + (m + 1) * dt and s - slack <= t + (k + 1) * dt for t, k in b):
            n += 1
    return n


def rig_events(path: Path, t_start: float, dt: float = 0.002) -> list[tuple[float, int]]:
    """The run's miss events on the same clock as the bare loop's (perf_counter)."""
    r = runfile.read(path)
    out = []
    for tr in r.trials:
        for tick, m in zip(tr.commands["tick"], tr.commands["missed"], strict=True):
            if m > 0:
                out.append((t_start + (int(tick) - int(m)) * dt, int(m)))
    return out


def loop_benchmark(seconds: float, tmp: Path, rigid: bool = False,
                   priority: int | None = None, second_bare: bool = False) -> None:
    prof = tmp / "long.yaml"
    prof.write_text("name: long\nsegments:\n  - {hold: 0.02}\n  - {ramp: 0.08, to: 30}\n"
                    "  - {hold: 0.2}\n  - {ramp: 0.04, to: 0}\n  - {hold: 0.26}\n")
    trials = int(np.ceil(seconds / 1.0))
    # measure, do not abort: a late streak is reported in the figures instead
    loop: dict[str, Any] = {"rest_s": 0.3}
    if priority is not None:
        loop["realtime_priority"] = priority
    cfg = config.builtin_sim(loop=loop, data_folder=str(tmp),
                             limits={"max_late_cycles_in_a_row": 100000},
                             **({"sim": {"effects": []}, "channels": {"strain_gauge": {
                                 "enabled": False}}} if rigid else {}))
    ctx = mp.get_context("spawn")
    q: mp.Queue = ctx.Queue()
    go = ctx.Event()
    bare = ctx.Process(target=bare_loop, args=(trials * 1.0, q, go, cfg.loop.realtime_priority))
    bare.start()
    assert q.get(timeout=60) == "ready"
    q2: mp.Queue = ctx.Queue()
    bare2 = None
    if second_bare:  # control: how far apart two identical bare loops are
        bare2 = ctx.Process(target=bare_loop, args=(trials * 1.0, q2, go,
                                                    cfg.loop.realtime_priority))
        bare2.start()
        assert q2.get(timeout=60) == "ready"

    started: dict[str, Any] = {"done": False, "t_start": 0.0}

    def start_bare(c: svc.CycleContext) -> None:
        if not started["done"]:
            go.set()
            started["done"] = True
            started["t_start"] = float(getattr(c.daq, "t_start", 0.0))

    rep = svc.run(prof, cfg, trials=trials, out=tmp / "bench.h5", on_cycle=start_bare)
    bare.join()
    b = q.get()
    lat = rep.lateness
    print(f"rig run, simulated rig in real time (effects {cfg.sim.effects}), {trials} forte "
          f"trials, {lat['cycles']:.0f} cycles ({lat['cycles'] / 500:.1f} s): {rep.status}")
    print(f"  loop lateness: median {lat['median_s'] * 1e3:.3f} ms, p99 {lat['p99_s'] * 1e3:.3f} "
          f"ms, max {lat['max_s'] * 1e3:.3f} ms, missed {lat['missed']:.0f}, late (>1 ms) "
          f"{lat['late_cycles']:.0f}")
    print(f"  bare loop:     median {b[0] * 1e3:.3f} ms, p99 {b[1] * 1e3:.3f} ms, max "
          f"{b[2] * 1e3:.3f} ms, missed {b[3]}")
    print(f"  scheduling: rig loop {_sched(lat['realtime_priority'])}, bare loop "
          f"{_sched(cfg.loop.realtime_priority if b[4] else 0)}")
    print(f"  ratio p99 rig/bare {lat['p99_s'] / max(b[1], 1e-9):.1f}; p99 target 0.5 ms: "
          f"{'met' if lat['p99_s'] < 5e-4 else 'NOT met'}; missed rig {lat['missed']:.0f} vs "
          f"bare {b[3]}")
    ev = rig_events(rep.path, started["t_start"])
    print(f"  miss events: rig {len(ev)} ({len(ev) - shared_events(ev, b[5])} not shared with the "
          f"bare loop), bare {len(b[5])} ({len(b[5]) - shared_events(b[5], ev)} not shared with "
          f"the rig loop)")
    if bare2 is not None:
        bare2.join()
        c2 = q2.get()
        print(f"  control, a second bare loop: missed {c2[3]}, p99 {c2[1] * 1e3:.3f} ms; events "
              f"{len(c2[5])} ({len(c2[5]) - shared_events(c2[5], b[5])} not shared with the first "
              f"bare loop, which had {len(b[5]) - shared_events(b[5], c2[5])} of its own)")


def _sched(priority: float) -> str:
    return f"SCHED_FIFO {priority:.0f}" if priority else "normal (SCHED_OTHER)"


def acquisition_benchmark(tmp: Path, seconds: float = 5.0) -> None:
    """Store blocks as fast as possible through the acquisition's own write path."""
    cfg = config.builtin_sim()
    cals = calrecords.lookup(cfg)
    width = len(calrecords.raw_names(cfg))
    w = runfile.RunWriter(tmp / "acq.h5", "measured", {}, crash_safe=True)

    class Q:
        def get_nowait(self):
            import queue
            raise queue.Empty

    acq = Acquisition(cfg, cals, w, Q(), None)
    acq._handle(("trial", 0, 0, 0))
    block = 40  # 20 ms at 2 kHz, the default read period
    n = 0
    t0 = time.perf_counter()
    last_flush = t0
    while time.perf_counter() - t0 < seconds:
        rows = np.zeros((block, width))
        rows[:, 0] = n + np.arange(block)
        acq.take(rows)
        n += block
        if time.perf_counter() - last_flush > 0.25:
            acq.write_pending()
            last_flush = time.perf_counter()
    acq.write_pending()
    wall = time.perf_counter() - t0
    w.close("complete")
    rate = n / wall
    channels = width - 1  # load cell, strain, 3 encoders
    print(f"acquisition storage: {rate:,.0f} samples/s x {channels} raw channels (+ calibrated) "
          f"in {block}-sample blocks, flushed every 0.25 s; headroom vs 2 kHz x 5 channels "
          f"{rate * channels / (2000 * 5):.0f}x")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=32.0)
    ap.add_argument("--rigid", action="store_true", help="rigid model, no strain gauge")
    ap.add_argument("--priority", type=int, default=None,
                    help="loop.realtime_priority for both loops (0 = normal scheduling)")
    ap.add_argument("--second-bare", action="store_true",
                    help="control: a second bare loop at the same time (bare vs bare spread)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        loop_benchmark(args.seconds, tmp, args.rigid, args.priority, args.second_bare)
        acquisition_benchmark(tmp)


if __name__ == "__main__":
    main()
