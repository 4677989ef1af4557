"""What every command of the `rig` command line shares: the app, the consoles, the global
options, one-line errors (``fail``), plain lines and JSON on stdout, the progress display."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console

from rig.errors import InputError

app = typer.Typer(add_completion=True, no_args_is_help=True,
                  help="Piano-action test rig: simulate, run, calibrate, compare.")
console = Console(soft_wrap=True)  # off a terminal: no wrapping at 80 columns
err = Console(stderr=True, soft_wrap=True)


def _version(value: bool) -> None:
    if value:
        from rig.recordings.runfile import git_commit
        from rig.version import __version__

        console.print(f"rig {__version__} (git {git_commit()[:12]})", markup=False,
                      highlight=False)
        raise typer.Exit()


@app.callback()
def _main(version: Annotated[bool, typer.Option(
        "--version", callback=_version, is_eager=True, help="print the version and exit")
] = False, verbose: Annotated[bool, typer.Option(
        "--verbose", "-v", help="tracebacks of internal errors")] = False,
        quiet: Annotated[bool, typer.Option(
            "--quiet", "-q", help="no progress display (results and errors only)")] = False,
) -> None:
    """Piano-action test rig: simulate, run, calibrate, compare."""
    options.verbose, options.quiet = verbose, quiet


_JsonOpt = Annotated[bool, typer.Option(
    "--json", help="print one JSON document instead of text (schemas: docs/json.md)")]


# the slow force ramps of `rig measure touch` (and of `rig touch --presses`, which presses
# the model as they press the key): rig.calibration.touch.Ramps
_FromOpt = Annotated[float, typer.Option(
    "--from", help="g at the key top where the slow ramp up begins (under the down-weight)")]
_ToOpt = Annotated[float, typer.Option(
    "--to", help="g at the key top where the ramp up ends (over the down-weight)")]
_LowOpt = Annotated[float, typer.Option(
    "--low", help="g at the key top where the ramp down ends (under the up-weight)")]
_RateOpt = Annotated[float, typer.Option(help="ramp rate, g per second")]
_ThresholdOpt = Annotated[float, typer.Option(
    help="mm of key travel, from its rest / its pressed stop, at which the key has gone")]
_ConditionOpt = Annotated[int, typer.Option(
    help="conditioning presses before the recorded trials (not recorded)")]


def _emit_json(doc: dict[str, Any]) -> None:
    """One JSON document on stdout (NaN and infinities as null), nothing else."""
    import json

    def clean(v: Any) -> Any:
        if isinstance(v, float):
            return v if math.isfinite(v) else None
        if isinstance(v, dict):
            return {str(k): clean(x) for k, x in v.items()}
        if isinstance(v, list | tuple):
            return [clean(x) for x in v]
        if hasattr(v, "item") and callable(v.item):  # numpy scalars
            return clean(v.item())
        return v

    print(json.dumps(clean(doc), allow_nan=False))


def _effect_names(incomplete: str) -> list[str]:
    """Shell completion of effect names (the library's)."""
    from rig.model.effects import BUILTIN

    return [n for n in BUILTIN if n.startswith(incomplete)]


class _Options:
    """The global options (``rig -v``, ``rig -q``)."""

    verbose = False
    quiet = False


options = _Options()


def _plain(text: str) -> None:
    console.print(text, markup=False, highlight=False, soft_wrap=True)


def _plain_err(text: str) -> None:
    err.print(text, markup=False, highlight=False, soft_wrap=True)


def _fail(exc: Exception) -> typer.Exit:
    """The user's bad input (InputError): one line, exit 2. Anything else failed inside rig
    or a library: one line and exit 1, the traceback with ``rig -v``."""
    if isinstance(exc, InputError):
        err.print(f"error: {exc}", markup=False, highlight=False, soft_wrap=True)
        return typer.Exit(code=2)
    if options.verbose:
        import traceback

        err.print("".join(traceback.format_exception(exc)), markup=False, highlight=False,
                  soft_wrap=True)
    hint = "" if options.verbose else " (`rig -v ...` shows the traceback)"
    err.print(f"error: {type(exc).__name__}: {exc}{hint}", markup=False, highlight=False,
              soft_wrap=True)
    return typer.Exit(code=1)


def _analysis_progress(bar: Any, task: object) -> Callable[[float, float, str], None]:
    def update(done: float, total: float, text: str = "") -> None:
        bar.update(task, total=total, completed=done, sim=text)

    return update


def _warn_unfinished(runs: list[Path]) -> None:
    """One line on stderr for each run file that is aborted or still running."""
    from rig.analysis.measurement import status_warning

    for path in runs:
        text = status_warning(path)
        if text:
            err.print(text, markup=False, highlight=False, soft_wrap=True)


class _LineProgress:
    """Progress as plain lines on stderr when stderr is not a terminal (pipes, logs,
    notebooks): a line when the stage changes and at most one every ``every`` seconds;
    nothing with ``rig -q``. The subset of rich's Progress the commands use."""

    def __init__(self, every: float = 2.0, quiet: bool = False) -> None:
        import time

        self._clock = time.monotonic
        self.every, self.quiet = every, quiet
        self._tasks: dict[int, dict[str, Any]] = {}
        self._last = -math.inf
        self._t0 = self._clock()

    def __enter__(self) -> _LineProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def add_task(self, description: str, total: float | None = None, **fields: Any) -> int:
        k = len(self._tasks)
        self._tasks[k] = {"description": description, "total": total, "completed": 0.0,
                          **fields}
        self._say(self._tasks[k], force=True)
        return k

    def update(self, task: int, **changes: Any) -> None:
        t = self._tasks[task]
        new_stage = "description" in changes and changes["description"] != t["description"]
        t.update(changes)
        self._say(t, force=new_stage)

    def _say(self, t: dict[str, Any], force: bool) -> None:
        now = self._clock()
        if self.quiet or not (force or now - self._last >= self.every):
            return
        self._last = now
        done = ""
        if t.get("total"):
            done = f" {100 * float(t['completed']) / float(t['total']):.0f} %"
        extra = f" {t['sim']}" if t.get("sim") else ""
        import sys

        print(f"rig: {t['description']}{done}{extra} ({now - self._t0:.0f} s)",
              file=sys.stderr, flush=True)


def _bar(console_: Console | None = None) -> Any:
    """The progress display: a bar on a terminal, plain lines on stderr off one, nothing
    with -q."""
    target = console_ or err
    if options.quiet or not target.is_terminal:
        return _LineProgress(quiet=options.quiet)
    # rich.progress only on a terminal (it imports some 30 of rich's modules)
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    return Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[sim]}"),
                    TimeElapsedColumn(), console=target, transient=True)
