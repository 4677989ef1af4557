"""`rig measure touch`: the action's down- and up-weight measured on the rig.

    result, record, run_file = measure_touch(cfg, Ramps(), trials=5, on_line=print)

The motor presses the key with slow force ramps (rig.calibration.touch): one trial is one
force profile run through the same torque loop, acquisition and run file as `rig run`
(rig.services.run; the simulated rig without hardware, the NI rig with it). The first
``ramps.condition`` trials of the run file are the conditioning presses, not analysed; the
rule ``auto`` is resolved here from the rig (``resolve_rule``). The run file
is kept (``--out``, refused when it exists unless ``force``); the figures with their spread
go into a calibration-style record (``touch``, rig.calibration.records) in the records
folder, which later runs embed in their metadata (``touch_record``). Nothing is recorded
when a trial does not show the key going down and coming back.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rig.calibration import records
from rig.calibration import touch as ct
from rig.calibration.settings import operator_name, records_folder
from rig.errors import InputError, RigError
from rig.inputs.config import RigConfig
from rig.recordings import runfile
from rig.services import run as run_svc

if TYPE_CHECKING:
    from rig.model.action import ActionModel

LET_GO_S = 0.05  # s: the key force down from low_g to none after a trial (the drive's step)


def count_m(cfg: RigConfig) -> float:
    """The key encoder's count (m of key dip): the finest motion it can see."""
    enc = [e for e in cfg.channels.encoders.values() if e.channel_name == "key_dip"]
    if not enc:
        raise InputError("channels.encoders: no encoder on the key (key_dip): rig measure "
                         "touch reads the key's motion from it")
    return abs(float(enc[0].si_per_count))


def resolve_rule(cfg: RigConfig, rule: str) -> str:
    """``auto``: ``onset`` on the simulated rig with the regularised friction laws (no force
    at zero speed: the key creeps off at the frictionless balance, so its onset is that
    balance), ``travel`` on every action that sticks (a real one, ``sim.friction: stick``)."""
    if rule != "auto":
        return rule
    return "onset" if cfg.simulated and cfg.sim.friction == "regularised" else "travel"


def measure_touch(cfg: RigConfig, ramps: ct.Ramps, *, trials: int = 5,
                  out: Path | None = None, force: bool = False, operator: str | None = None,
                  folder: Path | None = None, lockstep: bool = False,
                  on_line: Callable[[str], None] | None = None
                  ) -> tuple[ct.TouchMeasurement, Path, Path]:
    """Run the conditioning presses and ``trials`` recorded presses, read where the key goes
    down and back up by the rule, write the record.
    Returns the measurement, the record's path and the run file's path."""
    if trials < 2:
        raise InputError(f"--trials: expected at least 2 (the spread needs them), got {trials}")
    ramps.check(cfg.limits.max_force_n)
    ramps = replace(ramps, rule=resolve_rule(cfg, ramps.rule))
    count = count_m(cfg)
    lc = records.lookup(cfg)["load_cell"]
    if lc.nominal:  # a data-sheet zero is tenths of a newton off: tens of grams
        raise InputError(f"calibration: the load cell has no calibration record in "
                         f"{records_folder(cfg)}: run `rig calibrate loadcell` first (the "
                         f"weights are read from its force)")
    zero_g = ct.grams(abs(float(records.read(Path(lc.record_file))["uncertainty"]
                                 ["offset_v_per_v"]) / lc.sensitivity))
    profile = ramps.profile(cfg.limits.max_force_n, cfg.limits.max_profile_s)
    if on_line is not None and ramps.condition:
        on_line(f"{ramps.condition} conditioning press{'es' if ramps.condition > 1 else ''} "
                f"first (not recorded), then {trials} trials; the weight is read by the "
                f"{ramps.rule} rule")
    rep = run_svc.run(profile, cfg, trials=ramps.condition + trials, out=out, force=force,
                      lockstep=lockstep, on_line=on_line)
    if not rep.complete:
        raise RigError(f"run: {rep.path}: {rep.status}; nothing recorded")
    run = runfile.read(rep.path)
    result = ct.analyse([tr.channels for tr in run.trials[ramps.condition:]], ramps, count)
    result.load_cell_zero_g = zero_g
    rec = records.build(
        "touch", cfg, identifier=cfg.channels.encoders[_key_encoder(cfg)].counter,
        operator=operator_name(cfg, operator), kind="slow force ramps at the key top",
        units=ct.UNITS, raw_points=result.raw_points(),
        fit={"sensitivity": None, "offset": None, **result.figures},
        uncertainty={**{name: {"spread_g": f["spread_g"], "k": 2.0}
                        for name, f in result.figures.items()},
                     "load_cell_zero_g": zero_g, "load_cell_record": lc.source},
        checks={"trials": trials, "conditioning_presses": ramps.condition,
                "rule": ramps.rule, "per_trial_g": result.per_trial_g()},
        extra={"settings": ramps.__dict__ | {"key_encoder_count_m": count},
               "run_file": str(rep.path)})
    return result, records.write(records_folder(cfg, folder), rec), rep.path


def model_returns(model: ActionModel, cfg: RigConfig, ramps: ct.Ramps, *,
                  trials: int = 5) -> list[dict[str, Any]]:
    """What `rig measure touch` of ``cfg`` with ``ramps`` and ``trials`` presses the
    model's key to, and what a slow return from each stop then measures
    (rig.model.touch.stop_returns; docs/touch.md, "The up-weight after a press in time"):
    the same presses in time as the rig's run -- per trial ``loop.settle_s`` at no force,
    the ramps' profile, the force down to none in ``LET_GO_S`` and ``loop.rest_s`` at none,
    the conditioning presses first -- and the quasi-static return from where each recorded
    press holds the key at its stop (the end of its hold at ``to_g``). One return per
    recorded trial."""
    import numpy as np

    from rig.model import touch

    points, period = ramps.presses(ramps.condition + trials, let_go_s=LET_GO_S,
                                   gap_s=cfg.loop.rest_s, lead_s=cfg.loop.settle_s)
    t, f = np.array(points).T
    holds = [i * period + cfg.loop.settle_s + ramps.knots()[3][0]
             for i in range(ramps.condition, ramps.condition + trials)]
    return touch.stop_returns(model, t, f, holds, threshold_m=ramps.threshold_mm * 1e-3)


def returns_summary(returns: list[dict[str, Any]]) -> dict[str, Any]:
    """``model_returns``' presses summed up: the up-weights' mean (``up_weight_g``) and
    spread (2 sd, ``spread_g``; 0 for one press), each press's up-weight
    (``per_press_g``), where its key stopped (``stops``: the stroke stops whose contact is
    closed, rig.model.touch.STROKE_STOPS, joined by " and "; "no stop" when none is),
    its key-front dip there (``stop_dip_m``) and how far its jack stood off its whippen
    stop (``jack_off_stop_m``: contact 5's opening, 0 when closed)."""
    import numpy as np

    from rig.model import touch

    ups = np.array([float(r["up_weight"]) for r in returns])
    stops = [" and ".join(name for cid, name in touch.STROKE_STOPS.items()
                          if r["penetration_m"].get(cid, -1.0) > 0) or "no stop"
             for r in returns]
    return {"up_weight_g": float(ups.mean()),
            "spread_g": float(2 * ups.std(ddof=1)) if ups.size > 1 else 0.0,
            "per_press_g": [float(u) for u in ups], "stops": stops,
            "stop_dip_m": [float(r["stop_dip_m"]) for r in returns],
            "jack_off_stop_m": [max(0.0, -float(r["penetration_m"].get(5, 0.0)))
                                for r in returns]}


def compare_model(model: ActionModel, cfg: RigConfig, result: ct.TouchMeasurement
                  ) -> dict[str, Any]:
    """`rig measure touch --model`: the model's down- and up-weight for the presses just
    measured, beside the measured ones. Down: `rig touch`'s worked key (a slow press after
    a press and its return, the force where the key has gone its first 0.25 mm). Up: the
    rig's own presses in time on the model (``model_returns``: settle, the ramps, the
    conditioning presses first), then the force lowered from where each recorded press
    holds the key at its stop -- the stop, and so the up-weight, depends on how the key was
    pressed down (docs/touch.md, "The up-weight after a press in time"). Each figure:
    ``model_g``, ``measured_g``, their difference ``measured_minus_model_g`` and whether it
    is within the measurement's spread (``within_spread``); the up-weight also has the
    model's own spread over the presses (2 sd, ``model_spread_g``): `rig touch --presses`
    with the same settings prints the same up-weight."""
    from rig.model import touch

    down = touch.measure(model).worked_key()["down_weight"]
    ups = returns_summary(model_returns(model, cfg, result.ramps, trials=len(result.trials)))
    out: dict[str, Any] = {}
    for name, value, how in (
            ("down_weight", float(down), "rig touch's worked key"),
            ("up_weight", ups["up_weight_g"], "the rig's presses in time on the model, "
                                              "then a slow return from each stop")):
        f = result.figures[name]
        diff = f["mean_g"] - value
        out[name] = {"model_g": value, "measured_g": f["mean_g"], "spread_g": f["spread_g"],
                     "measured_minus_model_g": diff,
                     "within_spread": bool(abs(diff) <= f["spread_g"]), "how": how}
    out["up_weight"]["model_spread_g"] = ups["spread_g"]
    out["up_weight"]["model_per_trial_g"] = ups["per_press_g"]
    return out


def comparison_lines(cmp: dict[str, Any], model_file: Path | None) -> list[str]:
    """Lines for the terminal: each weight measured against the model's."""
    lines = [f"against the model {model_file if model_file else '(the base model)'}:"]
    for name in ("down_weight", "up_weight"):
        c = cmp[name]
        spread = (f" +- {c['model_spread_g']:.2f}" if "model_spread_g" in c else "")
        verdict = "within" if c["within_spread"] else "beyond"
        lines.append(f"  {name:<14}model {c['model_g']:6.2f} g{spread}, measured minus model "
                     f"{c['measured_minus_model_g']:+.2f} g: {verdict} the measured spread "
                     f"({c['spread_g']:.2f} g); model: {c['how']}")
    return lines


def _key_encoder(cfg: RigConfig) -> str:
    return next(n for n, e in cfg.channels.encoders.items() if e.channel_name == "key_dip")


DOCS = {"down_weight": "force at which the key goes down from rest (slow ramp up)",
        "up_weight": "force at which the key comes back up from its pressed stop (ramp down)",
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
    rule = (f"the weight is the force where the key had moved {r.threshold_mm:g} mm from its "
            f"rest / its pressed stop (travel rule)" if r.rule == "travel" else
            f"the weight is the force where the key left its elastic trend before it moved "
            f"{r.threshold_mm:g} mm (onset rule)")
    lines.append(f"{n} trials after {r.condition} conditioning press(es); +- is 2 x the "
                 f"trials' standard deviation (k = 2); the load cell's zero adds +- "
                 f"{result.load_cell_zero_g:.2f} g to every weight (k = 2, its record); ramps "
                 f"{r.from_g:g} -> {r.to_g:g} -> {r.low_g:g} g at {r.rate_g_s:g} g/s; {rule}")
    return lines


def document(result: ct.TouchMeasurement, record: Path, run_file: Path,
             model: dict[str, Any] | None = None) -> dict[str, Any]:
    """`rig measure touch --json`'s document (schema rig.measure-touch/1, docs/json.md);
    ``model``: ``compare_model``'s comparison (``--model``), else null."""
    return {"schema": "rig.measure-touch/1", "figures": result.figures,
            "per_trial_g": result.per_trial_g(), "rule": result.ramps.rule,
            "conditioning_presses": result.ramps.condition,
            "load_cell_zero_g": result.load_cell_zero_g,
            "record": str(record), "run_file": str(run_file), "model": model}
