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
    force_limit: Annotated[float, typer.Option(help="refuse profiles above this force, N")] = 120.0,
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


if __name__ == "__main__":  # pragma: no cover
    app()
