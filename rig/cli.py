"""The `rig` command line (thin: parsing, printing; the work is in rig.services)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="Piano-action test rig: simulate, run, calibrate, compare.")
console = Console()
err = Console(stderr=True)


def _fail(exc: Exception) -> typer.Exit:
    err.print(f"error: {exc}", markup=False, highlight=False, soft_wrap=True)
    return typer.Exit(code=2)


@app.command()
def simulate(
    profile: Annotated[Path, typer.Argument(help="force profile (YAML or CSV)")],
    out: Annotated[Path, typer.Option("--out", "-o", help="run file to write (.h5)")] = Path(
        "runs/simulated.h5"),
    model: Annotated[Path | None, typer.Option(help="model YAML (parameters, effects)")] = None,
    effect: Annotated[list[str] | None, typer.Option(
        "--effect", "-e", help="add an effect (library name, module:Class or file.py:Class)")
    ] = None,
    params: Annotated[Path | None, typer.Option(help="YAML of parameter overrides")] = None,
    duration: Annotated[float | None, typer.Option(help="simulated time, s")] = None,
    integrator: Annotated[str | None, typer.Option(
        help="rosenbrock (default), dopri54, rk4, or scipy-<method> e.g. scipy-BDF")] = None,
    output_rate: Annotated[float | None, typer.Option(help="channel rate, Hz")] = None,
    force_limit: Annotated[float, typer.Option(
        help="refuse profiles above this force, N")] = 120.0,
) -> None:
    """Simulate one blow of the action under PROFILE and write a run file."""
    from rig.services import simulate as svc

    try:
        with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn(
                "{task.fields[sim]}"), TimeElapsedColumn(), console=console,
                transient=True) as bar:
            task = bar.add_task("preparing the model (compiled once, ~30 s on first use)",
                                total=None, sim="")
            m = svc.build_model(model, effect or [], params, integrator, output_rate)

            def stage(text: str) -> None:
                bar.update(task, description=text)

            def progress(t: float, total: float) -> None:
                bar.update(task, total=total, completed=t, sim=f"{t:.3f}/{total:.3f} s")

            result = svc.simulate(profile, out, m, duration=duration, force_limit=force_limit,
                                  on_stage=stage, progress=progress)
    except ValueError as exc:
        raise _fail(exc) from None
    s = result.summary()
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


@app.command()
def info(run: Annotated[Path, typer.Argument(help="run file (.h5)")]) -> None:
    """Summarize a run file: status, provenance, trials, channels, events."""
    from rig import runfile

    try:
        r = runfile.read(run)
    except ValueError as exc:
        raise _fail(exc) from None
    a = r.attrs
    console.print(f"{run}: {r.kind} run, status {r.status}", markup=False, highlight=False,
                  soft_wrap=True)
    console.print(f"created {a.get('created')} on {a.get('host')} by rig "
                  f"{a.get('software_version')} ({str(a.get('git_commit'))[:12]})",
                  markup=False, highlight=False, soft_wrap=True)
    model = r.metadata.get("model")
    if isinstance(model, dict):
        names = [e.get("name") for e in model.get("effects", [])]
        console.print(f"model effects: {', '.join(names) or 'none'}", markup=False,
                      soft_wrap=True)
    for i, tr in enumerate(r.trials):
        n = tr.time.size if "time" in tr.channels else 0
        span = f"{tr.time[-1] - tr.time[0]:.3f} s" if n > 1 else "-"
        console.print(f"trial {i}: {n} samples over {span}, status {tr.attrs.get('status')}",
                      markup=False, highlight=False, soft_wrap=True)
        for name, data in tr.channels.items():
            console.print(f"  {name:<28} {tr.units.get(name, ''):<6} {data.shape}",
                          markup=False, highlight=False, soft_wrap=True)
        for name, t in tr.events.items():
            shown = f"{t * 1e3:.2f} ms" if math.isfinite(t) else "--"
            console.print(f"  event {name:<22} {shown}", markup=False, highlight=False,
                          soft_wrap=True)


@app.command("effects")
def list_effects() -> None:
    """List the effect library: parameters and the residual each effect explains."""
    from rig.model.effects import BUILTIN

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


# ---- rig run (issue 4): the torque loop and acquisition; the work is in rig.services.run ----
def _plain(text: str) -> None:
    console.print(text, markup=False, highlight=False, soft_wrap=True)


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
) -> None:
    """Press the key with PROFILE on the rig and record everything into a run file."""
    from rig import config as rig_config
    from rig.services import run as svc

    try:
        cfg, which = rig_config.resolve(rig)
    except ValueError as exc:
        raise _fail(exc) from None
    _plain(which)
    try:
        report = svc.run(profile, cfg, trials=trials, out=out, lockstep=lockstep,
                         on_line=_plain)
    except (ValueError, RuntimeError) as exc:
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
    if not report.complete:
        err.print(f"run {report.status}", markup=False, highlight=False, soft_wrap=True)
    _plain(f"wrote {report.path}")
    if not report.complete:
        raise typer.Exit(code=1)
# ---- end of rig run ----


# ---- rig calibrate / rig check (issue 5): the work is in rig.services.calibrate ----
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
    from rig import config as rig_config

    try:
        cfg, which = rig_config.resolve(rig)
    except ValueError as exc:
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
    from rig.calibration.bench import open_bench
    from rig.calibration.loadcell import parse_mass, read_csv
    from rig.calibration.settings import settings_for
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
            except ValueError as exc:
                raise _fail(exc) from None
        else:
            _say(f"Place each mass on the key top, loading up to the largest and then "
                 f"unloading (at least {s.min_points} masses). Each point is averaged for "
                 f"{s.average_s:g} s after {s.settle_s:g} s. Blank line to finish.")
            masses, readings = [], []
            while True:
                text = typer.prompt(f"point {len(masses) + 1}: mass on the key top (kg)",
                                    default="", show_default=False).strip()
                if not text:
                    break
                try:
                    m = parse_mass(text, f"points[{len(masses) + 1}] mass")
                    if masses and m == masses[-1]:
                        raise ValueError(f"points[{len(masses) + 1}] mass: same as the "
                                         f"previous point")
                except ValueError as exc:
                    err.print(f"refused: {exc}", markup=False, highlight=False)
                    continue
                from rig.calibration.loadcell import measure

                r = measure(bench, m, s, live)
                masses.append(m)
                readings.append(r[0])
                _say(f"  {m:g} kg: {r[0] * 1e3:+.5f} mV/V (sd {r[1] * 1e3:.5f}, {r[2]} "
                     f"samples)")
            try:
                pts = svc.loadcell_points(cfg, bench, masses, readings)
            except ValueError as exc:
                raise _fail(exc) from None
    finally:
        bench.close()
    from rig.calibration.loadcell import analyse

    try:
        result = analyse(pts, cfg, s, degree)
    except ValueError as exc:
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
    if cfg.backend != "sim":
        typer.confirm("Is the hammer shank at rest and untouched?", default=True, abort=True)
    try:
        result, path = svc.calibrate_strain(cfg, operator=operator, identifier=serial,
                                            folder=records_dir, shunt_ohm=shunt_ohm)
    except (ValueError, RuntimeError) as exc:
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
    if cfg.backend != "sim":
        typer.confirm("Is the arm pressing the static surface (key blocked), drive enabled?",
                      default=False, abort=True)
    try:
        result, path, track = svc.calibrate_motor(cfg, operator=operator, folder=records_dir,
                                                  profile=profile)
    except (ValueError, RuntimeError) as exc:
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
    if cfg.backend != "sim":
        typer.confirm("Press the key slowly to the bottom and back while the check runs "
                      "(about 4 s). Ready?", default=True, abort=True)
    try:
        result, path = svc.check_encoders(cfg, operator=operator, folder=records_dir)
    except (ValueError, RuntimeError) as exc:
        raise _fail(exc) from None
    for name, r in result.results.items():
        _say(f"{name}: {'ok' if not r['problem'] else r['problem']} ({r['counts_range']:.0f} "
             f"counts" + (f", {r['ratio_to_model']:.3f} of the model" if "ratio_to_model" in r
                          else "") + ")")
    _say(f"wrote {path}")
    if not result.passed:
        raise typer.Exit(code=1)
# ---- end of rig calibrate / rig check ----


# ---- rig compare / diagnose / fit / synth (issue 6): the work is in rig.analysis ----
from collections.abc import Callable  # noqa: E402


def _analysis_progress(bar: Progress, task: object) -> Callable[[float, float, str], None]:
    def update(done: float, total: float, text: str = "") -> None:
        bar.update(task, total=total, completed=done, sim=text)  # type: ignore[arg-type]

    return update


def _bar() -> Progress:
    return Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[sim]}"),
                    TimeElapsedColumn(), console=err, transient=True)


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
) -> None:
    """Drive each model with the run's measured input and tabulate its errors."""
    from rig.analysis import compare as cp
    from rig.services import compare as svc

    try:
        with _bar() as bar:
            bar.add_task("simulating the models against the run", total=None, sim="")
            comps = svc.compare(run, model or [], input=input, duration=duration, trials=trial,
                                channels=channel, report_path=report)
    except (ValueError, RuntimeError) as exc:
        raise _fail(exc) from None
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
        help="try only these library effects (default: all not in the model)")] = None,
    extra: Annotated[list[str] | None, typer.Option(
        help="also try a user effect (module:Class or file.py:Class)")] = None,
    jobs: Annotated[int | None, typer.Option(help="processes (default: one per core)")] = None,
    single: Annotated[bool, typer.Option(
        "--single", help="rank each candidate alone (no joint search)")] = False,
    backward: Annotated[bool, typer.Option(
        "--backward", help="after the joint search, check each chosen effect is needed")
    ] = False,
    write: Annotated[Path | None, typer.Option(
        help="save the model with the chosen effects and their fitted values here")] = None,
    report: Annotated[Path | None, typer.Option(help="write an HTML report here")] = None,
) -> None:
    """Where the model fails, and which library effect removes the residual."""
    from rig.services import diagnose as svc

    try:
        with _bar() as bar:
            task = bar.add_task("fitting candidate effects", total=None, sim="")
            diag = svc.diagnose(run, model, input=input, duration=duration, trials=trial,
                                channels=channel, candidates=candidate, extra=extra or (),
                                jobs=jobs, single=single, backward=backward, write=write,
                                report_path=report,
                                progress=_analysis_progress(bar, task))
    except (ValueError, RuntimeError) as exc:
        raise _fail(exc) from None
    for line in diag.report_lines():
        console.print(line, markup=False, highlight=False, soft_wrap=True)
    console.print(f"diagnosed in {diag.wall_s:.1f} s", markup=False, highlight=False)
    if write is not None and diag.best is None:
        err.print(f"no candidate explains the residual significantly; {write} was not written",
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
) -> None:
    """Fit model or effect parameters to one or many runs (scipy least squares)."""
    from rig.services import fit as svc

    try:
        with _bar() as bar:
            task = bar.add_task("fitting", total=None, sim="")
            res = svc.fit(runs, model, param, input=input, duration=duration, channels=channel,
                          jobs=jobs, max_nfev=max_nfev, write=write,
                          progress=_analysis_progress(bar, task))
    except (ValueError, RuntimeError) as exc:
        raise _fail(exc) from None
    from rig.analysis.stats import fmt

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
        help="pass the force through the load cell's 4-pole filter")] = True,
    noise_scale: Annotated[float, typer.Option(help="scale on the sensors' noise")] = 1.0,
    record_truth: Annotated[bool, typer.Option(
        help="store the truth model in the file's metadata (off: the analysis cannot peek)")
    ] = False,
) -> None:
    """Make a measurement-like run from a truth model through the drive and sensor models."""
    from rig.services import synth as svc

    try:
        made = svc.synth(model, profile, out, seed=seed, trials=trials, duration=duration,
                         rig=rig, load_cell_filter=load_cell_filter, noise_scale=noise_scale,
                         record_truth=record_truth)
    except (ValueError, RuntimeError) as exc:
        raise _fail(exc) from None
    chans = [c for c in made[0].channels if c != "time"]
    console.print(f"{len(made)} trial(s), channels {', '.join(chans)}", markup=False,
                  highlight=False, soft_wrap=True)
    console.print(f"wrote {out}", markup=False, highlight=False)
# ---- end of rig compare / diagnose / fit / synth ----


if __name__ == "__main__":  # pragma: no cover
    app()
