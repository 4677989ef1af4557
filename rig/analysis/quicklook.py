"""`rig plot`: a quick look at one trial of any run file (simulated, synthetic, measured).

Channels stacked on a time axis in ms (display units: mrad, mm, microstrain), the
trial's events as dotted lines. ``.html`` is an interactive Plotly page (plotly.js
embedded); ``.png`` is drawn with matplotlib (no browser or kaleido needed).
An existing output is never overwritten unless ``force``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rig.analysis import plots as pl
from rig.errors import InputError
from rig.recordings import runfile


def parse_window(text: str | None) -> tuple[float, float] | None:
    """``"0.05:0.09"`` (s) -> (0.05, 0.09); either side may be empty."""
    if text is None:
        return None
    lo, sep, hi = text.partition(":")
    try:
        if not sep:
            raise ValueError
        a = float(lo) if lo.strip() else -math.inf
        b = float(hi) if hi.strip() else math.inf
    except ValueError:
        raise InputError(f"window: expected START:END in seconds (e.g. 0.05:0.09), got "
                         f"{text!r}") from None
    if not a < b:
        raise InputError(f"window: START must be before END, got {text!r}")
    return a, b


def _trial(run: runfile.Run, k: int) -> runfile.Trial:
    if not 0 <= k < len(run.trials):
        raise InputError(f"trial: {k} is not a trial of {run.path} (it has {len(run.trials)})")
    tr = run.trials[k]
    if "time" not in tr.channels or tr.channels["time"].size < 2:
        raise InputError(f"{run.path}: trial {k} has no time channel")
    return tr


def channels_of(tr: runfile.Trial, names: Sequence[str] | None) -> list[str]:
    """The channels to plot: the named ones (checked), else the piano maker's first six."""
    one_d = [n for n, v in tr.channels.items() if n != "time" and np.ndim(v) == 1]
    if not names:
        return pl.pick_channels(one_d)
    for n in names:
        if n not in tr.channels or n == "time":
            raise InputError(f"channel: {n!r} is not a channel of this trial (it has "
                             f"{sorted(c for c in tr.channels if c != 'time')})")
    return list(names)


def _series(tr: runfile.Trial, name: str, mask: np.ndarray) -> tuple[list[tuple[str, np.ndarray]],
                                                                      str]:
    k, u = pl.scale(tr.units.get(name, ""))
    v = np.asarray(tr.channels[name], float)[mask]
    if v.ndim == 1:
        return [(name, v * k)], u
    cols = tr.columns.get(name, np.arange(v.shape[1]))
    return [(f"{name}[{c}]", v[:, j] * k) for j, c in enumerate(cols)], u


def plot(path: str | Path, out: str | Path, *, trial: int = 0,
         channels: Sequence[str] | None = None, window: tuple[float, float] | None = None,
         force: bool = False) -> Path:
    """Write the quick look of ``path``'s trial to ``out`` (.html or .png); returns ``out``."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".html", ".htm", ".png"):
        raise InputError(f"out: expected a .html or .png path, got {out}")
    if out.exists() and not force:
        raise InputError(f"out: {out} exists (use --force to replace it)")
    run = runfile.read(path)
    tr = _trial(run, trial)
    names, mask, tw, events = _selection(tr, channels, window, f"of trial {trial} ")
    title = (f"{Path(path).name} trial {trial}: {run.kind} run, status "
             f"{tr.attrs.get('status', run.status)}")
    out.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".png":
        _png(tr, names, mask, tw, events, title, out)
    else:
        _html(tr, names, mask, tw, events, title, out)
    return out


def figure(tr: runfile.Trial, channels: Sequence[str] | None = None,
           window: tuple[float, float] | None = None, title: str = "") -> Any:
    """The quick look of a trial as a Plotly figure (channels stacked, events marked)."""
    names, mask, tw, events = _selection(tr, channels, window)
    return _figure(tr, names, mask, tw, events, title)


def _selection(tr: runfile.Trial, channels: Sequence[str] | None,
               window: tuple[float, float] | None, which: str = ""
               ) -> tuple[list[str], np.ndarray, np.ndarray, dict[str, float]]:
    """The channels to plot, the window's mask and times, the events that happened."""
    names = channels_of(tr, channels)
    t = np.asarray(tr.time, float)
    lo, hi = window if window is not None else (-math.inf, math.inf)
    mask = (t >= lo) & (t <= hi)
    if mask.sum() < 2:
        raise InputError(f"window: no samples {which}in {lo:g}:{hi:g} s (the trial spans "
                         f"{t[0]:g} to {t[-1]:g} s)")
    events = {k: v for k, v in tr.events.items() if math.isfinite(v)}
    return names, mask, t[mask], events


def _figure(tr: runfile.Trial, names: list[str], mask: np.ndarray, tw: np.ndarray,
            events: dict[str, float], title: str) -> Any:
    fig = pl.stacked(names, title=title)
    pl.event_lines(fig, events, len(names), "", float(tw[0]), float(tw[-1]),
                   span=(float(tw[0]), float(tw[-1])))
    for r, name in enumerate(names, 1):
        series, u = _series(tr, name, mask)
        for j, (label, y) in enumerate(series):
            pl.line(fig, tw, y, r, label, pl.MODEL_COLOURS[j % len(pl.MODEL_COLOURS)]
                    if len(series) > 1 else "black", True, width=1.4)
        fig.update_yaxes(title_text=f"{name} [{u}]", title_font={"size": 12}, row=r, col=1)
    return fig


def _html(tr: runfile.Trial, names: list[str], mask: np.ndarray, tw: np.ndarray,
          events: dict[str, float], title: str, out: Path) -> None:
    fig = _figure(tr, names, mask, tw, events, title)
    ev = ", ".join(f"{pl.event_label(k)} {v * 1e3:.2f} ms" for k, v in
                   sorted(events.items(), key=lambda x: x[1])) or "none recorded"
    import html as _h

    body = [f"<h1>{_h.escape(title)}</h1>", f"<p>events: {_h.escape(ev)}</p>",
            pl.figure_html(fig, "fig1")]
    out.write_text(pl.page(title, body, 1), encoding="utf-8")


def _png(tr: runfile.Trial, names: list[str], mask: np.ndarray, tw: np.ndarray,
         events: dict[str, float], title: str, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(names), 1, figsize=(10, 1.9 * len(names) + 0.9), sharex=True,
                             squeeze=False)
    tms = tw * 1e3
    shown = sorted((v, k) for k, v in events.items() if tw[0] <= v <= tw[-1])
    for ax, name in zip(axes[:, 0], names, strict=True):
        series, u = _series(tr, name, mask)
        for label, y in series:
            ax.plot(tms, y, lw=1.0, label=label if len(series) > 1 else None,
                    color="black" if len(series) == 1 else None)
        for te, _ in shown:
            ax.axvline(te * 1e3, color="#555", ls=":", lw=0.8)
        ax.set_ylabel(f"{name}\n[{u}]", fontsize=9)
        ax.grid(alpha=0.3)
        if len(series) > 1:
            ax.legend(fontsize=6, ncol=4)
    top = axes[0, 0]
    for i, (te, k) in enumerate(shown):
        top.annotate(pl.event_label(k), (te * 1e3, 1.0), xycoords=("data", "axes fraction"),
                     xytext=(0, 2 + 10 * (i % 3)), textcoords="offset points", fontsize=8,
                     ha="center", va="bottom")
    axes[-1, 0].set_xlabel("time [ms]")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)
