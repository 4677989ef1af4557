"""Blows per second of `rig sweep` on 1 and 2 local processes and a 2-worker Dask cluster.

    .venv/bin/python benchmarks/sweep.py                 # 32 blows per executor
    .venv/bin/python benchmarks/sweep.py --blows 64 --project 4 8 16 64

The blow: the rigid base model under profiles/forte.yaml for 0.09 s (strike, let-off,
back check) with three parameters set per row (an LHS design), as `rig sweep` runs it:
rebuild the model with the row's values, settle its rest state, simulate, take the
metrics. The cluster is a distributed.LocalCluster (2 worker processes, 1 thread each,
on 127.0.0.1), started and warmed (model compiled, loaded) outside the timing.

Projection: a sweep of M blows on N workers takes M t_blow / N + M o, where t_blow is
one process's time per blow and o the per-task overhead the client and scheduler add
serially, measured from M no-op tasks on the 2-worker cluster (o = wall / M). So
blows/s(N) = 1 / (t_blow / N + o); it saturates at 1 / o. With B rows per task
(`rig sweep --batch B`) the overhead per blow is o / B.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
AXES = ("contacts.12.D=0.4:1.2", "springs.jack_torque=0.0035:0.005",
        "contacts.4.D=1.5:3.5")


def _noop(shared: object, x: object) -> object:
    return x


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--blows", type=int, default=32)
    ap.add_argument("--noop", type=int, default=500, help="no-op tasks for the overhead")
    ap.add_argument("--batch", type=int, default=8, help="rows per task, batched run")
    ap.add_argument("--project", type=int, nargs="*", default=[4, 8, 16, 32, 64])
    args = ap.parse_args()

    from distributed import Client, LocalCluster

    from rig.analysis import sweep as sw
    from rig.analysis.executor import DaskExecutor, LocalExecutor
    from rig.inputs import profiles
    from rig.model.action import ActionModel

    axes = [sw.Axis.parse(a) for a in AXES]
    study = sw.action_study(ActionModel(), profiles.load(ROOT / "profiles" / "forte.yaml"),
                            axes, duration=0.09)
    study.fn(study.shared, sw.make_design("lhs", axes, 2, seed=99)[0])  # compile, warm
    rates: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        def run(label: str, ex: object, seed: int, batch: int = 1) -> float:
            out = Path(tmp) / f"{label.replace(' ', '_')}.h5"
            t0 = time.perf_counter()
            res = sw.run_sweep(study, axes, "lhs", args.blows, out, ex,  # type: ignore[arg-type]
                               seed=seed, batch=batch)
            wall = time.perf_counter() - t0
            assert res.computed == args.blows
            rates[label] = args.blows / wall
            print(f"{label:<26} {args.blows} blows in {wall:6.2f} s: "
                  f"{rates[label]:6.2f} blows/s", flush=True)
            return wall

        run("1 local process", LocalExecutor(1), 1)
        with LocalExecutor(2) as lx:
            run("2 local processes", lx, 2)
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                          host="127.0.0.1", dashboard_address=None) as lc, \
                Client(lc) as client, DaskExecutor(client=client) as ex:
            # warm: every worker imports rig and loads the compiled model
            sw.run_sweep(study, axes, "lhs", 4, Path(tmp) / "warm.h5", ex, seed=7)
            run("Dask cluster, 2 workers", ex, 3)
            run(f"Dask, 2 workers, batch {args.batch}", ex, 4, args.batch)
            t0 = time.perf_counter()
            n = sum(1 for _ in ex.map(_noop, list(range(args.noop)), shared=None))
            overhead = (time.perf_counter() - t0) / n
    one = rates["1 local process"]
    t_blow = 1.0 / one
    print("\nefficiency vs one process (rate / (n x one-process rate)):")
    print(f"  2 local processes:        {rates['2 local processes'] / (2 * one):5.0%}")
    for label in ("Dask cluster, 2 workers", f"Dask, 2 workers, batch {args.batch}"):
        print(f"  {label + ':':<30}{rates[label] / (2 * one):5.0%}")
    print(f"\nper blow in one process t_blow = {t_blow * 1e3:.0f} ms; Dask per-task overhead "
          f"o = {overhead * 1e3:.2f} ms ({args.noop} no-op tasks, 2 workers)")
    print(f"projection blows/s(N) = 1 / (t_blow / N + o / B), B = 1 and B = {args.batch}:")
    for n_w in args.project:
        r = 1.0 / (t_blow / n_w + overhead)
        rb = 1.0 / (t_blow / n_w + overhead / args.batch)
        print(f"  {n_w:4d} workers: {r:8.1f} blows/s (efficiency {r / (n_w * one):4.0%}); "
              f"batch {args.batch}: {rb:8.1f} blows/s ({rb / (n_w * one):4.0%})")
    print(f"  saturation 1 / o: {1.0 / overhead:.0f} blows/s; with --batch B the overhead "
          f"per blow is o / B (batch {args.batch}: saturation "
          f"{args.batch / overhead:.0f} blows/s)")


if __name__ == "__main__":
    main()
