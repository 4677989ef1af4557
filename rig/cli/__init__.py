"""The `rig` command line (thin: parsing, printing; the work is in rig.services): the
commands, with ``rig calibrate`` / ``rig check`` in rig.cli.calibrate and what they all share
(the app, consoles, one-line errors, progress) in rig.cli.common."""

from __future__ import annotations

import gc
import math
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from rig.cli import calibrate as _calibrate  # noqa: F401 - registers rig calibrate / check
from rig.cli import measure as _measure  # noqa: F401 - registers rig measure touch
from rig.cli.common import (
    _analysis_progress,
    _bar,
    _ConditionOpt,
    _effect_names,
    _emit_json,
    _fail,
    _FromOpt,
    _JsonOpt,
    _LowOpt,
    _plain,
    _plain_err,
    _RateOpt,
    _ThresholdOpt,
    _ToOpt,
    _warn_unfinished,
    app,
    console,
    err,
    options,
)
from rig.errors import InputError, refuse_existing

__all__ = ["app", "main", "options"]

@app.command()
def simulate(
    profile: Annotated[Path, typer.Argument(help="force profile (YAML or CSV)")],
    out: Annotated[Path, typer.Option("--out", "-o", help="run file to write (.h5)")] = Path(
        "runs/simulated.h5"),
    model: Annotated[Path | None, typer.Option(
        "--model", "-m", help="model YAML (parameters, effects)")] = None,
    effect: Annotated[list[str] | None, typer.Option(
        "--effect", "-e", help="add an effect (library name, module:Class or file.py:Class)",
        autocompletion=_effect_names)] = None,
    params: Annotated[Path | None, typer.Option(help="YAML of parameter overrides")] = None,
    duration: Annotated[float | None, typer.Option(help="simulated time, s")] = None,
    integrator: Annotated[str | None, typer.Option(
        help="rosenbrock (default), dopri54, rk4, or scipy-<method> e.g. scipy-BDF")] = None,
    output_rate: Annotated[float | None, typer.Option(help="channel rate, Hz")] = None,
    force_limit: Annotated[float, typer.Option(
        help="refuse profiles above this force, N")] = 120.0,
    force: Annotated[bool, typer.Option("--force", help="replace an existing --out")] = False,
    as_json: _JsonOpt = False,
) -> None:
    """Simulate one blow of the action under PROFILE and write a run file."""
    from rig.services import simulate as svc

    try:
        refuse_existing(out, force)
        with _bar(err if as_json else console) as bar:
            task = bar.add_task("preparing the model (compiled on first use: about a minute)",
                                total=None, sim="")
            m = svc.build_model(model, effect or [], params, integrator, output_rate)

            def stage(text: str) -> None:
                bar.update(task, description=text)

            def progress(t: float, total: float) -> None:
                bar.update(task, total=total, completed=t, sim=f"{t:.3f}/{total:.3f} s")

            result = svc.simulate(profile, out, m, duration=duration, force_limit=force_limit,
                                  on_stage=stage, progress=progress)
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    s = result.summary()
    if as_json:
        _emit_json({"schema": "rig.simulate/1", "out": str(out), "success": result.success,
                    "message": result.message, "effects": list(m.effect_names),
                    "integrator": m.integrator.name,
                    "simulated_time_s": result.stats["simulated_time_s"],
                    "wall_time_s": result.stats["wall_time_s"], "summary": s,
                    "events": dict(result.events)})
        if not result.success:
            raise typer.Exit(code=1)
        return
    effects = ", ".join(m.effect_names) or "none (rigid base model)"
    console.print(f"model: effects {effects}; integrator {m.integrator.name}")
    if not result.success:
        err.print(f"simulation failed: {result.message}")
    console.print(f"simulated {result.stats['simulated_time_s']:.3f} s in "
                  f"{result.stats['wall_time_s']:.3f} s wall")
    speed = s["strike_speed_m_s"]
    if math.isfinite(speed):
        console.print(f"strike at {s['strike_s'] * 1e3:.2f} ms, hammer-head speed "
                      f"{speed:.2f} m/s, string contact {s['string_contact_s'] * 1e3:.2f} ms")
    else:
        console.print("the hammer did not reach the string")
    for name, t in result.events.items():
        shown = f"{t * 1e3:8.2f} ms" if math.isfinite(t) else "      --"
        console.print(f"  {name:<16} {shown}")
    console.print(f"wrote {out}")
    if not result.success:
        raise typer.Exit(code=1)


@app.command("import")
def import_cmd(
    files: Annotated[list[Path], typer.Argument(help="recordings: CSV, TSV, whitespace text, "
                                                "NI TDMS or HDF5 (every file one map)")],
    map_file: Annotated[Path, typer.Option("--map", help="the import map (YAML; "
                                           "docs/import.md)")],
    out: Annotated[Path, typer.Option("--out", "-o", help="run file to write (.h5)")],
    split_repeats: Annotated[bool | None, typer.Option(
        "--split-repeats/--keep-repeats",
        help="one trial per press of a repeated note (default: the map's segment section)")
    ] = None,
    whole: Annotated[bool, typer.Option(
        "--whole", help="no segmentation: each file is one trial")] = False,
    force: Annotated[bool, typer.Option("--force", help="replace an existing --out")] = False,
    as_json: _JsonOpt = False,
) -> None:
    """Import recordings through a map into a run file, one trial per stroke."""
    from rig.services import importer

    try:
        res = importer.import_files(files, map_file, out, force=force,
                                    split_repeats=split_repeats, segment=not whole)
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    if as_json:
        _emit_json({"schema": "rig.import/1", "out": str(out),
                    "files": [r.provenance() for r in res.recordings],
                    "segment_channel": res.segment_channel,
                    "trials": [t.as_dict() for t in res.trials],
                    "warnings": res.warnings})
        return
    for r in res.recordings:
        clipped = ", ".join(f"{k} {v}" for k, v in r.clipped.items() if v)
        _plain(f"{r.path}: {r.time.size} samples, {r.time[-1] - r.time[0]:.3f} s, sha256 "
               f"{r.sha256[:16]}" + (f"; clipped to the lookup table: {clipped}" if clipped
                                     else ""))
    if res.segment_channel is not None:
        from rig.sensors import display

        k, u = display.scale(res.segment_units)
        _plain(f"strokes found on {res.segment_channel}:")
        _plain(f"{'trial':>5} {'file':<24} {'onset s':>9} {'release s':>9} "
               f"{'length s':>8} {'peak ' + u:>10} {'presses':>7}")
        for t in res.trials:
            _plain(f"{t.trial:>5} {t.file[:24]:<24} {t.onset_s:>9.3f} {t.release_s:>9.3f} "
                   f"{t.duration_s:>8.3f} {t.peak * k:>10.4g} {t.presses:>7}")
    for w in res.warnings:
        _plain(f"warning: {w}")
    _plain(f"wrote {out}: {len(res.trials)} trial{'s' if len(res.trials) != 1 else ''}")


@app.command()
def info(run: Annotated[Path, typer.Argument(help="run file (.h5)")],
         as_json: _JsonOpt = False) -> None:
    """Summarize a run file: status, provenance, calibrations, loop statistics, and per
    trial its channels with value ranges and its events in time order."""
    from rig.services import info as svc

    try:
        r = svc.read(run)
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    if as_json:
        _emit_json(svc.document(run, r))
        return
    for line in svc.lines(run, r):
        _plain(line)


@app.command("plot")
def plot_cmd(
    run: Annotated[Path, typer.Argument(help="run file (.h5): simulated, synthetic or measured")],
    trial: Annotated[int, typer.Option(help="trial index")] = 0,
    channel: Annotated[list[str] | None, typer.Option(
        help="plot this channel; repeat (default: up to six, hammer and key first)")] = None,
    window: Annotated[str | None, typer.Option(
        help="time window START:END in s, e.g. 0.05:0.09")] = None,
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help=".html (interactive) or .png; default RUN-trialK.html")] = None,
    force: Annotated[bool, typer.Option(help="replace an existing --out")] = False,
) -> None:
    """A quick look at one trial of a run file, its events marked."""
    from rig.analysis import quicklook

    target = out if out is not None else run.with_name(f"{run.stem}-trial{trial}.html")
    try:
        quicklook.plot(run, target, trial=trial, channels=channel,
                       window=quicklook.parse_window(window), force=force)
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    _plain(f"wrote {target}")


@app.command("regulate")
def regulate(
    model: Annotated[Path | None, typer.Option(
        "--model", "-m", help="model YAML (parameters, effects)")] = None,
    to: Annotated[Path | None, typer.Option(
        "--to", help="targets YAML (m), e.g. rig/data/regulation-targets.yaml")] = None,
    write: Annotated[Path | None, typer.Option(help="model YAML to write (with --to)")] = None,
    force: Annotated[bool, typer.Option("--force", help="overwrite --write's file")] = False,
) -> None:
    """The model's regulation as a technician measures it (a slow key press), in mm; with
    --to, the regulating adjustments that meet the targets, written to --write."""
    from rig.model.regulation import FIGURE_DOCS
    from rig.services import regulate as svc

    try:
        reg = svc.regulate(model, to, write, force)
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    for name, value in reg.figures.items():
        target, label = svc.target_of(name, reg)
        shown = f"  ({label} {target * 1e3:.1f} mm)" if target is not None else ""
        _plain(f"{name:<17} {value * 1e3:7.2f} mm  {FIGURE_DOCS[name]}{shown}")
    for path, at in reg.points.items():
        _plain(f"adjusted {path}: y = {at[1] * 1e3:.3f} mm")
    if write is not None:
        svc.save(reg, write)
        _plain(f"wrote {write}")


@app.command("touch")
def touch(
    ctx: typer.Context,
    model: Annotated[Path | None, typer.Option(
        "--model", "-m", help="model YAML (parameters, effects)")] = None,
    as_json: _JsonOpt = False,
    plot: Annotated[Path | None, typer.Option(
        "--plot", help="write the key force along the slow press as an HTML page (Plotly)")
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="replace an existing --plot")] = False,
    accel: Annotated[float, typer.Option(
        "--accel", help="key-front acceleration (m/s^2) whose force to print")] = 10.0,
    presses: Annotated[int, typer.Option(
        "--presses", help="also press the model N times in time as rig measure touch "
                          "presses the key (the ramps below, the loop timing of --rig) and "
                          "print the up-weight each press's stop gives")] = 0,
    rig: Annotated[Path | None, typer.Option(
        "--rig", help="with --presses: the rig config whose loop timing the presses take "
                      "(default ./rig.yaml, else the built-in simulated rig)")] = None,
    from_g: _FromOpt = 25.0,
    to_g: _ToOpt = 70.0,
    low_g: _LowOpt = 10.0,
    rate: _RateOpt = 2.0,
    threshold: _ThresholdOpt = 0.25,
    condition: _ConditionOpt = 1,
) -> None:
    """The action's touch weights at the key front as a technician quotes them (down-, up-,
    balance weight, friction, strike and front weight, key and action ratios; docs/touch.md)."""
    from rig.calibration.touch import Ramps
    from rig.inputs import config as rig_config
    from rig.model import touch as tm
    from rig.services import touch as svc

    pressed = None
    try:
        refuse_existing(plot, force, "plot")
        if presses < 0:
            raise InputError(f"--presses: expected 0 (none) or more presses, got {presses}")
        if not presses:  # the press settings mean nothing without presses: say so
            for name, flag in (("rig", "--rig"), ("from_g", "--from"), ("to_g", "--to"),
                               ("low_g", "--low"), ("rate", "--rate"),
                               ("threshold", "--threshold"), ("condition", "--condition")):
                source = ctx.get_parameter_source(name)  # typer's own click: by name
                if source is not None and source.name == "COMMANDLINE":
                    raise InputError(f"{flag}: only with --presses N (it sets how the model "
                                     "is pressed in time)")
        ramps = Ramps(from_g=from_g, to_g=to_g, low_g=low_g, rate_g_s=rate,
                      threshold_mm=threshold, condition=condition)
        cfg, said = rig_config.resolve(rig) if presses else (None, "")
        if cfg is not None:  # the settings are refused before the model is solved
            ramps.check(cfg.limits.max_force_n)
        m, res = svc.touch(model)
        if cfg is not None:
            pressed = svc.presses(m, cfg, ramps, presses, said.removeprefix("rig config: "))
        if plot is not None:
            svc.write_plot(res, plot, f"Key force along a slow press: "
                           f"{model if model else 'base model'}", force)
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    if as_json:
        _emit_json(svc.document(m, res, model, accel, pressed))
        return
    for name in tm.FIGURES:
        value, units = res.figures[name], tm.UNITS[name]
        newtons = f"  ({res.newtons[name]:.4f} N)" if name in res.newtons else ""
        shown = f"{value:7.2f} {units}" if units == "g" else f"{value:7.3f}  "
        console.print(f"{name:<18} {shown}{newtons:<13}  {tm.FIGURE_DOCS[name]}",
                      markup=False, highlight=False, soft_wrap=True)
    if res.worked:
        w = res.worked_key()
        console.print(f"worked key: down {w['down_weight']:.2f} g at {w['down_dip_m'] * 1e3:.2f} "
                      f"mm, up {w['up_weight']:.2f} g at {w['up_dip_m'] * 1e3:.2f} mm (a press "
                      f"after a press and its return, from its rest at "
                      f"{w['rest_dip_m'] * 1e3:.3f} mm; rig measure touch's down-weight is "
                      "compared with it)",
                      markup=False, highlight=False, soft_wrap=True)
    elif "worked_key_failed" in res.method:
        console.print(f"worked key: not computed ({res.method['worked_key_failed']})",
                      markup=False, highlight=False, soft_wrap=True)
    console.print(f"key front: {res.key_front_radius_m * 1e3:.1f} mm from the balance pin; "
                  f"stroke {res.dip_m[0] * 1e3:.2f}-{res.dip_m[-1] * 1e3:.2f} mm of key-front "
                  f"dip, ended by: {res.stroke_end}", markup=False, highlight=False,
                  soft_wrap=True)
    console.print(f"mid-stroke: {res.method['mid_stroke_dip_m'] * 1e3:.2f} mm; weights are "
                  f"grams-force (N / {tm.G0} x 1000)", markup=False, highlight=False,
                  soft_wrap=True)
    push = tm.acceleration_force(res, accel)
    console.print(f"acceleration: {accel:g} m/s^2 at the key front needs {push:.3f} N "
                  f"({tm.grams(push):.1f} g) on top of the static force (inertia_mass x a)",
                  markup=False, highlight=False, soft_wrap=True)
    if pressed is not None:
        console.print(svc.presses_line(pressed), markup=False, highlight=False, soft_wrap=True)
    if plot is not None:
        console.print(f"wrote {plot}", markup=False, highlight=False, soft_wrap=True)


@app.command("effects")
def list_effects(as_json: _JsonOpt = False) -> None:
    """List the effect library: parameters and the residual each effect explains."""
    from rig.model.effects import BUILTIN

    if as_json:
        _emit_json({"schema": "rig.effects/1", "effects": [
            {"name": cls.name, "summary": cls.summary,
             "signature": {"kind": cls.signature.kind,
                           "frequency_hz": cls.signature.frequency_hz or None,
                           "channels": list(cls.signature.channels),
                           "phases": list(cls.signature.phases), "text": cls.signature.text},
             "parameters": [{"name": p.name, "default": p.default, "units": p.units,
                             "low": p.bounds[0], "high": p.bounds[1], "fitted": p.fitted,
                             "description": p.description} for p in cls.parameters]}
            for cls in BUILTIN.values()]})
        return

    for cls in BUILTIN.values():
        sig = cls.signature
        console.print(f"[bold]{cls.name}[/bold]: {cls.summary}")
        freq = f" at ~{sig.frequency_hz:g} Hz" if sig.frequency_hz else ""
        console.print(f"  signature: {sig.kind}{freq} in {', '.join(sig.channels)} during "
                      f"{', '.join(sig.phases)}: {sig.text}")
        for p in cls.parameters:
            fit = " (fitted)" if p.fitted else ""
            console.print(f"  - {p.name} = {p.default:g} {p.units} in [{p.bounds[0]:g}, "
                          f"{p.bounds[1]:g}]{fit}: {p.description}")


# ---- rig run: the torque loop and acquisition; the work is in rig.services.run ----
@app.command("run")
def run_profile(
    profile: Annotated[Path, typer.Argument(help="force profile (YAML or CSV)")],
    rig: Annotated[Path | None, typer.Option(
        "--rig", help="rig config YAML (default ./rig.yaml, else the built-in simulated rig)")
    ] = None,
    trials: Annotated[int, typer.Option(help="repeat the profile N times, resting between")] = 1,
    out: Annotated[Path | None, typer.Option("--out", "-o", help="run file to write (.h5); "
                                             "default <data_folder>/<time>-<profile>.h5")] = None,
    lockstep: Annotated[bool, typer.Option(
        help="simulated rig only: step as fast as possible instead of in real time")] = False,
    learn: Annotated[int, typer.Option(
        "--learn", help="learn the feedforward over N trials (ILC) and save it as a record")] = 0,
    learned: Annotated[bool, typer.Option(
        "--learned/--no-learned", help="use the learned-feedforward record of this profile "
        "if there is one")] = True,
    force: Annotated[bool, typer.Option(
        "--force", help="overwrite the --out file if it exists")] = False,
) -> None:
    """Press the key with PROFILE on the rig and record everything into a run file.

    Exit codes: 0 complete, 1 aborted (last line ``ABORTED: <reason>``), 2 refused input."""
    from rig.inputs import config as rig_config
    from rig.services import run as svc

    try:
        cfg, which = rig_config.resolve(rig)
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    # ---- --learn N, and the learned-feedforward record (rig.control.records) ----
    record = None
    if learn:
        if trials != 1:
            raise _fail(InputError("--learn: plays one trial per learning step; drop --trials"))
        from rig.services import learn as learn_svc

        _plain(which)
        try:
            lrep = learn_svc.learn(profile, cfg, learn, out=out, lockstep=lockstep,
                                   on_line=_plain, use_learned=learned)
        except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
            raise _fail(exc) from None
        if lrep.record is None:
            raise typer.Exit(code=1)
        return
    if learned:
        try:
            record = svc.learned_record(profile, cfg)
        except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
            raise _fail(exc) from None
    if record is not None:
        rec, rpath = record
        _plain(f"using the learned feedforward {rpath} ({len(rec['trials'])} trials, max error "
               f"{rec['final_error']['max_pct']:.2f} % of the peak; --no-learned to ignore it)")
    # ---- end of the learned feedforward ----
    _plain(which)
    try:
        report = svc.run(profile, cfg, trials=trials, out=out, lockstep=lockstep,
                         on_line=_plain, force=force, on_trace=_plain_err,
                         learned=record[0] if record else None)
    except svc.RunStopped as exc:
        err.print(f"ABORTED: {exc}", markup=False, highlight=False, soft_wrap=True)
        raise typer.Exit(code=1) from None
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    lat = report.lateness
    _plain(f"loop: {int(lat['cycles'])} cycles at {cfg.rates.control_hz:g} Hz, lateness "
                  f"median {lat['median_s'] * 1e3:.3f} ms, p99 {lat['p99_s'] * 1e3:.3f} ms, "
                  f"max {lat['max_s'] * 1e3:.3f} ms, missed {int(lat['missed'])}, late "
                  f"{int(lat['late_cycles'])}, "
                  + (f"real-time priority {int(lat['realtime_priority'])}"
                     if lat.get("realtime_priority") else "normal scheduling (no real-time "
                     "priority: see docs/running.md)")
                  + (f", pinned to CPU {int(lat['cpu'])}" if lat.get("cpu", -1) >= 0 else ""))
    if report.samples is not None:
        _plain(f"acquisition: {report.samples} samples at "
                      f"{cfg.rates.acquisition_hz:g} Hz, no gap")
    for name, r in report.repeatability.items():
        _plain(f"repeatability {name}: trial-to-trial RMS deviation {r['rms_deviation']:.3g} "
                      f"({r['relative'] * 100:.2f} % of its range)")
    _plain(f"wrote {report.path}")
    if not report.complete:
        reason = report.status.removeprefix("aborted:").strip()
        err.print(f"ABORTED: {reason}", markup=False, highlight=False, soft_wrap=True)
        raise typer.Exit(code=1)
# ---- end of rig run ----


@app.command()
def recover(
    run: Annotated[Path, typer.Argument(help="run file (.h5) with its journal RUN.h5.journal")],
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="write the rebuilt run file here instead of over RUN.h5")] = None,
    force: Annotated[bool, typer.Option("--force", help="replace an existing --out")] = False,
) -> None:
    """Rebuild a run file from the journal its run left beside it (a full disk, a killed or
    crashed run): every block the acquisition flushed, the loop's records, the status."""
    from rig.loop import journal

    try:
        rec = journal.recover(run, out=out, force=force)
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    torn = "; a last record cut short was dropped" if rec.torn else ""
    _plain(f"recovered {rec.path}: {rec.trials} trials, {rec.samples} samples, status "
           f"{rec.status}{torn}")




# ---- rig compare / diagnose / fit / synth: the work is in rig.analysis ----


@app.command("compare")
def compare_cmd(
    run: Annotated[Path, typer.Argument(help="run file (.h5): measured, synthetic or simulated")],
    model: Annotated[list[Path] | None, typer.Option(
        "--model", "-m", help="model YAML; repeat to compare models side by side")] = None,
    input: Annotated[str, typer.Option(
        help="what drives the models: force (measured), command (demand) or motion (key dip)")
    ] = "force",
    duration: Annotated[float | None, typer.Option(help="compare the first S seconds")] = None,
    trial: Annotated[list[int] | None, typer.Option(help="trial index (default 0); repeat")
                     ] = None,
    channel: Annotated[list[str] | None, typer.Option(help="compare only these channels")
                       ] = None,
    report: Annotated[Path | None, typer.Option(help="write an HTML report here")] = None,
    force: Annotated[bool, typer.Option("--force", help="replace an existing --report")
                     ] = False,
    as_json: _JsonOpt = False,
) -> None:
    """Drive each model with the run's measured input and tabulate its errors."""
    from rig.analysis import compare as cp
    from rig.services import compare as svc

    _warn_unfinished([run])
    try:
        refuse_existing(report, force, "report")
        with _bar() as bar:
            bar.add_task("simulating the models against the run", total=None, sim="")
            comps = svc.compare(run, model or [], input=input, duration=duration, trials=trial,
                                channels=channel, report_path=report)
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    if as_json:
        _emit_json({"schema": "rig.compare/1", "run": str(run),
                    "report": str(report) if report is not None else None,
                    "trials": [c.as_dict() for c in comps]})
    else:
        for comp in comps:
            console.print(cp.table(comp), markup=False, highlight=False, soft_wrap=True)
        if report is not None:
            console.print(f"wrote {report}", markup=False, highlight=False)
    if any(not m.ok for c in comps for m in c.models):
        raise typer.Exit(code=1)


@app.command("diagnose")
def diagnose_cmd(
    run: Annotated[Path, typer.Argument(help="run file (.h5)")],
    model: Annotated[Path | None, typer.Option("--model", "-m", help="model YAML (default: "
                                               "the rigid base model)")] = None,
    input: Annotated[str, typer.Option(help="force, command or motion")] = "force",
    duration: Annotated[float | None, typer.Option(help="use the first S seconds")] = None,
    trial: Annotated[list[int] | None, typer.Option(help="trial index; repeat (default all)")
                     ] = None,
    channel: Annotated[list[str] | None, typer.Option(help="use only these channels")] = None,
    candidate: Annotated[list[str] | None, typer.Option(
        help="try only these library effects (default: all not in the model)",
        autocompletion=_effect_names)] = None,
    extra: Annotated[list[str] | None, typer.Option(
        help="also try a user effect (module:Class or file.py:Class)")] = None,
    jobs: Annotated[int | None, typer.Option(help="processes (default: one per core)")] = None,
    single: Annotated[bool, typer.Option(
        "--single", help="rank each candidate alone (no joint search)")] = False,
    backward: Annotated[bool, typer.Option(
        "--backward", help="after the joint search, check each chosen effect is needed")
    ] = False,
    base: Annotated[bool, typer.Option(
        "--base", help="also try base parameters off by a factor (masses, inertias, felts, "
                       "springs, friction; docs/workflow.md)")] = False,
    write: Annotated[Path | None, typer.Option(
        help="save the model with the chosen effects and their fitted values here")] = None,
    report: Annotated[Path | None, typer.Option(help="write an HTML report here")] = None,
    scheduler: Annotated[str | None, typer.Option(
        help="Dask scheduler address (default: $RIG_SCHEDULER, else local processes)")] = None,
    force: Annotated[bool, typer.Option("--force", help="replace an existing --write / --report")
                     ] = False,
    as_json: _JsonOpt = False,
) -> None:
    """Where the model fails, and which library effect removes the residual."""
    from rig.services import diagnose as svc

    _warn_unfinished([run])
    try:
        refuse_existing(write, force, "write")
        refuse_existing(report, force, "report")
        with _bar() as bar:
            task = bar.add_task("fitting candidate effects", total=None, sim="")
            diag = svc.diagnose(run, model, input=input, duration=duration, trials=trial,
                                channels=channel, candidates=candidate, extra=extra or (),
                                jobs=jobs, single=single, backward=backward,
                                base_params=base, write=write,
                                report_path=report, scheduler=scheduler,
                                progress=_analysis_progress(bar, task))
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    if as_json:
        wrote = write is not None and diag.best is not None
        _emit_json({"schema": "rig.diagnose/1", "run": str(run),
                    "write": str(write) if wrote else None,
                    "report": str(report) if report is not None else None,
                    "diagnosis": diag.as_dict()})
        if write is not None and diag.best is None:
            raise typer.Exit(code=1)
        return
    for line in diag.report_lines():
        console.print(line, markup=False, highlight=False, soft_wrap=True)
    console.print(f"diagnosed in {diag.wall_s:.1f} s", markup=False, highlight=False)
    if write is not None and diag.best is None:
        bad = diag.worse_trial
        why = (f"the chosen set predicts {bad.label} worse than the base model" if bad else
               "the chosen set predicts the held-out data worse than the base model"
               if diag.withdrawn else "no candidate explains the residual significantly")
        err.print(f"{why}; {write} was not written",
                  markup=False, highlight=False, soft_wrap=True)
        raise typer.Exit(code=1)
    if write is not None:
        console.print(f"wrote {write}", markup=False, highlight=False)
    if report is not None:
        console.print(f"wrote {report}", markup=False, highlight=False)


@app.command("fit")
def fit_cmd(
    runs: Annotated[list[Path], typer.Argument(help="run files (.h5); every trial is used")],
    param: Annotated[list[str], typer.Option(
        help="parameter to fit: a path (contacts.4.D) or effect.param, optionally =LO:HI")],
    model: Annotated[Path | None, typer.Option("--model", "-m", help="model YAML")] = None,
    input: Annotated[str, typer.Option(help="force, command or motion")] = "force",
    duration: Annotated[float | None, typer.Option(help="use the first S seconds")] = None,
    channel: Annotated[list[str] | None, typer.Option(help="use only these channels")] = None,
    jobs: Annotated[int | None, typer.Option(help="processes (default: one per core)")] = None,
    max_nfev: Annotated[int, typer.Option(help="least-squares iterations at most")] = 40,
    write: Annotated[Path | None, typer.Option(help="save the fitted model YAML here")] = None,
    scheduler: Annotated[str | None, typer.Option(
        help="Dask scheduler address (default: $RIG_SCHEDULER, else local processes)")] = None,
    force: Annotated[bool, typer.Option("--force", help="replace an existing --write")] = False,
    as_json: _JsonOpt = False,
) -> None:
    """Fit model or effect parameters to one or many runs (scipy least squares)."""
    from rig.services import fit as svc

    _warn_unfinished(runs)
    try:
        refuse_existing(write, force, "write")
        with _bar() as bar:
            task = bar.add_task("fitting", total=None, sim="")
            res = svc.fit(runs, model, param, input=input, duration=duration, channels=channel,
                          jobs=jobs, max_nfev=max_nfev, write=write, scheduler=scheduler,
                          progress=_analysis_progress(bar, task))
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    from rig.analysis.stats import fmt

    if as_json:
        _emit_json({"schema": "rig.fit/1", "parameters": [
            {"name": t.label, "value": res.values[t.label], "sigma": res.sigma[t.label],
             "units": t.units, "start": t.value, "low": t.lo, "high": t.hi}
            for t in res.targets], "cost_start": res.cost_start, "cost": res.cost,
            "evaluations": res.nfev, "success": res.success, "message": res.message,
            "write": str(write) if write is not None else None})
        return
    for t in res.targets:
        console.print(f"{t.label} = {fmt(res.values[t.label], res.sigma[t.label], t.units)} "
                      f"(start {t.value:.6g}, bounds [{t.lo:.4g}, {t.hi:.4g}])",
                      markup=False, highlight=False)
    console.print(f"normalized mean square residual {res.cost_start:.4g} -> {res.cost:.4g} "
                  f"({res.nfev} evaluations; {res.message})", markup=False, highlight=False)
    if write is not None:
        console.print(f"wrote {write}", markup=False, highlight=False)


@app.command("synth")
def synth_cmd(
    model: Annotated[Path, typer.Option("--model", "-m", help="the truth model YAML")],
    profile: Annotated[list[Path], typer.Option(help="force profile; repeat for more trials")],
    out: Annotated[Path, typer.Option("--out", "-o", help="run file to write (.h5)")],
    seed: Annotated[int, typer.Option(help="seed of the sensors' truth and noise")] = 0,
    trials: Annotated[int, typer.Option(help="trials per profile (fresh noise each)")] = 1,
    duration: Annotated[float | None, typer.Option(help="simulated time per trial, s")] = None,
    rig: Annotated[Path | None, typer.Option("--rig", help="rig config YAML (default: the "
                                             "built-in simulated rig with a key rotary encoder)")
                   ] = None,
    load_cell_filter: Annotated[bool, typer.Option(
        help="filter the recorded force again in the load cell (4-pole, 100 Hz): it then "
             "lags the key force as on the real rig; the drive model already contains the "
             "filter as the thesis measured it")] = False,
    noise_scale: Annotated[float, typer.Option(help="scale on the sensors' noise")] = 1.0,
    record_truth: Annotated[bool, typer.Option(
        help="store the truth model in the file's metadata (off: the analysis cannot peek)")
    ] = False,
    force: Annotated[bool, typer.Option("--force", help="replace an existing --out")] = False,
) -> None:
    """Make a measurement-like run from a truth model through the drive and sensor models."""
    from rig.services import synth as svc

    try:
        refuse_existing(out, force)
        made = svc.synth(model, profile, out, seed=seed, trials=trials, duration=duration,
                         rig=rig, load_cell_filter=load_cell_filter, noise_scale=noise_scale,
                         record_truth=record_truth)
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    chans = [c for c in made[0].channels if c != "time"]
    console.print(f"{len(made)} trial(s), channels {', '.join(chans)}", markup=False,
                  highlight=False, soft_wrap=True)
    console.print(f"wrote {out}", markup=False, highlight=False)
# ---- end of rig compare / diagnose / fit / synth ----



# ---- rig sweep ----
@app.command("sweep")
def sweep_cmd(
    profile: Annotated[Path, typer.Option(help="force profile (YAML or CSV)")],
    param: Annotated[list[str], typer.Option(
        help="swept parameter NAME=LOW:HIGH: a path (contacts.12.D) or effect.param; repeat")],
    out: Annotated[Path, typer.Option("--out", "-o", help="sweep file to write (.h5)")],
    model: Annotated[Path | None, typer.Option("--model", "-m", help="model YAML")] = None,
    design: Annotated[str, typer.Option(help="grid, lhs or sobol")] = "sobol",
    samples: Annotated[int, typer.Option(
        help="grid: points per axis; lhs: rows; sobol: base samples (power of 2)")] = 64,
    seed: Annotated[int, typer.Option(help="seed of the lhs/sobol design")] = 0,
    duration: Annotated[float | None, typer.Option(help="simulated time per blow, s")] = None,
    scheduler: Annotated[str | None, typer.Option(
        help="Dask scheduler address (default: $RIG_SCHEDULER, else local processes)")] = None,
    jobs: Annotated[int | None, typer.Option(help="local processes (default: one per core)")
                    ] = None,
    resume: Annotated[bool, typer.Option(help="continue an interrupted sweep in --out")] = False,
    force: Annotated[bool, typer.Option(help="replace an existing --out / --report")] = False,
    report: Annotated[Path | None, typer.Option(help="write the indices as HTML here")] = None,
    batch: Annotated[int, typer.Option(help="blows per task sent to a worker")] = 1,
    touch: Annotated[bool, typer.Option(
        "--touch", help="also report each row's touch weights (down_weight_g, up_weight_g, "
        "...; rig touch, docs/touch.md)")] = False,
) -> None:
    """Blows over parameter ranges: per-blow metrics and Sobol sensitivity indices."""
    import signal
    import sys
    import time

    from rig.services import sweep as svc

    last = [0.0]
    stopping = [False]

    def on_sigint(signum: int, frame: object) -> None:  # finish the running blow, then stop
        if stopping[0]:
            raise KeyboardInterrupt
        stopping[0] = True
        print("sweep: stopping after the running blows (Ctrl-C again to stop at once)",
              file=sys.stderr, flush=True)

    previous = signal.signal(signal.SIGINT, on_sigint)

    def progress(done: int, total: int, eta: float) -> None:
        now = time.monotonic()
        if done == total or now - last[0] >= 2.0:
            last[0] = now
            print(f"sweep: {done}/{total} blows, ETA {eta:.0f} s", file=sys.stderr, flush=True)

    try:
        res, sens = svc.sweep(model, profile, param, out, design=design, samples=samples,
                              seed=seed, duration=duration, scheduler=scheduler, jobs=jobs,
                              resume=resume, force=force, report=report, batch=batch,
                              progress=progress, stop=lambda: stopping[0], touch=touch)
    except Exception as exc:  # noqa: BLE001 - _fail sorts input from internal errors
        raise _fail(exc) from None
    except (KeyboardInterrupt, SystemError) as exc:  # numba wraps a Ctrl-C in SystemError
        if not isinstance(exc, KeyboardInterrupt) and not stopping[0]:
            raise
        err.print(f"interrupted: the finished blows are in {out}; the same command with "
                  "--resume computes the rest", markup=False, highlight=False, soft_wrap=True)
        raise typer.Exit(code=130) from None
    finally:
        signal.signal(signal.SIGINT, previous)
    console.print(f"{res.rows} blows: {res.computed} computed, {res.reused} already in {out} "
                  f"({res.wall_s:.1f} s)", markup=False, highlight=False)
    if sens is not None:
        console.print("Sobol indices (first order S1, total order ST, 95 % half-widths):",
                      markup=False, highlight=False)
        for line in sens.lines():
            console.print(line, markup=False, highlight=False, soft_wrap=True)
    console.print(f"wrote {out}", markup=False, highlight=False)
    if report is not None:
        console.print(f"wrote {report}", markup=False, highlight=False)


def main() -> None:
    """The ``rig`` command (console script and ``python -m rig``): the app, then an exit
    that skips the interpreter's last garbage collection.

    That collection walks every object the command's imports made (numba's dispatchers
    and type system, the model, h5py): 0.08-0.1 s of every command that simulates
    (docs/performance.md). Nothing depends on it: the commands close and flush their
    files themselves, and ``atexit`` handlers and ``weakref.finalize`` still run.
    """
    # typer 0.28 parses with its own copy of click (pyproject.toml pins typer < 0.29)
    from typer._click import exceptions as click_errors

    code: Any = 0
    try:
        code = app(prog_name="rig", standalone_mode=False)
    except click_errors.NoArgsIsHelpError as exc:   # `rig`, `rig calibrate`: the help
        exc.show()
        code = exc.exit_code
    except click_errors.UsageError as exc:  # a mistyped command, option or value: one
        # line naming it and the command, exit 2 (issue 37; click's was a four-line box)
        where = exc.ctx.command_path if exc.ctx is not None else "rig"
        err.print(f"{where}: {exc.format_message()} (see '{where} --help')", markup=False,
                  highlight=False)
        code = exc.exit_code
    except click_errors.ClickException as exc:
        err.print(f"rig: {exc.format_message()}", markup=False, highlight=False)
        code = exc.exit_code
    except typer.Abort:
        err.print("Aborted.", markup=False, highlight=False)
        code = 1
    finally:
        gc.freeze()
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":  # pragma: no cover
    main()
