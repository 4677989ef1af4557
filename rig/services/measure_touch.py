"""`rig measure touch`: the action's down- and up-weight measured on the rig.

    result, record, run_file = measure_touch(cfg, Ramps(), trials=5, on_line=print)

The motor presses the key with slow force ramps (rig.calibration.touch): one trial is one
force profile run through the same torque loop, acquisition and run file as `rig run`
(rig.services.run; the simulated rig without hardware, the NI rig with it). The run file
is kept (``--out``, refused when it exists unless ``force``); the figures with their spread
go into a calibration-style record (``touch``, rig.calibration.records) in the records
folder, which later runs embed in their metadata (``touch_record``). Nothing is recorded
when a trial does not show the key going down and coming back.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from rig.calibration import records
from rig.calibration import touch as ct
from rig.calibration.settings import operator_name, records_folder
from rig.errors import InputError, RigError
from rig.inputs.config import RigConfig
from rig.recordings import runfile
from rig.services import run as run_svc


def count_m(cfg: RigConfig) -> float:
    """The key encoder's count (m of key dip): the finest motion it can see."""
    enc = [e for e in cfg.channels.encoders.values() if e.channel_name == "key_dip"]
    if not enc:
        raise InputError("channels.encoders: no encoder on the key (key_dip): rig measure "
                         "touch reads the key's motion from it")
    return abs(float(enc[0].si_per_count))


def measure_touch(cfg: RigConfig, ramps: ct.Ramps, *, trials: int = 5,
                  out: Path | None = None, force: bool = False, operator: str | None = None,
                  folder: Path | None = None, lockstep: bool = False,
                  on_line: Callable[[str], None] | None = None
                  ) -> tuple[ct.TouchMeasurement, Path, Path]:
    """Run ``trials`` presses, find where the key starts down and back up, write the record.
    Returns the measurement, the record's path and the run file's path."""
    if trials < 2:
        raise InputError(f"--trials: expected at least 2 (the spread needs them), got {trials}")
    ramps.check(cfg.limits.max_force_n)
    count = count_m(cfg)
    lc = records.lookup(cfg)["load_cell"]
    if lc.nominal:  # a data-sheet zero is tenths of a newton off: tens of grams
        raise InputError(f"calibration: the load cell has no calibration record in "
                         f"{records_folder(cfg)}: run `rig calibrate loadcell` first (the "
                         f"weights are read from its force)")
    zero_g = ct.grams(abs(float(records.read(Path(lc.record_file))["uncertainty"]
                                 ["offset_v_per_v"]) / lc.sensitivity))
    profile = ramps.profile(cfg.limits.max_force_n, cfg.limits.max_profile_s)
    rep = run_svc.run(profile, cfg, trials=trials, out=out, force=force, lockstep=lockstep,
                      on_line=on_line)
    if not rep.complete:
        raise RigError(f"run: {rep.path}: {rep.status}; nothing recorded")
    run = runfile.read(rep.path)
    result = ct.analyse([tr.channels for tr in run.trials], ramps, count)
    result.load_cell_zero_g = zero_g
    rec = records.build(
        "touch", cfg, identifier=cfg.channels.encoders[_key_encoder(cfg)].counter,
        operator=operator_name(cfg, operator), kind="slow force ramps at the key top",
        units=ct.UNITS, raw_points=result.raw_points(),
        fit={"sensitivity": None, "offset": None, **result.figures},
        uncertainty={**{name: {"spread_g": f["spread_g"], "k": 2.0}
                        for name, f in result.figures.items()},
                     "load_cell_zero_g": zero_g, "load_cell_record": lc.source},
        checks={"trials": trials, "per_trial_g": result.per_trial_g()},
        extra={"settings": ramps.__dict__ | {"key_encoder_count_m": count},
               "run_file": str(rep.path)})
    return result, records.write(records_folder(cfg, folder), rec), rep.path


def _key_encoder(cfg: RigConfig) -> str:
    return next(n for n, e in cfg.channels.encoders.items() if e.channel_name == "key_dip")


DOCS = {"down_weight": "force at which the key starts down from rest (slow ramp up)",
        "up_weight": "force at which the key starts back up from its pressed stop (ramp down)",
        "balance_weight": "(down-weight + up-weight) / 2",
        "friction": "(down-weight - up-weight) / 2"}


def summary(result: ct.TouchMeasurement) -> list[str]:
    """Lines for the terminal: grams at the key top with newtons beside, the spread (2 sd)."""
    lines = []
    for name in ct.FIGURES:
        f = result.figures[name]
        lines.append(f"{name:<16}{f['mean_g']:7.2f} g +- {f['spread_g']:.2f} "
                     f"({f['mean_n']:.4f} N)   {DOCS[name]}")
    n = len(result.trials)
    r = result.ramps
    lines.append(f"{n} trials; +- is 2 x the trials' standard deviation (k = 2); the load "
                 f"cell's zero adds +- {result.load_cell_zero_g:.2f} g to every weight (k = 2, "
                 f"its record); ramps {r.from_g:g} -> "
                 f"{r.to_g:g} -> {r.low_g:g} g at {r.rate_g_s:g} g/s; the key goes at "
                 f"{r.threshold_mm:g} mm, its start is where it left its elastic trend")
    return lines


def document(result: ct.TouchMeasurement, record: Path, run_file: Path) -> dict[str, Any]:
    """`rig measure touch --json`'s document (schema rig.measure-touch/1, docs/json.md)."""
    return {"schema": "rig.measure-touch/1", "figures": result.figures,
            "per_trial_g": result.per_trial_g(),
            "load_cell_zero_g": result.load_cell_zero_g,
            "record": str(record), "run_file": str(run_file)}
