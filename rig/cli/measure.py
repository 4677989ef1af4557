"""`rig measure touch` (parsing and printing; the work is in rig.services.measure_touch)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from rig.cli.calibrate import _OperatorOpt, _RecordsOpt, _rig_for_calibration, _RigOpt, _say
from rig.cli.common import (
    _ConditionOpt,
    _emit_json,
    _fail,
    _FromOpt,
    _JsonOpt,
    _LowOpt,
    _RateOpt,
    _ThresholdOpt,
    _ToOpt,
    app,
)

measure_app = typer.Typer(no_args_is_help=True,
                          help="Measure the action on the rig; writes a record runs embed.")
app.add_typer(measure_app, name="measure")


@measure_app.command("touch")
def measure_touch(
    rig: _RigOpt = None,
    trials: Annotated[int, typer.Option(help="presses (2 or more: the spread)")] = 5,
    from_g: _FromOpt = 25.0,
    to_g: _ToOpt = 70.0,
    low_g: _LowOpt = 10.0,
    rate: _RateOpt = 2.0,
    threshold: _ThresholdOpt = 0.25,
    rule: Annotated[str, typer.Option(
        help="the weight: travel (the force where the key has gone --threshold), onset (where "
             "it left its elastic trend before it), auto (onset on the simulated rig's "
             "regularised friction, travel on an action that sticks)")] = "auto",
    condition: _ConditionOpt = 1,
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="the presses' run file (.h5); default <data_folder>/<time>-"
                            "touch-ramps.h5")] = None,
    force: Annotated[bool, typer.Option("--force", help="overwrite the --out file")] = False,
    lockstep: Annotated[bool, typer.Option(
        help="simulated rig only: step as fast as possible instead of in real time")] = False,
    operator: _OperatorOpt = None,
    records_dir: _RecordsOpt = None,
    json_out: _JsonOpt = False,
    model: Annotated[Path | None, typer.Option(
        "--model", "-m", help="a model YAML to compare with: its down-weight (rig touch's "
                              "worked key) and the up-weight the same presses leave on it")
    ] = None,
) -> None:
    """Slow force ramps on the key: down-weight, up-weight, balance weight, friction."""
    from rig.calibration.touch import Ramps
    from rig.model.action import ActionModel
    from rig.services import measure_touch as svc

    try:  # a bad model file stops before the presses
        action = ActionModel.from_yaml(model) if model is not None else None
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None

    if json_out:  # (the document alone on stdout)
        from rig.inputs import config as rig_config

        try:
            cfg, _ = rig_config.resolve(rig)
        except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
            raise _fail(exc) from None
    else:
        cfg = _rig_for_calibration(rig)
    if not cfg.simulated:
        typer.confirm("Is the arm on the key top, the key free, the drive ready?",
                      default=False, abort=True)
    try:
        result, record, run_file = svc.measure_touch(
            cfg, Ramps(from_g=from_g, to_g=to_g, low_g=low_g, rate_g_s=rate,
                       threshold_mm=threshold, rule=rule, condition=condition),
            trials=trials, out=out, force=force,
            operator=operator, folder=records_dir, lockstep=lockstep,
            on_line=None if json_out else _say)
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    cmp: dict | None = None
    failed: Exception | None = None
    if action is not None:  # the measurement is recorded: a model that fails loses nothing
        try:
            cmp = svc.compare_model(action, cfg, result)
        except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
            failed = exc
    if json_out:
        _emit_json(svc.document(result, record, run_file, cmp))
    else:
        for line in svc.summary(result):
            _say(line)
        if cmp is not None:
            for line in svc.comparison_lines(cmp, model):
                _say(line)
        _say(f"run file {run_file}")
        _say(f"wrote {record}")
    if failed is not None:
        raise _fail(failed) from None
