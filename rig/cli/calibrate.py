"""`rig calibrate loadcell|strain|motor` and `rig check encoders` (parsing and printing; the
work is in rig.services.calibrate)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from rig.cli.common import _fail, app, console, err

# ---- rig calibrate / rig check: the work is in rig.services.calibrate ----
calibrate_app = typer.Typer(no_args_is_help=True,
                            help="Calibrate a sensor or the motor; writes a calibration record.")
check_app = typer.Typer(no_args_is_help=True, help="Check sensors on the rig.")
app.add_typer(calibrate_app, name="calibrate")
app.add_typer(check_app, name="check")

_RigOpt = Annotated[Path | None, typer.Option(
    "--rig", help="rig config YAML (default ./rig.yaml, else the built-in simulated rig)")]
_OperatorOpt = Annotated[str | None, typer.Option(help="who calibrates (default: login name)")]
_RecordsOpt = Annotated[Path | None, typer.Option(
    "--records", help="records folder (default calibration.records_folder or "
                      "<data_folder>/calibrations)")]


def _say(text: str) -> None:
    console.print(text, markup=False, highlight=False, soft_wrap=True)


def _rig_for_calibration(rig: Path | None):  # noqa: ANN202 - returns RigConfig
    from rig.inputs import config as rig_config

    try:
        cfg, which = rig_config.resolve(rig)
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    _say(which)
    return cfg


@calibrate_app.command("loadcell")
def calibrate_loadcell(
    rig: _RigOpt = None,
    points: Annotated[Path | None, typer.Option(
        "--points", help="CSV with mass_kg (and optionally reading_mv_per_v) per point, in "
                         "order; without it the command prompts for each mass")] = None,
    degree: Annotated[int, typer.Option(help="1 = linear (default), 2-3 = polynomial")] = 1,
    operator: _OperatorOpt = None,
    serial: Annotated[str | None, typer.Option(help="load cell serial number")] = None,
    records_dir: _RecordsOpt = None,
) -> None:
    """Known masses, loading then unloading (>= 5 points): fit, spec figures, uncertainty."""
    from rig.calibration.loadcell import read_csv
    from rig.calibration.settings import settings_for
    from rig.loop.backends import open_bench
    from rig.services import calibrate as svc

    cfg = _rig_for_calibration(rig)
    s = settings_for(cfg).load_cell

    def live(v: float) -> None:
        console.print(f"  reading {v * 1e3:+.5f} mV/V", end="\r", markup=False,
                      highlight=False)

    bench = open_bench(cfg)
    try:
        if points is not None:
            try:
                rows = read_csv(points)
                masses = [m for m, _ in rows]
                pts = svc.loadcell_points(cfg, bench, masses, [r for _, r in rows], live)
            except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
                raise _fail(exc) from None
        else:
            _say(f"Place each mass on the key top, loading up to the largest and then "
                 f"unloading (at least {s.min_points} masses). Each point is averaged for "
                 f"{s.average_s:g} s after {s.settle_s:g} s. Blank line to finish.")

            def ask(k: int) -> str:
                return str(typer.prompt(f"point {k}: mass on the key top (kg)", default="",
                                        show_default=False))

            try:
                pts = svc.loadcell_prompted(cfg, bench, ask, _say, live, lambda e: err.print(
                    f"refused: {e}", markup=False, highlight=False))
            except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
                raise _fail(exc) from None
    finally:
        bench.close()
    from rig.calibration.loadcell import analyse

    try:
        result = analyse(pts, cfg, s, degree)
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    for line in svc.summary_loadcell(result):
        _say(line)
    path = svc.save_loadcell(cfg, result, operator=operator, identifier=serial,
                             folder=records_dir)
    _say(f"wrote {path}")


@calibrate_app.command("strain")
def calibrate_strain(
    rig: _RigOpt = None,
    shunt_ohm: Annotated[float | None, typer.Option(
        help="shunt resistor, ohm (default calibration.strain_gauge.shunt_resistor_ohm)")] = None,
    operator: _OperatorOpt = None,
    serial: Annotated[str | None, typer.Option(help="gauge identifier")] = None,
    records_dir: _RecordsOpt = None,
) -> None:
    """Offset nulling with the shank at rest, then the shunt step; records the gain."""
    from rig.services import calibrate as svc

    cfg = _rig_for_calibration(rig)
    if not cfg.simulated:
        typer.confirm("Is the hammer shank at rest and untouched?", default=True, abort=True)
    try:
        result, path = svc.calibrate_strain(cfg, operator=operator, identifier=serial,
                                            folder=records_dir, shunt_ohm=shunt_ohm)
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    for line in svc.summary_strain(result):
        _say(line)
    _say(f"wrote {path}")


@calibrate_app.command("motor")
def calibrate_motor(
    rig: _RigOpt = None,
    profile: Annotated[Path | None, typer.Option(
        help="profile for the tracking report (default profiles/forte.yaml)")] = None,
    operator: _OperatorOpt = None,
    records_dir: _RecordsOpt = None,
) -> None:
    """Steps and ramps against a static surface: force map, lag, dynamic model."""
    from rig.services import calibrate as svc

    cfg = _rig_for_calibration(rig)
    if not cfg.simulated:
        typer.confirm("Is the arm pressing the static surface (key blocked), drive enabled?",
                      default=False, abort=True)
    try:
        result, path, track = svc.calibrate_motor(cfg, operator=operator, folder=records_dir,
                                                  profile=profile)
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    for line in svc.summary_motor(result, track):
        _say(line)
    _say(f"wrote {path}")


@check_app.command("encoders")
def check_encoders(rig: _RigOpt = None, operator: _OperatorOpt = None,
                   records_dir: _RecordsOpt = None) -> None:
    """Slow key travel: each encoder counts, in the right direction, at its resolution."""
    from rig.services import calibrate as svc

    cfg = _rig_for_calibration(rig)
    if not cfg.simulated:
        typer.confirm("Press the key slowly to the bottom and back while the check runs "
                      "(about 4 s). Ready?", default=True, abort=True)
    try:
        result, path = svc.check_encoders(cfg, operator=operator, folder=records_dir)
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    for name, r in result.results.items():
        _say(f"{name}: {'ok' if not r['problem'] else r['problem']} ({r['counts_range']:.0f} "
             f"counts" + (f", {r['ratio_to_model']:.3f} of the model" if "ratio_to_model" in r
                          else "") + ")")
    _say(f"wrote {path}")
    if not result.passed:
        raise typer.Exit(code=1)
# ---- end of rig calibrate / rig check ----
