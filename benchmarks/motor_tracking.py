"""Forte tracking on the simulated rig: `rig calibrate motor` and three `rig run`s.

The figures of docs/performance.md, "Calibration: motor tracking": the built-in
simulated rig (seed 4, lock-step) with the chosen drive variant; the calibration's
own tracking figures, then the maximum tracking error of a forte run with no lag
compensation, with the default 8 ms advance, and after the calibration.

    python benchmarks/motor_tracking.py [--variant single|asymmetric|step_size]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from rig.inputs import config
from rig.services import calibrate as svc
from rig.services import run as run_svc

FORTE = Path(__file__).resolve().parents[1] / "profiles" / "forte.yaml"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", default="single", choices=("single", "asymmetric",
                                                            "step_size"))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        data = {"name": "tracking", "backend": "sim", "drive": {"port": "sim"},
                "sim": {"realtime": False, "seed": 4, "drive_model": args.variant},
                "loop": {"rest_s": 0.1}, "data_folder": str(tmp)}
        cfg = config.from_mapping(data)
        bare = config.from_mapping({**data, "loop": {"rest_s": 0.1, "advance_s": 0}})
        none = run_svc.run(FORTE, bare, out=tmp / "none.h5")
        adv = run_svc.run(FORTE, cfg, out=tmp / "adv.h5")
        result, _, track = svc.calibrate_motor(cfg)
        comp = run_svc.run(FORTE, cfg, out=tmp / "comp.h5")
        fit = result.fit
        dyn = fit["dynamic_model"]
        print(f"drive model: {args.variant}")
        print(f"calibration: map {fit['sensitivity']:.3f} N/N, lag {fit['lag_s'] * 1e3:.2f} ms; "
              f"third-order K {dyn['K']:.3f}, Tw {dyn['Tw_s'] * 1e3:.2f} ms, zeta "
              f"{dyn['zeta']:.3f}, Tp3 {dyn['Tp3_s'] * 1e3:.2f} ms, RMS residual "
              f"{dyn['rms_residual_n']:.2f} N")
        for name, t in track.items():
            print(f"calibration tracking, {name}: {t['max_error_pct']:.1f} %")
        for name, r in (("no advance", none), ("8 ms advance", adv),
                        ("after the calibration", comp)):
            e = run_svc.tracking_error(r.path)
            print(f"rig run, {name}: {e['max_error_pct']:.1f} % ({e['max_error_n']:.2f} N)")


if __name__ == "__main__":
    main()
