"""`rig calibrate loadcell|strain|motor` and `rig check encoders` (thin: procedure -> record).

Each function runs a procedure of rig.calibration on a bench (the simulated
rig or the NI cards), refuses bad data before anything is written, and writes
one record file into the records folder; it returns the result and the path.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from rig.calibration import loadcell as lc
from rig.calibration import records
from rig.calibration.settings import operator_name, records_folder, settings_for
from rig.daq import Bench
from rig.errors import InputError
from rig.inputs.config import RigConfig
from rig.loop.backends import open_bench

Live = Callable[[float], None] | None


def _identifier(given: str | None, default: str) -> str:
    return given or default


def loadcell_points(cfg: RigConfig, bench: Bench, masses: Sequence[float],
                    readings: Sequence[float | None] | None = None,
                    live: Live = None) -> list[lc.LoadPoint]:
    """Measure (or take from ``readings``, V/V) each mass's point; directions inferred."""
    s = settings_for(cfg).load_cell
    out = []
    for i, m in enumerate(masses):
        r = None if readings is None else readings[i]
        if r is None:
            out.append(lc.measure(bench, m, s, live))
        else:
            out.append((float(r), float("nan"), 1, abs(float(r))))
    return lc.make_points(list(masses), out)


def loadcell_prompted(cfg: RigConfig, bench: Bench, ask: Callable[[int], str],
                      say: Callable[[str], None], live: Live = None,
                      refused: Callable[[ValueError], None] | None = None) -> list[lc.LoadPoint]:
    """The bench loop of an interactive load-cell calibration: ``ask(k)`` the k-th mass
    (kg; a blank answer ends), measure it, ``say`` its reading; a mass that cannot be read,
    or the previous one again, is ``refused`` and asked again."""
    s = settings_for(cfg).load_cell
    masses: list[float] = []
    readings: list[float | None] = []
    while True:
        text = ask(len(masses) + 1).strip()
        if not text:
            break
        try:
            m = lc.parse_mass(text, f"points[{len(masses) + 1}] mass")
            if masses and m == masses[-1]:
                raise InputError(f"points[{len(masses) + 1}] mass: same as the previous point")
        except ValueError as exc:
            if refused is not None:
                refused(exc)
            continue
        r = lc.measure(bench, m, s, live)
        masses.append(m)
        readings.append(r[0])
        say(f"  {m:g} kg: {r[0] * 1e3:+.5f} mV/V (sd {r[1] * 1e3:.5f}, {r[2]} samples)")
    return loadcell_points(cfg, bench, masses, readings)


def save_loadcell(cfg: RigConfig, result: lc.LoadCellResult, *, operator: str | None = None,
                  identifier: str | None = None, folder: Path | None = None) -> Path:
    rec = records.build(
        "load_cell", cfg, identifier=_identifier(identifier, cfg.channels.load_cell
                                                 .physical_channel),
        operator=operator_name(cfg, operator), kind="known masses",
        units=lc.UNITS, raw_points=result.raw_points(), fit=result.fit,
        uncertainty=result.uncertainty, checks=result.checks,
        extra={"figures": result.figures, "settings": settings_for(cfg).load_cell.model_dump()})
    return records.write(records_folder(cfg, folder), rec)


def calibrate_loadcell(cfg: RigConfig, masses: Sequence[float],
                       readings: Sequence[float | None] | None = None, *, degree: int = 1,
                       bench: Bench | None = None, operator: str | None = None,
                       identifier: str | None = None, folder: Path | None = None,
                       live: Live = None) -> tuple[lc.LoadCellResult, Path]:
    """Measure, analyse and record a load-cell calibration (nothing written if refused)."""
    own = bench is None
    b = bench or open_bench(cfg)
    try:
        points = loadcell_points(cfg, b, masses, readings, live)
    finally:
        if own:
            b.close()
    result = lc.analyse(points, cfg, settings_for(cfg).load_cell, degree)
    return result, save_loadcell(cfg, result, operator=operator, identifier=identifier,
                                 folder=folder)


def summary_loadcell(result: lc.LoadCellResult) -> list[str]:
    """Lines for the terminal."""
    f, u, c = result.figures, result.uncertainty, result.checks

    def ok(v: Any) -> str:
        return "n/a" if v is None else ("ok" if v else "OUT OF SPEC")

    nr = f["nonrepeatability_pct_fs"]
    return [
        f"fit ({result.fit['model']}): {f['scale_n_per_mv_per_v']:.4f} N per mV/V "
        f"(sensitivity {f['sensitivity_mv_per_v_per_n']:.6f} mV/V per N), zero offset "
        f"{f['zero_offset_mv_per_v']:.5f} mV/V",
        f"non-linearity {f['nonlinearity_pct_fs']:.3f} % FS ({ok(c['nonlinearity_within_spec'])}"
        f"), hysteresis {f['hysteresis_pct_fs']:.3f} % FS "
        f"({ok(c['hysteresis_within_spec'])}), non-repeatability "
        + ("not measured (one cycle)" if nr is None else
           f"{nr:.3f} % FS ({ok(c['nonrepeatability_within_spec'])})")
        + " [spec +-0.5 / +-0.5 / +-0.1 % FS]",
        "residuals (N): " + " ".join(f"{r:+.3f}" for r in result.fit["residuals_n"]),
        f"expanded uncertainty (k=2): scale {u['sensitivity_relative'] * 100:.3f} %, zero "
        f"{u['offset_v_per_v'] * 1e3:.5f} mV/V, force at full scale "
        f"{u['force_at_full_scale']['expanded_n']:.3f} N, single sample "
        f"{u['single_sample_expanded_n']:.3f} N (spec bound {u['spec_error_bound_n']:.2f} N)",
    ]


def calibrate_strain(cfg: RigConfig, *, bench: Bench | None = None, operator: str | None = None,
                     identifier: str | None = None, folder: Path | None = None,
                     shunt_ohm: float | None = None) -> tuple[Any, Path]:
    """Null, shunt-calibrate and record the strain gauge (nothing written if refused)."""
    from rig.calibration import strain as sg

    s = settings_for(cfg).strain_gauge
    if shunt_ohm is not None:
        s = s.model_copy(update={"shunt_resistor_ohm": float(shunt_ohm)})
    own = bench is None
    b = bench or open_bench(cfg)
    try:
        result = sg.calibrate(cfg, b, s)
    finally:
        if own:
            b.close()
    rec = records.build(
        "strain_gauge", cfg, identifier=_identifier(
            identifier, cfg.channels.strain_gauge.physical_channel),
        operator=operator_name(cfg, operator), kind="offset nulling + shunt",
        units=sg.UNITS, raw_points=result.raw_points, fit=result.fit,
        uncertainty=result.uncertainty, checks=result.checks,
        extra={"settings": s.model_dump()})
    return result, records.write(records_folder(cfg, folder), rec)


def summary_strain(result: Any) -> list[str]:
    f, u = result.fit, result.uncertainty
    drv = f["driver_gain_adjustment"]
    return [
        f"offset at rest {f['offset'] * 1e3:.5f} mV/V (+-{u['offset_v_per_v'] * 1e3:.5f}, "
        f"{u['offset_strain'] * 1e6:.2f} microstrain, k=2)",
        f"shunt {f['shunt_resistor_ohm']:g} ohm: expected {f['shunt_equivalent_strain'] * 1e6:.1f}"
        f" microstrain, read {f['shunt_measured_strain'] * 1e6:.1f}; gain adjustment "
        f"{f['gain_adjustment']:.5f} (tolerance 1 +- {result.checks['tolerance']:g})"
        + ("" if drv is None else f"; NI driver's {drv:.5f}"),
        f"effective gauge factor {f['sensitivity']:.4f} (config {f['gage_factor_config']:g}, "
        f"lead {f['lead_wire_resistance_ohm']:g} ohm), expanded uncertainty "
        f"{u['sensitivity_relative'] * 100:.2f} % (k=2)",
    ]


def _load_cell_in_use(cfg: RigConfig) -> tuple[tuple[float, float], str]:
    """(sensitivity, offset) of the newest load-cell record (else nominal) and its source."""
    rec = records.records_for_run(cfg)["load_cell"]
    return (rec.sensitivity, rec.offset), rec.source


def calibrate_motor(cfg: RigConfig, *, bench: Bench | None = None, operator: str | None = None,
                    folder: Path | None = None, profile: Path | None = None
                    ) -> tuple[Any, Path, dict[str, dict[str, float]]]:
    """Steps and ramps on a static surface -> map, lag, dynamic model; tracking of a forte
    profile before (demand = profile) and after (map + lag); one record."""
    from rig.calibration import motor
    from rig.inputs import profiles

    s = settings_for(cfg).motor
    own = bench is None
    b = bench or open_bench(cfg)
    try:
        lc_cal, lc_src = _load_cell_in_use(cfg)
        demand, segs, force = motor.measure(cfg, b, s, lc_cal)
        result = motor.analyse(cfg, demand, segs, force, s)
        prof = profiles.load(profile or Path(__file__).resolve().parents[2] / "profiles" /
                             "forte.yaml", force_limit=cfg.limits.max_force_n)
        track = {
            "uncompensated": motor.tracking(cfg, b, prof, None, lc_cal),
            "uncompensated_shift_8ms": motor.tracking(cfg, b, prof, None, lc_cal, 0.008),
            "compensated": motor.tracking(cfg, b, prof, result.compensation, lc_cal),
        }
    finally:
        if own:
            b.close()
    rec = records.build(
        "motor", cfg, identifier=cfg.channels.drive_output.physical_channel,
        operator=operator_name(cfg, operator), kind="steps and ramps, static surface",
        units=motor.UNITS, raw_points=result.raw_points, fit=result.fit,
        uncertainty=result.uncertainty, checks=result.checks,
        extra={"tracking": {"profile": prof.name, **track}, "load_cell_used": lc_src,
               "settings": s.model_dump()})
    return result, records.write(records_folder(cfg, folder), rec), track


def summary_motor(result: Any, track: dict[str, dict[str, float]]) -> list[str]:
    f, u = result.fit, result.uncertainty
    dm = f["dynamic_model"]
    return [
        f"static map: {f['sensitivity']:.4f} N per N of demand, offset {f['offset']:+.3f} N "
        f"(table of {len(f['map_demand_n'])} points)",
        f"lag {f['lag_s'] * 1e3:.2f} ms (+-{u['lag_s'] * 1e3:.2f} ms, k=2; thesis ~8 ms)",
        f"dynamic model: K {dm['K']:.4f}, Tw {dm['Tw_s'] * 1e3:.2f} ms, zeta {dm['zeta']:.3f}, "
        f"Tp3 {dm['Tp3_s'] * 1e3:.2f} ms (RMS residual {dm['rms_residual_n']:.2f} N)",
        f"forte tracking, maximum error: uncompensated "
        f"{track['uncompensated']['max_error_pct']:.1f} % "
        f"({track['uncompensated_shift_8ms']['max_error_pct']:.1f} % after the thesis's 8 ms "
        f"shift), with map + lag {track['compensated']['max_error_pct']:.1f} % "
        f"(thesis best 6.5 %)",
    ]


def check_encoders(cfg: RigConfig, *, bench: Bench | None = None, operator: str | None = None,
                   folder: Path | None = None) -> tuple[Any, Path]:
    """Slow key travel; every encoder counts, in the right direction, at its resolution.
    The result is recorded (pass or fail) as an ``encoders`` record."""
    from rig.calibration import encoders

    own = bench is None
    b = bench or open_bench(cfg)
    try:
        result = encoders.check(cfg, b)
    finally:
        if own:
            b.close()
    rec = records.build(
        "encoders", cfg, identifier=",".join(e.counter for e in cfg.channels.encoders.values()),
        operator=operator_name(cfg, operator), kind="slow key travel check",
        units=encoders.UNITS, raw_points=result.results,
        fit={"sensitivity": None, "offset": None,
             "configured": {n: {"si_per_count": e.si_per_count, "sign": e.sign}
                            for n, e in cfg.channels.encoders.items()}},
        uncertainty={}, checks={"passed": result.passed, "failures": result.failures()})
    return result, records.write(records_folder(cfg, folder), rec)
