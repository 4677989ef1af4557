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
        help="dopri54 (default), rk4, or scipy-<method> e.g. scipy-BDF")] = None,
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
    console.print(which, markup=False, highlight=False, soft_wrap=True)
    try:
        report = svc.run(profile, cfg, trials=trials, out=out, lockstep=lockstep,
                         on_line=lambda s: console.print(s, markup=False, highlight=False, soft_wrap=True))
    except (ValueError, RuntimeError) as exc:
        raise _fail(exc) from None
    lat = report.lateness
    console.print(f"loop: {int(lat['cycles'])} cycles at {cfg.rates.control_hz:g} Hz, lateness "
                  f"median {lat['median_s'] * 1e3:.3f} ms, p99 {lat['p99_s'] * 1e3:.3f} ms, "
                  f"max {lat['max_s'] * 1e3:.3f} ms, missed {int(lat['missed'])}, late "
                  f"{int(lat['late_cycles'])}", markup=False, highlight=False, soft_wrap=True)
    if report.samples is not None:
        console.print(f"acquisition: {report.samples} samples at "
                      f"{cfg.rates.acquisition_hz:g} Hz, no gap", markup=False, highlight=False, soft_wrap=True)
    for name, r in report.repeatability.items():
        console.print(f"repeatability {name}: trial-to-trial RMS deviation {r['rms_deviation']:.3g} "
                      f"({r['relative'] * 100:.2f} % of its range)", markup=False, highlight=False, soft_wrap=True)
    if not report.complete:
        err.print(f"run {report.status}", markup=False, highlight=False, soft_wrap=True)
    console.print(f"wrote {report.path}", markup=False, highlight=False, soft_wrap=True)
    if not report.complete:
        raise typer.Exit(code=1)
# ---- end of rig run ----


if __name__ == "__main__":  # pragma: no cover
    app()
