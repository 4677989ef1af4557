"""What the simulated rig's friction costs on a slow press (issue 40):

    .venv/bin/python benchmarks/slow_press.py [--repeats 3]

Simulates a 5 s slow press of the base model (0 -> 30 g at the key front in 0.5 s, then a
ramp to 60 g at 6.67 g/s) with ``ActionModel.simulate`` (the default integrator, the kernel
compiled first) on the shipped regularised friction laws and with ``sim.friction: stick``
(Dahl's law at every pin and contact with friction), and prints the best wall and CPU time
of ``--repeats`` runs, the integrator's steps, and where the key went 0.25 mm.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from rig.calibration import touch as ct
from rig.inputs import config, profiles
from rig.model.action import ActionModel
from rig.sim_backend.simrig import sim_parameters


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    press = profiles.from_points([[0.0, 0.0], [0.5, ct.newtons(30.0)],
                                  [5.0, ct.newtons(60.0)]], name="slow-press")
    for friction in ("regularised", "stick"):
        cfg = config.from_mapping({"backend": "sim", "sim": {"effects": [],
                                                             "friction": friction}})
        model = ActionModel(sim_parameters(cfg), output_rate=cfg.rates.acquisition_hz)
        model.simulate(profiles.from_points([[0.0, 0.0], [0.01, 0.0]], name="warm"))
        walls, cpus = [], []
        for _ in range(args.repeats):
            w0, c0 = time.perf_counter(), time.process_time()
            res = model.simulate(press)
            walls.append(time.perf_counter() - w0)
            cpus.append(time.process_time() - c0)
        if not res.success:
            raise SystemExit(f"{friction}: the press failed: {res.message}")
        i = int(np.argmax(res.channels["key_dip"] > 0.25e-3))
        went = f"{ct.grams(float(res.channels['force'][i])):.2f} g" if i else "never"
        print(f"{friction:12s} 5 s press: best {min(walls):.2f} s wall, {min(cpus):.2f} s CPU "
              f"({args.repeats} runs); {res.stats['steps']:.0f} steps, "
              f"{res.stats['rejected']:.0f} rejected; the key went 0.25 mm at {went}")


if __name__ == "__main__":
    main()
